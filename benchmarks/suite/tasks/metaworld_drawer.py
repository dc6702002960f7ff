"""Meta-World ``drawer-open-v3``: a Sawyer arm opens a drawer by hooking its fingers
behind the handle and pulling, with options written on Meta-World's 39-value observation.

The task comes from Meta-World 3.1.1 (``pip install metaworld``, MuJoCo physics), made as
:mod:`benchmarks.suite.tasks.metaworld_pick_place` makes ``pick-place-v3``: the
``metaworld.MT1("drawer-open-v3")`` benchmark's environment and its 50 tasks (the
drawer's place along the table's edge), with
:class:`~benchmarks.suite.tasks.metaworld_pick_place.SeededTask` making ``reset(seed=s)``
reproducible (Meta-World ignores the seed of ``reset``; see that module). This module
registers ``MetaWorldDrawerOpen-v3``, 150 steps at most (Meta-World allows 500; its
scripted expert needs about 90, the demonstrator here about 62). An action moves the
hand by up to 1 cm per axis and sets the gripper's effort. Success is the environment's
``info["success"]`` (the handle within 3 cm of its open position, about 17 cm out): :func:`success`.

The planner state is the observation as it is (no ``state_fn``). The options read

========  =====================================================
0:3       hand position (m)
4:7       handle position (m)
36:39     the handle's position with the drawer open (the goal, m)
========  =====================================================

Options: ``hover`` (open the gripper, go 12 cm above the handle), ``descend`` (go down
until the fingers are around the handle), ``pull`` (pull the hand towards the robot at
the handle's height), each stopping when its job is done (else with probability 2% per
step), and two distractors the demonstrator never uses, ``push`` (push the drawer's
front away from the robot: it shuts the drawer) and ``retreat`` (rise to a fixed pose).
The demonstrator chains hover, descend, pull, starting again from ``hover`` if the hand
loses the handle. Disturbance: the hand is shoved 4-6 cm in a random horizontal
direction once, at a step drawn from 15-45.
"""

from typing import Any

import gymnasium as gym
import numpy as np

from benchmarks.suite.tasks.metaworld_pick_place import (
    OnceAtStep,
    done_when,
    make_metaworld_env,
)
from dynoplan.adapters import OptionSpec, option_spec
from dynoplan.pipeline import Demonstrator

TASK = "drawer-open-v3"
ENV_ID = "MetaWorldDrawerOpen-v3"
MAX_STEPS = 150

HAND = slice(0, 3)
HANDLE = slice(4, 7)
GOAL = slice(36, 39)

GAIN = 10.0
"""Proportional gain from a position error (m) to an action (1 = 1 cm per step)."""
OPEN = -1.0
HOVER_HEIGHT = 0.12
"""m: where ``hover`` goes above the handle."""
ABOVE = 0.02
"""m: horizontal distance from hand to handle under which the hand is above it."""
AROUND = 0.03
"""m: height of the hand above the handle under which the fingers are around it."""
HOOKED = 0.04
"""m: horizontal distance from hand to handle within which a pull keeps the handle."""
PULL = 0.10
"""m: how far ahead of the handle (towards the robot) ``pull`` aims."""
OPENED = 0.03
"""m: distance from handle to its open position at which ``pull`` is done."""
HOME = np.array([0.0, 0.6, 0.3])
"""Where ``retreat`` goes: above the hand's start."""


def make_env(**kwargs: Any) -> gym.Env[Any, Any]:
    """``drawer-open-v3`` with a reproducible seeded reset (``kwargs``: ``benchmark_seed``)."""
    return make_metaworld_env(TASK, **kwargs)


if ENV_ID not in gym.registry:
    gym.register(ENV_ID, entry_point=make_env, max_episode_steps=MAX_STEPS)


def success(observation: Any, info: dict[str, Any]) -> bool:
    """Meta-World's own success: ``info["success"]`` (a float, 1.0 on success)."""
    return bool(info.get("success", 0.0) >= 1.0)


state_fn = None


# --- the options -------------------------------------------------------------------------


def _move(observation: Any, target: np.ndarray, gain: float = GAIN) -> np.ndarray:
    """The action that moves the hand towards ``target`` (m), the gripper open."""
    step = np.clip(gain * (target - np.asarray(observation[HAND])), -1.0, 1.0)
    return np.array([*step, OPEN], dtype=np.float32)


def _handle(observation: Any, offset: tuple[float, float, float]) -> np.ndarray:
    """The handle's position plus ``offset`` (m)."""
    return np.asarray(observation[HANDLE]) + np.array(offset)


def hover(observation: Any) -> np.ndarray:
    """Open the gripper and go ``HOVER_HEIGHT`` above the handle."""
    return _move(observation, _handle(observation, (0.0, 0.0, HOVER_HEIGHT)))


def descend(observation: Any) -> np.ndarray:
    """Go down over the handle until the fingers are around it (aiming 2 cm below it:
    the fingers stop on the drawer)."""
    return _move(observation, _handle(observation, (0.0, 0.0, -0.02)))


def pull(observation: Any) -> np.ndarray:
    """Pull the hand towards the robot (-y) at the handle's height, ``PULL`` ahead."""
    return _move(observation, _handle(observation, (0.0, -PULL, -0.02)))


def push(observation: Any) -> np.ndarray:
    """Distractor: push the drawer's front away from the robot (+y) at the handle's
    height, aiming ``PULL`` behind the handle."""
    return _move(observation, _handle(observation, (0.0, PULL, 0.0)))


def retreat(observation: Any) -> np.ndarray:
    """Distractor: rise to ``HOME``."""
    return _move(observation, HOME)


def _horizontal(states: np.ndarray) -> np.ndarray:
    return np.asarray(np.linalg.norm(states[:, 0:2] - states[:, 4:6], axis=1))


def above(states: np.ndarray) -> np.ndarray:
    """The hand is above the handle (within ``ABOVE`` horizontally), states ``(B, 39)``."""
    return _horizontal(states) < ABOVE


def around(states: np.ndarray) -> np.ndarray:
    """The fingers are around the handle: the hand within ``HOOKED`` horizontally and
    less than ``AROUND`` above it."""
    return (_horizontal(states) < HOOKED) & (states[:, 2] - states[:, 6] < AROUND)


def opened(states: np.ndarray) -> np.ndarray:
    """The handle is within ``OPENED`` of its open position."""
    return np.asarray(np.linalg.norm(states[:, 4:7] - states[:, 36:39], axis=1) < OPENED)


def shut(states: np.ndarray) -> np.ndarray:
    """The drawer is shut: the handle more than 18 cm from its open position."""
    return np.asarray(np.linalg.norm(states[:, 4:7] - states[:, 36:39], axis=1) > 0.18)


def pushed_shut(states: np.ndarray) -> np.ndarray:
    """The drawer is :func:`shut` and the fingers :func:`around` the handle."""
    return shut(states) & around(states)


def at_home(states: np.ndarray) -> np.ndarray:
    """The hand is within 2 cm of ``HOME``."""
    return np.asarray(np.linalg.norm(states[:, 0:3] - HOME, axis=1) < 0.02)


def make_options() -> list[OptionSpec]:
    """Five options: ``hover``, ``descend`` and ``pull`` (the task's chain), done when
    the hand is :func:`above` the handle, the fingers are :func:`around` it, or the
    drawer is :func:`opened`; the distractors ``push``, done when the drawer is
    :func:`shut` and the hand at the handle, and ``retreat``, done :func:`at_home`."""
    return [
        option_spec("hover", hover, termination=done_when(above)),
        option_spec("descend", descend, termination=done_when(around)),
        option_spec("pull", pull, termination=done_when(opened)),
        option_spec("push", push, termination=done_when(pushed_shut)),
        option_spec("retreat", retreat, termination=done_when(at_home)),
    ]


class DrawerScript(Demonstrator):
    """The expert: pull while the fingers are around the handle; else descend if the
    hand is above the handle, and hover otherwise (so a lost handle is found again)."""

    def choose(self, observation: Any) -> str:
        s = np.asarray(observation, dtype=np.float64)[None]
        if around(s)[0]:
            return "pull"
        return "descend" if above(s)[0] else "hover"


def make_demonstrator() -> Demonstrator:
    """The demonstrator of this task."""
    return DrawerScript()


# --- the disturbance ---------------------------------------------------------------------

DISTURBANCE = ("the hand is shoved 4-6 cm in a random horizontal direction once, at a step "
               "drawn from 15-45")


class ShoveHand(OnceAtStep):
    """At one step drawn from ``steps``, move the hand's target (Meta-World drives the
    hand through a MuJoCo mocap body) by ``distance`` (m) in a random horizontal
    direction: the hand follows within a few steps. Seeded from the seed of ``reset``."""

    def __init__(self, env: gym.Env[Any, Any], steps: tuple[int, int] = (15, 45),
                 distance: tuple[float, float] = (0.04, 0.06)) -> None:
        super().__init__(env, steps, distance)

    def disturb(self) -> None:
        base: Any = self.env.unwrapped
        shoved = base.data.mocap_pos[0] + np.r_[self.horizontal(), 0.0]
        base.data.mocap_pos[0] = np.clip(shoved, base.mocap_low, base.mocap_high)


def disturb(env: gym.Env[Any, Any]) -> gym.Env[Any, Any]:
    """The task's disturbance: :class:`ShoveHand`."""
    return ShoveHand(env)
