"""Success rates of several ``dynoplan pipeline`` runs (one per seed) side by side.

Usage (from the repository root)::

    python examples/summarize_seeds.py results/look/pendulum-s0 results/look/pendulum-s1 ...

Prints one markdown table: per controller, the success rate of each run and their mean,
then, per option, where it may start (the admissibility diagnostic) in each run. Reads
only the runs' ``summary.json``.
"""

import json
import sys
from pathlib import Path


def main(folders: list[str]) -> None:
    runs = [json.loads((Path(f) / "summary.json").read_text()) for f in folders]
    seeds = [r["settings"]["seed"] for r in runs]
    head = " | ".join(f"seed {s}" for s in seeds)
    print(f"| controller | {head} | mean |")
    print("|---|" + "---|" * (len(runs) + 1))
    for name in runs[0]["controllers"]:
        rates = [r["controllers"][name]["success_rate"] for r in runs]
        print(f"| {name} | " + " | ".join(f"{x:.2f}" for x in rates)
              + f" | {sum(rates) / len(rates):.2f} |")
    print()
    print(f"| option: admissible at start states / demonstration states | {head} |")
    print("|---|" + "---|" * len(runs))
    for name in runs[0]["admissibility"]:
        cells = [r["admissibility"][name] for r in runs]
        print(f"| {name} | " + " | ".join(
            f"{c['start_states']:.2f} / {c['demo_states']:.2f}" for c in cells) + " |")
    print()
    print("| steps to success (mean) | " + head + " |")
    print("|---|" + "---|" * len(runs))
    for name in runs[0]["controllers"]:
        steps = [r["controllers"][name]["steps_to_success_mean"] for r in runs]
        print(f"| {name} | " + " | ".join("–" if s is None else f"{s:.0f}" for s in steps)
              + " |")


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit("usage: python examples/summarize_seeds.py RUN_FOLDER [RUN_FOLDER ...]")
    main(sys.argv[1:])
