"""Seeded trials of one gear option from its own starting region: ``summary.json``
(success, robot-human contacts and distance, planning time) and an optional video.

Per trial ``i`` of seed ``S``: ``rng = default_rng([S, i])``; the env is driven to a start
of the option (:func:`~dynoplan.envs.gear.options.starts.reach_start`), the policy is
reset there and acts until it reports that it is finished or ``max_steps`` env steps
pass; then the policy judges its own success from the simulator (``succeeded(info)``).
"""

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from dynoplan.envs.gear.env import CONTROL_DT, GearAssemblyEnv
from dynoplan.envs.gear.human import HUMAN_MODES
from dynoplan.envs.gear.options.base import GearOptionPolicy, GearPolicyFactory
from dynoplan.envs.gear.options.catalog import gear_option
from dynoplan.envs.gear.options.starts import reach_start
from dynoplan.errors import DynoplanError
from dynoplan.io import ensure_writable_dir, write_json
from dynoplan.pipeline.evaluate import quantile_or_none
from dynoplan.progress import track
from dynoplan.reports.video import write_mp4


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
    """Run trial ``index`` of ``option`` (see the module docstring)."""
    rng = np.random.default_rng([seed, index])
    start = reach_start(env, option, rng, human_mode=human_mode)
    obs, info = start.observation, start.info
    policy.reset(obs, rng)
    contacts = collisions = steps = 0
    min_distance = float(info["min_human_distance"])
    if frames is not None:
        frames.append(_frame(env))
    while steps < max_steps:
        obs, _, terminated, truncated, info = env.step(policy.act(obs))
        steps += 1
        contacts += int(info["human_contacts"])
        collisions += int(info["robot_collisions"] > 0)
        min_distance = min(min_distance, float(info["min_human_distance"]))
        if frames is not None:
            frames.append(_frame(env))
        if policy.finished() or terminated or truncated:
            break
    return TrialResult(index=index, env_seed=start.env_seed, human_mode=start.human_mode,
                       success=bool(policy.succeeded(info)), status=policy.status,
                       steps=steps, human_contacts=contacts, min_human_distance=min_distance,
                       robot_collision_steps=collisions, plan_ms=tuple(policy.plan_ms))


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
        "contacts": int(sum(r.human_contacts for r in results)),
        "contacts_unit": "physics steps (2 ms) with a robot-human contact, summed",
        "trials_with_contact": int(sum(r.human_contacts > 0 for r in results)),
        "min_human_distance": float(min(r.min_human_distance for r in results)),
        "min_human_distance_median": float(np.median([r.min_human_distance for r in results])),
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
    ``video``, ``out/{option}.mp4`` of trial 0. Returns the summary; ``option`` must be
    registered (:mod:`~dynoplan.envs.gear.options.catalog`)."""
    gear_option(option)
    if trials < 1:
        raise DynoplanError(f"--trials must be >= 1, got {trials}")
    if max_steps < 1:
        raise DynoplanError(f"--max-steps must be >= 1, got {max_steps}")
    if human_mode is not None and human_mode not in HUMAN_MODES:
        raise DynoplanError(f"--human must be one of {', '.join(HUMAN_MODES)}, "
                            f"got {human_mode!r}")
    folder = ensure_writable_dir(out)
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
    if video:
        summary["video"] = str(write_mp4(folder / f"{option}.mp4", frames,
                                         fps=int(env.metadata["render_fps"])))
    write_json(folder / "summary.json", summary)
    return summary


def _frame(env: GearAssemblyEnv) -> npt.NDArray[np.uint8]:
    frame = env.render()
    if frame is None:
        raise RuntimeError("the env was not made with render_mode='rgb_array'")
    return frame


__all__ = ["GearPolicyFactory", "TrialResult", "run_option_trials", "run_trial",
           "summarise_trials"]
