"""The gear evaluation, collection and sweep on two Ray workers give exactly what one
worker gives, and an episode whose worker dies is run again, once, on another."""

import csv
import dataclasses
import os
from pathlib import Path
from typing import Any

import gymnasium as gym
import pytest
from typer.testing import CliRunner

from dynoplan.cli.main import app
from dynoplan.envs.gear.controllers import GEAR_CONTROL
from dynoplan.envs.gear.option_runs import collect_gear_transitions
from dynoplan.envs.gear.pipeline_task import GearTask
from dynoplan.parallel import SERIAL, Workers, parallel_map
from dynoplan.pipeline.evaluate import ControllerJob
from dynoplan.pipeline.jobs import build_runner, evaluate_many
from dynoplan.seeding import episode_seeds

pytestmark = pytest.mark.slow

QUICK_PLANNER = dataclasses.replace(GEAR_CONTROL, horizon=6, samples=32)
EPISODES = 4


def _comparable(metrics: Any) -> dict[str, Any]:
    """Everything but the wall-clock decision latencies."""
    d = dataclasses.asdict(metrics)
    d.pop("decision_ms")
    return d


def _assert_same_dataset(one: dict[str, Any], two: dict[str, Any], a: Path, b: Path) -> None:
    """Two runs' summaries agree (but for the folder) and their folders byte for byte."""
    assert {k: v for k, v in one.items() if k != "dataset"} == \
        {k: v for k, v in two.items() if k != "dataset"}
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert files
    for f in files:
        assert (a / f).read_bytes() == (b / f).read_bytes(), f


def evaluate(job: ControllerJob, seeds: list[Any], workers: Workers = SERIAL) -> list[Any]:
    return evaluate_many([(job, seeds)], workers)[0]


@pytest.fixture(scope="module")
def job(quick_gear_run: Path) -> ControllerJob:
    return ControllerJob(GearTask(), quick_gear_run / "models", "dynoplan", QUICK_PLANNER)


@pytest.fixture(scope="module")
def serial(job: ControllerJob) -> list[Any]:
    return evaluate(job, episode_seeds(7, EPISODES), SERIAL)


def test_gear_evaluation_is_identical_on_one_and_two_workers(ray_runtime, job, serial):
    parallel = evaluate(job, episode_seeds(7, EPISODES), Workers(2))
    assert [_comparable(m) for m in parallel] == [_comparable(m) for m in serial]
    assert [m.env_seed for m in parallel] == [s.env_seed for s in episode_seeds(7, EPISODES)]


def test_a_worker_dying_mid_episode_is_retried_without_losing_or_repeating_one(
        ray_runtime, job, serial, tmp_path: Path):
    marker, log = tmp_path / "died-once", tmp_path / "completed"

    class DiesAtStep30(gym.Wrapper):
        def __init__(self, env: gym.Env) -> None:
            super().__init__(env)
            self.steps = 0

        def step(self, action):
            self.steps += 1
            if self.steps == 30:
                os._exit(1)  # the worker process dies in the middle of the episode
            return self.env.step(action)

    def dies_once(runner, seed):
        if seed.index == 1 and not marker.exists():
            marker.touch()
            runner = dataclasses.replace(runner, env=DiesAtStep30(runner.env))
        metrics = runner.episode(seed)
        with log.open("a") as f:
            f.write(f"{seed.index}\n")
        return metrics

    parallel = parallel_map(build_runner, dies_once, job, episode_seeds(7, EPISODES),
                            Workers(2))
    assert marker.exists()
    assert sorted(int(i) for i in log.read_text().split()) == list(range(EPISODES))
    assert [_comparable(m) for m in parallel] == [_comparable(m) for m in serial]


def test_collection_writes_the_same_dataset_on_two_workers(ray_runtime, quick_gear_run,
                                                           tmp_path: Path):
    models = quick_gear_run / "models"
    one = collect_gear_transitions(models, 1, 3, tmp_path / "one", max_decisions=3, progress=False)
    two = collect_gear_transitions(models, 1, 3, tmp_path / "two", max_decisions=3, progress=False,
                              workers=Workers(2))
    _assert_same_dataset(one, two, tmp_path / "one", tmp_path / "two")


def test_sweep_command_on_two_workers_then_resumed(ray_runtime, quick_gear_run,
                                                   tmp_path: Path):
    config = tmp_path / "grid.toml"
    config.write_text(f'models = "{quick_gear_run / "models"}"\nepisodes = 1\n'
                      '[grid]\nhorizon = [3, 6]\nsamples = [16]\n')
    out = tmp_path / "out"
    args = ["sweep", str(config), "--out", str(out), "--workers", "2", "--quiet"]
    first = CliRunner().invoke(app, args)
    assert first.exit_code == 0, first.output
    assert "2 cells (2 run, 0 already finished)" in first.output
    with (out / "results.csv").open() as f:
        assert [r["horizon"] for r in csv.DictReader(f)] == ["3", "6"]
    again = CliRunner().invoke(app, args)
    assert again.exit_code == 0 and "(0 run, 2 already finished)" in again.output


def test_demonstrations_are_the_same_dataset_on_two_workers(ray_runtime, quick_gear_run,
                                                            tmp_path: Path):
    from dynoplan.envs.gear.demonstrations import record_demos

    models = quick_gear_run / "models"
    one = record_demos(3, 5, tmp_path / "one", False, demonstrator="options", models=models)
    two = record_demos(3, 5, tmp_path / "two", False, demonstrator="options", models=models,
                       workers=Workers(2))
    _assert_same_dataset(one, two, tmp_path / "one", tmp_path / "two")


def test_option_network_data_is_the_same_on_two_workers_in_any_order(ray_runtime):
    import numpy as np

    from dynoplan.envs.gear.options.catalog import (
        NetworkData,
        build_network_data,
        network_data_episode,
    )

    for option in ("pick", "insert"):
        job = NetworkData(option, 3)
        serial = parallel_map(build_network_data, network_data_episode, job, [0, 1, 2])
        backwards = parallel_map(build_network_data, network_data_episode, job, [2, 1, 0])
        parallel = parallel_map(build_network_data, network_data_episode, job, [0, 1, 2],
                                Workers(2))
        for a, b, c in zip(serial, backwards[::-1], parallel, strict=True):
            for field in dataclasses.fields(a):
                x, y, z = (getattr(e, field.name) for e in (a, b, c))
                assert np.array_equal(x, y) and np.array_equal(x, z), (option, field.name)


def test_one_map_of_several_jobs_gives_each_job_its_own_results(ray_runtime, job, serial):
    from dynoplan.pipeline.jobs import evaluate_many

    seeds = episode_seeds(7, EPISODES)
    script = dataclasses.replace(job, controller="fixed_script")
    both = evaluate_many([(script, seeds[:2]), (job, seeds)], Workers(2))
    assert [_comparable(m) for m in both[1]] == [_comparable(m) for m in serial]
    assert [_comparable(m) for m in both[0]] == \
        [_comparable(m) for m in evaluate(script, seeds[:2])]
