"""The gear's results table: one row per controller from its episodes' records.

Controllers (rows of ``results.csv``):

- ``dynoplan``: the option planner (Eq. 1) with the learned dynamics ensembles, the
  learned goal heuristic and the Gaussian-mixture regions as initiation sets;
- ``oracle``: the same controller, but each option's future simulated by MuJoCo itself
  (:class:`~dynoplan.planning.SimulatorOracle`);
- ``fixed_script``: pick, fast move, insert, each run to its end, ignoring the human
  and the regions;
- ``random``: a uniformly random admissible option at every decision;
- ``flat_ppo``: one PPO network from observation to action (:mod:`dynoplan.baselines`).

Every controller runs on the same episodes: episode ``i`` resets the env with the same
seed (gear pose and human schedule: none, crossing or blocking). An episode depends on
its :class:`~dynoplan.seeding.EpisodeSeed` alone, not on the episodes run
before it, so a run split over workers (:mod:`dynoplan.envs.gear.pipeline_task`) gives the
same metrics.
"""

from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from dynoplan.envs.gear.env import CONTROL_DT
from dynoplan.io import write_csv, write_json
from dynoplan.pipeline.evaluate import EpisodeRecord, quantile_or_none
from dynoplan.reports.tables import markdown_table

RESULT_COLUMNS = (
    "controller", "episodes", "success_rate", "time_to_success_s", "contacts",
    "episodes_with_contact", "contacts_moving", "contacts_at_rest", "sp_violations_moving",
    "protective_stops", "min_human_distance", "out_of_region_starts", "switches", "holds",
    "decision_ms_p50", "decision_ms_p99",
)
"""Columns of ``results.csv``, in order."""


def seconds(record: EpisodeRecord) -> float:
    """The episode's simulated duration (s)."""
    return record.env_steps * CONTROL_DT


def human_mode(record: EpisodeRecord) -> str:
    """The human's behaviour in the episode (``away``, ``cross``, ``block``)."""
    return str(record.task_metrics["human_mode"])


def summarise(name: str, episodes: Sequence[EpisodeRecord]) -> dict[str, Any]:
    """One row of ``results.csv`` (see :data:`RESULT_COLUMNS`) plus per-mode success."""
    ms = [m for e in episodes for m in e.decision_ms]
    ok = [e for e in episodes if e.success]
    contacts = [int(e.task_metrics["contacts"]) for e in episodes]
    row: dict[str, Any] = {
        "controller": name,
        "episodes": len(episodes),
        "success_rate": float(np.mean([e.success for e in episodes])) if episodes else 0.0,
        "time_to_success_s": float(np.median([seconds(e) for e in ok])) if ok else None,
        "contacts": int(sum(contacts)),
        "episodes_with_contact": int(sum(c > 0 for c in contacts)),
        **{key: int(sum(int(e.task_metrics.get(key, 0)) for e in episodes))
           for key in ("contacts_moving", "contacts_at_rest", "sp_violations_moving",
                       "protective_stops")},
        "min_human_distance": float(min(e.task_metrics["min_human_distance"]
                                        for e in episodes)),
        "out_of_region_starts": int(sum(e.out_of_region_starts for e in episodes)),
        "switches": int(sum(e.switches for e in episodes)),
        "holds": int(sum(e.no_admissible for e in episodes)),
        "decision_ms_p50": quantile_or_none(ms, 0.5),
        "decision_ms_p99": quantile_or_none(ms, 0.99),
    }
    by_mode = {}
    for mode in sorted({human_mode(e) for e in episodes}):
        sub = [e for e in episodes if human_mode(e) == mode]
        by_mode[mode] = {"episodes": len(sub),
                         "success_rate": float(np.mean([e.success for e in sub])),
                         "contacts": int(sum(int(e.task_metrics["contacts"]) for e in sub))}
    row["by_human_mode"] = by_mode
    return row


def write_results(out: Path, rows: Sequence[dict[str, Any]],
                  episodes: dict[str, list[EpisodeRecord]]) -> None:
    """``out/results.csv`` (the :data:`RESULT_COLUMNS` of every row) and
    ``out/episodes.json`` (every controller's episode records), each written atomically."""
    write_csv(out / "results.csv", [{c: r.get(c) for c in RESULT_COLUMNS} for r in rows])
    write_json(out / "episodes.json", {k: [asdict(e) for e in v] for k, v in episodes.items()})


def behaviour_table(rows: Sequence[dict[str, Any]]) -> str:
    """Markdown: per controller (row of :func:`summarise`), success and contacts by the
    human's behaviour."""
    modes = sorted({m for r in rows for m in r["by_human_mode"]})
    return markdown_table([
        {"controller": r["controller"], **{m: _mode_cell(r["by_human_mode"].get(m))
                                           for m in modes}} for r in rows])


def _mode_cell(entry: dict[str, Any] | None) -> str:
    if not entry:
        return "–"
    return f"{entry['success_rate']:.0%} of {entry['episodes']}, contacts {entry['contacts']}"


__all__ = ["RESULT_COLUMNS", "behaviour_table", "human_mode", "seconds", "summarise",
           "write_results"]
