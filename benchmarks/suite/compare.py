"""Suite runs side by side: the ablation table of the composition suite.

Usage (from the repository root)::

    python -m benchmarks.suite.compare results/suite-first/* results/suite
    python -m benchmarks.suite.compare "first run=results/suite-first/classic" ...

Reads each folder's ``suite.json`` (written by ``python -m benchmarks.suite``) and prints
one markdown table: a row per run (named by the settings it changed, or by the label
given as ``LABEL=FOLDER``), a column per task,
each cell DynoPlan's success on every seed and, in brackets, the composition ratio.
Runs of the same settings on different tasks (one folder per group of tasks) are merged
into one row.
"""

import json
import sys
from pathlib import Path
from typing import Any


def variant(run: dict[str, Any]) -> str:
    """The run's name: the settings it changed (``defaults`` when none)."""
    sets = run.get("settings") or {}
    return ", ".join(f"{k}={v}" for k, v in sorted(sets.items())) or "defaults"


def cell(task: dict[str, Any]) -> str:
    seeds = " / ".join(f"{x:.2f}" for x in task["dynoplan"])
    ratio = task.get("composition_ratio")
    return seeds + ("" if ratio is None else f" ({ratio:.2f})")


def compare(folders: list[str]) -> str:
    """The markdown table of the runs in ``folders``."""
    rows: dict[str, dict[str, str]] = {}
    tasks: list[str] = []
    for item in folders:
        label, _, folder = item.rpartition("=")
        run = json.loads((Path(folder) / "suite.json").read_text(encoding="utf-8"))
        row = rows.setdefault(label or variant(run), {})
        for task in run["tasks"]:
            row[task["task"]] = cell(task)
            if task["task"] not in tasks:
                tasks.append(task["task"])
    lines = ["| settings changed | " + " | ".join(tasks) + " |",
             "|---|" + "---|" * len(tasks)]
    lines += [f"| {name} | " + " | ".join(row.get(t, "–") for t in tasks) + " |"
              for name, row in rows.items()]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit("usage: python -m benchmarks.suite.compare SUITE_FOLDER [SUITE_FOLDER ...]")
    print(compare(sys.argv[1:]), end="")
