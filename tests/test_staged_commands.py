"""Issue 34: every command that writes a folder stages it whole.

``gear run``, ``gear option``, ``gear figures`` and ``sweep`` build their output in a
``.NAME.PID.XXXX.staging`` folder beside the target and move it in at the end: a failure
or an interrupt (``KeyboardInterrupt``, which SIGINT and SIGTERM raise in the command
line) leaves the target and its parent as they were, and the paths recorded in the
outputs name the target, never the staging folder. A sweep keeps its finished cells as
they finish, so that an interrupted sweep resumes, in its resume folder beside the target
(``.OUT_NAME.sweep-cells``), and moves them into the target with the results.

The stages' work is replaced by stand-ins here (seconds in all); the real runs are
``tests/test_gear_run.py``'s (slow) and ``tests/test_sweep.py``'s.
"""

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from dynoplan.envs.gear.pipeline_stages import GearStages
from dynoplan.errors import DynoplanWarning
from dynoplan.io import retarget, staged_folder, write_json
from test_bad_input import leftovers

FAILURES = [RuntimeError("a stage failed"), KeyboardInterrupt()]


def _snapshot(folder: Path) -> dict[str, bytes | None]:
    """Every entry under ``folder`` (hidden ones too), with a file's bytes."""
    return {str(p.relative_to(folder)): (p.read_bytes() if p.is_file() else None)
            for p in sorted(folder.rglob("*"))}


def _previous_run(out: Path) -> None:
    (out / "models").mkdir(parents=True)
    (out / "models" / "pick_policy.safetensors").write_bytes(b"a trained network")
    (out / "summary.json").write_text('{"previous": true}')
    (out / "notes.txt").write_text("the user's")


def test_retarget_renames_paths_under_the_stage_only(tmp_path):
    stage, target = tmp_path / ".out.1.x.staging", tmp_path / "out"
    value = {"a": str(stage / "figures" / "f.png"), "b": [str(stage), (str(tmp_path),)],
             "c": str(stage) + "-other", "d": 3}
    assert retarget(value, stage, target) == {
        "a": str(target / "figures" / "f.png"), "b": [str(target), (str(tmp_path),)],
        "c": str(stage) + "-other", "d": 3}


def test_json_files_of_a_staged_folder_name_the_target(tmp_path):
    out = tmp_path / "out é"
    with staged_folder(out) as stage:
        write_json(stage / "a.json", {"file": str(stage / "x.png"), "n": 1})
        (stage / "sub").mkdir()
        (stage / "sub" / "b.json").write_text(json.dumps({"dir": str(stage)},
                                                         ensure_ascii=False))
        (stage / "plain.json").write_text('{"kept": "as it was"}\n')
    assert json.loads((out / "a.json").read_text()) == {"file": str(out / "x.png"), "n": 1}
    assert json.loads((out / "sub" / "b.json").read_text()) == {"dir": str(out)}
    assert (out / "plain.json").read_text() == '{"kept": "as it was"}\n'
    assert not leftovers(tmp_path)


# --- gear run -----------------------------------------------------------------------------


def _fake_stages(out: Path, failure: BaseException | None):
    """A stand-in of the pipeline on gear run's stages: what they write (a stage's own
    staged folder inside, a JSON file naming another stage's folder), then ``failure``."""

    def run_pipeline(*, stages: object, out: Path, **kwargs) -> dict:
        assert isinstance(stages, GearStages)
        return write(out)

    def write(stage: Path) -> dict:
        assert stage != out and stage.parent == out.parent
        if (out / "models").is_dir():  # the previous networks are there to be reused
            assert (stage / "models" / "pick_policy.safetensors").read_bytes() == \
                b"a trained network"
        with staged_folder(stage / "figures") as figures:
            write_json(figures / "figures.json", {"file": str(stage / "figures" / "a.png")})
        (stage / "models").mkdir(exist_ok=True)
        write_json(stage / "models" / "metrics.json", {"demos": str(stage / "demos")})
        (stage / "results.csv").write_text("controller\ndynoplan\n")
        if failure is not None:
            raise failure
        return {"results": [], "figures": {"file": str(stage / "figures" / "a.png")}}

    return run_pipeline


@pytest.mark.parametrize("failure", FAILURES)
@pytest.mark.parametrize("previous", [True, False])
def test_gear_run_that_fails_leaves_the_target_and_its_parent_as_they_were(
        tmp_path, monkeypatch, failure, previous):
    import dynoplan.experiments.gear_run as gear_run

    out = tmp_path / "run"
    if previous:
        _previous_run(out)
    before = _snapshot(tmp_path)
    monkeypatch.setattr(gear_run, "run_pipeline", _fake_stages(out, failure))
    with pytest.raises(type(failure)):
        gear_run.run_gear_pipeline(out)
    assert _snapshot(tmp_path) == before and not leftovers(tmp_path)


def test_gear_run_replaces_the_folder_whole_and_records_the_target(tmp_path, monkeypatch):
    import dynoplan.experiments.gear_run as gear_run

    out = tmp_path / "run"
    _previous_run(out)
    monkeypatch.setattr(gear_run, "run_pipeline", _fake_stages(out, None))
    monkeypatch.setattr(gear_run, "results_markdown", lambda summary: "the table\n")
    summary = gear_run.run_gear_pipeline(out)
    figure = str(out / "figures" / "a.png")
    assert summary["figures"]["file"] == figure
    assert json.loads((out / "summary.json").read_text())["figures"]["file"] == figure
    assert json.loads((out / "figures" / "figures.json").read_text()) == {"file": figure}
    assert json.loads((out / "models" / "metrics.json").read_text()) == {
        "demos": str(out / "demos")}
    assert (out / "notes.txt").read_text() == "the user's"  # the previous folder's, kept
    assert (out / "models" / "pick_policy.safetensors").is_file()
    assert (out / "results.md").read_text() == "the table\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"] and not leftovers(tmp_path)


# --- sweep --------------------------------------------------------------------------------


@pytest.fixture
def sweep_dir(tmp_path: Path) -> Path:
    import test_sweep

    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "models.json").write_text('{"kind": "stand-in"}')
    (tmp_path / "grid.toml").write_text(test_sweep.CONFIG)
    test_sweep.calls.clear()
    test_sweep.STOP_AT[0] = 0
    return tmp_path


def _sweep(root: Path) -> dict:
    import test_sweep
    from dynoplan.experiments.sweep import run_sweep

    return run_sweep(root / "grid.toml", root / "out", progress=False,
                     setup=test_sweep.fake_setup, run=test_sweep.fake_run)


def test_sweep_interrupted_before_a_cell_finished_leaves_no_folder(sweep_dir):
    import test_sweep

    test_sweep.STOP_AT[0] = 2  # in the first cell
    before = _snapshot(sweep_dir)
    with pytest.raises(KeyboardInterrupt):
        _sweep(sweep_dir)
    assert _snapshot(sweep_dir) == before and not leftovers(sweep_dir)


def test_sweep_interrupted_keeps_its_finished_cells_beside_the_target(sweep_dir):
    import test_sweep

    test_sweep.STOP_AT[0] = 8  # two cells finish
    before = _snapshot(sweep_dir)
    with pytest.warns(DynoplanWarning, match="kept 2 finished cells of 4"), \
            pytest.raises(KeyboardInterrupt):
        _sweep(sweep_dir)
    resume = sweep_dir / ".out.sweep-cells"
    assert {k: v for k, v in _snapshot(sweep_dir).items()
            if not k.startswith(resume.name)} == before  # no OUT
    assert len(list(resume.iterdir())) == 2 and not leftovers(sweep_dir)


def test_sweep_results_are_replaced_together_or_not_at_all(sweep_dir, monkeypatch):
    import dynoplan.reports.sweep_figures as sweep_figures

    _sweep(sweep_dir)
    out = sweep_dir / "out"
    (out / "cells" / next(iter(sorted(p.name for p in (out / "cells").iterdir())))).unlink()
    before = _snapshot(out)

    def plot_fails(*args, **kwargs):
        raise RuntimeError("no figure")

    monkeypatch.setattr(sweep_figures, "plot_sweep", plot_fails)
    with pytest.warns(DynoplanWarning, match="kept 1 finished cell of 4"), \
            pytest.raises(RuntimeError):
        _sweep(sweep_dir)  # the cell runs again, then results.csv and .md, then the figure
    assert _snapshot(out) == before  # none of the new results, nor the cell
    assert len(list((sweep_dir / ".out.sweep-cells").iterdir())) == 1  # the cell that ran
    assert not leftovers(sweep_dir)


# --- gear option and gear figures -----------------------------------------------------------


class _FakeEnv:
    def __init__(self, render_mode=None):
        self.metadata = {"render_fps": 10}

    def close(self) -> None:
        pass


@pytest.mark.parametrize("failure", FAILURES)
def test_gear_option_that_fails_while_writing_keeps_the_previous_outputs(
        tmp_path, monkeypatch, failure):
    import dynoplan.envs.gear.options.trials as trials

    out = tmp_path / "option"
    out.mkdir()
    (out / "summary.json").write_text('{"previous": true}')
    (out / "pick.mp4").write_bytes(b"the previous video")
    before = _snapshot(tmp_path)
    monkeypatch.setattr(trials, "GearAssemblyEnv", _FakeEnv)
    monkeypatch.setattr(trials, "run_trial", lambda *a, **k: None)
    monkeypatch.setattr(trials, "summarise_trials", lambda *a, **k: {"trials": 1})

    def write_mp4(path: Path, frames, fps: int) -> Path:
        path.write_bytes(b"a new video")
        raise failure

    monkeypatch.setattr(trials, "write_mp4", write_mp4)
    with pytest.raises(type(failure)):
        trials.run_option_trials("pick", lambda env: None, 1, 0, out, video=True,
                                 progress=False)
    assert _snapshot(tmp_path) == before and not leftovers(tmp_path)

    def write_mp4_ok(path: Path, frames, fps: int) -> Path:
        path.write_bytes(b"a new video")
        return path

    monkeypatch.setattr(trials, "write_mp4", write_mp4_ok)
    summary = trials.run_option_trials("pick", lambda env: None, 1, 0, out, video=True,
                                       progress=False)
    assert summary["video"] == str(out / "pick.mp4")
    assert (out / "pick.mp4").read_bytes() == b"a new video"
    assert json.loads((out / "summary.json").read_text()) == summary
    assert not leftovers(tmp_path)


@pytest.mark.parametrize("failure", FAILURES)
def test_gear_figures_interrupted_between_the_figures_keep_the_previous_ones(
        tmp_path, monkeypatch, failure):
    import dynoplan.envs.gear.reports.figures as gear_figures

    out = tmp_path / "figures"
    out.mkdir()
    for name in (gear_figures.GOAL_FIGURE, gear_figures.TSNE_FIGURE, "figures.json"):
        (out / name).write_bytes(b"previous " + name.encode())
    before = _snapshot(tmp_path)
    held = SimpleNamespace(seed=7)
    monkeypatch.setattr(gear_figures, "RegionsOnFeatures", object)
    monkeypatch.setattr(gear_figures, "load_gear_models", lambda m: SimpleNamespace(
        regions=object(), goal=None, option_names=("pick",)))

    class _Set(list):
        metadata = SimpleNamespace(extra={})

    monkeypatch.setattr(gear_figures, "read_dataset", lambda p: _Set([held]))
    states = np.zeros((3, 2))
    monkeypatch.setattr(gear_figures, "_trial_arrays", lambda s, planner: [
        (states, np.zeros(2), np.zeros(2, dtype=int), False)])

    def goal_figure(goal, states, truth, labels, path: Path, *args) -> dict:
        path.write_bytes(b"a new figure")
        return {}

    def tsne_figure(*args) -> dict:
        raise failure

    monkeypatch.setattr(gear_figures, "plot_goal_trial", goal_figure)
    monkeypatch.setattr(gear_figures, "plot_tsne_regions", tsne_figure)
    with pytest.raises(type(failure)):
        gear_figures.make_gear_figures(tmp_path / "models", tmp_path / "demos",
                                       tmp_path / "held", out, max_points=10)
    assert _snapshot(tmp_path) == before and not leftovers(tmp_path)


# --- gear outcomes --------------------------------------------------------------------------


def _fake_outcomes(monkeypatch, failure: BaseException | None) -> None:
    """Outcome runs and the initiation's fit replaced: what they write, then ``failure``
    (in the fit, after the runs' dataset is written)."""
    import dynoplan.envs.gear.learning.outcomes as outcomes

    def collect(models: Path, seed: int, out: Path, settings, progress, workers) -> dict:
        (out / "data").mkdir(parents=True)
        (out / "data" / "main_data.hdf5").write_bytes(b"the new runs")
        return {"dataset": str(out), "runs": 1, "starts": {"pick": 1},
                "ended_well": {"pick": 1}}

    def fit(models: Path, runs: Path, seed: int) -> dict:
        assert (runs / "data" / "main_data.hdf5").read_bytes() == b"the new runs"
        (models / "initiation.safetensors").write_bytes(b"a new initiation")
        if failure is not None:
            raise failure
        return {"options": {"pick": 1}, "file": str(models / "initiation.safetensors")}

    monkeypatch.setattr(outcomes, "collect_outcomes", collect)
    monkeypatch.setattr(outcomes, "fit_gear_initiation", fit)


def _outcomes_folders(tmp_path: Path) -> tuple[Path, Path]:
    models, out = tmp_path / "models", tmp_path / "outcomes"
    models.mkdir()
    (models / "initiation.safetensors").write_bytes(b"the previous initiation")
    (models / "initiation.json").write_text('{"previous": true}')
    (out / "data").mkdir(parents=True)
    (out / "data" / "main_data.hdf5").write_bytes(b"the previous runs")
    (out / "outcomes.json").write_text('{"previous": true}')
    return models, out


@pytest.mark.parametrize(("failure", "status"), [
    pytest.param(None, 0, id="ok"), pytest.param("error", 2, id="error"),
    pytest.param("interrupt", 130, id="interrupt")])
def test_gear_outcomes_stages_its_dataset_and_the_initiation_together(
        tmp_path, monkeypatch, capsys, failure, status):
    from dynoplan.errors import DynoplanError
    from test_bad_input import invoke

    models, out = _outcomes_folders(tmp_path)
    before = _snapshot(tmp_path)
    _fake_outcomes(monkeypatch, {None: None, "error": DynoplanError("the fit failed"),
                                 "interrupt": KeyboardInterrupt()}[failure])
    code, _, err = invoke(monkeypatch, capsys, "gear", "outcomes", "--models", str(models),
                          "--out", str(out), "--runs", "1", "--workers", "1", "--quiet")
    assert code == status, err
    assert not leftovers(tmp_path)
    if failure is not None:
        assert _snapshot(tmp_path) == before
        return
    assert (out / "data" / "main_data.hdf5").read_bytes() == b"the new runs"
    assert json.loads((out / "outcomes.json").read_text())["dataset"] == str(out)
    assert (models / "initiation.safetensors").read_bytes() == b"a new initiation"
    assert json.loads((models / "initiation.json").read_text())["file"] == str(
        models / "initiation.safetensors")


def test_gear_outcomes_run_again_into_its_out_replaces_the_previous_outcomes(
        tmp_path, monkeypatch, capsys):
    """A second ``gear outcomes`` into the same OUT (a dataset folder with outcomes.json,
    and transitions-beyond from ``--merge``) is not refused as "not a dataset folder": the
    new runs' dataset (written by :func:`~dynoplan.data.dataset.write_dataset`) and
    outcomes.json replace the previous ones, whose transitions-beyond, made of the previous
    runs, goes with them; the user's files stay."""
    import dynoplan.envs.gear.learning.outcomes as outcomes
    from dynoplan.data.dataset import read_dataset, write_dataset
    from test_bad_input import invoke
    from test_data import make_episode, make_metadata

    def collect(models: Path, seed: int, out: Path, settings, progress, workers) -> dict:
        write_dataset(out, [make_episode(np.random.default_rng(seed))],
                      make_metadata(seed=seed))
        return {"dataset": str(out), "seed": seed, "runs": 1, "starts": {"pick": 1},
                "ended_well": {"pick": 1}}

    def beyond(transitions: Path, runs: Path, out: Path) -> dict:
        write_dataset(out, [make_episode(np.random.default_rng(0))], make_metadata())
        return {"dataset": str(out), "episodes": 1}

    def fit(models: Path, runs: Path, seed: int) -> dict:
        assert read_dataset(runs).metadata.seed == seed  # this run's dataset
        (models / "initiation.safetensors").write_bytes(b"seed %d" % seed)
        return {"options": {"pick": 1}, "file": str(models / "initiation.safetensors")}

    monkeypatch.setattr(outcomes, "collect_outcomes", collect)
    monkeypatch.setattr(outcomes, "transitions_beyond", beyond)
    monkeypatch.setattr(outcomes, "fit_gear_initiation", fit)
    models, out = tmp_path / "models", tmp_path / "outcomes"
    models.mkdir()
    args = ["gear", "outcomes", "--models", str(models), "--out", str(out), "--runs", "1",
            "--workers", "1", "--quiet"]
    code, _, err = invoke(monkeypatch, capsys, *args, "--seed", "1", "--merge",
                          str(tmp_path / "collected"))
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == ["data", "outcomes.json",
                                                     "transitions-beyond"]
    (out / "notes.txt").write_text("the user's")
    code, _, err = invoke(monkeypatch, capsys, *args, "--seed", "2")
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == ["data", "notes.txt", "outcomes.json"]
    assert read_dataset(out).metadata.seed == 2
    assert json.loads((out / "outcomes.json").read_text()) == {
        "dataset": str(out), "seed": 2, "runs": 1, "starts": {"pick": 1},
        "ended_well": {"pick": 1}}
    assert (models / "initiation.safetensors").read_bytes() == b"seed 2"
    assert (out / "notes.txt").read_text() == "the user's" and not leftovers(tmp_path)
