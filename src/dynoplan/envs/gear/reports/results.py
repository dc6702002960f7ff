"""The gear's results table: one row per controller from its episodes' records.

Controllers (rows of ``results.csv``):

- ``dynoplan``: the option planner (Eq. 1) with the learned dynamics ensembles, the
  learned goal heuristic and the Gaussian-mixture regions as initiation sets;
- ``oracle``: the same controller, but each option's future simulated by MuJoCo itself
  (:class:`~dynoplan.planning.SimulatorOracle`);
- ``fixed_script``: pick, fast move, insert, each run to its end, ignoring the human
  and the regions;
- ``random``: a uniformly random admissible option at every decision;
- ``flat_ppo``: one PPO network from observation to action
  (:mod:`dynoplan.envs.gear.flat_policy`).

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

from dynoplan.envs.gear.env import MAX_EPISODE_STEPS
from dynoplan.envs.gear.flat_policy import FLAT_POLICY
from dynoplan.envs.gear.metrics import human_mode, seconds
from dynoplan.io import write_csv, write_json
from dynoplan.pipeline.evaluate import EpisodeRecord, summarize
from dynoplan.pipeline.improve import learning_curve_text
from dynoplan.reports.tables import markdown_table

RESULT_COLUMNS = (
    "controller", "episodes", "success_rate", "time_to_success_s", "contacts",
    "episodes_with_contact", "contacts_moving", "contacts_at_rest", "sp_violations_moving",
    "protective_stops", "min_human_distance", "out_of_region_starts", "switches", "holds",
    "decision_ms_p50", "decision_ms_p99",
)
"""Columns of ``results.csv``, in order."""


def failure_kind(record: EpisodeRecord) -> str:
    """How a failed episode ended: ``dropped`` (before the step limit: the env ends an
    episode early only when the gear falls off the table), ``never started`` (to the
    limit without running an option: nothing admissible, or every option unsafe, at every
    step from the first), ``held`` (to the limit, half of its steps or more with no option
    run), or, to the limit, the option that ran the most steps (``ran`` for a controller
    without options)."""
    if record.env_steps < MAX_EPISODE_STEPS:
        return "dropped"
    if record.no_admissible >= record.env_steps:
        return "never started"
    if 2 * record.no_admissible >= record.env_steps:
        return "held"
    if not record.option_steps:
        return "ran"
    return max(record.option_steps, key=lambda pair: pair[1])[0]


def summarise(name: str, episodes: Sequence[EpisodeRecord]) -> dict[str, Any]:
    """One row of ``results.csv`` (see :data:`RESULT_COLUMNS`) plus per-mode success and
    the failed episodes by :func:`failure_kind` (``failures``: kind -> count): every
    task's summary (:func:`~dynoplan.pipeline.evaluate.summarize`) in the gear's
    columns, with the gear's time to success, contacts and distances."""
    every = summarize(episodes)
    ok = [e for e in episodes if e.success]
    contacts = [int(e.task_metrics["contacts"]) for e in episodes]
    row: dict[str, Any] = {
        "controller": name,
        "episodes": every["episodes"],
        "success_rate": every["success_rate"],
        "time_to_success_s": float(np.median([seconds(e) for e in ok])) if ok else None,
        "contacts": int(sum(contacts)),
        "episodes_with_contact": int(sum(c > 0 for c in contacts)),
        **{key: int(sum(int(e.task_metrics.get(key, 0)) for e in episodes))
           for key in ("contacts_moving", "contacts_at_rest", "sp_violations_moving",
                       "protective_stops")},
        "min_human_distance": float(min(e.task_metrics["min_human_distance"]
                                        for e in episodes)),
        "out_of_region_starts": every["out_of_region_starts"],
        "switches": every["switches"],
        "holds": every["no_admissible"],
        "decision_ms_p50": every["latency_ms_p50"],
        "decision_ms_p99": every["latency_ms_p99"],
    }
    by_mode = {}
    for mode in sorted({human_mode(e) for e in episodes}):
        sub = [e for e in episodes if human_mode(e) == mode]
        by_mode[mode] = {"episodes": len(sub),
                         "success_rate": float(np.mean([e.success for e in sub])),
                         "contacts": int(sum(int(e.task_metrics["contacts"]) for e in sub))}
    row["by_human_mode"] = by_mode
    kinds = [failure_kind(e) for e in episodes if not e.success]
    row["failures"] = {k: kinds.count(k)
                       for k in sorted(set(kinds), key=lambda k: (-kinds.count(k), k))}
    return row


def results_rows(episodes: dict[str, list[EpisodeRecord]]) -> list[dict[str, Any]]:
    """One row of ``results.csv`` per controller (:func:`summarise`), in the given order;
    the flat policy's option columns are empty (it has no options)."""
    rows = []
    for name, records in episodes.items():
        row = summarise(name, records)
        if name == FLAT_POLICY:
            row["out_of_region_starts"] = row["switches"] = row["holds"] = None
        rows.append(row)
    return rows


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


def failure_table(rows: Sequence[dict[str, Any]]) -> str:
    """Markdown: per controller (row of :func:`summarise`), its failed episodes by how
    they ended (:func:`failure_kind`)."""
    return markdown_table([
        {"controller": r["controller"],
         "failed": sum(r["failures"].values()),
         "how they ended": ", ".join(f"{k} {n}" for k, n in r["failures"].items()) or "–"}
        for r in rows])


FAILURE_NOTE = ("How failed episodes ended: `dropped`, the gear fell off the table; "
                "`never started`, to the 40 s limit without running an option (nothing "
                "admissible, or every option unsafe, from the first step on); `held`, to "
                "the limit with no option run on half of the steps or more; an option's "
                "name, to the limit with that option running the most steps.")


def results_markdown(summary: dict[str, Any]) -> str:
    """``results.md``: the controllers' table, the faults, the models and the stages."""
    lines = ["# Gear assembly: DynoPlan and baselines", ""]
    s = {**summary["settings"], **summary["settings"]["evaluation"]}
    lines.append(f"Seed {summary['seed']}; {s['episodes']} evaluation episodes per controller "
                 f"(oracle: the first {s['oracle_episodes']}); planner horizon "
                 f"{s['planner']['horizon']}, samples {s['planner']['samples']}; flat PPO "
                 f"{s['ppo_steps']} env steps.")
    lines += ["", markdown_table(summary["results"], RESULT_COLUMNS), "",
              "Success by human mode:", "", behaviour_table(summary["results"]), "",
              FAILURE_NOTE, "", failure_table(summary["results"])]
    if summary.get("ablation"):
        lines += ["", "## Ablation: what each learned part does", "",
                  f"The same first {s['ablation_episodes']} episodes for every row. "
                  "`dynoplan` and `random` choose on the learned sets (Eq. 5 regions and the "
                  "initiation learned from outcomes); `dynoplan+rules` adds the hand-written "
                  "conditions; `dynoplan_regions` plans on the Eq. 5 regions alone (the "
                  "paper's method); `epistemic=0.3` penalises the dynamics ensemble's "
                  "disagreement.", "",
                  markdown_table(summary["ablation"], RESULT_COLUMNS)]
    if summary.get("improvement"):
        lines += ["", "## Learning from its own episodes", "",
                  learning_curve_text(summary["improvement"])]
    lines += ["", "## Faults (DynoPlan)", "",
              markdown_table(summary["faults"], ("fault", "episodes", "success_rate",
                                                 "contacts", "switches", "holds")),
              "", "## Learned models", "",
              markdown_table([summary["model_metrics"]],
                             ("goal_spearman", "goal_mae", "region_inside_rate",
                              "region_far_outside_rate", "dynamics_coverage_90")),
              "", "## Stages (s)", "", markdown_table([summary["stages_s"]])]
    if "wall_s" in summary:
        workers = summary["workers"]
        on = workers["address"] or f"{workers['count']} worker(s)"
        lines += ["", f"Whole run: {summary['wall_s']} s on {on}"
                  + ("; flat_ppo and video ran beside the other stages." if
                     workers["count"] > 1 or workers["address"] else ".")]
    return "\n".join(lines)


def evaluation_markdown(summary: dict[str, Any]) -> str:
    """``results.md`` of ``gear evaluate``: its settings, the table and the success by
    human behaviour."""
    rows, planner, human = summary["results"], summary["planner"], summary["human"]
    workers = summary["workers"]
    return "\n".join([
        "# Gear assembly: evaluation", "",
        f"Models {summary['models']}; seed {summary['seed']}; {summary['episodes']} episodes "
        f"per controller; planner horizon {planner['horizon']}, samples {planner['samples']}; "
        f"{workers['count']} worker(s)"
        f"{'' if workers['address'] is None else ' on ' + workers['address']}; "
        f"{summary['wall_s']:.1f} s wall; human behaviours "
        f"{', '.join(human or ('away, cross, block (the demonstrations mix)',))}; "
        f"runtime monitor {'on' if summary['shield'] else 'off'}.",
        "", markdown_table(rows, RESULT_COLUMNS), "", "Success by human behaviour:", "",
        behaviour_table(rows), "", FAILURE_NOTE, "", failure_table(rows)])


def _mode_cell(entry: dict[str, Any] | None) -> str:
    if not entry:
        return "–"
    return f"{entry['success_rate']:.0%} of {entry['episodes']}, contacts {entry['contacts']}"


__all__ = ["FAILURE_NOTE", "RESULT_COLUMNS", "behaviour_table", "evaluation_markdown",
           "failure_kind", "failure_table", "results_markdown", "results_rows", "summarise",
           "write_results"]
