"""The gear's controller settings against the generic defaults' rules, on the same episodes.

Usage::

    .venv/bin/python benchmarks/gear_controls.py --run results/gear --episodes 100
    .venv/bin/python benchmarks/gear_controls.py --run DIR --each --out results/gear-controls.json

DynoPlan on the models of one ``dynoplan gear run`` (``--run``: its output folder; the
evaluation seeds of ``--seed``, the run's own), under the gear's controller settings
(:data:`~dynoplan.envs.gear.controllers.GEAR_CONTROL`) and under the rules where those
differ from :class:`~dynoplan.pipeline.control_settings.ControllerSettings`' defaults,
which every other Task runs on (:data:`GENERIC_RULES`: an option may not start where its
termination holds, a fallback must gain, the stall rule, no margin, the no-effect rule's
tolerance as a share of the state scale, the loop rule). With ``--each``, also each of
those rules alone; with ``--sizes``, also the generic defaults whole
(:class:`~dynoplan.pipeline.control_settings.ControllerSettings()`, its horizon and
samples too; the gear's decision period and episode limits kept). The last two rules
need the state scale that the fit records (``models.json``'s ``report.state_scale``);
models trained before it was recorded get one error line.

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

GENERIC_RULES: dict[str, Any] = {"start_where_done": False, "fallback_must_gain": True,
                                 "stall_progress": 0.5, "margin": 0.0,
                                 "no_effect_tolerance": None, "no_effect_share": 0.01,
                                 "loop_share": 0.05}
"""The generic defaults' rules where the gear's settings differ (its sizes aside)."""

GENERIC_FIT: dict[str, Any] = {"goal_off_demos": True, "constant_dimensions_still": True,
                               "dynamics_min_updates": 1000}
"""The generic defaults' fit remedies where the gear's fit settings differ and the gear's
fit can take them (its one-step dynamics aside: ``option_model``)."""

GENERIC_SIZES = ("horizon", "samples")
"""The generic defaults' sizes that ``--sizes`` adds (the decision period and the episode
limits are the gear's own: they are in its units)."""

SHOWN = ("success_rate", "time_to_success_s", "contacts", "contacts_moving",
         "episodes_with_contact", "failures")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="benchmarks/gear_controls.py",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--run", type=Path, default=Path("results/gear"),
                        help="a gear run's output folder (its models/)")
    parser.add_argument("--seed", type=int, default=0, help="the run's seed [0]")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--each", action="store_true", help="also each rule alone")
    parser.add_argument("--sizes", action="store_true",
                        help="also the generic defaults' horizon and samples")
    parser.add_argument("--fit", action="append", default=[], metavar="KEY=VALUE",
                        help="refit the models with this fit setting changed ('generic': "
                             "the generic fit remedies); repeatable")
    parser.add_argument("--work", type=Path, help="the refitted models' folder (with --fit)")
    parser.add_argument("--out", type=Path, help="write the rows as JSON")
    args = parser.parse_args(argv)

    import torch

    from dynoplan.envs.gear.controllers import GEAR_CONTROL
    from dynoplan.envs.gear.evaluation import evaluation_seeds
    from dynoplan.envs.gear.learning.files import load_gear_models
    from dynoplan.envs.gear.pipeline_task import GearTask
    from dynoplan.envs.gear.reports.results import summarise
    from dynoplan.errors import DynoplanError
    from dynoplan.io import write_json
    from dynoplan.parallel import SERIAL
    from dynoplan.pipeline.control_settings import ControllerSettings
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
    rows: dict[str, dict[str, Any]] = {"the gear's settings": {}}
    if args.each:
        rows.update({f"{k}={v}": {k: v} for k, v in GENERIC_RULES.items()})
    rows["the generic rules"] = GENERIC_RULES
    if args.sizes:
        defaults = ControllerSettings()
        rows["the generic defaults"] = {**GENERIC_RULES,
                                        **{k: getattr(defaults, k) for k in GENERIC_SIZES}}
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
    """``KEY=VALUE`` fit settings (a TOML value, a bare word as a string; ``generic``:
    :data:`GENERIC_FIT`) as changes of the gear's
    :class:`~dynoplan.pipeline.fit_settings.FitSettings`.

    Raises:
        DynoplanError: not ``KEY=VALUE``, or no such setting.
    """
    import tomllib
    from dataclasses import fields

    from dynoplan.errors import DynoplanError
    from dynoplan.pipeline.fit_settings import FitSettings

    known = {f.name for f in fields(FitSettings)}
    out: dict[str, Any] = {}
    for item in items:
        if item == "generic":
            out.update(GENERIC_FIT)
            continue
        key, sep, text = item.partition("=")
        if not sep or key not in known:
            raise DynoplanError(f"--fit {item!r}: expected KEY=VALUE with KEY one of "
                                f"{', '.join(sorted(known))}")
        try:
            out[key] = tomllib.loads(f"v = {text}")["v"]
        except tomllib.TOMLDecodeError:
            out[key] = text
    return out


def refit(run: Path, seed: int, changes: dict[str, Any], work: Path) -> Path:
    """The run's models fitted again from its own data with the run's fit settings
    (``summary.json``'s) changed by ``changes``, and the initiation learned again from its
    outcome runs, into ``work`` (a copy of ``run/models``: the option networks are the
    run's); returns ``work``."""
    import shutil

    from dynoplan.envs.gear.learning.outcomes import fit_gear_initiation
    from dynoplan.envs.gear.learning.settings import GearMetricsSettings
    from dynoplan.envs.gear.learning.training import train_gear_models
    from dynoplan.io import read_json_object, write_json
    from dynoplan.pipeline.fit_settings import FitSettings

    recorded = read_json_object(run / "summary.json", "gear run summary")["settings"]
    values: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v
                              for k, v in recorded["fit"].items()}
    fit = replace(FitSettings(**values), **changes)
    measures = GearMetricsSettings(**recorded["metrics"])
    if work.exists():
        shutil.rmtree(work)
    shutil.copytree(run / "models", work)
    train_gear_models(run / "demos", run / "transitions", work, seed, run / "heldout", False,
                      progress=False, settings=fit, measures=measures)
    write_json(work / "initiation.json", fit_gear_initiation(work, run / "outcomes", seed))
    return work


if __name__ == "__main__":
    sys.exit(main())
