"""The random-walk experiment's tables: ``results.md`` and the traced episode's rows."""

from typing import Any

from dynoplan.control.controller import EpisodeTrace
from dynoplan.reports.tables import markdown_table

_COLUMNS = ["controller", "success_rate", "planning_steps_median", "planning_steps_p90",
            "planning_steps_mean_of_successes", "seconds"]
_HEADERS = ["controller", "success rate", "planning steps median", "p90", "mean (successes)",
            "seconds"]


def trace_rows(trace: EpisodeTrace) -> list[dict[str, Any]]:
    """Per planning step of a one-dimensional walk: state, every option's mean predicted end
    state, scores, choice, state after."""
    rows = []
    for d in trace.decisions:
        rows.append({
            "planning_step": d.index,
            "state": float(d.state[0]),
            "predicted_end_state_mean": {
                name: float(d.plan.end_states[o, :, 0].mean())
                for o, name in enumerate(d.plan.option_names)},
            "scores": dict(zip(d.plan.option_names, map(float, d.plan.scores), strict=True)),
            "chosen": d.option,
            "state_after": float(d.state_after[0]),
        })
    return rows


def random_walk_markdown(settings: dict[str, Any], main: dict[str, Any],
                         baselines: dict[str, dict[str, Any]],
                         robustness: list[dict[str, Any]]) -> str:
    """``results.md``: DynoPlan (``main``) against ``baselines`` by name, then one row per
    ``robustness`` noise; ``settings`` as ``summary.json`` records them (``episodes``,
    ``noise``, ``seed``, ``horizon``, ``samples``, ``max_decisions``)."""
    s = settings
    command = (f"dynoplan random-walk --episodes {s['episodes']} --noise {s['noise']:g} "
               f"--seed {s['seed']} --horizon {s['horizon']} --samples {s['samples']}")
    rows = [{"controller": "DynoPlan", **main}]
    rows += [{"controller": name, **row} for name, row in baselines.items()]
    noise_rows = [{"controller": f"DynoPlan, noise {r['noise']:g}", **r} for r in robustness]
    return (f"Produced by `{command}` ({s['episodes']} episodes per row; at most "
            f"{s['max_decisions']} planning steps; \"–\" where the quantile falls on "
            f"failed episodes).\n\n"
            f"### Noise {s['noise']:g}: DynoPlan against each option alone and random choice"
            f"\n\n{markdown_table(rows, _COLUMNS, _HEADERS)}\n"
            f"### Robustness to model misprediction\n\n"
            f"{markdown_table(noise_rows, _COLUMNS, _HEADERS)}")


__all__ = ["random_walk_markdown", "trace_rows"]
