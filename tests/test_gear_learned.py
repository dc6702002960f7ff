"""The gear's learned-only controllers: initiation learned from outcomes, the variant rows."""

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from dynoplan.cli.main import app
from dynoplan.envs.gear.controllers import INITIATION_SETS, gear_options, own_sets
from dynoplan.envs.gear.env import GearAssemblyEnv
from dynoplan.envs.gear.models_folder import load_gear_models
from dynoplan.envs.gear.options.catalog import gear_option, gear_option_names, policy_factories
from dynoplan.envs.gear.state import STATE_DIM, PlannerState
from dynoplan.errors import DynoplanError
from dynoplan.options.initiation import Everywhere
from dynoplan.options.option import admissible


@pytest.mark.slow
def test_outcome_initiation_and_the_variant_rows_reach_results_csv(quick_gear_run: Path,
                                                                   tmp_path: Path):
    models = tmp_path / "models"
    shutil.copytree(quick_gear_run / "models", models)
    runner = CliRunner()
    result = runner.invoke(app, ["gear", "outcomes", "--models", str(models), "--out",
                                 str(tmp_path / "outcomes"), "--runs", "2",
                                 "--max-decisions", "6", "--lead-decisions", "2",
                                 "--quiet"])
    assert result.exit_code == 0, result.output
    manifest = json.loads((models / "models.json").read_text())
    assert manifest["initiation"]["file"] == "initiation.safetensors"
    report = json.loads((models / "initiation.json").read_text())
    assert set(report["options"]) | set(report["without_runs"]) == set(
        manifest["option_names"])
    rows = ["dynoplan", "random+rules", "dynoplan_regions", "random_everywhere"]
    out = tmp_path / "eval"
    result = runner.invoke(app, ["gear", "evaluate", "--models", str(models), "--out",
                                 str(out), "--controllers", ",".join(rows), "--episodes", "1",
                                 "--epistemic", "0.5", "--quiet"])
    assert result.exit_code == 0, result.output
    with (out / "results.csv").open() as f:
        table = list(csv.DictReader(f))
    assert [r["controller"] for r in table] == rows
    assert json.loads((out / "summary.json").read_text())["planner"]["epistemic"] == 0.5


def test_gear_options_fall_back_to_their_own_sets():
    """Where no option may start under its sets, a gear option may start under its own
    set, as every task's option does (``FittedModels.build`` makes it the fallback):
    everywhere without hand-written conditions, its registered conditions under
    ``rules``."""
    states = np.random.default_rng(0).normal(0.0, 0.5, size=(500, STATE_DIM))
    for name in gear_option_names():
        own = gear_option(name).sets()[0].contains(states)
        assert 0 < own.sum() < len(states) or isinstance(gear_option(name).sets()[0],
                                                        Everywhere)
        for sets in INITIATION_SETS:
            fallback = own_sets(name, sets)[0]
            if sets == "rules":
                assert np.array_equal(fallback.contains(states), own)
            else:
                assert isinstance(fallback, Everywhere)
    with pytest.raises(DynoplanError, match="unknown initiation sets"):
        own_sets("pick", "learnt")


@pytest.mark.slow
def test_dynoplan_starts_an_option_where_no_learned_region_holds(quick_gear_run: Path):
    """A start state no region admits (the gear lying far from every demonstration) does
    not leave DynoPlan holding for good: the options compete under their own sets."""
    models_dir = quick_gear_run / "models"
    models = load_gear_models(models_dir)
    env = GearAssemblyEnv()
    try:
        options = gear_options(env, models, policy_factories(models_dir), "learned")
        obs, _ = env.reset(seed=0)
        far = PlannerState()(obs[None])[0] + 10.0  # every coordinate 10 units away
        assert models.regions is not None
        assert not models.regions.contains_all(far[None]).any()
        assert not any(o.may_run(far, False) for o in options)
        assert admissible(options, far).all()
        # on every variant's sets, built as every task's options are: their own sets
        # as the fallback, and a region's likelihood wherever a region is used
        states = PlannerState()(obs[None]) + np.random.default_rng(0).normal(
            0.0, 0.05, size=(200, STATE_DIM))
        for sets in INITIATION_SETS:
            for o in gear_options(env, models, policy_factories(models_dir), sets):
                assert np.array_equal(o.fallback.contains(states),
                                      own_sets(o.name, sets)[0].contains(states))
                assert (o.likelihood is None) == (sets == "everywhere"
                                                  or models.region(o.name) is None)
    finally:
        env.close()
