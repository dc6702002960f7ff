"""Move Gymnasium's cart-pole to a mark one metre to the right and hold it there, balanced.

The environment is Gymnasium's classic-control ``CartPole`` (the dynamics of
``CartPole-v1``: two discrete actions, push the cart left or right with 10 N, 50 Hz; the
episode ends when the pole leans more than 12 degrees or the cart leaves ``|x| < 2.4``).
The observation is ``[x, x velocity, pole angle, pole angular velocity]`` (angle 0
upright, positive leaning right); episodes start near rest at ``x`` within 0.05 of 0.

The task, registered here as ``CartPoleMove-v0`` (250 steps at most): bring the cart to
``x = TARGET = 1.0`` and keep it within ``TOLERANCE = 0.1`` of it, pole up, for
``HOLD_STEPS = 30`` consecutive steps; the episode then terminates with
``info["is_success"] = True`` (a fallen pole or a cart off the track terminates it with
``is_success = False``).

Options (plain functions of the observation; each is a bang-bang version of one
linear balance controller, ``push right if K . (state - set point) > 0`` with LQR gains,
with a different set point):

- ``balance``: balance in place; the set point is the cart at rest where it is (no
  position feedback). Done when the cart is still and the pole upright.
- ``move_right``: balance while the set point moves right at ``CRUISE = 0.6`` m/s, so
  that the cart follows it (it crosses the 0.2 m wide mark in about 17 steps, too few to
  count). Stops with probability ``BETA`` per step.
- ``move_left``: the same to the left.
- ``push_right``: the distractor; always push right (the pole falls over).

The demonstrator (:class:`MoveThenHold`): ``move_right`` until the cart would stop
past the mark if it braked now (``x + STOP_TIME * v > TARGET``, ``v`` a running mean
of the cart's speed), then ``balance``; when the cart has stopped more than ``NUDGE``
short of (beyond) the mark, it moves right (left) again in the same way.

Disturbance (:func:`disturb`): a push on the pole; once per episode, at a random step
between 20 and 120, the pole's angular velocity changes by 0.5-1.0 rad/s either way.
"""

from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium.envs.classic_control.cartpole import CartPoleEnv

from dynoplan.adapters import OptionSpec, option_spec
from dynoplan.pipeline import Demonstrator

ENV_ID = "CartPoleMove-v0"
MAX_STEPS = 250
X, V, THETA, OMEGA = range(4)

TARGET = 1.0
"""Where the cart must stop (m)."""
TOLERANCE = 0.1
HOLD_STEPS = 30
"""Consecutive steps within ``TOLERANCE`` of ``TARGET`` that make a success (0.6 s)."""

GAINS = np.array([16.3, 92.5, 24.0])
"""State-feedback gains on ``[v - v_set, angle, angular velocity]``: push right when
the weighted sum is positive. They are the LQR gains of the linearised cart-pole
(``Q = diag(10, 10, 10, 1)`` on ``[x, v, angle, angular velocity]``, ``R = 0.1``)
without the position term."""
CRUISE = 0.6
"""Speed of the set point of ``move_right``/``move_left`` (m/s)."""
BETA = 0.05
"""Termination probability per step of the move options and the distractor."""
STOP_TIME = 0.55
"""``balance`` stops a cart moving at ``v`` within about ``STOP_TIME * v`` metres
(0.3 m from ``CRUISE``)."""
SMOOTHING = 0.2
"""Weight of the newest speed in the demonstrator's running mean of the cart's speed
(the bang-bang control makes the speed jump by 0.18 m/s at every push)."""
NUDGE = 0.05
"""Distance (m) from the mark beyond which the demonstrator moves the cart again."""


class HoldAtTarget(gym.Wrapper[Any, Any, Any, Any]):
    """Success = the cart within ``TOLERANCE`` of ``TARGET`` (pole up: the environment
    has not terminated) for ``HOLD_STEPS`` consecutive steps; terminates then, with
    ``info["is_success"] = True``. Every other step reports ``False``."""

    def __init__(self, env: gym.Env[Any, Any]) -> None:
        super().__init__(env)
        self.held = 0

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        self.held = 0
        return self.env.reset(**kwargs)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        at_mark = not terminated and abs(float(obs[X]) - TARGET) < TOLERANCE
        self.held = self.held + 1 if at_mark else 0
        success = self.held >= HOLD_STEPS
        return obs, float(reward), bool(terminated) or success, truncated, {
            **info, "is_success": success}


def make_env(**kwargs: Any) -> gym.Env[Any, Any]:
    """``CartPoleEnv`` (no time limit of its own) with :class:`HoldAtTarget`."""
    return HoldAtTarget(CartPoleEnv(**kwargs))


if ENV_ID not in gym.registry:
    gym.register(ENV_ID, entry_point=make_env, max_episode_steps=MAX_STEPS)

success = None
"""The environment reports ``info["is_success"]`` itself (:class:`HoldAtTarget`)."""
state_fn = None
"""The 4-value ``Box`` observation is the state."""


# --- options -----------------------------------------------------------------------------


def balance_at(observation: Any, v_set: float) -> np.int64:
    """Push right (1) when ``GAINS . (state - set point) > 0``, else left (0); the set
    point is the cart moving at ``v_set``, pole upright and still."""
    o = np.asarray(observation, dtype=np.float64)
    error = np.array([o[V] - v_set, o[THETA], o[OMEGA]])
    return np.int64(1 if float(GAINS @ error) > 0.0 else 0)


def balance(observation: Any) -> np.int64:
    """Keep the pole up and the cart still, wherever it is."""
    return balance_at(observation, 0.0)


def move_right(observation: Any) -> np.int64:
    """Keep the pole up while the cart travels right at ``CRUISE``."""
    return balance_at(observation, CRUISE)


def move_left(observation: Any) -> np.int64:
    """Keep the pole up while the cart travels left at ``CRUISE``."""
    return balance_at(observation, -CRUISE)


def push_right(observation: Any) -> np.int64:
    """Always push right (a distractor)."""
    return np.int64(1)


def settled(states: np.ndarray) -> np.ndarray:
    """Cart still and pole upright and still (up to the chatter of the bang-bang
    control: one push changes the cart's speed by 0.18 m/s, the pole's by 0.29 rad/s)."""
    return np.asarray((np.abs(states[:, V]) < 0.1) & (np.abs(states[:, THETA]) < 0.03)
                      & (np.abs(states[:, OMEGA]) < 0.3))


def make_options() -> list[OptionSpec]:
    """``balance`` (done when settled), ``move_right``, ``move_left`` and the distractor
    ``push_right`` (each stopping with probability ``BETA`` per step)."""
    return [
        option_spec("balance", balance, termination=settled),
        option_spec("move_right", move_right, termination=BETA),
        option_spec("move_left", move_left, termination=BETA),
        option_spec("push_right", push_right, termination=BETA),
    ]


class MoveThenHold(Demonstrator):
    """Move right, brake by balancing in place, nudge until at the mark (see the module
    docstring)."""

    def reset(self, observation: Any, rng: np.random.Generator) -> None:
        self.current = "move_right"
        self.speed = float(np.asarray(observation)[V])

    def choose(self, observation: Any) -> str:
        o = np.asarray(observation, dtype=np.float64)
        self.speed += SMOOTHING * (float(o[V]) - self.speed)
        offset = float(o[X]) - TARGET
        stop = offset + STOP_TIME * self.speed
        heading = {"move_right": 1.0, "move_left": -1.0}.get(self.current, 0.0)
        if heading * stop > 0.0:
            self.current = "balance"
        elif self.current == "balance" and bool(settled(o[None])[0]):
            if offset < -NUDGE:
                self.current = "move_right"
            elif offset > NUDGE:
                self.current = "move_left"
        return self.current


def make_demonstrator() -> Demonstrator:
    """The demonstrator the command line uses for ``--demos N``."""
    return MoveThenHold()


# --- disturbance -------------------------------------------------------------------------

DISTURBANCE = ("a push on the pole: once per episode, at a random step in [20, 120], its "
               "angular velocity changes by 0.5-1.0 rad/s either way")


class PolePush(gym.Wrapper[Any, Any, Any, Any]):
    """One push on the pole per episode, drawn from the seed of ``reset``."""

    def __init__(self, env: gym.Env[Any, Any]) -> None:
        super().__init__(env)
        self.rng = np.random.default_rng()
        self.t = 0
        self.at = 0
        self.kick = 0.0

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        seed = kwargs.get("seed")
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        self.t = 0
        self.at = int(self.rng.integers(20, 121))
        side = 1.0 if self.rng.random() < 0.5 else -1.0
        self.kick = side * float(self.rng.uniform(0.5, 1.0))
        return self.env.reset(**kwargs)

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        if self.t == self.at:
            cartpole = self.env.unwrapped
            state = np.array(cartpole.state, dtype=np.float64)  # type: ignore[attr-defined]
            state[OMEGA] += self.kick
            cartpole.state = state  # type: ignore[attr-defined]
        self.t += 1
        return self.env.step(action)


def disturb(env: gym.Env[Any, Any]) -> gym.Env[Any, Any]:
    """The task's environment with :class:`PolePush`."""
    return PolePush(env)
