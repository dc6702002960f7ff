"""``dynoplan sweep``: configuration errors are one line; an interrupted sweep resumes
without running finished cells again; damaged or stale cell files are never read as
finished. The episodes here are stand-ins (no models needed); the real ones run in
``test_scale_out_gear.py``."""

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest

from dynoplan.errors import DynoplanError
from dynoplan.experiments.sweep import cell_key, load_sweep_config, run_sweep
from dynoplan.pipeline.evaluate import ControllerJob, EpisodeRecord
from dynoplan.seeding import EpisodeSeed

ROOT = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-c", "from dynoplan.cli.main import main; main()"]

CONFIG = """
models = "models"
episodes = 3
[grid]
horizon = [2, 4]
samples = [8]
seed = [0, 1]
"""

calls: list[tuple[int, int]] = []


def fake_setup(job: ControllerJob) -> ControllerJob:
    return job


def fake_run(job: ControllerJob, seed: EpisodeSeed) -> EpisodeRecord:
    """A stand-in episode: succeeds when horizon + episode index is even."""
    calls.append((job.settings.horizon, seed.index))
    if len(calls) == STOP_AT[0]:
        raise KeyboardInterrupt  # the user pressed Ctrl-C mid-sweep
    return EpisodeRecord(seed.env_seed, (job.settings.horizon + seed.index) % 2 == 0, 20, 0.0,
                         1, 1, 0, 0, (0.1,), (("pick", 20),), ("pick",),
                         {"human_mode": "away", "contacts": 0, "min_human_distance": 0.5})


STOP_AT = [0]


@pytest.fixture
def sweep_dir(tmp_path: Path) -> Path:
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "models.json").write_text('{"kind": "stand-in"}')
    (tmp_path / "grid.toml").write_text(CONFIG)
    calls.clear()
    STOP_AT[0] = 0
    return tmp_path


def _sweep(root: Path) -> dict:
    return run_sweep(root / "grid.toml", root / "out", progress=False, setup=fake_setup,
                     run=fake_run)


def test_interrupted_sweep_resumes_without_rerunning_finished_cells(sweep_dir: Path):
    STOP_AT[0] = 8  # cells of 3 episodes: two finish, the third is cut after 1 episode
    with pytest.raises(KeyboardInterrupt):
        _sweep(sweep_dir)
    cells = sweep_dir / "out" / "cells"
    assert len(list(cells.glob("cell-*.json"))) == 2
    assert not (sweep_dir / "out" / "results.csv").exists()
    calls.clear()
    STOP_AT[0] = 0
    summary = _sweep(sweep_dir)
    assert summary["cells_reused"] == 2 and summary["cells_run"] == 2
    assert len(calls) == 2 * 3  # only the two unfinished cells ran
    with (sweep_dir / "out" / "results.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [(r["horizon"], r["samples"], r["seed"]) for r in rows] == [
        ("2", "8", "0"), ("2", "8", "1"), ("4", "8", "0"), ("4", "8", "1")]
    assert all(r["episodes"] == "3" for r in rows)
    assert float(rows[0]["success_rate"]) == pytest.approx(2 / 3)  # episodes 0 and 2
    for name in ("results.md", "sweep.png", "summary.json"):
        assert (sweep_dir / "out" / name).is_file()
    calls.clear()
    assert _sweep(sweep_dir)["cells_run"] == 0 and calls == []


def test_damaged_or_stale_cell_files_are_computed_again(sweep_dir: Path):
    _sweep(sweep_dir)
    cells = load_sweep_config(sweep_dir / "grid.toml").cells()
    files = [sweep_dir / "out" / "cells" / f"{cell_key(c)}.json" for c in cells]
    text = files[0].read_text()
    files[0].write_text(text[: len(text) // 2])  # truncated
    edited = json.loads(files[1].read_text())
    edited["settings"]["samples"] = 16  # another cell's result under this name
    files[1].write_text(json.dumps(edited))
    (files[2].parent / f".{files[2].stem}.x.tmp.json").write_text("{")  # a write cut short
    calls.clear()
    assert _sweep(sweep_dir)["cells_run"] == 2
    (sweep_dir / "models" / "models.json").write_text('{"kind": "trained again"}')
    calls.clear()
    assert _sweep(sweep_dir)["cells_run"] == 4  # new models: nothing is finished


@pytest.mark.parametrize(("text", "message"), [
    ("episodes = 2\n[grid]\nhorizon = [2]\n", "models: expected the models folder"),
    ('models = "m"\n[grid]\nhorizon = [0]\n', "grid.horizon: expected an integer in 1..1000"),
    ('models = "m"\n[grid]\nhorizon = "6"\n', "grid.horizon: expected a non-empty list"),
    ('models = "m"\n[grid]\nhorizons = [6]\n', "grid.horizons: unknown key"),
    ('models = "m"\n[grid]\nmargin = [-0.1]\n', "grid.margin: expected a number >= 0"),
    ('models = "m"\n[grid]\ncontroller = ["flat_ppo"]\n', "grid.controller: expected one of"),
    ('models = "m"\n[grid]\nseed = [1, 1]\n', "grid.seed: repeated values"),
    ('models = "m"\nepisodes = true\n[grid]\nseed = [1]\n', "episodes: expected an integer"),
    ('models = "m"\nextra = 1\n[grid]\nseed = [1]\n', "unknown key(s) extra"),
    ('models = "m"\n', "grid: expected a table"),
    ('models = "m"\n[grid\n', "not valid TOML"),
])
def test_bad_configs_name_the_file_and_field(tmp_path: Path, text: str, message: str):
    path = tmp_path / "grid.toml"
    path.write_text(text)
    with pytest.raises(DynoplanError) as info:
        load_sweep_config(path)
    assert str(path) in str(info.value) and message in str(info.value)
    assert "\n" not in str(info.value)


def test_json_configs_and_the_example_parse(tmp_path: Path):
    path = tmp_path / "grid.json"
    path.write_text(json.dumps({"models": "/m", "episodes": 2,
                                "grid": {"samples": [8, 16], "dynamics_noise": [0, 0.02]}}))
    config = load_sweep_config(path)
    assert config.models == Path("/m") and len(config.cells()) == 4
    assert config.cells()[1].planner.dynamics_noise == 0.02
    example = load_sweep_config(ROOT / "examples" / "sweep" / "planner-grid.toml")
    assert len(example.cells()) == 16 and example.models.name == "models"


def test_cli_bad_config_and_missing_models_are_one_line(tmp_path: Path):
    bad = tmp_path / "bad.toml"
    bad.write_text('models = "m"\n[grid]\nhorizon = [0]\n')
    missing = tmp_path / "missing.toml"
    missing.write_text('models = "nowhere"\n[grid]\nhorizon = [3]\n')
    for config, message in ((bad, "grid.horizon"), (missing, "models.json not found"),
                            (tmp_path / "absent.toml", "cannot read")):
        done = subprocess.run([*CLI, "sweep", str(config), "--out", str(tmp_path / "out")],
                              capture_output=True, text=True, timeout=120)
        lines = done.stderr.strip().splitlines()
        assert done.returncode == 2 and len(lines) == 1, done.stderr
        assert lines[0].startswith("dynoplan: error: ") and message in lines[0]
