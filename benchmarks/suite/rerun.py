"""DynoPlan again on a suite run's fitted models, with other controller settings.

Usage (from the repository root)::

    python -m benchmarks.suite.rerun results/suite --set control.replan_every=0

A controller setting (``control.*``) changes nothing the pipeline fits, so its ablation
row needs no new fit: for every task and seed of the suite run ``RUN`` (the ``--out`` of
:mod:`benchmarks.suite`), this loads ``RUN/<task>/seed<s>/models``, builds DynoPlan on the
settings given with ``--set`` and runs it on the run's own seeded evaluation episodes
(clean, and with ``--disturbed`` under the task's disturbance). With no ``--set`` it
gives the run's own DynoPlan row again. Prints one line per task: DynoPlan's success on
every seed and its composition ratio against the run's demonstrator, beside the run's
own DynoPlan; ``--out FILE`` writes the table too.
"""

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.suite.__main__ import parse_sets
from benchmarks.suite.registry import select
from dynoplan.errors import DynoplanError
from dynoplan.io import write_text
from dynoplan.pipeline import evaluate_controllers
from dynoplan.pipeline.config import pipeline_settings
from dynoplan.pipeline.evaluate import DEMONSTRATOR, DYNOPLAN, learned_regions, planning_settings
from dynoplan.pipeline.fit import FittedModels
from dynoplan.reports.tables import markdown_table


def rerun_one(run: Path, task_name: str, seed: int, sets: dict[str, Any],
              disturbed: bool) -> tuple[float, float, float]:
    """DynoPlan's success on ``settings`` over the evaluation episodes of one task and
    seed of the suite run ``run``; with it, the run's own DynoPlan and demonstrator
    success on the same episodes (``disturbed``: the rows under the disturbance)."""
    import torch

    torch.set_num_threads(1)
    (entry,) = select(task_name)
    task = entry.load()
    folder = run / task_name / f"seed{seed}"
    recorded = json.loads((folder / "suite-run.json").read_text())
    summary = json.loads((folder / "summary.json").read_text())
    rows = recorded["disturbed"] if disturbed else recorded["controllers"]
    settings = pipeline_settings({**sets, "episodes": int(rows[DYNOPLAN]["episodes"])})
    fitted = FittedModels.load(folder / "models")
    options, planner_options = fitted.build(task.module.make_options())
    result = evaluate_controllers(
        task.make_env(disturbed=disturbed), options, fitted.goal,
        planning_settings(settings.control, fitted), settings.episodes,
        summary["seeds"]["evaluation"], planner_options, [DYNOPLAN],
        regions=learned_regions(fitted), state_scale=fitted.state_scale)
    return (float(result[DYNOPLAN]["success_rate"]), float(rows[DYNOPLAN]["success_rate"]),
            float(rows[DEMONSTRATOR]["success_rate"]))


def _seeds(values: list[float]) -> str:
    return " / ".join(f"{v:.2f}" for v in values)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.suite.rerun",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path, help="a suite run's --out folder")
    parser.add_argument("--tasks", help="comma-separated task names [every task of RUN]")
    parser.add_argument("--seeds", help="comma-separated seeds [the run's]")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="a controller setting (control.*) for every task")
    parser.add_argument("--disturbed", action="store_true",
                        help="under each task's disturbance")
    parser.add_argument("--out", type=Path, help="also write the table to this file")
    args = parser.parse_args(argv)
    try:
        sets = parse_sets(args.set)
        fitted_keys = [k for k in sets if not k.startswith("control.")]
        if fitted_keys:
            raise DynoplanError(f"--set {fitted_keys[0]}: only control.* settings can change "
                                "without fitting again (run python -m benchmarks.suite)")
        pipeline_settings(sets)  # a mistake before any work
        suite_file = args.run / "suite.json"
        if not suite_file.is_file():
            raise DynoplanError(f"{suite_file}: not found (RUN is a suite run's --out folder)")
        suite = json.loads(suite_file.read_text())
        names = args.tasks.split(",") if args.tasks else [t["task"] for t in suite["tasks"]]
        seeds = ([int(s) for s in args.seeds.split(",")] if args.seeds
                 else [int(s) for s in suite["seeds"]])
        lines: list[dict[str, str]] = []
        for name in names:
            got = [rerun_one(args.run, name, s, sets, args.disturbed) for s in seeds]
            new, old, demo = (np.array(v) for v in zip(*got, strict=True))
            lines.append({"task": name, "new": _seeds(list(new)),
                          "new_ratio": f"{new.mean() / demo.mean():.2f}",
                          "old": _seeds(list(old)),
                          "old_ratio": f"{old.mean() / demo.mean():.2f}"})
            print(" | ".join(lines[-1].values()), flush=True)
    except (DynoplanError, OSError, ValueError, KeyError) as exc:
        print(f"rerun: error: {exc}", file=sys.stderr)
        return 2
    command = "python -m benchmarks.suite.rerun " + " ".join(
        sys.argv[1:] if argv is None else argv)
    table = markdown_table(lines, headers=["task", "DynoPlan (seeds)", "composition ratio",
                                           "the run's DynoPlan", "its ratio"])
    print(table)
    if args.out is not None:
        write_text(args.out, f"Produced by `{command}`.\n\n{table}")
    return 0


if __name__ == "__main__":
    os.environ.setdefault("MUJOCO_GL", "egl")
    sys.exit(main())
