"""Held-out coverage of the safety regions: the default fit against the paper's reading.

For one finished ``dynoplan pipeline`` run, refits the regions on the run's own
demonstrations and transitions with (a) the default settings (held-out fit) and (b) the
previous default (``region_fit="bic"``, coverage 0.99 on the training states, at most 12
components, undemonstrated options admissible everywhere), then measures per option:

- ``fresh``: the share of its states in *new* demonstrations (recorded here with another
  seed, never used for fitting) that lie inside its region;
- ``starts``: the share of the run's evaluation start states inside its region.

Usage (from the repository root)::

    python examples/region_coverage.py --env PendulumSwingUp-v0 \\
        --options examples.pendulum.options:make_options --run results/look/pendulum-s0
"""

import argparse
import json
from pathlib import Path

import numpy as np

from dynoplan.data import read_dataset
from dynoplan.data.episodes import OPTION_KEY
from dynoplan.pipeline import (
    FitSettings,
    GymTask,
    call_factory,
    demos_from_dataset,
    fit_option_regions,
    record_demonstrations,
    start_states,
)
from dynoplan.pipeline.fit import episode_states

PAPER = FitSettings(region_fit="bic", region_coverage=0.99, region_max_components=12,
                    region_undemonstrated="everywhere")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--env", required=True)
    parser.add_argument("--options", required=True)
    parser.add_argument("--run", required=True, type=Path, help="a pipeline output folder")
    parser.add_argument("--fresh-demos", type=int, default=20)
    parser.add_argument("--seed", type=int, default=12345, help="seed of the new demos")
    args = parser.parse_args()

    summary = json.loads((args.run / "summary.json").read_text())
    task = GymTask(args.env, args.options)
    env, specs = task.make_env(), task.make_options()
    names = [s.name for s in specs]
    demonstrator = call_factory(f"{args.options.partition(':')[0]}:make_demonstrator",
                                "demonstrator")
    demos = demos_from_dataset(read_dataset(args.run / "demos"), names)
    transitions = demos_from_dataset(read_dataset(args.run / "transitions"), names)
    fresh = record_demonstrations(env, specs, demonstrator, args.fresh_demos, args.seed)
    fresh_states = np.concatenate([episode_states(e)[:-1] for e in fresh])
    fresh_labels = np.concatenate([e.infos[OPTION_KEY] for e in fresh])
    starts = start_states(env, summary["seeds"]["evaluation"],
                          summary["settings"]["episodes"])
    print(f"run {args.run}: {len(demos)} training demonstrations, {len(fresh)} new ones "
          f"(seed {args.seed}), {len(starts)} evaluation start states\n")
    print("| option | fit | components | new demo states inside | start states inside |")
    print("|---|---|---|---|---|")
    for label, settings in (("held-out (default)", FitSettings()), ("BIC (paper)", PAPER)):
        regions, _ = fit_option_regions(demos, transitions, names, settings,
                                       summary["seeds"]["fit"])
        for k, name in enumerate(names):
            if name not in regions.option_names:
                print(f"| {name} | {label} | none | 1 (everywhere) | 1 (everywhere) |")
                continue
            own = fresh_labels == k
            inside = (f"{regions.contains(fresh_states[own], name).mean():.2f}"
                      if own.any() else "– (not demonstrated)")
            comps = int(regions.members[regions.option_index(name)].sum())
            print(f"| {name} | {label} | {comps} | {inside} | "
                  f"{regions.contains(starts, name).mean():.2f} |")


if __name__ == "__main__":
    main()
