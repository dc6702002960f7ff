"""How long the ``dynoplan`` console script takes to answer ``--help`` and a usage
error: the median wall time of ``--runs`` runs of each, in new processes, with
``import torch`` alone for comparison (issue 34: at most 0.5 s, with no torch import).

Run ``python benchmarks/cli_startup.py [--runs 5] [--dynoplan PATH]`` (default: the
``dynoplan`` script beside this Python); ``--json`` for one JSON object.
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path


def median_seconds(command: list[str], runs: int) -> float:
    """The median wall time of ``runs`` runs of ``command`` (output discarded)."""
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        subprocess.run(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                       check=False)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--dynoplan", default=str(Path(sys.executable).parent / "dynoplan"))
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    cases = {
        "dynoplan --help": [args.dynoplan, "--help"],
        "dynoplan gear evaluate --help": [args.dynoplan, "gear", "evaluate", "--help"],
        "dynoplan random-walk --bogus (usage error)": [args.dynoplan, "random-walk",
                                                       "--bogus"],
        "python -c 'import torch' (for comparison)": [sys.executable, "-c", "import torch"],
    }
    result = {name: round(median_seconds(cmd, args.runs), 3) for name, cmd in cases.items()}
    result["load_average_1min"] = round(os.getloadavg()[0], 2)
    if args.json:
        print(json.dumps(result))
        return
    for name, value in result.items():
        print(f"{name}: {value}")


if __name__ == "__main__":
    main()
