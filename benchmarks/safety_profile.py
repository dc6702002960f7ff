"""Where the time of a safety evaluation episode goes: cProfile over seeded episodes.

Runs the first ``--episodes`` episodes of ``dynoplan gear evaluate --human all --shield``
(seed 0, the same episodes) of one controller in this process under cProfile, and
writes a table of the cumulative time of the parts that matter (the cautious move's
OMPL plans and their validity checks, Eq. 1's planner with its rollouts and the safety
constraint, the environment's steps under the runtime monitor), the episodes' wall time
and outcomes, and the load average, to ``--out`` (Markdown) and ``--out`` with
``.prof`` (the raw profile, for ``python -m pstats``)::

    python benchmarks/safety_profile.py --controller dynoplan_safe --episodes 4 \\
        --models results/gear/models --out results/safety/profile.md
"""

import argparse
import cProfile
import os
import pstats
import time
from pathlib import Path

from dynoplan.envs.gear.controllers import GEAR_CONTROL
from dynoplan.envs.gear.evaluation import EVAL_SEED_OFFSET
from dynoplan.envs.gear.human import BEHAVIOURS
from dynoplan.envs.gear.pipeline_task import GearTask
from dynoplan.reports.tables import markdown_table
from dynoplan.seeding import episode_seeds

PARTS = (
    ("episodes", "dynoplan/control/controller.py", "run"),
    ("cautious move: (re)plans", "envs/gear/options/moves.py", "_replan"),
    ("moves started (each plans at reset)", "envs/gear/options/moves.py", "reset"),
    ("OMPL validity checks", "envs/gear/options/motion.py", "is_valid"),
    ("  of which the hand clearance", "envs/gear/options/moves.py", "clear"),
    ("Eq. 1 planner", "dynoplan/planning/option_planner.py", "plan"),
    ("  rollouts", "dynoplan/planning/option_planner.py", "rollout"),
    ("  safety constraint", "dynoplan/safety/constraint.py", "unsafe"),
    ("  learned dynamics", "dynoplan/models/ensemble_rollouts.py", "step"),
    ("env steps under the monitor", "dynoplan/safety/shield.py", "step"),
    ("  MuJoCo steps", "envs/gear/env.py", "step"),
)
"""(label, file the function is in, function name) of the rows of the table."""


def profile(controller: str, models: Path, episodes: int,
            out: Path) -> tuple[list[dict[str, object]], str]:
    """The table's rows and a one-line summary; writes the raw profile next to ``out``."""
    runner = GearTask(human=BEHAVIOURS, shield=True).make_runner(controller, models,
                                                                 GEAR_CONTROL)
    seeds = episode_seeds(EVAL_SEED_OFFSET, episodes)
    profiler = cProfile.Profile()
    load_before = os.getloadavg()[0]
    t0 = time.perf_counter()
    profiler.enable()
    records = [runner.episode(seed) for seed in seeds]
    profiler.disable()
    wall = time.perf_counter() - t0
    load_after = os.getloadavg()[0]
    out.parent.mkdir(parents=True, exist_ok=True)
    raw = out.with_suffix(".prof")
    profiler.dump_stats(raw)
    stats = pstats.Stats(str(raw)).stats  # type: ignore[attr-defined]
    rows: list[dict[str, object]] = []
    for label, path, name in PARTS:
        hits = [(v[1], v[3]) for k, v in stats.items() if k[0].endswith(path) and k[2] == name]
        calls, seconds = sum(h[0] for h in hits), sum(h[1] for h in hits)
        rows.append({"part": label, "calls": calls, "seconds": round(seconds, 1),
                     "share": f"{100 * seconds / wall:.0f} %"})
    steps = sum(r.env_steps for r in records)
    summary = (f"{controller}, {episodes} episodes ({sum(r.success for r in records)} "
               f"successes, {steps} env steps) in {wall:.1f} s on one process, "
               f"{episodes / wall:.3f} episodes/s, load average {load_before:.1f} -> "
               f"{load_after:.1f} on {os.cpu_count()} CPUs")
    return rows, summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--controller", default="dynoplan_safe")
    parser.add_argument("--models", type=Path, default=Path("results/gear/models"))
    parser.add_argument("--episodes", type=int, default=4)
    parser.add_argument("--out", type=Path, default=Path("results/safety/profile.md"))
    args = parser.parse_args()
    rows, summary = profile(args.controller, args.models, args.episodes, args.out)
    text = "\n".join([summary, "", markdown_table(rows, ("part", "calls", "seconds", "share"))])
    args.out.write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
