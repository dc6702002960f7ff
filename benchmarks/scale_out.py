"""Scale-out: the gear evaluation on one worker against N Ray workers, in one run.

The same seeded episodes of one controller run twice with the library's map
(:func:`dynoplan.parallel.imap_unordered`): in this process (one worker, no Ray) and as
Ray tasks on a local runtime of ``--workers`` CPUs. The episodes are split into
``--rounds`` consecutive chunks; each chunk runs both ways, back to back, the order
alternating between rounds, so that both see the same (shared, noisy) machine.
Reported:

- ``serial_s`` and ``parallel_map_s`` (summed over the rounds), ``ray_start_s`` (the
  local runtime's start), ``speedup_map = serial_s / parallel_map_s`` and ``speedup =
  serial_s / (parallel_map_s + ray_start_s)``;
- ``identical``: every episode's metrics equal, all but the wall-clock decision
  latencies (``EpisodeRecord`` minus ``decision_ms``);
- per-episode wall times of the serial run (p50, p90, max, mean; the first includes the
  set-up), for estimating larger runs;
- bytes a task sends (its job and seed, pickled) and returns (its metrics), and the
  models folder's size (what every node needs once);
- the 1-minute load average at the start of each map, and the share of a CPU each
  episode got while it ran (CPU seconds over wall seconds, in the process that ran it):
  the machine is shared, and 2 workers on 2 cores only help if both cores are free.

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

from dynoplan.envs.gear.controllers import GEAR_CONTROL
from dynoplan.envs.gear.evaluation import EVAL_SEED_OFFSET
from dynoplan.envs.gear.metrics import seconds
from dynoplan.envs.gear.pipeline_task import GearTask
from dynoplan.io import write_json
from dynoplan.parallel import SERIAL, Workers, imap_unordered, ray_session
from dynoplan.pipeline.evaluate import ControllerJob
from dynoplan.pipeline.jobs import build_runner
from dynoplan.seeding import episode_seeds


def timed_episode(runner: Any, seed: Any) -> tuple[Any, float, float]:
    """``runner.episode(seed)`` with its wall and CPU seconds (in the process running it)."""
    wall, cpu = time.perf_counter(), time.process_time()
    metrics = runner.episode(seed)
    return metrics, time.perf_counter() - wall, time.process_time() - cpu


def timed_map(job: ControllerJob, seeds: list[Any],
              workers: Workers) -> tuple[list[Any], list[float], float, float]:
    """Results in seed order, the wall time from the start to each result, and the
    episodes' summed wall and CPU seconds."""
    t0 = time.perf_counter()
    results: list[Any] = [None] * len(seeds)
    marks, walls, cpus = [], [], []
    tasks = [(job, s) for s in seeds]
    for i, (metrics, wall, cpu) in imap_unordered(build_runner, timed_episode, tasks,
                                                  workers):
        results[i] = metrics
        marks.append(time.perf_counter() - t0)
        walls.append(wall)
        cpus.append(cpu)
    return results, marks, sum(walls), sum(cpus)


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
    parser.add_argument("--rounds", type=int, default=4, help="alternating chunks")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--out", type=Path, help="also write the JSON object here")
    args = parser.parse_args()

    import torch

    torch.set_num_threads(1)
    os.environ.setdefault("MUJOCO_GL", "egl")
    job = ControllerJob(GearTask(), args.models, args.controller, GEAR_CONTROL)
    seeds = episode_seeds(args.seed + EVAL_SEED_OFFSET, args.episodes)

    workers = Workers(args.workers)
    serial: list[Any] = []
    parallel: list[Any] = []
    marks: list[float] = []
    serial_s = parallel_s = 0.0
    wall = {"serial": 0.0, "parallel": 0.0}
    cpu = {"serial": 0.0, "parallel": 0.0}
    load = []
    per_round: list[dict[str, float]] = []
    t0 = time.perf_counter()
    with ray_session(workers):
        ready = time.perf_counter() - t0
        for r, chunk in enumerate(np.array_split(np.arange(len(seeds)), args.rounds)):
            part = [seeds[i] for i in chunk]
            per_round.append({})
            for way in (("serial", "parallel") if r % 2 == 0 else ("parallel", "serial")):
                load.append(os.getloadavg()[0])
                results, ends, w, c = timed_map(job, part, SERIAL if way == "serial"
                                                else workers)
                wall[way] += w
                cpu[way] += c
                per_round[-1][f"{way}_s"] = round(ends[-1], 1)
                per_round[-1][f"{way}_cpu_share"] = round(c / w, 2)
                if way == "serial":
                    serial += results
                    marks += [serial_s + e for e in ends]
                    serial_s += ends[-1]
                else:
                    parallel += results
                    parallel_s += ends[-1]

    per_episode = np.diff([0.0, *marks])
    mismatched = [i for i, (a, b) in enumerate(zip(serial, parallel, strict=True))
                  if comparable(a) != comparable(b)]
    models_bytes = sum(p.stat().st_size for p in args.models.rglob("*") if p.is_file())
    result = {
        "command": " ".join([Path(sys.executable).name, *sys.argv]),
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
        "controller": args.controller, "episodes": args.episodes, "workers": args.workers,
        "rounds": args.rounds,
        "serial_s": round(serial_s, 1), "parallel_map_s": round(parallel_s, 1),
        "ray_start_s": round(ready, 1),
        "speedup_map": round(serial_s / parallel_s, 2),
        "speedup": round(serial_s / (parallel_s + ready), 2),
        "identical": not mismatched, "mismatched_episodes": mismatched,
        "success_rate": float(np.mean([m.success for m in serial])),
        "episode_s": {"p50": round(float(np.median(per_episode)), 2),
                      "p90": round(float(np.quantile(per_episode, 0.9)), 2),
                      "max": round(float(per_episode.max()), 2),
                      "mean": round(float(per_episode.mean()), 2)},
        "simulated_s_mean": round(float(np.mean([seconds(m) for m in serial])), 1),
        "task_in_bytes": len(pickle.dumps((job, seeds[0]))),
        "task_out_bytes": int(np.mean([len(pickle.dumps(m)) for m in serial])),
        "models_bytes": models_bytes,
        "load_1min_at_each_start": [round(v, 2) for v in load],
        "per_round": per_round,
        # the share of a CPU an episode got while it ran (1.0: a core of its own)
        "cpu_share_serial": round(cpu["serial"] / wall["serial"], 2),
        "cpu_share_parallel": round(cpu["parallel"] / wall["parallel"], 2),
        "episodes_cpu_s": {k: round(v, 1) for k, v in cpu.items()},
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
