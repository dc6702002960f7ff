"""DynoPlan again on a suite run's fitted models, with other controller or goal settings.

Usage (from the repository root)::

    python -m benchmarks.suite.rerun results/suite --set control.replan_every=0
    python -m benchmarks.suite.rerun results/suite --set fit.goal_members=5 --goal-seed 1

A controller setting (``control.*``) changes nothing the pipeline fits, so its ablation
row needs no new fit: for every task and seed of the suite run ``RUN`` (the ``--out`` of
:mod:`benchmarks.suite`), this loads ``RUN/<task>/seed<s>/models``, builds DynoPlan on the
settings given with ``--set`` and runs it on the run's own seeded evaluation episodes
(clean, and with ``--disturbed`` under the task's disturbance). With no ``--set`` it
gives the run's own DynoPlan row again. Prints one line per task: DynoPlan's success on
every seed and its composition ratio against the run's demonstrator, beside the run's
own DynoPlan; ``--out FILE`` writes the table too.

A goal setting (``fit.goal_*``) or ``--goal-seed N`` fits the goal heuristic again on the
run's own demonstrations and exploration episodes (``RUN/<task>/seed<s>/demos`` and
``transitions``), with the run's fit settings but those given, from the run's fit seed
plus ``N``, and keeps every other model (the dynamics are fitted before the goal and do
not depend on it); the initiation learned from outcomes, which reads the goal, is
fitted again with it when the run's settings use it. ``--goal-seed`` alone measures how
much the goal's fit seed moves a row.
"""

import argparse
import json
import os
import sys
from dataclasses import dataclass
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
from dynoplan.pipeline.fit import FittedModels, named_feature_map
from dynoplan.pipeline.fit_settings import FitSettings
from dynoplan.reports.tables import markdown_table

GOAL_KEYS = "fit.goal_"
"""The prefix of the fit settings :func:`refit_goal` fits the goal heuristic again with."""


def split_sets(sets: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """``--set`` pairs as ``(goal, control)``: the ``fit.goal_*`` keys (:func:`refit_goal`
    fits the goal again with them) and the ``control.*`` keys.

    Raises:
        DynoplanError: another key, which would need every model fitted again."""
    refit = [k for k in sets if not k.startswith(("control.", GOAL_KEYS))]
    if refit:
        raise DynoplanError(f"--set {refit[0]}: only control.* and fit.goal_* settings can "
                            "change without fitting everything again (run python -m "
                            "benchmarks.suite)")
    goal = {k: v for k, v in sets.items() if k.startswith(GOAL_KEYS)}
    return goal, {k: v for k, v in sets.items() if k not in goal}


def refit_goal(fitted: FittedModels, folder: Path, summary: dict[str, Any],
               goal_sets: dict[str, Any], goal_seed: int) -> FittedModels:
    """``fitted`` with its goal heuristic fitted again on ``folder``'s demonstrations and
    exploration episodes, with the run's fit settings (``summary``) but the ``fit.goal_*``
    keys ``goal_sets``, from the run's fit seed plus ``goal_seed`` (and the initiation
    learned from outcomes fitted again on it, when the run's settings use it)."""
    from dataclasses import replace

    from dynoplan.data.dataset import read_dataset
    from dynoplan.pipeline.fit_goal import fit_goal
    from dynoplan.pipeline.fit_initiation import fit_outcome_initiation

    given = pipeline_settings(goal_sets).fit
    names = [k.removeprefix("fit.") for k in goal_sets]
    fit = replace(FitSettings.from_record(summary["settings"]["fit"]),
                  **{n: getattr(given, n) for n in names})
    fit.validate()
    seed = int(summary["seeds"]["fit"]) + goal_seed
    demos = read_dataset(folder / "demos").episodes
    transitions = read_dataset(folder / "transitions").episodes
    # the pipeline's runs have no named feature maps: a goal_features name is refused
    goal, _ = fit_goal(demos, fit, seed, features=named_feature_map(fit.goal_features, None),
                       off=transitions)
    learned = fitted.learned_initiation
    if fit.outcome_initiation:
        learned, _ = fit_outcome_initiation(transitions, fitted.option_names, goal, fit, seed)
    return replace(fitted, goal=goal, learned_initiation=learned)


@dataclass(frozen=True)
class RunSeed:
    """One task and seed of a suite run: its ``task`` (the registry's), its ``folder``,
    ``summary.json``, the recorded controller ``rows`` (clean or disturbed, as asked) and
    its fitted models."""

    task: Any
    folder: Path
    summary: dict[str, Any]
    rows: dict[str, Any]
    fitted: FittedModels


def load_run_seed(run: Path, task_name: str, seed: int, disturbed: bool) -> RunSeed:
    """Task ``task_name``'s seed ``seed`` of the suite run ``run`` (its ``--out``); torch
    on one thread, as the suite runs.

    Raises:
        DynoplanError: the folder holds no such task and seed."""
    import torch

    torch.set_num_threads(1)
    folder, summary = run_seed_folder(run, task_name, seed)
    (entry,) = select(task_name)
    recorded = json.loads((folder / "suite-run.json").read_text())
    return RunSeed(entry.load(), folder, summary,
                   recorded["disturbed"] if disturbed else recorded["controllers"],
                   FittedModels.load(folder / "models"))


def run_seed_folder(run: Path, task_name: str, seed: int) -> tuple[Path, dict[str, Any]]:
    """The folder of task ``task_name``'s seed ``seed`` in the suite run ``run`` (its
    ``--out``) and its ``summary.json``.

    Raises:
        DynoplanError: the folder holds no such task and seed."""
    folder = run / task_name / f"seed{seed}"
    summary_file = folder / "summary.json"
    if not summary_file.is_file():
        raise DynoplanError(f"{summary_file}: not found (RUN TASK SEED name one task and "
                            "seed of a suite run's --out folder)")
    return folder, json.loads(summary_file.read_text())


def rerun_one(run: Path, task_name: str, seed: int, sets: dict[str, Any],
              disturbed: bool, goal_seed: int = 0) -> tuple[float, float, float]:
    """DynoPlan's success on ``settings`` over the evaluation episodes of one task and
    seed of the suite run ``run``; with it, the run's own DynoPlan and demonstrator
    success on the same episodes (``disturbed``: the rows under the disturbance). With
    ``fit.goal_*`` keys in ``sets`` or a ``goal_seed``, the goal is fitted again
    (:func:`refit_goal`)."""
    loaded = load_run_seed(run, task_name, seed, disturbed)
    task, folder, summary, rows, fitted = (loaded.task, loaded.folder, loaded.summary,
                                           loaded.rows, loaded.fitted)
    goal_sets, control = split_sets(sets)
    settings = pipeline_settings({**control, "episodes": int(rows[DYNOPLAN]["episodes"])})
    if goal_seed or goal_sets:
        fitted = refit_goal(fitted, folder, summary, goal_sets, goal_seed)
    options, planner_options = fitted.build(task.module.make_options())
    result = evaluate_controllers(
        task.make_env(disturbed=disturbed), options, fitted.goal,
        planning_settings(settings.control, fitted), settings.episodes,
        summary["seeds"]["evaluation"], planner_options, [DYNOPLAN],
        regions=learned_regions(fitted), state_scale=fitted.state_scale,
        fresh_env=lambda: task.make_env(disturbed=disturbed))
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
                        help="a controller setting (control.*) or a goal setting (fit.goal_*) "
                        "for every task")
    parser.add_argument("--goal-seed", type=int, default=0, metavar="N",
                        help="fit the goal heuristic again from the run's fit seed plus N")
    parser.add_argument("--disturbed", action="store_true",
                        help="under each task's disturbance")
    parser.add_argument("--out", type=Path, help="also write the table to this file")
    args = parser.parse_args(argv)
    try:
        sets = parse_sets(args.set)
        split_sets(sets)  # a key that needs a new fit, before any work
        if args.goal_seed < 0:
            raise DynoplanError(f"--goal-seed must be >= 0, got {args.goal_seed}")
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
            got = [rerun_one(args.run, name, s, sets, args.disturbed, args.goal_seed)
                   for s in seeds]
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
