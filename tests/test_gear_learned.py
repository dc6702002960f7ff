"""The gear's learned-only controllers: initiation learned from outcomes, the variant rows."""

import csv
import json
import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from dynoplan.cli.main import app


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
