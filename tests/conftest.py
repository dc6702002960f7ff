import os

import pytest

os.environ.setdefault("MUJOCO_GL", "egl")


def pytest_configure(config):
    # One torch thread: on a 2-core machine shared with other work, two threads make small
    # training runs 10-50x slower (oversubscription). Results do not depend on this.
    import torch

    torch.set_num_threads(1)


def pytest_collection_modifyitems(config, items):
    """Under ``pytest -n N`` (pytest-xdist, ``--dist loadgroup``) the tests that use the
    session's Ray runtime run on one worker, so that one Ray runtime serves them all; every
    other test, those on the quick gear run too, goes to whichever worker is free (each
    worker builds its own quick gear run: a few minutes, against about ten of the tests
    that read it)."""
    for item in items:
        if "ray_runtime" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.xdist_group("ray"))


def run_quick_gear(out):
    """``dynoplan gear run --quick`` on 3 episodes (the oracle on 1, no video) into ``out``,
    in this process; returns ``out``."""
    from typer.testing import CliRunner

    from dynoplan.cli.main import app

    result = CliRunner().invoke(app, ["gear", "run", "--quick", "--out", str(out), "--quiet",
                                      "--no-video", "--episodes", "3",
                                      "--oracle-episodes", "1"])
    assert result.exit_code == 0, result.output
    return out


@pytest.fixture(scope="session")
def quick_gear_run(tmp_path_factory):
    """``dynoplan gear run --quick`` once per session (a few minutes; slow tests only): its
    output folder, with ``models/``, ``flat_ppo/`` and the results of 3 episodes."""
    return run_quick_gear(tmp_path_factory.mktemp("gear-quick") / "run")


@pytest.fixture(scope="session")
def quick_gear_rerun(tmp_path_factory, quick_gear_run):
    """The command of :func:`quick_gear_run` run again, after it, into another folder."""
    return run_quick_gear(tmp_path_factory.mktemp("gear-quick-again") / "run")


@pytest.fixture(scope="session")
def ray_runtime():
    """A light local Ray runtime (2 CPUs, no dashboard) for the session's Ray tests; the
    library's maps use it rather than starting their own."""
    import logging

    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False, logging_level=logging.ERROR,
             log_to_driver=False)
    yield ray
    ray.shutdown()
