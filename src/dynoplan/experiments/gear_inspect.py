"""One evaluation episode of one controller, decision by decision (``dynoplan gear episode``).

The evaluation (``dynoplan gear run`` / ``gear evaluate``) reports per-episode metrics in
``episodes.json``; this module replays one of those episodes (the same
:class:`~dynoplan.seeding.EpisodeSeed`, hence the same gear pose, human
schedule and, for the same models, the same decisions) and keeps its trace: per decision,
the option chosen (or a hold), why it stopped, which options were admissible and how the
planner scored them, where the tool, the gear and the human's hand were, and the
robot-human contacts and distance while it ran.
"""

from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from dynoplan.control.controller import EpisodeTrace
from dynoplan.envs.gear.controllers import GEAR_CONTROL, VARIANTS
from dynoplan.envs.gear.env import CONTROL_DT, GearAssemblyEnv
from dynoplan.envs.gear.pipeline_task import GearTask
from dynoplan.envs.gear.state import STATE_SLICES, tool_human_distance
from dynoplan.errors import DynoplanError
from dynoplan.experiments.gear_run import EVAL_SEED_OFFSET, caption_gear_frames
from dynoplan.pipeline.evaluate import ControllerRunner, ControllerSettings, EpisodeRecord
from dynoplan.seeding import EpisodeSeed, episode_seeds

TRACE_COLUMNS = (
    "decision", "time_s", "option", "stop_reason", "steps", "admissible", "tool_hand_m",
    "contacts", "min_human_distance_m", "latency_ms", "gear_x", "gear_y", "gear_z",
    "hand_x", "hand_y", "hand_z",
)
"""Columns of ``trace.csv`` before the per-option ``score_<option>`` and
``disagreement_<option>`` columns."""


def inspect_episode(models: Path, controller: str, index: int, seed: int = 0,
                    planner: ControllerSettings = GEAR_CONTROL, frames: list[Any] | None = None
                    ) -> tuple[EpisodeRecord, list[dict[str, Any]], dict[str, Any]]:
    """Replay evaluation episode ``index`` (0-based, as in ``episodes.json``) of
    ``controller`` on the models in ``models``; with ``frames``, render it offscreen and
    append one frame per step (for :func:`~dynoplan.experiments.gear_run.video_clip`).

    Returns:
        The episode's metrics (the same as the evaluation's for the same models, seed
        and planner settings, but for the measured latencies), one row per decision
        (:data:`TRACE_COLUMNS`, ``score_<option>``: the planner's score, and
        ``disagreement_<option>``: its ensemble disagreement; empty when
        the option was not admissible or the chooser does not score), and the human
        schedule (``events``, keyframe ``times`` and hand ``positions``).
    """
    if controller not in VARIANTS:
        raise DynoplanError(f"unknown controller {controller!r}; expected one of "
                            f"{', '.join(VARIANTS)} (flat_ppo has no decisions)")
    episode = evaluation_episode(index, seed)
    runner = GearTask(render=frames is not None).make_runner(controller, models, planner)
    assert isinstance(runner, ControllerRunner)
    try:
        trace = runner.run(episode, frames)
    finally:
        runner.env.close()
    if frames is not None:
        caption_gear_frames(frames, trace)
    metrics = runner.record(trace, episode)
    names = tuple(o.name for o in runner.controller.options)
    gear_env = runner.env.unwrapped
    assert isinstance(gear_env, GearAssemblyEnv)
    schedule = gear_env.schedule
    human = {"events": list(schedule.events), "times": schedule.times.round(3).tolist(),
             "positions": schedule.positions.round(3).tolist()}
    return metrics, decision_rows(trace, names), human


def evaluation_episode(index: int, seed: int = 0) -> EpisodeSeed:
    """The seed of evaluation episode ``index`` of ``gear run`` / ``gear evaluate`` with
    ``--seed seed``."""
    if index < 0:
        raise DynoplanError(f"episode index must be >= 0, got {index}")
    return episode_seeds(seed + EVAL_SEED_OFFSET, index + 1)[index]


def decision_rows(trace: EpisodeTrace, option_names: tuple[str, ...]) -> list[dict[str, Any]]:
    """One row per decision of ``trace`` (recorded with ``record_infos``); see
    :func:`inspect_episode`."""
    rows = []
    for d in trace.decisions:
        infos = trace.infos[d.env_step:d.env_step + d.steps]
        gear, hand = d.state[STATE_SLICES["gear_pos"]], d.state[STATE_SLICES["human_pos"]]
        row: dict[str, Any] = {
            "decision": d.index, "time_s": round(d.env_step * CONTROL_DT, 2),
            "option": d.option or "hold", "stop_reason": d.stop_reason, "steps": d.steps,
            "admissible": "+".join(n for n, a in zip(option_names, d.plan.admissible,
                                                     strict=True) if a),
            "tool_hand_m": round(float(tool_human_distance(d.state[None])[0]), 4),
            "contacts": sum(int(i["human_contacts"]) for i in infos),
            "min_human_distance_m": round(min((float(i["min_human_distance"]) for i in infos),
                                              default=float("nan")), 4),
            "latency_ms": round(1e3 * d.latency_s, 3),
            **{f"gear_{a}": round(float(v), 4) for a, v in zip("xyz", gear, strict=True)},
            **{f"hand_{a}": round(float(v), 4) for a, v in zip("xyz", hand, strict=True)},
        }
        for name, score in zip(option_names, d.plan.scores, strict=True):
            row[f"score_{name}"] = "" if np.isnan(score) else round(float(score), 4)
        split = d.plan.disagreements
        for k, name in enumerate(option_names):
            value = np.nan if split is None else float(split[k])
            row[f"disagreement_{name}"] = "" if np.isnan(value) else round(value, 4)
        rows.append(row)
    return rows


def episode_summary(metrics: EpisodeRecord, controller: str, index: int, seed: int,
                    human: dict[str, Any]) -> dict[str, Any]:
    """What ``summary.json`` of ``dynoplan gear episode`` holds."""
    out = {"controller": controller, "index": index, "seed": seed, **asdict(metrics),
           "human": human}
    out["decision_ms"] = [round(v, 3) for v in metrics.decision_ms]
    return out


__all__ = ["TRACE_COLUMNS", "decision_rows", "episode_summary", "evaluation_episode",
           "inspect_episode"]
