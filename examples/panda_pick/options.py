"""User-written options and a scripted demonstrator for panda-gym's pick-and-place.

``PandaPickAndPlace-v3`` (the ``panda-gym`` package, PyBullet physics; install it with
``pip install "dynoplan[examples]"`` or ``pip install panda-gym``): a Franka Panda arm
must pick a 4 cm cube from a random place on the table and bring it within 5 cm of a
random target, on the table or in the air, in 50 steps. An action moves the gripper by
up to 5 cm per axis and opens or closes the fingers. The episode terminates on success
(``info["is_success"]``).

Its observation is a ``Dict`` (``observation``, ``achieved_goal``, ``desired_goal``),
which the pipeline does not take, so this module registers ``PandaPickAndPlaceFlat-v3``,
the same environment with the planner state as one vector of 22 values:

========  ===================================
0:3       gripper position (m)
3:6       gripper velocity
6         finger opening (m)
7:10      cube position
10:13     cube orientation (Euler angles)
13:16     cube velocity
16:19     cube angular velocity
19:22     target position
========  ===================================

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
GRIPPER = slice(0, 3)
FINGERS = 6
CUBE = slice(7, 10)
TARGET = slice(19, 22)
HOME = np.array([0.0, 0.0, 0.2])
"""Where ``retreat`` takes the gripper (panda-gym's start position, roughly)."""
GAIN = 10.0
"""Proportional gain from a position error (m) to an action (1 = 5 cm per step)."""
BETA = 0.1
"""Termination probability per step of every option."""


class FlatPickAndPlace(gym.ObservationWrapper[Any, Any, Any]):
    """``[observation (19), desired_goal (3)]`` as one ``float64`` Box of 22 values."""

    def __init__(self, env: gym.Env[Any, Any]) -> None:
        super().__init__(env)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (22,), np.float64)

    def observation(self, observation: dict[str, np.ndarray]) -> np.ndarray:
        return np.concatenate([observation["observation"],
                               observation["desired_goal"]]).astype(np.float64)


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


def _move(observation: Any, target: np.ndarray, fingers: float) -> np.ndarray:
    step = np.clip(GAIN * (np.asarray(target) - np.asarray(observation[GRIPPER])), -1.0, 1.0)
    return np.array([*step, fingers], dtype=np.float32)


def reach(observation: Any) -> np.ndarray:
    """Open the fingers and go to the cube: above it first, then down onto it."""
    cube = np.asarray(observation[CUBE])
    above = np.linalg.norm(np.asarray(observation[GRIPPER])[:2] - cube[:2]) > 0.01
    return _move(observation, cube + np.array([0.0, 0.0, 0.05 if above else 0.0]), 1.0)


def grasp(observation: Any) -> np.ndarray:
    """Close the fingers where the gripper is."""
    return _move(observation, observation[GRIPPER], -1.0)


def carry(observation: Any) -> np.ndarray:
    """Keep the fingers closed and go to the target."""
    return _move(observation, observation[TARGET], -1.0)


def retreat(observation: Any) -> np.ndarray:
    """Open the fingers and go back to the home position."""
    return _move(observation, HOME, 1.0)


def sweep(observation: Any) -> np.ndarray:
    """Move sideways (+y) at table height with the fingers open."""
    gripper = np.asarray(observation[GRIPPER])
    return _move(observation, gripper + np.array([0.0, 0.1, 0.0]) * [1, 1, 0]
                 + np.array([0.0, 0.0, 0.02 - gripper[2]]), 1.0)


def make_options() -> list[OptionSpec]:
    """Five options: ``reach``, ``grasp`` and ``carry`` (the task's sequence) and two
    distractors the demonstrations never use, ``retreat`` and ``sweep``; each stops with
    probability ``BETA`` per step."""
    return [
        option_spec("reach", reach, termination=BETA),
        option_spec("grasp", grasp, termination=BETA),
        option_spec("carry", carry, termination=BETA),
        option_spec("retreat", retreat, termination=BETA),
        option_spec("sweep", sweep, termination=BETA),
    ]


def holding(observation: Any) -> bool:
    """The cube is between the closed fingers."""
    near = np.linalg.norm(np.asarray(observation[GRIPPER]) - np.asarray(observation[CUBE]))
    return bool(near < 0.02 and float(observation[FINGERS]) < 0.045)


class PickAndPlaceScript(Demonstrator):
    """The expert: reach the cube, close the fingers on it, carry it to the target.

    It reaches until the gripper is within 1 cm of the cube, grasps until the fingers
    hold it, then carries; if the cube slips out, it starts again.
    """

    def choose(self, observation: Any) -> str:
        if holding(observation):
            return "carry"
        at_cube = np.linalg.norm(np.asarray(observation[GRIPPER])
                                 - np.asarray(observation[CUBE])) < 0.01
        return "grasp" if at_cube else "reach"


def make_demonstrator() -> Demonstrator:
    """The demonstrator the command line uses for ``--demos N``."""
    return PickAndPlaceScript()
