"""``dynoplan sweep``: configuration errors are one line; an interrupted sweep leaves
its output folder as it was, keeps its finished cells in the resume folder beside it
(``.OUT.sweep-cells``) and resumes from them without running them again; damaged or
stale cell files are never read as finished. The episodes here are stand-ins (no models
needed); the real ones run in ``test_scale_out_gear.py``."""

import csv
import functools
import hashlib
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from dynoplan.errors import DynoplanError, DynoplanWarning
from dynoplan.experiments.sweep import cell_key, load_sweep_config, resume_folder, run_sweep
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


def _sweep(root: Path, out: str = "out", config: str = "grid.toml") -> dict:
    return run_sweep(root / config, root / out, progress=False, setup=fake_setup,
                     run=fake_run)


def _listing(folder: Path) -> dict[str, str | None]:
    """Every entry under ``folder`` (hidden ones too), with a file's SHA-256; {} when
    ``folder`` does not exist."""
    return {str(p.relative_to(folder)): (hashlib.sha256(p.read_bytes()).hexdigest()
                                         if p.is_file() else None)
            for p in sorted(folder.rglob("*"))}


def _rows(out: Path) -> list[dict[str, str]]:
    with (out / "results.csv").open() as f:
        return list(csv.DictReader(f))


def _interrupted(root: Path, stop_at: int, kept: int, of: int, out: str = "out",
                 config: str = "grid.toml") -> None:
    """A sweep into ``root/out`` stopped by Ctrl-C at episode ``stop_at``: it says that
    ``kept`` finished cells of ``of`` are kept in the resume folder."""
    calls.clear()
    STOP_AT[0] = stop_at
    resume = resume_folder(root / out)
    with pytest.warns(DynoplanWarning) as record, pytest.raises(KeyboardInterrupt):
        _sweep(root, out, config)
    assert [str(w.message) for w in record] == [
        f"kept {kept} finished cell{'s' if kept > 1 else ''} of {of} in {resume}; run the "
        "same command again to resume"]
    calls.clear()
    STOP_AT[0] = 0


def test_interrupted_sweep_resumes_without_rerunning_finished_cells(sweep_dir: Path):
    out, resume = sweep_dir / "out", sweep_dir / ".out.sweep-cells"
    assert resume_folder(out) == resume
    _interrupted(sweep_dir, 8, kept=2, of=4)  # cells of 3 episodes: two finish, the third
    assert not out.exists()  # is cut after 1 episode; OUT is not made
    assert sorted(p.name for p in sweep_dir.iterdir()) == [
        ".out.sweep-cells", "grid.toml", "models"]
    assert len(list(resume.glob("cell-*.json"))) == 2 and len(list(resume.iterdir())) == 2
    summary = _sweep(sweep_dir)
    assert summary["cells_reused"] == 2 and summary["cells_run"] == 2
    assert len(calls) == 2 * 3  # only the two unfinished cells ran
    rows = _rows(out)
    assert [(r["horizon"], r["samples"], r["seed"]) for r in rows] == [
        ("2", "8", "0"), ("2", "8", "1"), ("4", "8", "0"), ("4", "8", "1")]
    assert all(r["episodes"] == "3" for r in rows)
    assert float(rows[0]["success_rate"]) == pytest.approx(2 / 3)  # episodes 0 and 2
    for name in ("results.md", "sweep.png", "summary.json"):
        assert (out / name).is_file()
    assert not resume.exists()  # its cells moved into OUT with the results
    cells = load_sweep_config(sweep_dir / "grid.toml").cells()
    assert sorted(p.name for p in (out / "cells").iterdir()) == sorted(
        f"{cell_key(c)}.json" for c in cells)
    calls.clear()
    assert _sweep(sweep_dir)["cells_run"] == 0 and calls == []
    calls.clear()
    _sweep(sweep_dir, out="whole")  # uninterrupted: the same rows
    assert len(calls) == 4 * 3 and _rows(out) == _rows(sweep_dir / "whole")
    assert (out / "results.md").read_text() == (sweep_dir / "whole" / "results.md").read_text()


def test_interrupted_sweep_leaves_a_previous_output_byte_identical(sweep_dir: Path):
    """A larger grid into the folder of a completed sweep: its cells are reused, the new
    ones wait in the resume folder, OUT (results, cells, the user's file) stays as it was
    until the larger sweep completes."""
    _sweep(sweep_dir)
    out = sweep_dir / "out"
    (out / "notes.txt").write_text("the user's")
    (sweep_dir / "larger.toml").write_text(CONFIG.replace("[2, 4]", "[2, 4, 6]"))
    before = _listing(out)
    _interrupted(sweep_dir, 4, kept=1, of=6, config="larger.toml")  # one new cell finishes
    assert _listing(out) == before
    assert len(list(resume_folder(out).glob("cell-*.json"))) == 1
    summary = _sweep(sweep_dir, config="larger.toml")
    assert (summary["cells_reused"], summary["cells_run"]) == (5, 1) and len(calls) == 3
    assert not resume_folder(out).exists()
    assert len(list((out / "cells").iterdir())) == 6
    assert (out / "notes.txt").read_text() == "the user's"
    calls.clear()
    _sweep(sweep_dir, out="whole", config="larger.toml")
    assert len(calls) == 6 * 3 and _rows(out) == _rows(sweep_dir / "whole")
    assert [r["horizon"] for r in _rows(out)] == ["2", "2", "4", "4", "6", "6"]


def test_cells_of_an_earlier_version_in_out_are_reused(sweep_dir: Path):
    """An earlier dynoplan kept the finished cells of an interrupted sweep in OUT/cells:
    a re-run reads them as finished."""
    _sweep(sweep_dir)
    out = sweep_dir / "out"
    for name in ("results.csv", "results.md", "sweep.png", "summary.json"):
        (out / name).unlink()
    for path in sorted((out / "cells").iterdir())[:2]:
        path.unlink()
    calls.clear()
    summary = _sweep(sweep_dir)
    assert (summary["cells_reused"], summary["cells_run"]) == (2, 2) and len(calls) == 6
    assert len(list((out / "cells").iterdir())) == 4 and (out / "results.csv").is_file()


@pytest.mark.parametrize(("sig", "status"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_cli_sweep_stopped_by_a_signal_says_where_its_cells_are(sweep_dir, monkeypatch, capsys,
                                                                 sig, status):
    """The command line: a signal after two finished cells is two lines (the cells kept,
    then ``dynoplan: aborted``), no OUT; the same command again resumes."""
    import dynoplan.experiments.sweep as experiments_sweep
    from dynoplan.cli import interrupts
    from test_bad_input import invoke

    def signalled_run(job: ControllerJob, seed: EpisodeSeed) -> EpisodeRecord:
        if len(calls) == 7:  # two cells of 3 episodes are finished
            os.kill(os.getpid(), sig)
        return fake_run(job, seed)

    monkeypatch.setattr(experiments_sweep, "run_sweep", functools.partial(
        experiments_sweep.run_sweep, setup=fake_setup, run=signalled_run))
    out = sweep_dir / "out"
    args = ["sweep", str(sweep_dir / "grid.toml"), "--out", str(out), "--workers", "1",
            "--quiet"]
    monkeypatch.setattr(interrupts, "received", [])  # the signals of this process's run
    code, stdout, err = invoke(monkeypatch, capsys, *args)
    resume = sweep_dir / ".out.sweep-cells"
    assert code == status and stdout == ""
    assert err.splitlines() == [
        f"dynoplan: warning: kept 2 finished cells of 4 in {resume}; run the same command "
        "again to resume", "dynoplan: aborted"]
    assert not out.exists() and len(list(resume.iterdir())) == 2
    calls.clear()
    monkeypatch.setattr(interrupts, "received", [])
    code, stdout, err = invoke(monkeypatch, capsys, *args)
    assert code == 0 and err == "", err
    assert stdout.startswith("4 cells (2 run, 2 already finished) in ")
    assert len(calls) == 2 * 3 and not resume.exists()
    assert len(list((out / "cells").iterdir())) == 4 and len(_rows(out)) == 4


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
