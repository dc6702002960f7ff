"""User-written options and a scripted demonstrator for panda-gym's pick-and-place.

``PandaPickAndPlace-v3`` (the ``panda-gym`` package, PyBullet physics; install it with
``pip install "dynoplan[examples]"`` or ``pip install panda-gym``): a Franka Panda arm
must pick a 4 cm cube from a random place on the table and bring it within 5 cm of a
random target, on the table or in the air, in 50 steps. An action moves the gripper by
up to 5 cm per axis and opens or closes the fingers. The episode terminates on success
(``info["is_success"]``).

Its observation is a ``Dict`` (``observation``, ``achieved_goal``, ``desired_goal``),
which the pipeline does not take, so this module registers ``PandaPickAndPlaceFlat-v3``,
the same environment with the planner state as one vector of 7 values:

========  ===================================================
0:3       cube position minus gripper position (m)
3         finger opening (m)
4:7       target position minus cube position (m)
========  ===================================================

Why relative positions: the first version of this example used the absolute positions
(and the velocities and the cube's orientation). The goal heuristic learned from the
demonstrations then read "progress" from the gripper's height, which drops along every
demonstration, and rated the distractor ``sweep`` (which lowers the gripper to the
table) above ``reach``; DynoPlan reached 5% on 20 episodes (``results/try/``). Every
option here needs relative positions only.

Run it with::

    dynoplan pipeline --env PandaPickAndPlaceFlat-v3 \\
        --options examples.panda_pick.options:make_options --out results/panda-pick
"""

from typing import Any

import gymnasium as gym
import numpy as np

from dynoplan.adapters import OptionSpec, option_spec
from dynoplan.errors import DynoplanError
from dynoplan.pipeline import Demonstrator

ENV_ID = "PandaPickAndPlaceFlat-v3"
TO_CUBE = slice(0, 3)
FINGERS = 3
TO_TARGET = slice(4, 7)
GAIN = 10.0
"""Proportional gain from a position error (m) to an action (1 = 5 cm per step)."""
BETA = 0.1
"""Termination probability per step of the distractors."""
BETA_RUNNING = 0.02
"""Termination probability per step of the task's options before their job is done."""


class FlatPickAndPlace(gym.ObservationWrapper[Any, Any, Any]):
    """Cube minus gripper, finger opening, target minus cube: one ``float64`` Box of 7
    values (see the module docstring)."""

    def __init__(self, env: gym.Env[Any, Any]) -> None:
        super().__init__(env)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (7,), np.float64)

    def observation(self, observation: dict[str, np.ndarray]) -> np.ndarray:
        robot = observation["observation"]
        gripper, cube = robot[0:3], robot[7:10]
        return np.concatenate([cube - gripper, robot[6:7],
                               observation["desired_goal"] - cube]).astype(np.float64)


def make_env(**kwargs: Any) -> gym.Env[Any, Any]:
    """``PandaPickAndPlace-v3`` (without its own time limit) with :class:`FlatPickAndPlace`."""
    try:
        import panda_gym  # noqa: F401  (registers the Panda environments)
    except ImportError:
        raise DynoplanError("this example needs panda-gym: pip install panda-gym") from None
    return FlatPickAndPlace(gym.make("PandaPickAndPlace-v3", max_episode_steps=None,
                                     **kwargs).unwrapped)


if ENV_ID not in gym.registry:
    gym.register(ENV_ID, entry_point=make_env, max_episode_steps=50)


def _move(offset: np.ndarray, fingers: float) -> np.ndarray:
    """The action that moves the gripper by ``offset`` (m), as far as one step allows."""
    step = np.clip(GAIN * np.asarray(offset, dtype=np.float64), -1.0, 1.0)
    return np.array([*step, fingers], dtype=np.float32)


def reach(observation: Any) -> np.ndarray:
    """Open the fingers and go to the cube: above it first, then down onto it."""
    to_cube = np.asarray(observation[TO_CUBE])
    above = np.linalg.norm(to_cube[:2]) > 0.01
    return _move(to_cube + np.array([0.0, 0.0, 0.05 if above else 0.0]), 1.0)


def grasp(observation: Any) -> np.ndarray:
    """Close the fingers where the gripper is."""
    return _move(np.zeros(3), -1.0)


def carry(observation: Any) -> np.ndarray:
    """Keep the fingers closed and go to the target (the cube's offset to it, plus the
    gripper's to the cube)."""
    return _move(np.asarray(observation[TO_TARGET]) + np.asarray(observation[TO_CUBE]), -1.0)


def retreat(observation: Any) -> np.ndarray:
    """Open the fingers and go straight up."""
    return _move(np.array([0.0, 0.0, 0.1]), 1.0)


def sweep(observation: Any) -> np.ndarray:
    """Open the fingers and move sideways (+y)."""
    return _move(np.array([0.0, 0.05, 0.0]), 1.0)


def _distance(states: np.ndarray, part: slice) -> np.ndarray:
    return np.asarray(np.linalg.norm(states[:, part], axis=1))


def reached(states: np.ndarray) -> np.ndarray:
    """``reach``'s termination ``beta(s)``, states ``(batch, 7)``: 1 at the cube (within
    1 cm), else ``BETA_RUNNING``."""
    return np.where(_distance(states, TO_CUBE) < 0.01, 1.0, BETA_RUNNING)


def grasped(states: np.ndarray) -> np.ndarray:
    """``grasp``'s termination: 1 once the fingers hold the cube, else ``BETA_RUNNING``."""
    holds = (_distance(states, TO_CUBE) < 0.02) & (states[:, FINGERS] < 0.045)
    return np.where(holds, 1.0, BETA_RUNNING)


def delivered(states: np.ndarray) -> np.ndarray:
    """``carry``'s termination: 1 with the cube within 5 cm of the target, else
    ``BETA_RUNNING``."""
    return np.where(_distance(states, TO_TARGET) < 0.05, 1.0, BETA_RUNNING)


def make_options() -> list[OptionSpec]:
    """Five options: ``reach``, ``grasp`` and ``carry`` (the task's sequence), each
    stopping when its job is done (:func:`reached`, :func:`grasped`, :func:`delivered`),
    and two distractors the demonstrations never use, ``retreat`` and ``sweep``, which
    stop with probability ``BETA`` per step."""
    return [
        option_spec("reach", reach, termination=reached),
        option_spec("grasp", grasp, termination=grasped),
        option_spec("carry", carry, termination=delivered),
        option_spec("retreat", retreat, termination=BETA),
        option_spec("sweep", sweep, termination=BETA),
    ]


def holding(observation: Any) -> bool:
    """The cube is between the closed fingers."""
    return bool(grasped(np.asarray(observation, dtype=np.float64)[None])[0] == 1.0)


class PickAndPlaceScript(Demonstrator):
    """The expert: reach the cube, close the fingers on it, carry it to the target.

    It reaches until the gripper is within 1 cm of the cube, grasps until the fingers
    hold it, then carries; if the cube slips out, it starts again.
    """

    def choose(self, observation: Any) -> str:
        if holding(observation):
            return "carry"
        at_cube = bool(reached(np.asarray(observation, dtype=np.float64)[None])[0] == 1.0)
        return "grasp" if at_cube else "reach"


def make_demonstrator() -> Demonstrator:
    """The demonstrator the command line uses for ``--demos N``."""
    return PickAndPlaceScript()
