"""The gear's downstream task (issue 32): the peg module held at another pose each
episode, solved on the first task's option dynamics with only its own goal heuristic
(``dynoplan.envs.gear.peg_pose``, ``benchmarks/transfer/gear_peg_task.py``)."""

import itertools
import json
from pathlib import Path

import numpy as np
import pytest

from dynoplan.data.episodes import OPTION_KEY, Episode
from dynoplan.envs.gear.env import GearAssemblyEnv
from dynoplan.envs.gear.features import FEATURE_MAPS, PEG_OBJECTS
from dynoplan.envs.gear.learning.settings import QUICK_SETTINGS
from dynoplan.envs.gear.models_folder import TASK_NAME, load_gear_models
from dynoplan.envs.gear.options.catalog import gear_option_names
from dynoplan.envs.gear.peg_pose import PEG_TASK_NAME, PEG_WORKSPACE, GearPegPoseEnv
from dynoplan.envs.gear.state import DECISION_STEPS, STATE_DIM, PlannerState
from dynoplan.errors import DynoplanError
from dynoplan.models.folder import file_sha256, read_manifest
from dynoplan.pipeline.fit import FittedModels
from dynoplan.pipeline.run_settings import PipelineSettings
from dynoplan.pipeline.task_fit import fit_task, load_option_models

FIRST_TIP = np.array([0.615, -0.0887, 0.911])  # the first task's peg tip (docs/gear.md)


def test_the_right_hand_holds_the_peg_where_the_episode_draws_it():
    env = GearPegPoseEnv()
    for corner in itertools.product(*zip(PEG_WORKSPACE.low, PEG_WORKSPACE.high, strict=True)):
        env.reset(seed=0, options={"peg_offset": corner})
        tip, rot = env.peg_pose()
        assert np.abs(tip - FIRST_TIP - np.array(corner)).max() < 1.5e-3
        assert rot[2, 2] > np.cos(np.deg2rad(1.0))  # the peg's axis stays vertical
    first, _ = env.reset(seed=7)
    again, _ = env.reset(seed=7)
    assert np.array_equal(first, again)  # the pose is the seed's
    offset = env.peg_offset
    assert np.all(offset >= PEG_WORKSPACE.low) and np.all(offset <= PEG_WORKSPACE.high)
    assert np.abs(offset).max() > 1e-3
    for _ in range(20):  # held still, as in the first task
        env.step(np.concatenate([env.arm_targets, [0.0]]))
    assert np.linalg.norm(env.peg_pose()[0] - first[33:36]) < 5e-3
    # the first task draws nothing more: its peg stays where it always was
    base = GearAssemblyEnv()
    base.reset(seed=7)
    assert np.abs(base.peg_pose()[0] - FIRST_TIP).max() < 1e-3


def test_peg_objects_read_the_gear_relative_to_the_peg():
    env, planner = GearPegPoseEnv(), PlannerState()
    states, relative = [], []
    for seed in range(4):
        obs, _ = env.reset(seed=seed)
        states.append(planner(obs))
        relative.append(obs[26:29] - obs[33:36])  # gear bottom minus peg tip, observed
    features = PEG_OBJECTS(np.array(states))
    assert features.shape == (4, 7)
    assert np.abs(features[:, 4:7] - np.array(relative)).max() < 5e-4


def test_peg_relative_is_relative_read_in_the_first_tasks_frame():
    """The downstream task's region features: what ``relative`` reads of the state moved
    into the first task's frame, the gear's place taken from the first task's peg tip."""
    from dynoplan.envs.gear.features import FEATURE_MAPS
    from dynoplan.envs.gear.peg_pose import PegFrame

    env, planner = GearPegPoseEnv(), PlannerState()
    states = np.array([planner(env.reset(seed=seed)[0]) for seed in range(4)])
    ours = FEATURE_MAPS["peg_relative"](states)
    framed = FEATURE_MAPS["relative"](PegFrame().to_option(states))
    assert ours.shape == (4, 8)
    gap = framed - ours
    assert np.abs(gap[:, [0, 1, 2, 3, 7]]).max() < 1e-9
    assert np.abs(gap[:, 4:7] - FIRST_TIP).max() < 5e-3  # the first task's peg tip


def test_the_options_learned_initiation_is_read_in_the_first_tasks_frame():
    """In the peg frame an option may start where its outcome runs in the first task say
    it works relative to the peg: at a state of the downstream task the initiation
    answers what it answers at that state moved into the first task's frame."""
    from dynoplan.envs.gear.features import feature_map
    from dynoplan.envs.gear.peg_pose import PegFrame, initiation_in_frame
    from dynoplan.models.outcome_initiation import (
        OutcomeInitiation,
        OutcomeInitiationOnFeatures,
    )

    env, planner = GearPegPoseEnv(), PlannerState()
    states = np.array([planner(env.reset(seed=seed)[0]) for seed in range(12)])
    frame, relative = PegFrame(), feature_map("relative")
    seen = frame.to_option(states)
    rng = np.random.default_rng(0)
    starts = seen[rng.integers(0, len(seen), 200)] + rng.normal(0, 0.03, (200, STATE_DIM))
    good = starts[:, 16] > np.median(starts[:, 16])  # the gear's x, in the first frame
    inner, _ = OutcomeInitiation.fit({"pick": relative(starts)}, {"pick": good}, seed=0)
    learned = OutcomeInitiationOnFeatures(inner, relative)
    in_frame = initiation_in_frame(learned, frame)
    assert np.array_equal(in_frame.probability(states, "pick"),
                          learned.probability(seen, "pick"))
    assert not np.array_equal(in_frame.contains(states, "pick"),
                              learned.contains(states, "pick"))  # the frame matters here
    assert np.array_equal(in_frame.contains(states, "pick"), learned.contains(seen, "pick"))
    plain, _ = OutcomeInitiation.fit({"pick": starts}, {"pick": good}, seed=0)  # no features
    assert np.array_equal(initiation_in_frame(plain, frame).contains(states, "pick"),
                          plain.contains(seen, "pick"))


def _options_folder(root: Path, names: list[str]) -> Path:
    """A tiny valid gear models folder (untrained widths of 4) with the dynamics of
    ``names``, and no option runs."""
    from dynoplan.envs.gear.features import feature_map
    from dynoplan.models.features import GoalOnFeatures, RegionsOnFeatures
    from dynoplan.models.goal_network import GoalNetwork
    from dynoplan.models.neural_dynamics import MLPEnsembleDynamics
    from dynoplan.models.regions import SafetyRegions

    folder = root / "models"
    rng = np.random.default_rng(0)
    x = rng.normal(size=(20 * len(names), STATE_DIM))
    goal_map = feature_map(QUICK_SETTINGS.goal_features or "")
    goal, _ = GoalNetwork.fit(goal_map(x), rng.uniform(size=len(x)), hidden=4, members=1,
                              epochs=1, seed=0)
    regions = feature_map(QUICK_SETTINGS.region_features or "")
    fitted = SafetyRegions.fit(regions(x), np.repeat(np.arange(len(names)), 20), names,
                               n_components=len(names))
    dynamics = {n: MLPEnsembleDynamics(STATE_DIM, [4], 1, option=n) for n in names}
    FittedModels(names, dynamics, GoalOnFeatures(goal, goal_map),
                 RegionsOnFeatures(fitted, regions), DECISION_STEPS,
                 {"state_scale": x.std(axis=0).tolist()}, True, TASK_NAME).write(folder)
    return root


def _demos(n: int = 3, steps: int = 16) -> list[Episode]:
    """Demonstrations' shape in the downstream environment: real observations, each step
    labelled with an option (what a goal fit reads)."""
    env, out = GearPegPoseEnv(), []
    for seed in range(n):
        obs, _ = env.reset(seed=seed)
        observations = [obs]
        for _ in range(steps):
            action = np.concatenate([env.arm_targets, [0.0]])
            action[0] += 0.02  # the left arm turns: states that differ
            observations.append(env.step(action)[0])
        labels = np.minimum(np.arange(steps) // 4, 3).astype(np.int64)
        out.append(Episode(np.array(observations), np.zeros((steps, 13)), np.zeros(steps),
                           np.zeros(steps, bool), np.zeros(steps, bool),
                           {OPTION_KEY: labels,
                            "progress": np.arange(1, steps + 1) / steps}, seed))
    return out


def test_the_task_keeps_the_first_tasks_dynamics_byte_for_byte_and_fits_its_goal(tmp_path):
    from dataclasses import replace

    from dynoplan.adapters.spec import OptionSpec
    from dynoplan.options.termination import ConstantTermination

    names = list(gear_option_names())
    root = _options_folder(tmp_path / "options", names)
    options = load_option_models(root, FEATURE_MAPS, PlannerState())
    settings = PipelineSettings(fit=replace(QUICK_SETTINGS, goal_features=PEG_OBJECTS.name,
                                            goal_epochs=2))
    specs = [OptionSpec(n, None, ConstantTermination(0.0))  # type: ignore[arg-type]
             for n in names]
    fitted = fit_task(options, specs, _demos(), settings, 0, PEG_TASK_NAME,
                      state_fn=PlannerState(), feature_maps=FEATURE_MAPS)
    fitted.write(tmp_path / "task")
    first, task = read_manifest(root / "models"), read_manifest(tmp_path / "task")
    for name in names:  # the same files, byte for byte
        assert file_sha256(task.dynamics[name]) == file_sha256(first.dynamics[name])
    assert task.goal.features == PEG_OBJECTS.name  # its own goal, on the peg features
    assert file_sha256(task.goal.path) != file_sha256(first.goal.path)
    assert load_gear_models(tmp_path / "task", PEG_TASK_NAME).task == PEG_TASK_NAME
    with pytest.raises(DynoplanError, match="task is 'gear_peg_pose'"):
        load_gear_models(tmp_path / "task")  # not the first task's models


@pytest.mark.parametrize("mode", [[], ["--demonstrator"], ["--script"]])
def test_no_episodes_is_one_line_in_every_mode(tmp_path, capsys, monkeypatch, mode):
    """--episodes 0 is refused before anything runs, the demonstrator's and the script's
    measures too (not a mean over no episodes)."""
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[1]))  # benchmarks/
    from benchmarks.transfer.gear_peg_task import main

    root = _options_folder(tmp_path / "options", list(gear_option_names()))
    code = main(["--options-models", str(root), "--out", str(tmp_path / "out"),
                 "--episodes", "0", *mode])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err == ["error: --episodes and --demos must be >= 1"]
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(("flag", "message"), [
    (["--region-features", "nope"], "error: unknown feature map 'nope'"),
    (["--task-improve", "-1"], "error: improve")])
def test_bad_task_settings_are_one_line_and_write_nothing(tmp_path, capsys, monkeypatch,
                                                          flag, message):
    """An unknown feature map for the regions, or negative improvement rounds, is one
    error line before the output folder is made."""
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[1]))  # benchmarks/
    from benchmarks.transfer.gear_peg_task import main

    root = _options_folder(tmp_path / "options", list(gear_option_names()))
    code = main(["--options-models", str(root), "--out", str(tmp_path / "out"), *flag])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith(message)
    assert not (tmp_path / "out").exists()


def test_an_options_folder_without_an_option_the_task_needs_is_one_line(tmp_path, capsys,
                                                                       monkeypatch):
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[1]))  # benchmarks/
    from benchmarks.transfer.gear_peg_task import main

    names = list(gear_option_names())
    root = _options_folder(tmp_path / "options", [n for n in names if n != "insert"])
    code = main(["--options-models", str(root), "--out", str(tmp_path / "out"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and err[0].startswith("error: ")
    assert "'insert'" in err[0] and "models.json" in err[0]
    assert not (tmp_path / "out").exists()  # nothing written


@pytest.mark.slow
def test_the_downstream_task_runs_on_a_quick_gear_run(quick_gear_run: Path, tmp_path: Path):
    """The benchmark's rows on the first task's dynamics, on small settings: the task's
    demonstrations recorded in its environment, the first task's dynamics byte for byte,
    the same goal heuristic whether the dynamics are rolled in the first task's frame or
    not. (The retrained row is left out: with a quick run's networks the operator
    succeeds too rarely in the new task for its held-out trials.)"""
    from benchmarks.transfer.gear_peg_task import main

    out = tmp_path / "peg"
    assert main(["--options-models", str(quick_gear_run), "--out", str(out), "--quick",
                 "--demos", "2", "--episodes", "2", "--rows", "shared,shared-frame",
                 "--quiet"]) == 0
    results = json.loads((out / "results.json").read_text())
    shared, framed = results["rows"]["shared"], results["rows"]["shared-frame"]
    first = read_manifest(quick_gear_run / "models")
    assert shared["dynamics_sha256"] == {n: file_sha256(p) for n, p in first.dynamics.items()
                                         if p is not None}
    assert framed["dynamics_sha256"] == shared["dynamics_sha256"]
    assert framed["goal_sha256"] == shared["goal_sha256"]
    assert shared["demonstrations"] == 2 and shared["episodes"] == 2
    assert read_manifest(out / "shared" / "models").goal.features == PEG_OBJECTS.name


def test_gear_task_fit_on_a_folder_without_an_option_the_task_needs_is_one_line(
        tmp_path, capsys, monkeypatch):
    """``dynoplan gear task-fit`` checks the options folder before any work."""
    from test_bad_input import assert_one_line_error, invoke

    names = list(gear_option_names())
    root = _options_folder(tmp_path / "options", [n for n in names if n != "insert"])
    code, _, err = invoke(monkeypatch, capsys, "gear", "task-fit", "--options-models",
                          str(root), "--out", str(tmp_path / "out"), "--quiet")
    assert_one_line_error(code, err, "'insert'", "models.json")
    assert not (tmp_path / "out" / "demos").exists()  # nothing recorded


@pytest.mark.slow
def test_gear_task_fit_solves_the_downstream_task_on_a_gear_runs_dynamics(
        quick_gear_run: Path, tmp_path: Path, capsys, monkeypatch):
    """From the command line: the task's own demonstrations, the options folder's dynamics
    byte for byte, its own goal on the peg features, and a line saying what it needed."""
    from test_bad_input import invoke

    out = tmp_path / "peg"
    code, stdout, err = invoke(monkeypatch, capsys, "gear", "task-fit", "--options-models",
                               str(quick_gear_run), "--out", str(out), "--quick", "--demos",
                               "2", "--episodes", "2", "--quiet", "--workers", "1")
    assert code == 0, err
    assert "the task needed 2 demonstrations" in stdout
    summary = json.loads((out / "task" / "summary.json").read_text())
    assert summary["task_fit"]["demonstrations"] == 2
    assert summary["controllers"]["dynoplan"]["episodes"] == 2
    first, task = read_manifest(quick_gear_run / "models"), read_manifest(out / "task" / "models")
    assert {n: file_sha256(p) for n, p in task.dynamics.items() if p is not None} == {
        n: file_sha256(p) for n, p in first.dynamics.items() if p is not None}
    assert task.goal.features == PEG_OBJECTS.name


def test_the_table_says_which_fit_each_time_is_from():
    """The goal fit of the models kept, the first fit and the improvement round each
    have their column, and so does whether the row reused the options' learned
    initiation; a row without a round (without the initiation) shows '-'."""
    from benchmarks.transfer.gear_peg_task import _table

    row = {"success_rate": 0.73, "episodes": 100, "demonstrations": 10,
           "demonstration_steps": 2723, "goal_fit_seconds": 17.2, "fit_seconds": 15.0}
    results = {"command": "x", "rows": {
        "shared-frame": {**row, "improvement": {"seconds": 263.2}, "reused_initiation": True},
        "retrained": {**row, "improvement": None, "reused_initiation": False}}}
    lines = _table(results).splitlines()
    assert "the goal fit of the models kept (s)" in lines[2]
    assert "learned initiation" in lines[2]
    assert lines[4].endswith("| 17.2 | 15.0 | 263.2 | reused |")
    assert lines[5].endswith("| 17.2 | 15.0 | - | - |")
