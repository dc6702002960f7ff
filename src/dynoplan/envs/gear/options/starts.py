"""Seeded starting states of each gear option (its "own starting region").

An option's start sampler (:attr:`~dynoplan.envs.gear.options.registry.GearOption.start`)
drives an env just reset (with the human away) to where the option starts:

- :func:`at_reset` (``pick``): a fresh reset (random gear pose), the gripper open at the
  home pose;
- :func:`after_pick` (``fast_move`` and ``cautious_move``): the gear grasped and lifted,
  where the expert would start carrying it (:data:`CARRY_STEP`);
- :func:`before_insertion` (``insert``): the gear held at the pre-insertion offset above
  the peg, with the arm displaced by a random joint offset (a "noisy pre-insertion
  pose").

The scripted expert (with the human kept away) drives the robot to the start; then the
human's schedule is replaced by one of the requested mode (default: the option's
``human_mode``) whose first event begins within ``event_delay`` seconds, so that the
option meets the human while it runs.
"""

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from dynoplan.envs.gear.env import GRIPPER_CLOSED, GearAssemblyEnv
from dynoplan.envs.gear.expert import GearExpert
from dynoplan.envs.gear.human import HUMAN_MODES, HumanSchedule, sample_schedule
from dynoplan.errors import DynoplanError
from dynoplan.types import FloatArray, Generator

CARRY_STEP = "transport"
INSERT_STEP = "insert"
DATA_EPISODE_STEPS = 10_000
"""``max_episode_steps`` of the environments the option networks' training data is
generated in (the data's own episodes end far sooner)."""


@dataclass(frozen=True)
class StartConfig:
    """How start states are drawn."""

    insert_noise: float = 0.02  # rad, std of the left-arm joint offset before insert
    settle_steps: int = 10  # env steps holding the displaced pose
    event_delay: tuple[float, float] = (0.0, 1.0)  # s from the start to the first event
    max_expert_steps: int = 600
    attempts: int = 5


@dataclass
class OptionStart:
    """A reached start: the observation and info to hand to the option, the env seed it
    came from and the human mode of the installed schedule."""

    observation: FloatArray
    info: dict[str, Any]
    env_seed: int
    human_mode: str


def shifted_schedule(env: GearAssemblyEnv, mode: str, rng: Generator,
                     delay: tuple[float, float] = (0.0, 1.0)) -> HumanSchedule:
    """A schedule of ``mode`` drawn for the env's current gear and peg positions, whose
    first event starts ``U(delay)`` seconds from now (the hand rests until then)."""
    if mode not in HUMAN_MODES:
        raise DynoplanError(f"human mode must be one of {HUMAN_MODES}, got {mode!r}")
    gear, _ = env.gear_pose()
    tip, _ = env.peg_pose()
    base = sample_schedule(rng, gear[:2], tip, mode=mode)
    times = base.times.copy()
    now = env.time
    if mode == "away" or len(times) < 2:
        times = times + now
    else:  # keyframe 1 ends the initial rest: move it to now + delay
        shift = now + rng.uniform(*delay) - times[1]
        times = np.concatenate([[now], times[1:] + shift])
        times[0] = min(times[0], times[1])
    return HumanSchedule(times=times, positions=base.positions, shoulder=base.shoulder,
                         events=base.events)


def at_reset(env: GearAssemblyEnv, rng: Generator, config: StartConfig) -> bool:
    """Start where the env was reset: the gear on the table, the arm at home."""
    return True


def after_pick(env: GearAssemblyEnv, rng: Generator, config: StartConfig) -> bool:
    """Start with the gear grasped and lifted: the expert runs until it would start
    carrying it (:data:`CARRY_STEP`)."""
    return _run_expert_until(env, CARRY_STEP, config.max_expert_steps) is not None


def before_insertion(env: GearAssemblyEnv, rng: Generator, config: StartConfig) -> bool:
    """Start at a noisy pre-insertion pose: the expert runs until it would insert
    (:data:`INSERT_STEP`), then the left arm is held at a random joint offset
    (``config.insert_noise``) for ``config.settle_steps`` steps with the gear held."""
    if _run_expert_until(env, INSERT_STEP, config.max_expert_steps) is None:
        return False
    return displace(env, rng, config) is not None


StartSampler = Callable[[GearAssemblyEnv, Generator, StartConfig], bool]
"""An option's start sampler: drives an env just reset to a start of the option (False:
this attempt did not reach one)."""


def drive_to_start(env: GearAssemblyEnv, start: StartSampler, rng: Generator, mode: str,
                   start_sets_human: bool = False, config: StartConfig | None = None,
                   option: str = "the option") -> OptionStart:
    """Reset ``env`` and drive it to a start state with the sampler ``start``, then
    install a schedule of the human mode ``mode`` unless ``start_sets_human`` (the sampler installs
    its own); all randomness from ``rng``. The registered options' starts by name:
    :func:`~dynoplan.envs.gear.options.catalog.reach_start`. Raises
    :class:`DynoplanError` if no attempt reaches it."""
    cfg = config or StartConfig()
    if mode not in HUMAN_MODES:
        raise DynoplanError(f"human mode must be one of {HUMAN_MODES}, got {mode!r}")
    for _ in range(cfg.attempts):
        seed = int(rng.integers(2**31 - 1))
        env.reset(seed=seed, options={"human_mode": "away"})
        if not start(env, rng, cfg):
            continue
        schedule = (env.schedule if start_sets_human
                    else shifted_schedule(env, mode, rng, cfg.event_delay))
        obs, info = env.set_human_schedule(schedule)
        return OptionStart(observation=obs, info=info, env_seed=seed, human_mode=schedule.mode)
    raise DynoplanError(f"could not reach a start state of {option!r} in {cfg.attempts} "
                        "attempts")


def _run_expert_until(env: GearAssemblyEnv, step: str,
                      max_steps: int) -> tuple[FloatArray, dict[str, Any]] | None:
    """Run the expert until it is about to take its first action of ``step``."""
    expert = GearExpert(env)
    obs, info = env.set_human_schedule(env.schedule)
    for _ in range(max_steps):
        decision = expert.act(obs, info)
        if decision.step == step:
            return obs, info
        if decision.step in ("failed", "done"):
            return None
        obs, _, terminated, truncated, info = env.step(decision.action)
        if terminated or truncated:
            return None
    return None


def displace(env: GearAssemblyEnv, rng: Generator,
             cfg: StartConfig) -> tuple[FloatArray, dict[str, Any]] | None:
    """Hold the left arm at a random joint offset for a few steps; ``None`` if the gear
    is no longer held."""
    q = env.arm_qpos
    q[:6] += rng.normal(0.0, cfg.insert_noise, size=6)
    lim = env.joint_limits
    q = np.clip(q, lim[:, 0], lim[:, 1])
    action = np.concatenate([q, [GRIPPER_CLOSED]])
    obs, info = env.set_human_schedule(env.schedule)
    for _ in range(cfg.settle_steps):
        obs, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            return None
    if int(info["pads_on_gear"]) < 2:
        return None
    return obs, info


__all__ = ["CARRY_STEP", "DATA_EPISODE_STEPS", "INSERT_STEP", "OptionStart", "StartConfig",
           "StartSampler", "after_pick", "at_reset", "before_insertion", "displace",
           "drive_to_start", "shifted_schedule"]
