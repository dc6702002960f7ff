"""The core install: ``pip install dynoplan`` runs the generic pipeline without MuJoCo, OMPL,
mink, daqp, video libraries or Stable-Baselines3 (the ``gear`` extra's)."""

import json
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from dynoplan.cli.params import GEAR_MODULES

ROOT = Path(__file__).resolve().parents[1]
EXTRAS = (*GEAR_MODULES, "imageio_ffmpeg", "ray", "minari")

RUN_CORE = textwrap.dedent('''
    import sys

    import dynoplan.cli.main  # the command line, gear commands included
    from dynoplan.pipeline import ControllerSettings, FitSettings, PipelineSettings, run_pipeline
    from examples.mountain_car.options import make_demonstrator, make_options

    settings = PipelineSettings(
        demos=2, exploration_episodes=3, episodes=2,
        fit=FitSettings(dynamics_hidden=(8,), dynamics_members=1, dynamics_epochs=2,
                        dynamics_min_updates=20,
                        goal_hidden=8, goal_epochs=5, region_components=1),
        control=ControllerSettings(horizon=3, samples=4, max_decisions=30))
    run_pipeline("MountainCarContinuous-v0", make_options(), make_demonstrator(),
                 settings=settings, success=lambda obs, info: obs[0] >= 0.45)
    print(" ".join(sorted({m.split(".")[0] for m in sys.modules})))
''')


def test_the_core_pipeline_imports_no_extra():
    done = subprocess.run([sys.executable, "-c", RUN_CORE], capture_output=True, text=True,
                          timeout=300, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    loaded = set(done.stdout.split())
    assert "torch" in loaded and "gymnasium" in loaded
    assert not loaded & set(EXTRAS), loaded & set(EXTRAS)


def test_a_gear_command_without_the_gear_extra_is_one_line(monkeypatch, capsys):
    import importlib.util

    from dynoplan.cli.main import main

    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name in ("mujoco", "ompl") else
                        find_spec(name, *a))
    for args in (["gear", "expert", "--episodes", "1"], ["sweep", "grid.toml"]):
        monkeypatch.setattr(sys, "argv", ["dynoplan", *args])
        with pytest.raises(SystemExit) as exit_info:
            main()
        err = capsys.readouterr().err
        assert exit_info.value.code == 2, err
        assert err == ("dynoplan: error: the gear needs mujoco, ompl, which the core install "
                       "does not have: pip install 'dynoplan[gear]'\n")


@pytest.mark.slow
def test_a_fresh_environment_with_the_core_alone_runs_the_pipeline(tmp_path):
    """``pip install torch==2.13.0`` (the Makefile's pinned CPU wheel) then ``pip install
    .`` (no extra) in a new virtual environment; MountainCar's pipeline runs in it."""
    package = tmp_path / "package"
    package.mkdir()
    shutil.copytree(ROOT / "src", package / "src",
                    ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, package / name)
    shutil.copytree(ROOT / "examples" / "mountain_car", tmp_path / "examples" / "mountain_car")
    (tmp_path / "examples" / "__init__.py").touch()
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    pip = [str(venv / "bin" / "python"), "-m", "pip", "install", "--quiet"]
    for target in ("torch==2.13.0", str(package)):
        done = subprocess.run([*pip, target], capture_output=True, text=True, timeout=1800)
        assert done.returncode == 0, done.stderr[-3000:]
    python = str(venv / "bin" / "python")
    probe = f"import importlib.util as u; print(*(m for m in {EXTRAS!r} if u.find_spec(m)))"
    installed = subprocess.run([python, "-c", probe], capture_output=True, text=True,
                               timeout=300, check=True).stdout.split()
    assert installed == [], installed
    done = subprocess.run(
        [str(venv / "bin" / "dynoplan"), "pipeline", "--env", "MountainCarContinuous-v0",
         "--options", "examples.mountain_car.options:make_options", "--demos", "3",
         "--explore", "4", "--episodes", "3", "--dynamics-epochs", "3",
         "--dynamics-min-updates", "50", "--goal-epochs",
         "10", "--region-components", "1", "--horizon", "5", "--samples", "8", "--quiet",
         "--out", "out"], capture_output=True, text=True, timeout=1800, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["controllers"]["option:pump"]["success_rate"] > 0.0
    assert (tmp_path / "out" / "settings.toml").is_file()
    done = subprocess.run([str(venv / "bin" / "dynoplan"), "gear", "expert"],
                          capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert done.returncode == 2 and "pip install 'dynoplan[gear]'" in done.stderr
