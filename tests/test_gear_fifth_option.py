"""A fifth gear option is a policy file and one registration (``examples/gear_lift_option.py``),
and every stage then has it: the option list, standalone trials, collection, a dynamics
model in ``models.json``, the figures, the outcome runs and the initiation learned from
them, and the DynoPlan controllers, the default one (learned sets only) too.

Registrations are undone after every test (:func:`temporary_gear_options`), so the other
tests see the paper's four options only.
"""

import dataclasses
import importlib
import json
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from dynoplan.envs.gear.controllers import GEAR_CONTROL, own_sets
from dynoplan.envs.gear.env import GearAssemblyEnv
from dynoplan.envs.gear.options import (
    GearOption,
    gear_option,
    gear_option_names,
    register_gear_option,
    temporary_gear_options,
)
from dynoplan.envs.gear.options.catalog import INSERT_FILE, PAPER_OPTIONS, RECOGNIZER_FILE
from dynoplan.envs.gear.pipeline_task import GearTask
from dynoplan.envs.gear.state import STATE_DIM, STATE_SLICES
from dynoplan.errors import DynoplanError
from dynoplan.seeding import episode_seeds

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "gear_lift_option.py"


def _unused(env: GearAssemblyEnv) -> None:
    raise AssertionError("never built")


@pytest.fixture
def lift(monkeypatch: pytest.MonkeyPatch) -> Iterator[ModuleType]:
    """The example module, its option registered for this test only."""
    monkeypatch.syspath_prepend(str(ROOT))
    with temporary_gear_options():
        module = importlib.import_module("examples.gear_lift_option")
        register_gear_option(module.LIFT)  # the import registered it only the first time
        yield module


def test_a_registered_option_comes_last_with_the_next_label(lift: ModuleType) -> None:
    assert gear_option_names() == (*PAPER_OPTIONS, "lift")
    assert gear_option("lift") is lift.LIFT
    assert gear_option("lift").factory(None) is lift.LiftPolicy  # no network to read
    # where it may start: its own condition (it has no learned region until demonstrated)
    s = np.zeros((3, STATE_DIM))
    s[:, STATE_SLICES["gripper"]] = 0.0  # closed
    s[:, STATE_SLICES["gear_pos"].stop - 1] = [0.9, 0.9, 0.72]  # lifted, lifted, on the table
    s[:, STATE_SLICES["tool_pos"].stop - 1] = [0.95, lift.LIFT_Z, 0.75]
    initiation, continuation = own_sets("lift", "rules")
    assert initiation.contains(s).tolist() == [True, False, False]
    assert continuation is None
    env = GearAssemblyEnv()
    beta = lift.LiftPolicy(env).termination()
    env.close()
    assert beta.probability(s).tolist() == [0.0, 1.0, 0.0]


def test_registration_is_undone_after_the_block() -> None:
    toy = GearOption("toy", _unused)
    with temporary_gear_options(toy):
        assert gear_option_names()[-1] == "toy"
        register_gear_option(GearOption("toy2", _unused))
    assert gear_option_names() == PAPER_OPTIONS


def test_bad_registrations_are_one_clear_error() -> None:
    with temporary_gear_options():
        with pytest.raises(DynoplanError, match="'pick' is already registered"):
            register_gear_option(GearOption("pick", _unused))
        with pytest.raises(DynoplanError, match="without spaces"):
            GearOption("two words", _unused)
        with pytest.raises(DynoplanError, match="exactly one of policy"):
            GearOption("nothing")
        with pytest.raises(DynoplanError, match="human_mode must be one of"):
            GearOption("x", _unused, human_mode="dance")
        with pytest.raises(DynoplanError, match=r"unknown option 'lift'.*DYNOPLAN_GEAR_OPTIONS"):
            gear_option("lift")
        assert gear_option_names() == PAPER_OPTIONS


def _dynoplan(*args: str, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", "from dynoplan.cli.main import main; main()",
                           *args], capture_output=True, text=True, timeout=300, cwd=ROOT,
                          env={**os.environ, **env})


def test_the_command_line_runs_an_option_named_in_the_environment(tmp_path: Path) -> None:
    out = tmp_path / "lift"
    done = _dynoplan("gear", "option", "lift", "--trials", "3", "--out", str(out), "--quiet",
                     env={"DYNOPLAN_GEAR_OPTIONS": "examples/gear_lift_option.py"})
    assert done.returncode == 0, done.stderr
    summary = json.loads((out / "summary.json").read_text())
    # started after the pick (gear in hand), lifted to the height and held, 3 of 3
    assert summary["option"] == "lift" and summary["successes"] == 3
    assert summary["statuses"] == {"done": 3} and summary["human_modes"] == ["away"]

    broken = _dynoplan("gear", "option", "lift", env={"DYNOPLAN_GEAR_OPTIONS": "nowhere.py"})
    assert broken.returncode == 2
    assert broken.stderr.strip() == ("dynoplan: error: DYNOPLAN_GEAR_OPTIONS: file nowhere.py "
                                     "not found")


@pytest.mark.slow
def test_the_fifth_option_flows_through_every_stage(lift: ModuleType, quick_gear_run: Path,
                                                    tmp_path: Path) -> None:
    from dynoplan.data import read_dataset
    from dynoplan.envs.gear.learning.training import train_gear_models
    from dynoplan.envs.gear.models_folder import load_gear_models
    from dynoplan.envs.gear.option_runs import collect_gear_transitions
    from dynoplan.envs.gear.pipeline_stages import run_settings
    from dynoplan.envs.gear.reports.figures import make_gear_figures
    from dynoplan.envs.gear.stages import learned_initiation

    models = tmp_path / "models"
    models.mkdir()
    for file in (RECOGNIZER_FILE, INSERT_FILE):  # the paper's networks, from the quick run
        shutil.copy(quick_gear_run / "models" / file, models / file)

    # collection runs it from its start sampler, labelled 4
    collected = collect_gear_transitions(models, 4, 0, tmp_path / "transitions", max_decisions=15,
                                    progress=False)
    assert collected["transitions"]["lift"] > 20
    dataset = read_dataset(tmp_path / "transitions")
    assert dataset.metadata.option_names == [*PAPER_OPTIONS, "lift"]
    assert {int(e.options[0]) for e in dataset if e.options is not None} == {0, 1, 2, 3, 4}

    # a dynamics model for it, listed in models.json; the demonstrations (recorded before
    # it was registered, by an operator that does not use it) give it no region
    metrics = train_gear_models(quick_gear_run / "demos", tmp_path / "transitions", models,
                                seed=0, heldout_demos=quick_gear_run / "heldout", quick=True,
                                progress=False)
    assert metrics["option_names"][-1] == "lift" and metrics["dynamics"]["lift"]["epochs"] > 0
    manifest = json.loads((models / "models.json").read_text())
    assert manifest["option_names"] == [*PAPER_OPTIONS, "lift"]
    assert manifest["dynamics"]["lift"]["file"] == "dynamics-lift.safetensors"
    loaded = load_gear_models(models)
    assert loaded.option_names == [*PAPER_OPTIONS, "lift"]
    assert loaded.regions.option_names == list(PAPER_OPTIONS)
    assert "lift" not in metrics["regions"]["inside_rate_by_option"]

    figures = make_gear_figures(models, quick_gear_run / "demos", quick_gear_run / "heldout",
                                tmp_path / "figures", max_points=200)
    assert figures["fig3b"]["region_share"]["lift"] is None
    assert figures["fig3b"]["region_share"]["pick"] is not None

    # DynoPlan on the options' own conditions plans with it: admissible once the gear is
    # carried, scored, one episode run
    scored = _lift_decisions("dynoplan+rules", models)
    assert scored and all(np.isfinite(score) for score in scored)

    # the default DynoPlan (learned sets only) has no set for it yet: no region, no
    # outcomes, so it is never admissible ...
    assert _lift_decisions("dynoplan", models) == []
    # ... until the outcomes stage (gear run's, its --quick sizes) has run every registered
    # option, the lift too, from starts beyond its own, and learned where each may start
    outcomes = learned_initiation(models, tmp_path / "outcomes", 0, run_settings(True).outcomes,
                                  progress=False)
    assert outcomes["starts"]["lift"] > 0 and outcomes["ended_well"]["lift"] > 0
    assert outcomes["options"]["lift"]["admissible_share"] > 0
    assert json.loads((models / "initiation.json").read_text())["without_runs"] == []
    learned = load_gear_models(models).learned_initiation
    assert learned is not None and learned.option_names == [*PAPER_OPTIONS, "lift"]
    # the default DynoPlan now plans with it: admissible and scored in a seeded episode
    scored = _lift_decisions("dynoplan", models)
    assert scored and all(np.isfinite(score) for score in scored)


def _lift_decisions(controller: str, models: Path) -> list[float]:
    """The planner's scores of the lift in the decisions of one seeded episode of
    ``controller`` (small planner settings) where it was admissible."""
    runner = GearTask().make_runner(controller, models,
                                    dataclasses.replace(GEAR_CONTROL, horizon=3, samples=8))
    names = [o.name for o in runner.controller.options]
    assert names == [*PAPER_OPTIONS, "lift"]
    lift = names.index("lift")
    trace = runner.run(episode_seeds(7, 1)[0])
    runner.env.close()
    assert trace.env_steps > 0
    return [float(d.plan.scores[lift]) for d in trace.decisions if d.plan.admissible[lift]]
