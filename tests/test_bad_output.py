"""Issue 34: output folders that cannot be written, and leftovers of killed runs.

A folder that exists but cannot be written (read-only, immutable, on a shared drive) is
reported before any work, as one line ``dynoplan: error: cannot write to OUT: permission
denied`` with exit status 2, and the target and its parent stay as they were (no staging
folder, no ``.old`` folder). The staging folder of a run killed with SIGKILL is removed by
the next run into the same target, which says so in one line.

The read-only folders are made with ``chmod 0555``, or, for root (who writes through
modes), with ``chattr +i``; the tests are skipped when neither can make a folder
unwritable here.
"""

import json
import os
import shutil
import signal
import subprocess
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

import test_bad_input
from test_bad_input import (
    COMMANDS,
    assert_one_line_error,
    command,
    invoke,
    leftovers,
    start_long_random_walk,
)

gear_models = test_bad_input.gear_models  # the fixture: a tiny valid gear models folder


def _snapshot(folder: Path) -> dict[str, bytes | None]:
    """Every entry under ``folder`` (hidden ones too), with a file's bytes."""
    return {str(p.relative_to(folder)): (p.read_bytes() if p.is_file() else None)
            for p in sorted(folder.rglob("*"))}


def _writable(folder: Path) -> bool:
    try:
        (folder / ".probe").write_bytes(b"")
    except OSError:
        return False
    (folder / ".probe").unlink()
    return True


@pytest.fixture
def read_only() -> Iterator[Callable[[Path], None]]:
    """``read_only(folder)`` makes ``folder`` unwritable until the test ends."""
    made: list[tuple[Path, bool]] = []

    def make(folder: Path) -> None:
        if os.geteuid() != 0:
            folder.chmod(0o555)
            made.append((folder, False))
        elif subprocess.run(["chattr", "+i", str(folder)], capture_output=True).returncode:
            pytest.skip("root, and chattr +i does not work here: no folder is read-only")
        else:
            made.append((folder, True))
        if _writable(folder):
            pytest.skip(f"{folder} stays writable (chmod 0555 / chattr +i had no effect)")

    yield make
    for folder, immutable in reversed(made):
        if immutable:
            subprocess.run(["chattr", "-i", str(folder)], check=True)
        else:
            folder.chmod(0o755)


WRITERS = {**COMMANDS, "sweep": ["sweep", "CONFIG", "--out", "OUT", "--workers", "1"],
           "trap-walk": ["trap-walk", "--out", "OUT"],
           "gear outcomes": ["gear", "outcomes", "--out", "OUT", "--models", "MODELS"]}
"""Every command that writes a folder (``gear seeds`` writes one file: below)."""


def _args(name: str, tmp_path: Path) -> list[str]:
    if name in COMMANDS:
        return command(name, tmp_path) + (["--index", "0"] if name == "gear episode" else [])
    config = tmp_path / "grid.toml"
    config.write_text('models = "m"\n[grid]\nhorizon = [5]\n')
    return [{"CONFIG": str(config), "OUT": str(tmp_path / "out"),
             "MODELS": str(tmp_path / "models")}.get(a, a) for a in WRITERS[name]]


@pytest.mark.parametrize("name", list(WRITERS))
def test_read_only_output_folder_is_one_line_before_any_work(tmp_path, monkeypatch, capsys,
                                                             read_only, name):
    args = _args(name, tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    (out / "summary.json").write_text('{"previous": true}')
    read_only(out)
    before = _snapshot(tmp_path)
    monkeypatch.chdir(tmp_path)
    code, stdout, err = invoke(monkeypatch, capsys, *args)
    assert_one_line_error(code, err)
    assert err.strip() == f"dynoplan: error: cannot write to {out}: permission denied"
    assert stdout == ""  # no progress line: nothing ran
    assert _snapshot(tmp_path) == before and not leftovers(tmp_path)


@pytest.mark.parametrize("name", list(WRITERS))
def test_read_only_parent_is_one_line_before_any_work(tmp_path, monkeypatch, capsys,
                                                      read_only, name):
    """The target does not exist (or does, writable) but its staging folder cannot be
    made beside it."""
    args = _args(name, tmp_path)
    read_only(tmp_path)
    before = _snapshot(tmp_path)
    code, _, err = invoke(monkeypatch, capsys, *args)
    assert err.strip() == f"dynoplan: error: cannot write to {tmp_path}: permission denied"
    assert_one_line_error(code, err)
    assert _snapshot(tmp_path) == before


def test_sweep_with_a_read_only_resume_folder_is_one_line_before_any_work(
        tmp_path, monkeypatch, capsys, read_only):
    """The finished cells of an interrupted sweep wait beside OUT (``.out.sweep-cells``):
    checked with OUT, before the configuration is read."""
    args = _args("sweep", tmp_path)
    resume = tmp_path / ".out.sweep-cells"
    resume.mkdir()
    (resume / "cell-0123456789abcdef.json").write_text("{}")
    read_only(resume)
    before = _snapshot(tmp_path)
    code, stdout, err = invoke(monkeypatch, capsys, *args)
    assert err.strip() == f"dynoplan: error: cannot write to {resume}: permission denied"
    assert_one_line_error(code, err)
    assert stdout == "" and _snapshot(tmp_path) == before and not leftovers(tmp_path)


def test_gear_outcomes_with_read_only_models_is_one_line_before_any_work(
        tmp_path, monkeypatch, capsys, read_only):
    """The initiation goes into MODELS after the runs: checked before them."""
    models = tmp_path / "models"
    models.mkdir()
    read_only(models)
    before = _snapshot(tmp_path)
    code, stdout, err = invoke(monkeypatch, capsys, "gear", "outcomes", "--models",
                               str(models), "--out", str(tmp_path / "out"), "--runs", "1",
                               "--workers", "1", "--quiet")
    assert err.strip() == f"dynoplan: error: cannot write to {models}: permission denied"
    assert_one_line_error(code, err)
    assert stdout == "" and _snapshot(tmp_path) == before


def test_gear_seeds_into_a_read_only_folder_is_one_line(tmp_path, monkeypatch, capsys,
                                                        read_only):
    folder = tmp_path / "tables"
    folder.mkdir()
    read_only(folder)
    before = _snapshot(tmp_path)
    code, stdout, err = invoke(monkeypatch, capsys, "gear", "seeds", str(tmp_path / "run"),
                               "--out", str(folder / "seeds.md"))
    assert err.strip() == f"dynoplan: error: cannot write to {folder}: permission denied"
    assert_one_line_error(code, err)
    assert stdout == "" and _snapshot(tmp_path) == before


def test_staged_folder_checks_before_the_block_runs(tmp_path, read_only):
    """The library's own staged write: the error comes before the work, nothing made."""
    from dynoplan.errors import DynoplanError
    from dynoplan.io import staged_folder

    out = tmp_path / "out"
    out.mkdir()
    read_only(out)
    ran = []
    with pytest.raises(DynoplanError, match=r"cannot write to .*out: permission denied"), \
            staged_folder(out, keep=True):
        ran.append(True)
    assert not ran and sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_staging_folder_of_a_killed_run_is_removed_by_the_next_run(tmp_path, monkeypatch,
                                                                   capsys):
    out = tmp_path / "rw"
    out.mkdir()
    (out / "notes.txt").write_text("the user's")
    proc, staged = start_long_random_walk(out)
    time.sleep(0.3)  # inside the run
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=60)
    assert proc.returncode == -signal.SIGKILL
    assert [p.exists() for p in staged] == [True]  # SIGKILL: no clean-up ran
    assert staged[0].name.startswith(f".rw.{proc.pid}.")

    code, _, err = invoke(monkeypatch, capsys, "random-walk", "--episodes", "1",
                          "--out", str(out), "--quiet")
    assert code == 0, err
    assert err.strip().splitlines() == [
        f"dynoplan: warning: removed {staged[0]}, left by process {proc.pid}, which no "
        "longer runs"]
    assert not leftovers(tmp_path) and sorted(p.name for p in tmp_path.iterdir()) == ["rw"]
    assert (out / "notes.txt").read_text() == "the user's" and (out / "summary.json").is_file()


def test_staging_folder_of_a_running_writer_is_kept(tmp_path):
    """Only leftovers of processes that no longer run are removed, and only the target's
    own (``.rw.5.x.staging`` is not a leftover of ``rw.5``... nor of ``rw``)."""
    from dynoplan.io import staged_folder

    alive = tmp_path / f".rw.{os.getppid()}.abc_123.staging"
    other = tmp_path / ".rw.5.999.abcdefgh.staging"  # staging of a target named rw.5
    for folder in (alive, other):
        folder.mkdir()
    with staged_folder(tmp_path / "rw"):
        pass
    assert alive.is_dir() and other.is_dir()


# --- models folders and dataset targets (issue 34) ----------------------------------------

def _manifest(folder: Path, change) -> None:
    path = folder / "models.json"
    path.write_text(json.dumps(change(json.loads(path.read_text()))))


NEWER_MODELS_COMMANDS = {
    "gear evaluate": ["gear", "evaluate", "--controllers", "random", "--episodes", "1",
                      "--workers", "1", "--quiet", "--out", "OUT"],
    "gear episode": ["gear", "episode", "--index", "0", "--controller", "random", "--out",
                     "OUT"],
    "gear option": ["gear", "option", "pick", "--trials", "1", "--quiet", "--out", "OUT"],
    "gear demos": ["gear", "demos", "--n", "1", "--workers", "1", "--quiet", "--out", "OUT"],
    "gear collect": ["gear", "collect", "--runs", "1", "--workers", "1", "--quiet", "--out",
                     "OUT"],
    "gear outcomes": ["gear", "outcomes", "--runs", "1", "--workers", "1", "--quiet",
                      "--out", "OUT"],
    "gear figures": ["gear", "figures", "--quiet", "--out", "OUT"],
}


@pytest.mark.parametrize("name", list(NEWER_MODELS_COMMANDS))
def test_models_of_a_newer_format_are_refused_before_any_work(tmp_path, monkeypatch, capsys,
                                                              gear_models, name):
    from dynoplan.models.folder import FORMAT_VERSION

    folder = tmp_path / "models"
    shutil.copytree(gear_models, folder)
    _manifest(folder, lambda m: {**m, "format_version": FORMAT_VERSION + 1})
    before = _snapshot(tmp_path)
    args = [str(tmp_path / "out") if a == "OUT" else a for a in NEWER_MODELS_COMMANDS[name]]
    code, stdout, err = invoke(monkeypatch, capsys, *args, "--models", str(folder))
    assert_one_line_error(code, err, f"format_version {FORMAT_VERSION + 1}",
                          f"this dynoplan reads {FORMAT_VERSION}")
    assert stdout == "" and _snapshot(tmp_path) == before


def test_unknown_option_name_in_models_json_names_the_field(tmp_path, monkeypatch, capsys,
                                                            gear_models):
    folder = tmp_path / "models"
    shutil.copytree(gear_models, folder)
    _manifest(folder, lambda m: {**m, "option_names": [*m["option_names"][:-1], "nosuch"]})
    code, _, err = invoke(monkeypatch, capsys, "gear", "evaluate", "--controllers", "random",
                          "--episodes", "1", "--workers", "1", "--quiet", "--models",
                          str(folder), "--out", str(tmp_path / "out"))
    assert_one_line_error(code, err, "option_names", "nosuch")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("name", ["gear demos", "gear collect"])
def test_dataset_out_holding_other_things_is_one_line_before_any_work(
        tmp_path, monkeypatch, capsys, name):
    """The option networks missing from MODELS would be trained first (a progress line,
    minutes): the dataset target is checked before."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("the user's")
    before = _snapshot(tmp_path)
    extra = ["--n", "1"] if name == "gear demos" else ["--runs", "1"]
    code, stdout, err = invoke(monkeypatch, capsys, *command(name, tmp_path), *extra,
                               "--workers", "1", "--quiet")
    assert_one_line_error(code, err, f"{out}: exists and is not a dataset folder")
    assert stdout == "" and _snapshot(tmp_path) == before


def test_sweep_of_models_of_a_newer_format_is_refused(tmp_path, monkeypatch, capsys,
                                                      gear_models):
    """Refused before any cell (finished cells would be reused without loading models)."""
    from dynoplan.models.folder import FORMAT_VERSION

    folder = tmp_path / "models"
    shutil.copytree(gear_models, folder)
    _manifest(folder, lambda m: {**m, "format_version": FORMAT_VERSION + 1})
    config = tmp_path / "grid.toml"
    config.write_text(f'models = "{folder}"\nepisodes = 1\n[grid]\nhorizon = [2]\n')
    code, _, err = invoke(monkeypatch, capsys, "sweep", str(config), "--out",
                          str(tmp_path / "out"), "--workers", "1", "--quiet")
    assert_one_line_error(code, err, f"format_version {FORMAT_VERSION + 1}",
                          f"this dynoplan reads {FORMAT_VERSION}")
    assert not (tmp_path / "out").exists()
