"""Seeded trials of one gear option from its own starting region: ``summary.json``
(success, robot-human contacts and distance, planning time) and an optional video.

Per trial ``i`` of seed ``S``: ``rng = default_rng([S, i])``; the env is driven to a start
of the option (:func:`~dynoplan.envs.gear.options.catalog.reach_start`), the policy is
reset there and acts until it reports that it is finished or ``max_steps`` env steps
pass; then the policy judges its own success from the simulator (``succeeded(info)``).
"""

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
import numpy.typing as npt
from gymnasium.wrappers import RenderCollection

from dynoplan.adapters.spec import OptionSpec
from dynoplan.envs.gear.env import CONTROL_DT, GearAssemblyEnv
from dynoplan.envs.gear.human import HUMAN_MODES
from dynoplan.envs.gear.metrics import contact_summary
from dynoplan.envs.gear.options.base import GearOptionPolicy, GearPolicyFactory
from dynoplan.envs.gear.options.catalog import gear_option, reach_start
from dynoplan.errors import DynoplanError
from dynoplan.io import check_writable, staged_folder, write_json
from dynoplan.options.termination import ConstantTermination
from dynoplan.pipeline.collect import OptionRun, RunStart, record_episode
from dynoplan.pipeline.evaluate import quantile_or_none
from dynoplan.progress import track
from dynoplan.reports.video import write_mp4

TRIAL_INFO_KEYS = ("human_contacts", "robot_collisions", "min_human_distance")
"""What a trial records of every step."""


@dataclass(frozen=True)
class TrialResult:
    """One trial: outcome, safety and timing."""

    index: int
    env_seed: int
    human_mode: str
    success: bool
    status: str
    steps: int
    human_contacts: int
    min_human_distance: float
    robot_collision_steps: int
    plan_ms: tuple[float, ...]


def run_trial(env: GearAssemblyEnv, policy: GearOptionPolicy, option: str, index: int,
              seed: int, human_mode: str | None, max_steps: int,
              frames: list[npt.NDArray[np.uint8]] | None = None) -> TrialResult:
    """Run trial ``index`` of ``option`` (see the module docstring), recorded by the
    pipeline's recorder as an option run
    (:func:`~dynoplan.pipeline.collect.record_episode`,
    :class:`~dynoplan.pipeline.collect.OptionRun`); with ``frames``, the start's frame
    and one after every step are appended."""
    rng = np.random.default_rng([seed, index])
    start = reach_start(env, option, rng, human_mode=human_mode)
    spec = OptionSpec(option, policy, ConstantTermination(0.0))
    rendered = None if frames is None else RenderCollection(env)
    if frames is not None:
        frames.append(_frame(env))
    recording = record_episode(env if rendered is None else rendered, [spec], OptionRun(spec),
                               None, rng, max_steps,
                               start=RunStart(start.observation, start.info, start.env_seed),
                               info_keys=TRIAL_INFO_KEYS)
    if frames is not None and rendered is not None:
        frames += [cast(npt.NDArray[np.uint8], f) for f in rendered.render()]
    infos = recording.episode.infos
    return TrialResult(
        index=index, env_seed=start.env_seed, human_mode=start.human_mode,
        success=bool(policy.succeeded(recording.info)), status=policy.status,
        steps=len(recording.episode), human_contacts=int(infos["human_contacts"].sum()),
        min_human_distance=min(float(start.info["min_human_distance"]),
                               float(infos["min_human_distance"].min())),
        robot_collision_steps=int((infos["robot_collisions"] > 0).sum()),
        plan_ms=tuple(policy.plan_ms))


def summarise_trials(option: str, results: list[TrialResult], seed: int,
                     wall_seconds: float, extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """The ``summary.json`` content of ``results``."""
    plan_ms = [ms for r in results for ms in r.plan_ms]
    success = [r.success for r in results]
    steps = [r.steps for r in results if r.success]
    return {
        "option": option,
        "trials": len(results),
        "seed": seed,
        "human_modes": sorted({r.human_mode for r in results}),
        "success_rate": float(np.mean(success)) if results else 0.0,
        "successes": int(np.sum(success)),
        "failed_trials": [r.index for r in results if not r.success],
        **contact_summary([r.human_contacts for r in results],
                          [r.min_human_distance for r in results], "trials"),
        "robot_collision_steps": int(sum(r.robot_collision_steps for r in results)),
        "plans": len(plan_ms),
        "plan_ms_p50": quantile_or_none(plan_ms, 0.5),
        "plan_ms_p90": quantile_or_none(plan_ms, 0.9),
        "seconds_to_success_median": (float(np.median(steps) * CONTROL_DT) if steps else None),
        "statuses": {s: sum(r.status == s for r in results)
                     for s in sorted({r.status for r in results})},
        "wall_seconds": wall_seconds,
        **(extra or {}),
    }


def run_option_trials(option: str, factory: GearPolicyFactory, trials: int, seed: int, out: Path,
                      human_mode: str | None = None, max_steps: int = 600,
                      video: bool = False, progress: bool = True,
                      extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """Run ``trials`` seeded trials of ``option``; write ``out/summary.json`` and, with
    ``video``, ``out/{option}.mp4`` of trial 0, staged (:func:`~dynoplan.io.staged_folder`:
    both or neither; ``out`` is checked writable before the trials). Returns the summary;
    ``option`` must be registered (:mod:`~dynoplan.envs.gear.options.catalog`)."""
    gear_option(option)
    if trials < 1:
        raise DynoplanError(f"--trials must be >= 1, got {trials}")
    if max_steps < 1:
        raise DynoplanError(f"--max-steps must be >= 1, got {max_steps}")
    if human_mode is not None and human_mode not in HUMAN_MODES:
        raise DynoplanError(f"--human must be one of {', '.join(HUMAN_MODES)}, "
                            f"got {human_mode!r}")
    check_writable(out)  # before the trials
    env = GearAssemblyEnv(render_mode="rgb_array" if video else None)
    frames: list[npt.NDArray[np.uint8]] = []
    t0 = time.perf_counter()
    try:
        policy = factory(env)
        results = [run_trial(env, policy, option, i, seed, human_mode, max_steps,
                             frames if (video and i == 0) else None)
                   for i in track(range(trials), f"{option} trials", total=trials,
                                  enabled=progress)]
    finally:
        env.close()
    summary = summarise_trials(option, results, seed, time.perf_counter() - t0, extra)
    with staged_folder(out) as folder:  # out's files replaced together, or none
        if video:
            written = write_mp4(folder / f"{option}.mp4", frames,
                                fps=int(env.metadata["render_fps"]))
            summary["video"] = str(out / written.name)
        write_json(folder / "summary.json", summary)
    return summary


def _frame(env: GearAssemblyEnv) -> npt.NDArray[np.uint8]:
    frame = env.render()
    if frame is None:
        raise RuntimeError("the env was not made with render_mode='rgb_array'")
    return frame


__all__ = ["GearPolicyFactory", "TrialResult", "run_option_trials", "run_trial",
           "summarise_trials"]
