"""The gear's controller settings: the library's defaults against the gear's former own.

Usage::

    .venv/bin/python benchmarks/gear_controls.py --run results/gear --episodes 100
    .venv/bin/python benchmarks/gear_controls.py --run DIR --each --out results/gear-controls.json

DynoPlan on the models of one ``dynoplan gear run`` (``--run``: its output folder; the
evaluation seeds of ``--seed``, the run's own), under ``gear run``'s controller settings
(:data:`~dynoplan.envs.gear.controllers.GEAR_CONTROL`: the library's defaults, as on
every Task, in the gear's units) and under the gear's former own settings
(:data:`~dynoplan.envs.gear.controllers.GEAR_TUNED`: a longer horizon's worth of samples
over a shorter horizon, a margin, the no-effect rule in millimetres, the generic rules
off). With ``--each``, also each of the tuned settings alone. The defaults' no-effect
and loop rules need the state scale that the fit records (``models.json``'s
``report.state_scale``); models trained before it was recorded get one error line.
(Before ``GEAR_CONTROL`` became the library's defaults, this benchmark's rows were the
gear's settings, the generic rules and, with ``--sizes``, the generic defaults: the
command of ``docs/suite.md``'s eighth round, at ``aadcbbc``.)

With ``--fit KEY=VALUE`` (repeatable, a field of
:class:`~dynoplan.pipeline.fit_settings.FitSettings`), the rows run on models fitted
again from the run's own data (its demonstrations, option runs, held-out trials and
outcome runs) with the gear's fit settings changed so, written into ``--work`` (a copy
of the run's ``models/``, whose option networks are the run's); ``--fit generic`` sets
the generic pipeline's fit remedies that the gear's fit can take (:data:`GENERIC_FIT`).

Prints and writes (``--out``, JSON) one row per setting: success, median time to success,
contacts with the person (all, and while the arm moved) and the failures by kind.
"""

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from dynoplan.pipeline.fit_settings import FitSettings

GENERIC_FIT: dict[str, Any] = {
    name: getattr(FitSettings(), name)
    for name in ("goal_off_demos", "constant_dimensions_still", "dynamics_min_updates")}
"""The generic defaults' fit remedies where the gear's fit settings differ and the gear's
fit can take them (its one-step dynamics aside: ``option_model``), at the library's
default values."""

SHOWN = ("success_rate", "time_to_success_s", "contacts", "contacts_moving",
         "episodes_with_contact", "failures")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="benchmarks/gear_controls.py",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--run", type=Path, default=Path("results/gear"),
                        help="a gear run's output folder (its models/)")
    parser.add_argument("--seed", type=int, default=0, help="the run's seed [0]")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--each", action="store_true",
                        help="also each of the tuned settings alone")
    parser.add_argument("--fit", action="append", default=[], metavar="KEY=VALUE",
                        help="refit the models with this fit setting changed ('generic': "
                             "the generic fit remedies); repeatable")
    parser.add_argument("--work", type=Path, help="the refitted models' folder (with --fit)")
    parser.add_argument("--out", type=Path, help="write the rows as JSON")
    args = parser.parse_args(argv)

    import torch

    from dynoplan.envs.gear.controllers import GEAR_CONTROL, TUNED_CHANGES
    from dynoplan.envs.gear.evaluation import evaluation_seeds
    from dynoplan.envs.gear.models_folder import load_gear_models
    from dynoplan.envs.gear.pipeline_task import GearTask
    from dynoplan.envs.gear.reports.results import summarise
    from dynoplan.errors import DynoplanError
    from dynoplan.io import write_json
    from dynoplan.parallel import SERIAL
    from dynoplan.pipeline.evaluate import ControllerJob
    from dynoplan.pipeline.jobs import evaluate_rows

    torch.set_num_threads(1)
    models = args.run / "models"
    fit_changes: dict[str, Any] = {}
    try:
        if args.episodes < 1:
            raise DynoplanError(f"--episodes must be >= 1, got {args.episodes}")
        if args.fit:
            fit_changes = fit_overrides(args.fit)
            if args.work is None:
                raise DynoplanError("--fit needs --work DIR for the refitted models")
            models = refit(args.run, args.seed, fit_changes, args.work)
        if load_gear_models(models).state_scale is None:
            raise DynoplanError(f"{models}: the models record no state scale (trained before "
                                "it was recorded); train them again with 'dynoplan gear run'")
    except DynoplanError as exc:
        print(f"gear_controls: error: {exc}", file=sys.stderr)
        return 2
    rows: dict[str, dict[str, Any]] = {"gear run's (the library's defaults)": {}}
    if args.each:
        rows.update({f"{k}={v}": {k: v} for k, v in TUNED_CHANGES.items()})
    rows["the gear-tuned settings"] = TUNED_CHANGES
    seeds = evaluation_seeds(args.seed, args.episodes)
    results: dict[str, Any] = {"run": str(args.run), "seed": args.seed,
                               "episodes": args.episodes, "fit": fit_changes,
                               "models": str(models), "rows": {}}
    for label, changes in rows.items():
        started = time.perf_counter()
        job = ControllerJob(GearTask(), models, "dynoplan", replace(GEAR_CONTROL, **changes))
        episodes = evaluate_rows({label: (job, seeds)}, SERIAL, label)[label]
        row = summarise("dynoplan", episodes)
        results["rows"][label] = {"changes": changes, **{k: row[k] for k in SHOWN},
                                  "seconds": round(time.perf_counter() - started, 1)}
        print(label, json.dumps(results["rows"][label]), flush=True)
        if args.out is not None:
            write_json(args.out, results)
    return 0


def fit_overrides(items: list[str]) -> dict[str, Any]:
    """``KEY=VALUE`` fit settings (read as the suite's ``--set``,
    :func:`benchmarks.suite.__main__.parse_sets`, and checked as the pipeline's
    ``fit.KEY``; ``generic``: :data:`GENERIC_FIT`) as changes of the gear's
    :class:`~dynoplan.pipeline.fit_settings.FitSettings`.

    Raises:
        DynoplanError: not ``KEY=VALUE``, no such setting, or a value it cannot take.
    """
    from dataclasses import fields

    from benchmarks.suite.__main__ import parse_sets
    from dynoplan.errors import DynoplanError
    from dynoplan.pipeline.config import pipeline_settings

    known = {f.name for f in fields(FitSettings)}
    out: dict[str, Any] = {}
    for item in items:
        if item == "generic":
            out.update(GENERIC_FIT)
            continue
        ((key, value),) = parse_sets([item], "--fit").items()
        if key not in known:
            raise DynoplanError(f"--fit {item!r}: expected KEY=VALUE with KEY one of "
                                f"{', '.join(sorted(known))}")
        out[key] = value
    fit = pipeline_settings({f"fit.{k}": v for k, v in out.items()}).fit
    return {k: getattr(fit, k) for k in out}


def refit(run: Path, seed: int, changes: dict[str, Any], work: Path) -> Path:
    """The run's models fitted again from its own data by ``gear run``'s own stages
    (:func:`~dynoplan.envs.gear.stages.learned_models`, then
    :func:`~dynoplan.envs.gear.stages.outcome_initiation` on the run's outcome runs), with
    the run's fit settings (``summary.json``'s) changed by ``changes``, into ``work`` (a
    copy of ``run/models``: the option networks are the run's); returns ``work``."""
    import shutil

    from dynoplan.envs.gear.learning.settings import GearMetricsSettings
    from dynoplan.envs.gear.pipeline_stages import OUTCOME_RUNS
    from dynoplan.envs.gear.stages import learned_models, outcome_initiation
    from dynoplan.io import read_json_object

    recorded = read_json_object(run / "summary.json", "gear run summary")["settings"]
    fit = replace(FitSettings.from_record(recorded["fit"]), **changes)
    if work.exists():
        shutil.rmtree(work)
    shutil.copytree(run / "models", work)
    learned_models(run / "demos", run / "transitions", work, seed, run / "heldout", fit,
                   GearMetricsSettings(**recorded["metrics"]), progress=False)
    outcome_initiation(work, run / "outcomes", seed, OUTCOME_RUNS, progress=False,
                       collect=False)  # the run's outcome runs: OUTCOME_RUNS is unused
    return work


if __name__ == "__main__":
    sys.exit(main())
