"""Issue 20's corpus of bad input as tests: every command x every class of bad input.

Each rejected command must exit with status 2 and print exactly one line,
``dynoplan: error: ...``, with no traceback, and leave nothing behind: no output folder
(not even an empty one), no temporary file, and any previous output as it was. Bad files
(models folders, model files, flat policies, datasets, sweep configurations) are
rejected at load with the file and the field named. Interrupted runs (Ctrl-C, SIGTERM)
print ``dynoplan: aborted`` and keep the previous output.

Everything here runs in-process on tiny inputs (seconds in all) except the two signal
tests (one subprocess each) and the slow-marked gear training test.
"""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from dynoplan.errors import DynoplanError
from dynoplan.limits import EPISODES_MAX, SEED_MAX

CLI = [sys.executable, "-c", "from dynoplan.cli.main import main; main()"]

# every command, with the arguments it needs besides the flag under test; OUT and MODELS
# are replaced by paths in the test's folder
COMMANDS: dict[str, list[str]] = {
    "random-walk": ["random-walk", "--out", "OUT"],
    "gear expert": ["gear", "expert", "--out", "OUT"],
    "gear demos": ["gear", "demos", "--out", "OUT", "--models", "MODELS"],
    "gear collect": ["gear", "collect", "--out", "OUT", "--models", "MODELS"],
    "gear option": ["gear", "option", "pick", "--out", "OUT", "--models", "MODELS"],
    "gear train": ["gear", "train", "--out", "OUT"],
    "gear figures": ["gear", "figures", "--out", "OUT", "--models", "MODELS"],
    "gear run": ["gear", "run", "--out", "OUT"],
    "gear evaluate": ["gear", "evaluate", "--out", "OUT", "--models", "MODELS"],
    "gear episode": ["gear", "episode", "--out", "OUT", "--models", "MODELS"],
    "gear render": ["gear", "render", "--out", "OUT"],
    "pipeline": ["pipeline", "--env", "MountainCarContinuous-v0", "--options",
                 "examples.mountain_car.options:make_options", "--out", "OUT"],
}
WITH_MODELS = [c for c, args in COMMANDS.items() if "MODELS" in args]

TOO_BIG = str(10**30)  # beyond memory, C longs and numpy dimensions alike
# (command, flag, a bad value) for every count of every command
COUNTS = [
    ("random-walk", "--episodes", "0"), ("random-walk", "--episodes", TOO_BIG),
    ("random-walk", "--samples", "0"), ("random-walk", "--samples", TOO_BIG),
    ("random-walk", "--horizon", "0"), ("random-walk", "--horizon", TOO_BIG),
    ("random-walk", "--max-decisions", TOO_BIG), ("random-walk", "--start-state", "-1"),
    ("gear expert", "--episodes", "0"), ("gear expert", "--episodes", TOO_BIG),
    ("gear demos", "--n", "0"), ("gear demos", "--n", TOO_BIG),
    ("gear collect", "--runs", "0"), ("gear collect", "--runs", TOO_BIG),
    ("gear collect", "--max-decisions", TOO_BIG),
    ("gear option", "--trials", "0"), ("gear option", "--trials", TOO_BIG),
    ("gear option", "--max-steps", TOO_BIG),
    ("gear figures", "--trial", "-1"), ("gear figures", "--trial", TOO_BIG),
    ("gear figures", "--points", TOO_BIG),
    ("gear run", "--episodes", "0"), ("gear run", "--episodes", TOO_BIG),
    ("gear run", "--oracle-episodes", "-1"),
    ("gear evaluate", "--episodes", TOO_BIG), ("gear evaluate", "--horizon", TOO_BIG),
    ("gear evaluate", "--samples", TOO_BIG), ("gear evaluate", "--samples", "0"),
    ("gear evaluate", "--depth", "0"), ("gear evaluate", "--depth", TOO_BIG),
    ("gear episode", "--index", "-1"), ("gear episode", "--index", str(EPISODES_MAX)),
    ("pipeline", "--episodes", TOO_BIG), ("pipeline", "--demos", "0"),
    ("pipeline", "--explore", TOO_BIG), ("pipeline", "--samples", TOO_BIG),
    ("pipeline", "--horizon", TOO_BIG), ("pipeline", "--stride", "0"),
    ("pipeline", "--replan-every", "-1"), ("pipeline", "--dynamics-epochs", TOO_BIG),
    ("pipeline", "--goal-epochs", "0"),
]


def invoke(monkeypatch, capsys, *args: str) -> tuple[int, str, str]:
    """Run ``dynoplan ARGS`` in this process as the console script does: exit status,
    stdout, stderr."""
    from dynoplan.cli.main import main

    monkeypatch.setattr(sys, "argv", ["dynoplan", *args])
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        with pytest.raises(SystemExit) as exit_info:
            main()
    finally:
        for s, handler in handlers.items():
            signal.signal(s, handler)
    out, err = capsys.readouterr()
    code = exit_info.value.code
    return code if isinstance(code, int) else 1, out, err


def assert_one_line_error(code: int, err: str, *needles: str) -> str:
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("dynoplan: error: "), err
    assert "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


def command(name: str, tmp_path: Path, models: Path | None = None) -> list[str]:
    swap = {"OUT": str(tmp_path / "out"), "MODELS": str(models or tmp_path / "models")}
    return [swap.get(a, a) for a in COMMANDS[name]]


def leftovers(folder: Path) -> list[str]:
    """Hidden temporary files or folders under ``folder``."""
    return sorted(str(p.relative_to(folder)) for p in folder.rglob(".*")
                  if ".tmp" in p.name or p.name.endswith((".staging", ".old")))


# --- counts and seeds ---------------------------------------------------------------


@pytest.mark.parametrize("name", list(COMMANDS))
@pytest.mark.parametrize("seed", ["-1", str(SEED_MAX + 1)])
def test_seed_out_of_range_names_the_flag(tmp_path, monkeypatch, capsys, name, seed):
    extra = ["--index", "0"] if name == "gear episode" else []
    code, _, err = invoke(monkeypatch, capsys, *command(name, tmp_path), *extra,
                          "--seed", seed)
    assert_one_line_error(code, err, "'--seed'")
    assert not (tmp_path / "out").exists() and not (tmp_path / "models").exists()


@pytest.mark.parametrize(("name", "flag", "value"), COUNTS)
def test_count_out_of_range_names_the_flag(tmp_path, monkeypatch, capsys, name, flag, value):
    extra = ["--index", "0"] if name == "gear episode" and flag != "--index" else []
    code, _, err = invoke(monkeypatch, capsys, *command(name, tmp_path), *extra, flag, value)
    assert_one_line_error(code, err, f"'{flag}'")
    assert not (tmp_path / "out").exists() and not (tmp_path / "models").exists()


# --- a file where a folder is expected --------------------------------------------------


@pytest.mark.parametrize("name", WITH_MODELS)
def test_models_naming_a_file_is_one_line(tmp_path, monkeypatch, capsys, name):
    file = tmp_path / "models.txt"
    file.write_text("not a folder")
    extra = ["--index", "0"] if name == "gear episode" else []
    code, _, err = invoke(monkeypatch, capsys, *command(name, tmp_path, models=file), *extra)
    assert_one_line_error(code, err, "'--models'", "is a file, expected a folder")
    assert file.read_text() == "not a folder" and not (tmp_path / "out").exists()


@pytest.mark.parametrize("name", list(COMMANDS))
def test_out_naming_a_file_is_one_line(tmp_path, monkeypatch, capsys, name):
    args = command(name, tmp_path)
    file = tmp_path / "out"
    file.write_text("keep me")
    extra = ["--index", "0"] if name == "gear episode" else []
    code, _, err = invoke(monkeypatch, capsys, *args, *extra)
    assert_one_line_error(code, err, "'--out'", "is a file, expected a folder")
    assert file.read_text() == "keep me"


# --- sweep configurations ---------------------------------------------------------------


@pytest.mark.parametrize(("body", "field"), [
    ('models = "m"\n[grid]\nhorizon = [100000000000]\n', "grid.horizon"),
    ('models = "m"\n[grid]\nsamples = [1, 1000000000]\n', "grid.samples"),
    ('models = "m"\n[grid]\nseed = [-1]\n', "grid.seed"),
    ('models = "m"\nseed = -5\n[grid]\nhorizon = [5]\n', "seed"),
    ('models = "m"\nepisodes = 1000000000\n[grid]\nhorizon = [5]\n', "episodes"),
    ('models = "m"\n[grid]\nseed = ' + str(list(range(200))) + "\nsamples = "
     + str(list(range(1, 101))) + "\n", "grid: 20000 cells"),
])
def test_sweep_config_out_of_bounds_is_one_line(tmp_path, monkeypatch, capsys, body, field):
    config = tmp_path / "grid.toml"
    config.write_text(body)
    code, _, err = invoke(monkeypatch, capsys, "sweep", str(config), "--out",
                          str(tmp_path / "out"), "--workers", "1", "--quiet")
    assert_one_line_error(code, err, str(config), field)
    assert not (tmp_path / "out").exists()


# --- models folders and model files -----------------------------------------------------


@pytest.fixture(scope="module")
def gear_models(tmp_path_factory) -> Path:
    """A tiny but valid gear models folder (untrained widths of 4; loads, never runs)."""
    from dynoplan.envs.gear.features import feature_map
    from dynoplan.envs.gear.learning.settings import QUICK_SETTINGS
    from dynoplan.envs.gear.models_folder import TASK_NAME, load_gear_models
    from dynoplan.envs.gear.options.catalog import gear_option_names
    from dynoplan.envs.gear.state import DECISION_STEPS, STATE_DIM
    from dynoplan.models.features import GoalOnFeatures, RegionsOnFeatures
    from dynoplan.models.goal_network import GoalNetwork
    from dynoplan.models.neural_dynamics import MLPEnsembleDynamics
    from dynoplan.models.regions import SafetyRegions
    from dynoplan.pipeline.fit import FittedModels

    folder = tmp_path_factory.mktemp("models") / "models"
    folder.mkdir()
    rng = np.random.default_rng(0)
    names = list(gear_option_names())
    x = rng.normal(size=(20 * len(names), STATE_DIM))
    goal_map = feature_map(QUICK_SETTINGS.goal_features or "")
    goal, _ = GoalNetwork.fit(goal_map(x), rng.uniform(size=len(x)), hidden=4, members=1,
                              epochs=1, seed=0)
    labels = np.repeat(np.arange(len(names)), 20)
    regions = feature_map(QUICK_SETTINGS.region_features or "")
    fitted = SafetyRegions.fit(regions(x), labels, names, n_components=len(names))
    dynamics = {name: MLPEnsembleDynamics(STATE_DIM, [4], 1, option=name) for name in names}
    FittedModels(names, dynamics, GoalOnFeatures(goal, goal_map),
                 RegionsOnFeatures(fitted, regions), DECISION_STEPS,
                 {"state_scale": x.std(axis=0).tolist()}, True, TASK_NAME).write(folder)
    load_gear_models(folder)  # valid as made
    return folder


def _rewrite(file: Path, arrays_fn=None, meta_fn=None) -> None:
    """Change a model file's arrays or header and record its new SHA-256 in the manifest
    (a corrupt file whose checksum matches)."""
    from safetensors import safe_open
    from safetensors.numpy import save_file

    from dynoplan.models.folder import MANIFEST_FILE, file_sha256

    with safe_open(str(file), framework="numpy") as f:
        header = f.metadata()
        arrays = {k: f.get_tensor(k) for k in f.keys()}  # noqa: SIM118
    meta = json.loads(header["dynoplan"])
    arrays = arrays_fn(arrays) if arrays_fn else arrays
    meta = meta_fn(meta) if meta_fn else meta
    save_file(arrays, str(file), metadata={"dynoplan": json.dumps(meta)})
    manifest_path = file.parent / MANIFEST_FILE
    manifest = json.loads(manifest_path.read_text())
    for entry in [manifest["goal"], manifest["regions"], *manifest["dynamics"].values()]:
        if entry["file"] == file.name:
            entry["sha256"] = file_sha256(file)
    manifest_path.write_text(json.dumps(manifest))


def _nan_in(name: str, index: int = 0):
    def change(arrays):
        a = arrays[name].copy()
        a.reshape(-1)[index] = np.nan if index == 0 else np.inf
        return {**arrays, name: a}
    return change


def _corrupt_outside(folder: Path) -> None:
    shutil.copy(folder / "goal.safetensors", folder.parent / "outside.safetensors")
    manifest = json.loads((folder / "models.json").read_text())
    manifest["goal"]["file"] = "../outside.safetensors"
    (folder / "models.json").write_text(json.dumps(manifest))


def _first_dynamics(folder: Path) -> Path:
    return sorted(folder.glob("dynamics-*.safetensors"))[0]


MODEL_CORRUPTIONS = {
    "manifest path outside the folder": (_corrupt_outside, "outside the models folder"),
    "manifest not JSON": (lambda f: (f / "models.json").write_text("{not json"),
                          "models.json: not a readable models manifest"),
    "manifest a list": (lambda f: (f / "models.json").write_text("[]"),
                        "expected a JSON object"),
    "manifest format version": (lambda f: (f / "models.json").write_text(json.dumps(
        {**json.loads((f / "models.json").read_text()), "format_version": 99})),
        "format_version 99"),
    "truncated model file": (lambda f: (f / "regions.safetensors").write_bytes(
        (f / "regions.safetensors").read_bytes()[:-16]), "does not match models.json"),
    "NaN dynamics weight": (lambda f: _rewrite(_first_dynamics(f), _nan_in("weight_0")),
                            "array 'weight_0' must be finite"),
    "inf dynamics normaliser": (lambda f: _rewrite(_first_dynamics(f),
                                                   _nan_in("input_std", 1)),
                                "array 'input_std' must be finite"),
    "NaN region mean": (lambda f: _rewrite(f / "regions.safetensors", _nan_in("means")),
                        "array 'means' must be finite"),
    "NaN region precision": (lambda f: _rewrite(f / "regions.safetensors",
                                                _nan_in("precisions_cholesky")),
                             "array 'precisions_cholesky' must be finite"),
    "inf region threshold": (lambda f: _rewrite(f / "regions.safetensors",
                                                _nan_in("log_thresholds", 1)),
                             "array 'log_thresholds' must be finite"),
    "NaN goal weight": (lambda f: _rewrite(f / "goal.safetensors", _nan_in("w1")),
                        "array 'w1' must be finite"),
    "huge hidden sizes": (lambda f: _rewrite(_first_dynamics(f), meta_fn=lambda m: {
        **m, "hidden_sizes": [1_000_000, 1_000_000]}), "metadata describes a network"),
    "huge goal width": (lambda f: _rewrite(f / "goal.safetensors", meta_fn=lambda m: {
        **m, "hidden": 10**7}), "metadata describes a network"),
    "model format version": (lambda f: _rewrite(f / "goal.safetensors", meta_fn=lambda m: {
        **m, "format_version": 7}), "format_version 7 is not supported"),
}
MODEL_COMMANDS = {
    "gear evaluate": ["gear", "evaluate", "--controllers", "random", "--episodes", "1",
                      "--workers", "1", "--quiet"],
    "gear episode": ["gear", "episode", "--index", "0", "--controller", "random"],
}


@pytest.mark.parametrize("corruption", list(MODEL_CORRUPTIONS))
@pytest.mark.parametrize("name", list(MODEL_COMMANDS))
def test_corrupt_models_folder_is_one_line(tmp_path, monkeypatch, capsys, gear_models,
                                           name, corruption):
    folder = tmp_path / "models"
    shutil.copytree(gear_models, folder)
    corrupt, message = MODEL_CORRUPTIONS[corruption]
    corrupt(folder)
    code, _, err = invoke(monkeypatch, capsys, *MODEL_COMMANDS[name], "--models", str(folder),
                          "--out", str(tmp_path / "out"))
    assert_one_line_error(code, err, message)
    assert not (tmp_path / "out").exists() and not leftovers(tmp_path)


@pytest.mark.parametrize("corruption", list(MODEL_CORRUPTIONS))
def test_corrupt_models_folder_in_a_sweep_is_one_line(tmp_path, monkeypatch, capsys,
                                                      gear_models, corruption):
    folder = tmp_path / "models"
    shutil.copytree(gear_models, folder)
    corrupt, message = MODEL_CORRUPTIONS[corruption]
    corrupt(folder)
    config = tmp_path / "grid.toml"
    config.write_text(f'models = "{folder}"\nepisodes = 1\n[grid]\nhorizon = [2]\n')
    code, _, err = invoke(monkeypatch, capsys, "sweep", str(config), "--out",
                          str(tmp_path / "out"), "--workers", "1", "--quiet")
    assert_one_line_error(code, err, message)


# --- flat policies ----------------------------------------------------------------------


def _flat_folder(tmp_path: Path, meta, tensors=None) -> Path:
    import torch
    from safetensors.torch import save_file

    folder = tmp_path / "flat"
    folder.mkdir(exist_ok=True)
    text = meta if isinstance(meta, str) else json.dumps(meta)
    (folder / "flat_policy.json").write_text(text)
    save_file(tensors if tensors is not None else {"w": torch.zeros(64, 50)},
              str(folder / "flat_policy.safetensors"))
    return folder


FLAT_CASES = {
    "a list": ("[128, 128]", "expected a JSON object"),
    "no net_arch": ({"format_version": 1}, "field 'net_arch'"),
    "garbage net_arch": ({"format_version": 1, "net_arch": "big"}, "field 'net_arch'"),
    "negative net_arch": ({"format_version": 1, "net_arch": [64, -1]}, "field 'net_arch'"),
    "huge net_arch": ({"format_version": 1, "net_arch": [10**6, 10**6]},
                      "metadata describes a network"),
    "format version": ({"format_version": 2, "net_arch": [64]}, "format_version 2"),
    "NaN weights": ({"format_version": 1, "net_arch": [64]}, "tensor 'w' must be finite"),
    "not JSON": ("{", "not a readable flat policy's metadata"),
}


@pytest.mark.parametrize("case", list(FLAT_CASES))
def test_malformed_flat_policy_is_one_line(tmp_path, monkeypatch, capsys, gear_models, case):
    import torch

    from dynoplan.envs.gear.flat_policy import read_flat_policy

    meta, message = FLAT_CASES[case]
    tensors = {"w": torch.full((64, 50), float("nan"))} if case == "NaN weights" else None
    flat = _flat_folder(tmp_path, meta, tensors)
    with pytest.raises(DynoplanError, match="flat_policy") as info:
        read_flat_policy(flat)
    assert message in str(info.value)
    code, _, err = invoke(monkeypatch, capsys, "gear", "evaluate", "--models", str(gear_models),
                          "--controllers", "flat_ppo", "--flat", str(flat), "--episodes", "1",
                          "--workers", "1", "--quiet", "--out", str(tmp_path / "out"))
    assert_one_line_error(code, err, message)
    assert not (tmp_path / "out").exists()


def test_flat_policy_of_another_architecture_is_one_line(tmp_path):
    from dynoplan.envs.gear.env import GearAssemblyEnv
    from dynoplan.envs.gear.flat_policy import FlatPolicy

    flat = _flat_folder(tmp_path, {"format_version": 1, "net_arch": [8]})
    env = GearAssemblyEnv()
    try:
        with pytest.raises(DynoplanError, match="weights do not fit the net_arch"):
            FlatPolicy(flat, env)
    finally:
        env.close()


def test_gear_evaluation_of_flat_ppo_without_its_folder_is_one_error(tmp_path):
    from dynoplan.experiments.gear_evaluate import run_gear_evaluation

    with pytest.raises(DynoplanError, match="flat_ppo needs the flat policy's folder"):
        run_gear_evaluation(tmp_path / "models", tmp_path / "out", ["flat_ppo"], 1)
    assert not (tmp_path / "out").exists()


# --- datasets ---------------------------------------------------------------------------


def _empty_dataset(folder: Path) -> Path:
    import h5py

    data = folder / "data"
    data.mkdir(parents=True)
    h5py.File(data / "main_data.hdf5", "w").close()
    (data / "metadata.json").write_text(json.dumps({
        "dataset_id": "empty-v0", "total_episodes": 0, "total_steps": 0,
        "data_format": "hdf5", "observation_space": "{}", "action_space": "{}"}))
    return folder


@pytest.mark.parametrize("name", ["gear train", "pipeline"])
def test_dataset_with_zero_episodes_is_one_line(tmp_path, monkeypatch, capsys, name):
    demos = _empty_dataset(tmp_path / "demos")
    flag = "--demos" if name == "gear train" else "--demo-dataset"
    code, _, err = invoke(monkeypatch, capsys, *command(name, tmp_path), flag, str(demos))
    assert_one_line_error(code, err, "total_episodes", "expected at least one episode")
    assert not (tmp_path / "out").exists() and not leftovers(tmp_path)


# --- no lost output: staged folders, interrupted runs, leftovers ------------------------


@pytest.mark.parametrize("failure", [DynoplanError("bad data"), KeyboardInterrupt()])
def test_failed_training_keeps_the_previous_models(tmp_path, monkeypatch, gear_models,
                                                   failure):
    import dynoplan.envs.gear.learning.training as gear_models_module
    from dynoplan.envs.gear.learning.settings import QUICK_METRICS, QUICK_SETTINGS
    from dynoplan.envs.gear.models_folder import load_gear_models
    from dynoplan.envs.gear.stages import learned_models

    folder = tmp_path / "models"
    shutil.copytree(gear_models, folder)
    before = {p.name: p.read_bytes() for p in folder.iterdir()}

    def fail_halfway(demos, transitions, out, *args, **kwargs):
        (out / "models.json").unlink()  # as training began: the manifest gone,
        (out / "goal.safetensors").write_bytes(b"half")  # a model half-written
        raise failure

    monkeypatch.setattr(gear_models_module, "train_gear_models", fail_halfway)
    with pytest.raises(type(failure)):
        learned_models(tmp_path / "demos", None, folder, 0, tmp_path / "held", QUICK_SETTINGS,
                       QUICK_METRICS)
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before
    load_gear_models(folder)
    assert not leftovers(tmp_path)


def test_staged_folder_replaces_entries_only_when_complete(tmp_path):
    from dynoplan.io import staged_folder, write_json

    out = tmp_path / "out"
    out.mkdir()
    (out / "summary.json").write_text("old")
    (out / "notes.txt").write_text("the user's")
    with pytest.raises(RuntimeError), staged_folder(out) as stage:
        write_json(stage / "summary.json", {"run": 2})
        raise RuntimeError("failed")
    assert (out / "summary.json").read_text() == "old" and not leftovers(tmp_path)
    with staged_folder(out) as stage:
        write_json(stage / "summary.json", {"run": 3})
        assert (out / "summary.json").read_text() == "old"  # not until complete
    assert json.loads((out / "summary.json").read_text()) == {"run": 3}
    assert (out / "notes.txt").read_text() == "the user's" and not leftovers(tmp_path)
    with pytest.raises(RuntimeError), staged_folder(tmp_path / "a" / "b" / "new"):
        raise RuntimeError("rejected")
    assert not (tmp_path / "a").exists()  # the folders made for it are gone too



@pytest.mark.parametrize("keep", [False, True])
@pytest.mark.parametrize("cwd", ["parent", "target"])
def test_staged_folder_drops_the_previous_outputs_the_block_did_not_write(
        tmp_path, monkeypatch, keep, cwd):
    """``drop``: a previous run's outputs go at the move unless written anew (the target
    replaced whole, or entry by entry when the working folder is inside it); the other
    entries stay; nothing changes until the block completes."""
    from dynoplan.io import staged_folder

    out = tmp_path / "out"
    (out / "beyond" / "data").mkdir(parents=True)
    (out / "beyond" / "data" / "main_data.hdf5").write_text("the previous run's")
    (out / "runs.json").write_text("the previous run's")
    (out / "notes.txt").write_text("the user's")
    monkeypatch.chdir(out if cwd == "target" else tmp_path)
    with pytest.raises(RuntimeError), staged_folder(out, keep, drop=("beyond",
                                                                     "runs.json")) as stage:
        assert not (stage / "beyond").exists()  # not copied with keep
        raise RuntimeError("failed")
    assert (out / "beyond" / "data" / "main_data.hdf5").is_file() and not leftovers(tmp_path)
    with staged_folder(out, keep, drop=("beyond", "runs.json", "missing")) as stage:
        (stage / "runs.json").write_text("this run's")
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt", "runs.json"]
    assert (out / "runs.json").read_text() == "this run's"
    assert (out / "notes.txt").read_text() == "the user's" and not leftovers(tmp_path)


def _dead_pid() -> int:
    pid = 2**22 - 1
    while True:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return pid
        except OSError:
            pass
        pid -= 1


def test_leftovers_of_a_killed_writer_are_removed_by_the_next_write(tmp_path):
    from dynoplan.io import staged_folder, write_json

    dead = _dead_pid()
    stale_file = tmp_path / f".summary.{dead}.x1y2.tmp.json"
    stale_file.write_bytes(b"")
    stale_stage = tmp_path / f".out.{dead}.abcd.staging"
    stale_stage.mkdir()
    alive = tmp_path / f".summary.{os.getpid()}.busy.tmp.json"  # another write of ours
    alive.write_bytes(b"")
    write_json(tmp_path / "summary.json", {})
    with staged_folder(tmp_path / "out"):
        pass
    assert not stale_file.exists() and not stale_stage.exists() and alive.exists()


def start_long_random_walk(out: Path) -> "tuple[subprocess.Popen[str], list[Path]]":
    """A ``random-walk`` into ``out`` long enough to be interrupted, in a subprocess, once
    its staging folder exists beside ``out``: the process and that folder (a list of one)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    proc = subprocess.Popen([*CLI, "random-walk", "--episodes", "100000", "--out", str(out),
                             "--quiet"], stderr=subprocess.PIPE, text=True, env=env)
    deadline = time.monotonic() + 120
    while not (staged := [p for p in out.parent.iterdir() if p.name.endswith(".staging")]):
        assert proc.poll() is None and time.monotonic() < deadline, proc.stderr
        time.sleep(0.05)
    return proc, staged


@pytest.mark.parametrize(("sig", "status"), [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_interrupted_run_prints_aborted_and_keeps_the_previous_output(tmp_path, sig, status):
    out = tmp_path / "rw"
    out.mkdir()
    (out / "summary.json").write_text('{"previous": true}')
    proc, _ = start_long_random_walk(out)
    time.sleep(0.5)  # inside the run
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == status
    assert err.strip().splitlines() == ["dynoplan: aborted"]
    assert [p.name for p in out.iterdir()] == ["summary.json"]
    assert (out / "summary.json").read_text() == '{"previous": true}'
    assert not leftovers(tmp_path)


@pytest.mark.slow
def test_labels_of_one_option_train_nothing(tmp_path, monkeypatch, capsys, gear_models):
    """Demonstrations that show one option only: one line, and the models folder that was
    there before stays as it was (training used to leave a half-written goal.safetensors
    behind)."""
    from dataclasses import replace

    from dynoplan.data import read_dataset, write_dataset

    for out, extra in (("demos", []), ("held", ["--heldout"])):
        code, _, err = invoke(monkeypatch, capsys, "gear", "demos", "--n", "1",
                              "--demonstrator", "expert", "--quiet", "--workers", "1",
                              "--out", str(tmp_path / out), *extra)
        assert code == 0, err
    demos = read_dataset(tmp_path / "demos")
    one = [replace(e, infos={**e.infos, "option": np.zeros_like(e.infos["option"])})
           for e in demos]
    write_dataset(tmp_path / "one", one, demos.metadata)
    folder = tmp_path / "models"
    shutil.copytree(gear_models, folder)
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    code, _, err = invoke(monkeypatch, capsys, "gear", "train", "--demos", str(tmp_path / "one"),
                          "--heldout", str(tmp_path / "held"), "--out", str(folder),
                          "--quick", "--quiet", "--workers", "1")
    assert_one_line_error(code, err, "transitions to learn its dynamics")
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before
    assert not leftovers(tmp_path)


# --- rejected after the flags' checks: still no output folder ----------------------------

LATE_REJECTIONS = {
    "random-walk": (["--noise", "2"], "--noise"),
    "gear expert": (["--human", "nobody"], "--human"),
    "gear demos": (["--human", "nobody"], "--human"),
    "gear collect": (["--workers", "0"], "--workers"),
    "gear option": (["--human", "nobody"], "--human"),
    "gear train": (["--demos", "missing-demos"], "missing-demos"),
    "gear figures": (["--demos", "missing-demos"], ""),
    "gear run": (["--workers", "0"], "--workers"),
    "gear evaluate": (["--controllers", "nosuch"], "nosuch"),
    "gear episode": (["--index", "0", "--controller", "nosuch"], "nosuch"),
    "gear render": (["--human", "nobody"], "--human"),
    "pipeline": (["--options", "examples.mountain_car.options:nosuch"], "nosuch"),
}


@pytest.mark.parametrize("name", list(COMMANDS))
def test_rejected_command_leaves_no_output_folder(tmp_path, monkeypatch, capsys, name):
    extra, needle = LATE_REJECTIONS[name]
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(Path(__file__).parents[1]))  # examples/, from anywhere
    code, _, err = invoke(monkeypatch, capsys, *command(name, tmp_path), *extra)
    assert_one_line_error(code, err, needle)
    assert sorted(p.name for p in tmp_path.iterdir()) == [], err


def test_unknown_goal_feature_map_is_one_line_and_no_output(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    code, _, err = invoke(monkeypatch, capsys, *command("gear train", tmp_path),
                          "--goal-features", "nosuch")
    assert_one_line_error(code, err, "unknown feature map 'nosuch'")
    assert sorted(p.name for p in tmp_path.iterdir()) == [], err
