"""Issue 34: the command line's start-up and shutdown.

``--help`` and usage errors import neither torch nor the pipeline (they answer in well
under a second: ``docs/benchmarks.md``), and SIGINT or SIGTERM at any moment, while
the modules of a command import and while the interpreter shuts down included, print
``dynoplan: aborted`` and exit with 130 or 143, never a traceback.

The signals are sent at moments read from ``/proc`` (the handler installed, torch's
library mapped), not after guessed delays.
"""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

CLI_CODE = "from dynoplan.cli.main import main; main()"
HEAVY = ("torch", "numpy", "dynoplan.pipeline", "dynoplan.experiments", "sklearn", "mujoco")


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}


@pytest.mark.parametrize("args", [["--help"], ["gear", "--help"], ["pipeline", "--help"],
                                  ["random-walk", "--bogus"], ["nosuch"],
                                  ["pipeline", "--episodes", "0"]])
def test_help_and_usage_errors_import_no_torch_nor_pipeline(args):
    code = ("import sys\nfrom dynoplan.cli.main import main\nsys.argv = ['dynoplan', *"
            f"{args!r}]\ntry:\n    main()\nexcept SystemExit as e:\n    status = e.code\n"
            f"print(status, [m for m in {HEAVY!r} if m in sys.modules])")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env=_env(), timeout=120)
    status, loaded = done.stdout.strip().splitlines()[-1].split(" ", 1)
    assert loaded == "[]", done.stdout
    assert int(status) == (0 if "--help" in args else 2), done.stderr
    if "--help" not in args:
        assert done.stderr.count("\n") == 1 and done.stderr.startswith("dynoplan: error: ")


def _caught(pid: int) -> int:
    """The signals process ``pid`` has a handler for (SigCgt of /proc/PID/status)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("SigCgt:"):
            return int(line.split()[1], 16)
    return 0


def _wait(proc: subprocess.Popen[str], ready, what: str) -> None:
    deadline = time.monotonic() + 120
    while True:
        try:
            if ready(proc.pid):
                return
        except OSError:  # /proc entry gone: the process ended
            pass
        assert proc.poll() is None, f"ended before {what}: {proc.communicate()}"
        assert time.monotonic() < deadline, f"never {what}"
        time.sleep(0.002)


def _handler_installed(pid: int) -> bool:
    return bool(_caught(pid) & (1 << (signal.SIGTERM - 1)))


def _torch_loading(pid: int) -> bool:
    return "libtorch" in Path(f"/proc/{pid}/maps").read_text()


def _snapshot(folder: Path) -> dict[str, bytes | None]:
    """Every entry under ``folder`` (hidden ones too), with a file's bytes."""
    return {str(p.relative_to(folder)): (p.read_bytes() if p.is_file() else None)
            for p in sorted(folder.rglob("*"))}


def _command(name: str, tmp_path: Path) -> list[str]:
    """The arguments of command ``name`` writing into ``tmp_path/out``: commands that
    import torch and the pipeline (or the gear) before they run."""
    out = str(tmp_path / "out")
    if name == "gear evaluate":
        return ["gear", "evaluate", "--models", str(tmp_path / "models"), "--out", out,
                "--quiet", "--workers", "1"]
    if name == "random-walk":
        return ["random-walk", "--episodes", "5", "--out", out, "--quiet"]
    config = tmp_path / "grid.toml"
    config.write_text('models = "m"\n[grid]\nhorizon = [5]\n')
    return ["sweep", str(config), "--out", out, "--workers", "1", "--quiet"]


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="needs Linux's /proc")
@pytest.mark.parametrize("name", ["gear evaluate", "random-walk", "sweep"])
@pytest.mark.parametrize("moment", ["start-up", "torch import"])
@pytest.mark.parametrize(("sig", "status"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_signal_while_modules_import_prints_aborted(tmp_path, sig, status, moment, name):
    """``gear evaluate``, ``random-walk`` and ``sweep`` import torch and the pipeline (or
    the gear) before they run: the signal lands in those imports (as soon as the handler
    is installed, or once torch's library is mapped, torch's import under way: the
    handler must be there before). The previous output and its parent stay as they
    were."""
    args = _command(name, tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    (out / "summary.json").write_text('{"previous": true}')
    before = _snapshot(tmp_path)
    proc = subprocess.Popen([sys.executable, "-c", CLI_CODE, *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=_env())
    if moment == "torch import":  # whether or not the handler is installed by then
        _wait(proc, _torch_loading, "imported torch")
    else:
        _wait(proc, _handler_installed, "installed its handler")
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    assert err.strip().splitlines() == ["dynoplan: aborted"], err
    assert proc.returncode == status
    assert _snapshot(tmp_path) == before


@pytest.mark.parametrize(("sig", "status"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_signal_at_shutdown_prints_aborted(tmp_path, sig, status):
    """A signal that arrives once the command is over, while ``atexit`` callbacks run (as
    torch's ``_del_library`` does), ends the process with one line, not with "Exception
    ignored in atexit callback" and a traceback."""
    code = ("import atexit, os, signal, time\n"
            f"atexit.register(lambda: (os.kill(os.getpid(), {int(sig)}), time.sleep(5)))\n"
            + CLI_CODE.replace("; ", "\n") + "\n")
    done = subprocess.run([sys.executable, "-c", code, "random-walk", "--episodes", "1",
                           "--out", str(tmp_path / "rw"), "--quiet"],
                          capture_output=True, text=True, env=_env(), timeout=120)
    assert done.stdout.startswith("success "), done.stdout  # the run finished
    assert done.stderr.strip().splitlines() == ["dynoplan: aborted"], done.stderr
    assert done.returncode == status
    assert (tmp_path / "rw" / "summary.json").is_file()


def test_python_dash_m_dynoplan_is_the_command():
    done = subprocess.run([sys.executable, "-m", "dynoplan", "nosuch"], capture_output=True,
                          text=True, env=_env(), timeout=60)
    assert done.returncode == 2
    assert done.stderr.strip().startswith("dynoplan: error:")
    assert "Traceback" not in done.stderr
