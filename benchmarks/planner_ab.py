"""Two versions of the library on the planner benchmark, in alternating runs.

On a shared machine one run's timings say little; a ratio of two engines measured in
the same minutes says more. This script runs ``benchmarks/planner.py --json`` (with the
extra arguments given after ``--``) ``--rounds`` times for each of two source trees,
alternating (A, B, A, B, ...), each run a new process with ``PYTHONPATH`` set to the
tree's ``src``, and prints per tree the median of the runs' p50 and GEMM fraction, the
ratio ``A p50 / B p50`` per round and its median, and the 1-minute load average before
and after.

    python benchmarks/planner_ab.py --a /work/main/src --b src --rounds 5 -- --depth 2

Both trees are timed with this checkout's ``benchmarks/planner.py``.
"""

import argparse
import json
import os
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def one_run(src: str, extra: Sequence[str]) -> dict[str, float]:
    env = dict(os.environ, PYTHONPATH=str(Path(src).resolve()))
    out = subprocess.run([sys.executable, str(HERE / "planner.py"), "--json", *extra],
                         env=env, check=True, capture_output=True, text=True).stdout
    result: dict[str, float] = json.loads(out.strip().splitlines()[-1])
    return result


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--a", required=True, help="the first tree's src folder (baseline)")
    parser.add_argument("--b", required=True, help="the second tree's src folder")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("extra", nargs="*", help="arguments for planner.py (after --)")
    args = parser.parse_args(argv)
    load_before = os.getloadavg()[0]
    runs: dict[str, list[dict[str, float]]] = {"a": [], "b": []}
    for _ in range(args.rounds):
        runs["a"].append(one_run(args.a, args.extra))
        runs["b"].append(one_run(args.b, args.extra))
    load_after = os.getloadavg()[0]
    ratios = [a["decision_ms_p50"] / b["decision_ms_p50"] for a, b in zip(runs["a"],
                                                                          runs["b"], strict=True)]
    summary = {
        "args": args.extra, "rounds": args.rounds,
        "load_before": load_before, "load_after": load_after,
        **{f"{k}_p50_ms_median": float(np.median([r["decision_ms_p50"] for r in v]))
           for k, v in runs.items()},
        **{f"{k}_p50_ms_runs": [round(r["decision_ms_p50"], 2) for r in v]
           for k, v in runs.items()},
        **{f"{k}_gemm_fraction_median": float(np.median([r["gemm_fraction"] for r in v]))
           for k, v in runs.items()},
        **{f"{k}_batched_vs_loop_median": (None if v[0]["batched_vs_loop"] is None else
                                           float(np.median([r["batched_vs_loop"] for r in v])))
           for k, v in runs.items()},
        "gemm_gflops_median": float(np.median([r["gemm_gflops"] for v in runs.values()
                                               for r in v])),
        "a_over_b_per_round": [round(r, 3) for r in ratios],
        "a_over_b_median": float(np.median(ratios)),
    }
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
