"""Wall and CPU time of DynoPlan's random-walk episodes in lockstep (one noise level).

``dynoplan random-walk --lockstep`` also runs the baselines and six noise levels; this
script times only DynoPlan's episodes at one noise level (the CLI's settings otherwise),
as :func:`~dynoplan.experiments.random_walk.run_lockstep` runs them, and prints one JSON
object: wall seconds, this process's CPU seconds, the 1-minute load average before, the
success rate and the planning steps' median and mean. ``--digest`` adds a SHA-256 of
every episode's decisions and plans (to compare two versions' results to the bit).

    python benchmarks/random_walk_lockstep.py --depth 1
"""

import argparse
import hashlib
import json
import os
import sys
import time
from collections.abc import Sequence

import numpy as np

from dynoplan.control.controller import EpisodeTrace
from dynoplan.experiments.random_walk import (
    RandomWalkSettings,
    make_walk_controller,
    run_lockstep,
)
from dynoplan.seeding import episode_seeds


def trace_digest(traces: Sequence[EpisodeTrace]) -> str:
    """SHA-256 (hex) of every episode's outcome, decisions (option, steps, stop reason,
    end state) and plans (admissible, scores, spreads, end states, steps, sequences)."""
    h = hashlib.sha256()
    for t in traces:
        h.update(repr((t.success, t.env_steps, t.total_reward, t.no_admissible)).encode())
        for d in t.decisions:
            h.update(repr((d.index, d.env_step, d.option, d.steps, d.stop_reason,
                           d.plan.chosen, d.plan.sequences)).encode())
            for a in (d.plan.admissible, d.plan.scores, d.plan.spreads, d.plan.end_states,
                      d.plan.steps, d.state_after):
                h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--depth", type=int, default=1)
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--noise", type=float, default=0.2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--digest", action="store_true",
                        help="also print a SHA-256 of every decision and plan")
    args = parser.parse_args(argv)
    settings = RandomWalkSettings(episodes=args.episodes, noise=args.noise, seed=args.seed,
                                  depth=args.depth, lockstep=True)
    controller = make_walk_controller("dynoplan", args.noise, settings)
    seeds = episode_seeds(args.seed, args.episodes)
    load = os.getloadavg()[0]
    t0, cpu0 = time.perf_counter(), time.process_time()
    traces = run_lockstep(controller, args.noise, settings, seeds)
    wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    steps = [t.planning_steps for t in traces]
    print(json.dumps({"depth": args.depth, "episodes": args.episodes, "noise": args.noise,
                      "seed": args.seed, "wall_s": round(wall, 3), "cpu_s": round(cpu, 3),
                      "load_before": round(load, 2),
                      "success": float(np.mean([t.success for t in traces])),
                      "planning_steps_median": float(np.median(steps)),
                      "planning_steps_mean": round(float(np.mean(steps)), 3),
                      **({"digest": trace_digest(traces)} if args.digest else {})}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
