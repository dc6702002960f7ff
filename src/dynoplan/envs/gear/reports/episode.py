"""One evaluation episode of one controller, replayed: decision by decision (``dynoplan gear
episode``) or rendered (the video of ``gear run`` and ``gear episode --video``).

The evaluation (``dynoplan gear run`` / ``gear evaluate``) reports per-episode metrics in
``episodes.json``; this module replays one of those episodes (the same
:class:`~dynoplan.seeding.EpisodeSeed`, hence the same gear pose, human
schedule and, for the same models, the same decisions) and keeps its trace: per decision,
the option chosen (or a hold), why it stopped, which options were admissible and how the
planner scored them, where the tool, the gear and the human's hand were, and the
robot-human contacts and distance while it ran.
"""

from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np

from dynoplan.control.controller import EpisodeTrace
from dynoplan.envs.gear.controllers import GEAR_CONTROL, VARIANTS
from dynoplan.envs.gear.env import CONTROL_DT, GearAssemblyEnv
from dynoplan.envs.gear.evaluation import evaluation_seeds
from dynoplan.envs.gear.metrics import human_mode
from dynoplan.envs.gear.pipeline_task import GearTask
from dynoplan.envs.gear.state import STATE_SLICES, tool_human_distance
from dynoplan.errors import DynoplanError
from dynoplan.io import write_with
from dynoplan.pipeline.control_settings import ControllerSettings
from dynoplan.pipeline.evaluate import ControllerRunner, EpisodeRecord
from dynoplan.reports.video import video_clip
from dynoplan.seeding import EpisodeSeed

TRACE_COLUMNS = (
    "decision", "time_s", "option", "stop_reason", "steps", "admissible", "tool_hand_m",
    "contacts", "min_human_distance_m", "latency_ms", "gear_x", "gear_y", "gear_z",
    "hand_x", "hand_y", "hand_z",
)
"""Columns of ``trace.csv`` before the per-option ``score_<option>`` and
``disagreement_<option>`` columns."""


def inspect_episode(models: Path, controller: str, index: int, seed: int = 0,
                    planner: ControllerSettings = GEAR_CONTROL, frames: list[Any] | None = None,
                    task: GearTask = GearTask()
                    ) -> tuple[EpisodeRecord, list[dict[str, Any]], dict[str, Any]]:
    """Replay evaluation episode ``index`` (0-based, as in ``episodes.json``) of
    ``controller`` on the models in ``models``; with ``frames``, render it offscreen and
    append one frame per step (for :func:`~dynoplan.reports.video.video_clip`). ``task``:
    the gear as the evaluation saw it (its human behaviours and runtime monitor; the
    ``render`` flag is set from ``frames``).

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
    runner, trace = replay(models, controller, episode, planner, frames, task)
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
    return evaluation_seeds(seed, index + 1)[index]


def replay(models: Path, controller: str, episode: EpisodeSeed, planner: ControllerSettings,
           frames: list[Any] | None = None, task: GearTask = GearTask()
           ) -> tuple[ControllerRunner, EpisodeTrace]:
    """Controller ``controller``'s episode ``episode`` on the models in ``models``, built
    and run as the evaluation builds and runs it on ``task``
    (:meth:`~dynoplan.envs.gear.pipeline_task.GearTask.make_runner`): the runner (its env
    closed) and the trace. With ``frames``, rendered offscreen, one captioned frame per
    step (:func:`caption_gear_frames`)."""
    task = replace(task, render=frames is not None)
    runner = task.make_runner(controller, models, planner)
    assert isinstance(runner, ControllerRunner)
    try:
        trace = runner.run(episode, frames)
    finally:
        runner.env.close()
    if frames is not None:
        caption_gear_frames(frames, trace)
    return runner, trace


def render_video(models: Path, episode: EpisodeSeed, planner: ControllerSettings,
                 controller: str = "dynoplan") -> dict[str, Any]:
    """:func:`~dynoplan.reports.video.video_clip` of :func:`replay` rendered. Writes
    nothing but a temporary file, so it can run as a task on any worker."""
    frames: list[Any] = []
    _, trace = replay(models, controller, episode, planner, frames)
    return video_clip(frames, trace.success,
                      [d.option for d in trace.decisions if d.option is not None])


def caption_gear_frames(frames: list[Any], trace: EpisodeTrace) -> None:
    """Draw the decision on every frame of a gear episode, in place
    (:func:`~dynoplan.reports.video.caption_frames`): the running option, every option's
    score at the last decision and the robot's distance to the human's hand."""
    from dynoplan.reports.video import caption_frames

    caption_frames(frames, trace, CONTROL_DT, "min_human_distance", "robot-hand distance")


def save_video(video: dict[str, Any], evaluated: EpisodeRecord, index: int,
               path: Path) -> dict[str, Any]:
    """Write :func:`~dynoplan.reports.video.video_clip`'s file to ``path``; its entry of
    ``summary.json``."""
    def write(tmp: Path) -> None:
        tmp.write_bytes(video["mp4"])

    write_with(path, write)
    return {"file": path.name, "episode": index, "human_mode": human_mode(evaluated),
            "success": video["success"], "options": video["options"]}


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


__all__ = ["TRACE_COLUMNS", "caption_gear_frames", "decision_rows", "episode_summary",
           "evaluation_episode", "inspect_episode", "render_video", "replay", "save_video"]
