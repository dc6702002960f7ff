"""How far a suite run's safety regions reach beyond its demonstrations.

Usage (from the repository root)::

    python -m benchmarks.suite.regions results/suite panda-stack 2
    python -m benchmarks.suite.regions results/suite panda-stack 2 --fresh 20 --starts 100

For one task and seed of the suite run ``RUN`` (the ``--out`` of :mod:`benchmarks.suite`)
this fits the Eq. 5 regions again on the run's own demonstrations
(``RUN/<task>/seed<s>/demos``), with the run's fit settings and fit seed, as the first
fit of the run does (the improvement round's refit is not repeated), and once more
widened by ``--starts`` start states labelled by the demonstrator's first choice, drawn
as the run's ``region_starts`` would draw them (:func:`~dynoplan.pipeline.fit_regions.
start_regions`). Then it records ``--fresh`` new demonstrations from a seed stream none
of the run's used (``--fresh-seed``) and prints, for each fit, the share of the fresh
demonstrations' states labelled with each option that lie inside that option's region,
and at their first states the share inside each option's region and inside none.
"""

import argparse
import os
import sys
import warnings
from pathlib import Path

import numpy as np

from benchmarks.suite.registry import select
from benchmarks.suite.rerun import run_seed_folder
from dynoplan.control.controller import flat_state
from dynoplan.data.dataset import read_dataset
from dynoplan.errors import DynoplanError
from dynoplan.pipeline.collect import record_demonstrations, start_choices
from dynoplan.pipeline.fit_data import labelled_states
from dynoplan.pipeline.fit_regions import RegionsModel, fit_option_regions
from dynoplan.pipeline.fit_settings import FitSettings
from dynoplan.pipeline.run_settings import starts_seed

FRESH_SEED = 987654
"""The default seed stream of the fresh demonstrations (no run's seed derives it)."""


def admission(regions: RegionsModel, names: list[str], states: np.ndarray,
              labels: np.ndarray) -> dict[str, float]:
    """Per option with a region: the share of ``states`` ``(N, d)`` labelled with it
    (``labels`` ``(N,)``) inside its region."""
    return {name: float(regions.contains(states[labels == k], name).mean())
            for k, name in enumerate(names)
            if name in regions.option_names and np.any(labels == k)}


def inside(regions: RegionsModel, names: list[str], states: np.ndarray) -> np.ndarray:
    """``(N, options)``: whether each state lies in each option's region (``False`` for an
    option without one)."""
    return np.stack([regions.contains(states, n) if n in regions.option_names
                     else np.zeros(len(states), dtype=bool) for n in names], axis=1)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.suite.regions",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path, help="a suite run's --out folder")
    parser.add_argument("task", help="the task's name")
    parser.add_argument("seed", type=int, help="one of the run's seeds")
    parser.add_argument("--fresh", type=int, default=20, metavar="N",
                        help="fresh demonstrations to measure on [20]")
    parser.add_argument("--fresh-seed", type=int, default=FRESH_SEED, metavar="S",
                        help=f"their seed stream [{FRESH_SEED}]")
    parser.add_argument("--starts", type=int, default=100, metavar="N",
                        help="start states for the widened fit [100]")
    args = parser.parse_args(argv)
    try:
        if args.fresh < 1 or args.starts < 1:
            raise DynoplanError("--fresh and --starts must be >= 1")
        folder, summary = run_seed_folder(args.run, args.task, args.seed)
        (entry,) = select(args.task)
        task = entry.load()
        env = task.make_env()
        specs = task.module.make_options()
        names = [s.name for s in specs]
        fit = FitSettings.from_record(summary["settings"]["fit"])
        fit_seed = int(summary["seeds"]["fit"])
        demos = read_dataset(folder / "demos").episodes
        starts = start_choices(env, task.module.make_demonstrator(), names,
                               starts_seed(int(summary["seeds"]["demos"])), args.starts)
        fresh = record_demonstrations(env, specs, task.module.make_demonstrator(),
                                      args.fresh, args.fresh_seed)
        states, labels, _ = labelled_states(fresh, len(names), flat_state)
        first = np.cumsum([0] + [len(e) for e in fresh[:-1]])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the fit's own warnings are the run's
            fits = {"demonstrations": fit_option_regions(demos, [], names, fit, fit_seed)[0],
                    f"demonstrations and {args.starts} start states": fit_option_regions(
                        demos, [], names, fit, fit_seed, starts=[] if starts is None
                        else [starts])[0]}
        print(f"{args.task} seed {args.seed}: {len(demos)} demonstrations; {len(fresh)} "
              f"fresh ones ({len(states)} states)")
        for what, regions in fits.items():
            shares = admission(regions, names, states, labels)
            at_first = inside(regions, names, states[first])
            print(f"regions on the {what}:")
            print("  fresh states inside their option's region: "
                  + ", ".join(f"{n} {v:.2f}" for n, v in shares.items()))
            print("  fresh first states inside each region: "
                  + ", ".join(f"{n} {v:.2f}" for n, v in zip(names, at_first.mean(axis=0),
                                                             strict=True))
                  + f"; inside none {float((~at_first.any(axis=1)).mean()):.2f}")
    except (DynoplanError, OSError, ValueError, KeyError) as exc:
        print(f"regions: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    os.environ.setdefault("MUJOCO_GL", "egl")
    sys.exit(main())
