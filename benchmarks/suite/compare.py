"""Suite runs side by side: the ablation table of the composition suite.

Usage (from the repository root)::

    python -m benchmarks.suite.compare results/suite-first/* results/suite
    python -m benchmarks.suite.compare "first run=results/suite-first/classic" ...

Reads each folder's ``suite.json`` (written by ``python -m benchmarks.suite``) and prints
one markdown table: a row per run (named by the settings it changed, or by the label
given as ``LABEL=FOLDER``), a column per task,
each cell DynoPlan's success on every seed and, in brackets, the composition ratio, and
a last column with the mean of the ratios (when every task has one). Under it, the same
rows under each task's disturbance, each cell's ratio against the disturbed
demonstrator's mean. Runs of the same settings on different tasks (one folder per group
of tasks) are merged into one row.
"""

import json
import sys
from pathlib import Path
from typing import Any


def variant(run: dict[str, Any]) -> str:
    """The run's name: the settings it changed (``defaults`` when none)."""
    sets = run.get("settings") or {}
    return ", ".join(f"{k}={v}" for k, v in sorted(sets.items())) or "defaults"


def ratio(task: dict[str, Any], disturbed: bool = False) -> float | None:
    """DynoPlan's mean success over the demonstrator's (clean, or under the disturbance);
    ``None`` where the demonstrator never succeeded or the run has no such rows."""
    prefix = "disturbed_" if disturbed else ""
    ours, bar = task.get(prefix + "dynoplan"), task.get(prefix + "demonstrator")
    if not ours or not bar or sum(bar) == 0:
        return None
    return sum(ours) / sum(bar)


def cell(task: dict[str, Any], disturbed: bool = False) -> str:
    seeds = " / ".join(f"{x:.2f}" for x in task["disturbed_dynoplan" if disturbed
                                                else "dynoplan"])
    share = ratio(task, disturbed)
    return seeds + ("" if share is None else f" ({share:.2f})")


def compare(folders: list[str]) -> str:
    """The markdown table of the runs in ``folders``."""
    runs: dict[str, dict[str, dict[str, Any]]] = {}
    tasks: list[str] = []
    for item in folders:
        label, _, folder = item.rpartition("=")
        run = json.loads((Path(folder) / "suite.json").read_text(encoding="utf-8"))
        row = runs.setdefault(label or variant(run), {})
        for task in run["tasks"]:
            row[task["task"]] = task
            if task["task"] not in tasks:
                tasks.append(task["task"])
    lines = ["| settings changed | " + " | ".join(tasks) + " | mean ratio |",
             "|---|" + "---|" * (len(tasks) + 1)]
    for disturbed in (False, True):
        for name, row in runs.items():
            if disturbed and not all(row[t].get("disturbed_dynoplan") for t in row):
                continue
            shares = [ratio(row[t], disturbed) if t in row else None for t in tasks]
            mean = ("–" if any(x is None for x in shares)
                    else f"{sum(x for x in shares if x is not None) / len(shares):.3f}")
            cells = [cell(row[t], disturbed) if t in row else "–" for t in tasks]
            lines.append(f"| {'disturbed, ' if disturbed else ''}{name} | "
                         + " | ".join(cells) + f" | {mean} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit("usage: python -m benchmarks.suite.compare SUITE_FOLDER [SUITE_FOLDER ...]")
    print(compare(sys.argv[1:]), end="")
