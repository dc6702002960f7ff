"""User-written options and a scripted demonstrator for a pendulum swing-up *and* balance.

Gymnasium's ``Pendulum-v1`` never terminates: it only has a reward and a 200-step time
limit. Its motor (2 N m) is too weak to lift the pendulum straight up, so reaching the
top needs a **swing-up** controller that pumps energy, and staying there needs a
**balance** controller; neither alone does the task. This module registers
``PendulumSwingUp-v0``: ``Pendulum-v1`` with a definition of success (upright,
``|angle| < 0.15`` rad and ``|angular velocity| < 1`` rad/s, for 25 consecutive steps),
after which the episode terminates with ``info["is_success"] = True``; 300 steps at
most. The observation stays ``[cos(angle), sin(angle), angular velocity]``, angle 0 up.

Run it with::

    dynoplan pipeline --env PendulumSwingUp-v0 \\
        --options examples.pendulum.options:make_options --out results/pendulum
"""

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.envs.classic_control.pendulum import PendulumEnv

from dynoplan.adapters import OptionSpec, option_spec
from dynoplan.pipeline import Demonstrator

ENV_ID = "PendulumSwingUp-v0"
MAX_TORQUE = 2.0
UPRIGHT_ANGLE = 0.15
"""rad: |angle| below this counts as upright."""
UPRIGHT_SPEED = 1.0
"""rad/s: |angular velocity| below this counts as held still."""
HOLD_STEPS = 25
"""Consecutive upright steps that make a success (1.25 s at Pendulum's 20 Hz)."""
BETA = 0.05
"""Termination probability per step of every option."""


class HoldUpright(gym.Wrapper[Any, Any, Any, Any]):
    """Success = the pendulum held :func:`upright` for ``HOLD_STEPS`` consecutive steps.

    Terminates the episode then, with ``info["is_success"] = True``; every other step
    reports ``info["is_success"] = False``.
    """

    def __init__(self, env: gym.Env[Any, Any]) -> None:
        super().__init__(env)
        self.held = 0

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        self.held = 0
        return self.env.reset(**kwargs)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.held = self.held + 1 if upright(obs, info) else 0
        success = self.held >= HOLD_STEPS
        return obs, float(reward), bool(terminated) or success, truncated, {
            **info, "is_success": success}


def make_env(**kwargs: Any) -> gym.Env[Any, Any]:
    """``Pendulum-v1`` (without its 200-step limit) with :class:`HoldUpright`."""
    return HoldUpright(PendulumEnv(**kwargs))


if ENV_ID not in gym.registry:
    gym.register(ENV_ID, entry_point=make_env, max_episode_steps=300)


# --8<-- [start:upright]
def upright(observation: Any, info: dict[str, Any]) -> bool:
    """Success of plain ``Pendulum-v1`` on the command line (``--success
    examples.pendulum.options:upright``): the rod is upright and nearly still,
    ``|angle| < UPRIGHT_ANGLE`` and ``|angular velocity| < UPRIGHT_SPEED``. The pipeline
    ends the episode there, so no wrapper or registered id is needed."""
    return abs(_angle(observation)) < UPRIGHT_ANGLE and abs(float(observation[2])) < UPRIGHT_SPEED
# --8<-- [end:upright]


def _angle(observation: Any) -> float:
    return float(np.arctan2(observation[1], observation[0]))


def _energy(observation: Any) -> float:
    """Mechanical energy of Pendulum's rod (m = l = 1, g = 10): 0 at rest at the top."""
    return float(observation[2]) ** 2 / 6.0 + 5.0 * (float(observation[0]) - 1.0)


def swing_up(observation: Any) -> np.ndarray:
    """Pump energy: full torque along the angular velocity while the energy is below
    the top's, none once it is there (the pendulum coasts up)."""
    if _energy(observation) >= 0.0:
        return np.zeros(1, dtype=np.float32)
    direction = 1.0 if float(observation[2]) >= 0.0 else -1.0
    return np.array([MAX_TORQUE * direction], dtype=np.float32)


def balance(observation: Any) -> np.ndarray:
    """PD control about the top (saturated at the motor's limit)."""
    torque = -(10.0 * _angle(observation) + 2.0 * float(observation[2]))
    return np.array([np.clip(torque, -MAX_TORQUE, MAX_TORQUE)], dtype=np.float32)


def coast(observation: Any) -> np.ndarray:
    """No torque."""
    return np.zeros(1, dtype=np.float32)


def push(observation: Any) -> np.ndarray:
    """Full torque one way (counter-clockwise), whatever the state."""
    return np.array([MAX_TORQUE], dtype=np.float32)


def make_options() -> list[OptionSpec]:
    """Four options: ``swing_up`` and ``balance`` (the two the task needs, in that
    order), and two distractors the demonstrations never use: ``coast`` and ``push``.
    Each stops with probability ``BETA`` per step."""
    return [
        option_spec("swing_up", swing_up, termination=BETA),
        option_spec("balance", balance, termination=BETA),
        option_spec("coast", coast, termination=BETA),
        option_spec("push", push, termination=BETA),
    ]


class SwingThenBalance(Demonstrator):
    """The expert: swing up until the pendulum is near the top and slow enough to catch
    (``|angle| < 0.6`` rad, ``|angular velocity| < 3`` rad/s), then balance."""

    def choose(self, observation: Any) -> str:
        near = abs(_angle(observation)) < 0.6 and abs(float(observation[2])) < 3.0
        return "balance" if near else "swing_up"


def make_demonstrator() -> Demonstrator:
    """The demonstrator the command line uses for ``--demos N``."""
    return SwingThenBalance()
