"""Cost of one task of each kind the scale-out runs: an evaluation episode per
controller and a collection run, timed serially in this process.

For each controller (the default planner settings, and ``dynoplan`` with horizon 20 and
128 samples), ``--episodes`` seeded episodes (the oracle: ``--oracle-episodes``) run
with one runner built by :meth:`dynoplan.envs.gear.pipeline_task.GearTask.make_runner`; then
``--runs`` collection runs of every option. Reported per kind: the mean CPU and wall
seconds of a task, the longest wall time, the mean simulated seconds, and for collection
the bytes a run returns (pickled). These are the inputs of the 1000-core estimate in
``docs/scale-out.md``.

Run ``python benchmarks/episode_costs.py --models DIR [--flat DIR]``; ``--json`` for one
JSON object.
"""

import argparse
import json
import os
import pickle
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from dynoplan.envs.gear.controllers import CONTROLLERS, GEAR_CONTROL
from dynoplan.envs.gear.flat_policy import FLAT_POLICY
from dynoplan.envs.gear.metrics import seconds
from dynoplan.envs.gear.options.catalog import gear_option_names
from dynoplan.envs.gear.pipeline_task import GearTask
from dynoplan.envs.gear.state import DECISION_STEPS
from dynoplan.pipeline.collect import OptionRunsJob, build_option_runs, option_run
from dynoplan.pipeline.evaluate import ControllerJob
from dynoplan.seeding import episode_seeds


def timed(fn: Any, *args: Any) -> tuple[Any, float, float]:
    wall, cpu = time.perf_counter(), time.process_time()
    out = fn(*args)
    return out, time.perf_counter() - wall, time.process_time() - cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--models", type=Path, required=True, help="gear models folder")
    parser.add_argument("--flat", type=Path, help="flat policy folder (default: "
                        "MODELS/../flat_ppo)")
    parser.add_argument("--episodes", type=int, default=8)
    parser.add_argument("--oracle-episodes", type=int, default=3)
    parser.add_argument("--runs", type=int, default=3, help="collection runs per option")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args()

    import torch

    torch.set_num_threads(1)
    os.environ.setdefault("MUJOCO_GL", "egl")
    flat = args.flat or args.models.parent / "flat_ppo"
    gear = GearTask(flat_folder=flat)
    jobs = {name: ControllerJob(gear, args.models, name, GEAR_CONTROL) for name in CONTROLLERS}
    jobs["dynoplan_h20_s128"] = ControllerJob(
        gear, args.models, "dynoplan", replace(GEAR_CONTROL, horizon=20, samples=128))
    if (flat / "flat_policy.json").is_file():
        jobs[FLAT_POLICY] = ControllerJob(gear, args.models, FLAT_POLICY, GEAR_CONTROL)
    result: dict[str, Any] = {}
    for name, job in jobs.items():
        n = args.oracle_episodes if name == "oracle" else args.episodes
        runner = job.build()
        rows = [timed(runner.episode, s) for s in episode_seeds(7, n)]
        result[name] = {"tasks": n, "cpu_s_mean": round(float(np.mean([r[2] for r in rows])), 2),
                        "wall_s_mean": round(float(np.mean([r[1] for r in rows])), 2),
                        "wall_s_max": round(float(np.max([r[1] for r in rows])), 2),
                        "simulated_s_mean": round(float(np.mean([seconds(r[0]) for r in rows])), 1)}
    state = build_option_runs(OptionRunsJob(GearTask(), args.models, gear_option_names(), 0,
                                            30 * DECISION_STEPS))
    rows = [timed(option_run, state, (name, r)) for name in gear_option_names()
            for r in range(args.runs)]
    result["collect_run"] = {"tasks": len(rows),
                             "cpu_s_mean": round(float(np.mean([r[2] for r in rows])), 2),
                             "wall_s_mean": round(float(np.mean([r[1] for r in rows])), 2),
                             "wall_s_max": round(float(np.max([r[1] for r in rows])), 2),
                             "bytes_mean": int(np.mean([len(pickle.dumps(r[0])) for r in rows]))}
    if args.json:
        print(json.dumps(result))
        return
    for name, row in result.items():
        print(f"{name:>18}: " + ", ".join(f"{k} {v}" for k, v in row.items()))


if __name__ == "__main__":
    main()
