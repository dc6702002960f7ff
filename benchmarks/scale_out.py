"""Scale-out: the gear evaluation on one worker against N Ray workers, in one run.

The same seeded episodes of one controller run twice with the library's map
(:func:`dynoplan.parallel.imap_unordered`): first in this process (one worker, no Ray),
then as Ray tasks on a local runtime of ``--workers`` CPUs. Reported:

- ``serial_s``, ``parallel_s`` (Ray's start and stop included) and ``parallel_map_s``
  (the map alone), ``speedup = serial_s / parallel_s`` and ``speedup_map``;
- ``identical``: every episode's metrics equal, all but the wall-clock decision
  latencies (``EpisodeMetrics`` minus ``decision_ms``);
- per-episode wall times of the serial run (p50, p90, max, mean; the first includes the
  set-up), for estimating larger runs;
- bytes a task sends (its job and seed, pickled) and returns (its metrics), and the
  models folder's size (what every node needs once);
- the 1-minute load average before and after each run (the machine is shared).

Run ``python benchmarks/scale_out.py --models DIR`` for a table, ``--json`` for one
JSON object (``--out FILE`` also writes it).
"""

import argparse
import dataclasses
import json
import os
import pickle
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from dynoplan.experiments.episodes import episode_seeds
from dynoplan.experiments.gear_controllers import PlannerSettings
from dynoplan.experiments.gear_jobs import EvalJob, build_evaluation, evaluate_episode
from dynoplan.experiments.gear_run import EVAL_SEED_OFFSET
from dynoplan.io import write_json
from dynoplan.parallel import SERIAL, Workers, imap_unordered, ray_session


def timed_map(job: EvalJob, seeds: list[Any], workers: Workers) -> tuple[list[Any], list[float]]:
    """Results in seed order and the wall time from the start to each result."""
    t0 = time.perf_counter()
    results: list[Any] = [None] * len(seeds)
    marks = []
    tasks = [(job, s) for s in seeds]
    for i, metrics in imap_unordered(build_evaluation, evaluate_episode, tasks, workers):
        results[i] = metrics
        marks.append(time.perf_counter() - t0)
    return results, marks


def comparable(metrics: Any) -> dict[str, Any]:
    d = dataclasses.asdict(metrics)
    d.pop("decision_ms")
    return d


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--models", type=Path, required=True, help="gear models folder")
    parser.add_argument("--controller", default="dynoplan")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0, help="as gear run / gear evaluate")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--out", type=Path, help="also write the JSON object here")
    args = parser.parse_args()

    import torch

    torch.set_num_threads(1)
    os.environ.setdefault("MUJOCO_GL", "egl")
    job = EvalJob(args.models, args.controller, PlannerSettings())
    seeds = episode_seeds(args.seed + EVAL_SEED_OFFSET, args.episodes)

    load = {"before_serial": os.getloadavg()[0]}
    serial, marks = timed_map(job, seeds, SERIAL)
    serial_s = marks[-1]
    load["after_serial"] = os.getloadavg()[0]
    t0 = time.perf_counter()
    workers = Workers(args.workers)
    with ray_session(workers):
        ready = time.perf_counter() - t0
        parallel, pmarks = timed_map(job, seeds, workers)
        load["after_parallel"] = os.getloadavg()[0]
    parallel_s = time.perf_counter() - t0

    per_episode = np.diff([0.0, *marks])
    mismatched = [i for i, (a, b) in enumerate(zip(serial, parallel, strict=True))
                  if comparable(a) != comparable(b)]
    models_bytes = sum(p.stat().st_size for p in args.models.rglob("*") if p.is_file())
    result = {
        "command": " ".join([Path(sys.executable).name, *sys.argv]),
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
        "controller": args.controller, "episodes": args.episodes, "workers": args.workers,
        "serial_s": round(serial_s, 1), "parallel_s": round(parallel_s, 1),
        "parallel_map_s": round(pmarks[-1], 1), "ray_start_s": round(ready, 1),
        "speedup": round(serial_s / parallel_s, 2),
        "speedup_map": round(serial_s / pmarks[-1], 2),
        "identical": not mismatched, "mismatched_episodes": mismatched,
        "success_rate": float(np.mean([m.success for m in serial])),
        "episode_s": {"p50": round(float(np.median(per_episode)), 2),
                      "p90": round(float(np.quantile(per_episode, 0.9)), 2),
                      "max": round(float(per_episode.max()), 2),
                      "mean": round(float(per_episode.mean()), 2)},
        "simulated_s_mean": round(float(np.mean([m.seconds for m in serial])), 1),
        "task_in_bytes": len(pickle.dumps((job, seeds[0]))),
        "task_out_bytes": int(np.mean([len(pickle.dumps(m)) for m in serial])),
        "models_bytes": models_bytes,
        "load_1min": {k: round(v, 2) for k, v in load.items()},
    }
    if args.out:
        write_json(args.out, result)
    if args.json:
        print(json.dumps(result))
        return
    for key, value in result.items():
        print(f"{key:>20}: {value}")


if __name__ == "__main__":
    main()
