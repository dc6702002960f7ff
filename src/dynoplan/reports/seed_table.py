"""One table over several runs of one experiment that differ only in their seed: each
controller's mean and range of every measure (``dynoplan gear seeds``).

A run is a folder with a ``summary.json`` whose ``results`` (and optionally ``ablation``)
list one row per controller, as ``dynoplan gear run`` writes it. A headline that rests
on one seed hides how far another seed lands; this table shows it.
"""

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from dynoplan.errors import DynoplanError
from dynoplan.io import read_json_object

MEASURES = (("success_rate", "success", "{:.0%}"),
            ("time_to_success_s", "median time (s)", "{:.1f}"),
            ("episodes_with_contact", "episodes with contact", "{:.0f}"),
            ("contacts_moving", "contact steps while moving", "{:,.0f}"),
            ("out_of_region_starts", "out-of-region starts", "{:,.0f}"))
"""``(column of a row, header, format)`` of the measures the table gives."""


def read_runs(folders: Sequence[Path]) -> list[dict[str, Any]]:
    """The ``summary.json`` of every folder, with its ``seed``.

    Raises:
        DynoplanError: a folder without a readable ``summary.json`` with ``results``, two
            runs of the same seed.
    """
    runs = []
    for folder in folders:
        path = Path(folder) / "summary.json"
        summary = read_json_object(path, "gear run's summary")
        if not isinstance(summary.get("results"), list):
            raise DynoplanError(f"{path}: no 'results' rows (a gear run's summary?)")
        runs.append(summary)
    seeds = [r.get("seed") for r in runs]
    if len(set(map(str, seeds))) < len(seeds):
        raise DynoplanError(f"two runs of the same seed among {seeds}")
    return runs


def seed_rows(runs: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per controller (in the first run's order, the ablation rows after the results'):
    ``{"controller", "seeds", "episodes", <measure>: (mean, low, high) or None}`` over the
    runs that have that controller; a measure missing or ``None`` in a run is left out."""
    by_name: dict[str, list[dict[str, Any]]] = {}  # in order of first appearance
    for run in runs:
        seen: set[str] = set()
        for row in [*run["results"], *(run.get("ablation") or [])]:
            name = str(row.get("controller"))
            if name not in seen:  # a results row before an ablation row of that name
                seen.add(name)
                by_name.setdefault(name, []).append(row)
    out = []
    for name, rows in by_name.items():
        entry: dict[str, Any] = {"controller": name, "seeds": len(rows),
                                 "episodes": sorted({int(r.get("episodes") or 0) for r in rows})}
        for key, _, _ in MEASURES:
            values = [float(r[key]) for r in rows if isinstance(r.get(key), int | float)
                      and math.isfinite(float(r[key]))]
            entry[key] = (sum(values) / len(values), min(values), max(values)) if values \
                else None
        out.append(entry)
    return out


def seed_markdown(runs: Sequence[dict[str, Any]]) -> str:
    """The table of :func:`seed_rows` in markdown: every cell ``mean (low-high)``."""
    seeds = ", ".join(str(r.get("seed")) for r in runs)
    header = ["controller", "episodes per seed", *[h for _, h, _ in MEASURES]]
    lines = [f"Seeds {seeds}: the mean over the seeds and, in brackets, the lowest and "
             "highest.", "", "| " + " | ".join(header) + " |",
             "|" + "---|" * len(header)]
    for row in seed_rows(runs):
        cells = [f"`{row['controller']}`", "/".join(map(str, row["episodes"]))]
        for key, _, fmt in MEASURES:
            value = row[key]
            cells.append("–" if value is None else
                         f"{fmt.format(value[0])} ({fmt.format(value[1])}-{fmt.format(value[2])})")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


__all__ = ["MEASURES", "read_runs", "seed_markdown", "seed_rows"]
