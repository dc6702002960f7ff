"""panda-gym's push: a Franka Panda with its fingers blocked shut pushes a cube to a target.

``PandaPush-v3`` (the ``panda-gym`` package, 3.0.7, PyBullet physics): a 4 cm cube and a
target (a ghost cube) are placed at random on a 30 x 30 cm patch of the table; the cube
must come within 5 cm of the target. The gripper cannot grasp (``block_gripper``), so
the cube can only be pushed. An action moves the gripper by up to 5 cm per axis. The
episode terminates on success (``info["is_success"]``). panda-gym registers it with 50
steps; re-approaching the cube after it turns away needs more, so this module registers
``PandaPushSuite-v3``: the same environment, 100 steps, reset as :class:`FreshContacts`
says.

The observation is a ``Dict``; :func:`state_fn` makes the planner state, 6 values:

========  ===================================================
0:3       cube position minus gripper position (m)
3:6       target position minus cube position (m)
========  ===================================================

The options (plain proportional controllers on that state; "the push direction" ``u``
is the horizontal unit vector from the cube to the target):

- ``get_behind``: fly at 6 cm above the cube's centre to the point 5 cm behind the cube
  along ``u``, then go down to the cube's height there; done within 1 cm of that point.
- ``push``: move along ``u`` while steering the gripper back onto the line behind the
  cube; done when the cube is within 2 cm of the target, or when the gripper has lost
  the cube (beside it, in front of it, or above it).
- ``retreat``: go straight up to 6 cm above the cube's centre; done there.
- ``sweep`` (the distractor): go down to the table and move sideways, across ``u``;
  stops with probability 0.1 per step.

The demonstrator: push while the gripper sits behind the cube; otherwise retreat if the
gripper is low (it would knock the cube on its way), else get behind the cube.

The disturbance (:func:`disturb`): once per episode, at a random step between 10 and 30,
the cube is moved 5 to 8 cm in a random horizontal direction (away from the gripper),
as if someone bumped it.

``reset(seed=s)`` reproduces the episode: panda-gym re-seeds its task's generator from
``seed`` on every reset (and from fresh entropy on a reset without a seed, rather than
carrying on the seeded stream), and :class:`FreshContacts` clears what PyBullet would
carry over from the previous episode.
"""

from typing import Any

import gymnasium as gym
import numpy as np

from dynoplan.adapters import OptionSpec, option_spec
from dynoplan.pipeline import Demonstrator

ENV_ID = "PandaPushSuite-v3"
MAX_STEPS = 100
DISTURBANCE = "the cube is moved 5-8 cm sideways once, at a random step between 10 and 30"

TO_CUBE = slice(0, 3)
TO_TARGET = slice(3, 6)
GAIN = 10.0
"""Proportional gain from a position error (m) to an action (1 = 5 cm per step)."""
STANDOFF = 0.05
"""m: how far behind the cube's centre ``get_behind`` puts the gripper."""
CONTACT = 0.035
"""m: where ``push`` holds the gripper, behind the cube's centre along ``u``."""
HOVER = 0.06
"""m: height above the cube's centre at which the gripper flies over the table."""
PUSH_SPEED = 0.4
"""Action along ``u`` while pushing (2 cm per step)."""
NEAR = 0.01
"""m: ``get_behind`` and ``retreat`` are done within this of their point."""
DELIVERED = 0.02
"""m: ``push`` is done with the cube this close to the target."""
BETA = 0.1
"""Termination probability per step of the distractor."""
BETA_RUNNING = 0.02
"""Termination probability per step of the task's options before their job is done."""

class FreshContacts(gym.Wrapper[Any, Any, Any, Any]):
    """Makes ``reset(seed=s)`` reproduce the whole episode, not only its first
    observation: panda-gym moves the cubes back onto the table at reset, and PyBullet
    keeps their old contacts with it, so the first steps differ by ~1e-5 m with the
    previous episode and an episode's length by a step now and then. Before each reset,
    the cubes are lifted far off the table for one simulation step, which drops those
    contacts."""

    def __init__(self, env: gym.Env[Any, Any], bodies: tuple[str, ...]) -> None:
        super().__init__(env)
        self.bodies = bodies

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        sim = self.env.unwrapped.sim  # type: ignore[attr-defined]
        for i, body in enumerate(self.bodies):
            sim.set_base_pose(body, np.array([5.0 + i, 5.0, 5.0]),
                              np.array([0.0, 0.0, 0.0, 1.0]))
        sim.step()
        return self.env.reset(**kwargs)


def make_env(**kwargs: Any) -> gym.Env[Any, Any]:
    """``PandaPush-v3``'s environment (no time limit of its own) with
    :class:`FreshContacts`."""
    from panda_gym.envs import PandaPushEnv

    return FreshContacts(PandaPushEnv(**kwargs), ("object",))


if ENV_ID not in gym.registry:
    gym.register(ENV_ID, entry_point=make_env, max_episode_steps=MAX_STEPS)


def state_fn(observation: dict[str, np.ndarray]) -> np.ndarray:
    """Cube minus gripper, target minus cube (see the module docstring)."""
    gripper = observation["observation"][0:3]
    cube = observation["achieved_goal"]
    return np.concatenate([cube - gripper, observation["desired_goal"] - cube]).astype(
        np.float64)


success = None
"""The environment's own ``info["is_success"]`` (it terminates on success)."""


def _direction(to_target: np.ndarray) -> np.ndarray:
    """The horizontal unit vector from the cube to the target (``+x`` at the target)."""
    flat = np.array([to_target[0], to_target[1], 0.0])
    norm = float(np.linalg.norm(flat))
    return flat / norm if norm > 1e-6 else np.array([1.0, 0.0, 0.0])


def _action(move: np.ndarray) -> np.ndarray:
    return np.clip(np.asarray(move, dtype=np.float64), -1.0, 1.0).astype(np.float32)


def _behind_offset(state: np.ndarray) -> np.ndarray:
    """From the gripper to the point ``STANDOFF`` behind the cube, at its height."""
    return np.asarray(state[TO_CUBE]) - STANDOFF * _direction(state[TO_TARGET])


def get_behind(state: np.ndarray) -> np.ndarray:
    """Fly to above the point behind the cube, then go down onto it (vertical moves at
    half speed at most: the arm lags its commands by a step or two and would overshoot)."""
    offset = _behind_offset(state)
    if np.linalg.norm(offset[:2]) > NEAR:
        offset = offset + np.array([0.0, 0.0, HOVER])
    move = GAIN * offset
    move[2] = np.clip(move[2], -0.5, 0.5)
    return _action(move)


def push(state: np.ndarray) -> np.ndarray:
    """Move along ``u``, holding the gripper on the line ``CONTACT`` behind the cube."""
    u = _direction(state[TO_TARGET])
    hold = np.asarray(state[TO_CUBE]) - CONTACT * u
    along = float(hold @ u)
    correction = hold - along * u  # sideways and vertical error only
    speed = min(PUSH_SPEED, GAIN * float(np.linalg.norm(state[TO_TARGET][:2])))
    return _action(GAIN * correction + speed * u)


def retreat(state: np.ndarray) -> np.ndarray:
    """Go straight up to ``HOVER`` above the cube's centre."""
    return _action(np.array([0.0, 0.0, GAIN * (state[2] + HOVER)]))


def sweep(state: np.ndarray) -> np.ndarray:
    """Go down to the cube's height and move across the push direction."""
    u = _direction(state[TO_TARGET])
    across = np.array([-u[1], u[0], 0.0])
    return _action(0.6 * across + np.array([0.0, 0.0, GAIN * state[2]]))


def _batch_direction(states: np.ndarray) -> np.ndarray:
    flat = states[:, TO_TARGET].copy()
    flat[:, 2] = 0.0
    norm = np.linalg.norm(flat, axis=1, keepdims=True)
    fallback = np.tile([1.0, 0.0, 0.0], (len(states), 1))
    return np.where(norm > 1e-6, flat / np.maximum(norm, 1e-6), fallback)


def behind(states: np.ndarray) -> np.ndarray:
    """Booleans ``(batch,)``: the gripper within ``NEAR`` of the point behind the cube."""
    offsets = states[:, TO_CUBE] - STANDOFF * _batch_direction(states)
    return np.asarray(np.linalg.norm(offsets, axis=1) < NEAR)


def lost_cube(states: np.ndarray) -> np.ndarray:
    """Booleans ``(batch,)``: the gripper is not pushing the cube: more than 2 cm beside
    the push line, less than 1.5 cm behind the cube's centre (beside or in front of it),
    more than 8 cm behind it, or more than 2 cm above or below its centre."""
    u = _batch_direction(states)
    to_cube = states[:, TO_CUBE]
    along = np.sum(to_cube * u, axis=1)
    side = np.linalg.norm(to_cube[:, :2] - along[:, None] * u[:, :2], axis=1)
    return np.asarray((side > 0.02) | (along < 0.015) | (along > 0.08)
                      | (np.abs(to_cube[:, 2]) > 0.02))


def delivered(states: np.ndarray) -> np.ndarray:
    """Booleans ``(batch,)``: the cube within ``DELIVERED`` of the target."""
    return np.asarray(np.linalg.norm(states[:, TO_TARGET], axis=1) < DELIVERED)


def high(states: np.ndarray) -> np.ndarray:
    """Booleans ``(batch,)``: the gripper within ``NEAR`` of ``HOVER`` above the cube's
    centre (or higher)."""
    return np.asarray(-states[:, 2] > HOVER - NEAR)


def got_behind(states: np.ndarray) -> np.ndarray:
    """``get_behind``'s termination: 1 behind the cube, else ``BETA_RUNNING``."""
    return np.where(behind(states), 1.0, BETA_RUNNING)


def pushed(states: np.ndarray) -> np.ndarray:
    """``push``'s termination: 1 with the cube delivered or lost, else ``BETA_RUNNING``."""
    return np.where(delivered(states) | lost_cube(states), 1.0, BETA_RUNNING)


def retreated(states: np.ndarray) -> np.ndarray:
    """``retreat``'s termination: 1 at hover height, else ``BETA_RUNNING``."""
    return np.where(high(states), 1.0, BETA_RUNNING)


def make_options() -> list[OptionSpec]:
    """``get_behind``, ``push`` and ``retreat`` (the demonstrator's), and the distractor
    ``sweep``."""
    return [
        option_spec("get_behind", get_behind, termination=got_behind),
        option_spec("push", push, termination=pushed),
        option_spec("retreat", retreat, termination=retreated),
        option_spec("sweep", sweep, termination=BETA),
    ]


class PushScript(Demonstrator):
    """Push while the gripper is behind the cube and has not lost it; else retreat when
    the gripper is low and away from the point behind the cube; else get behind it."""

    def __init__(self) -> None:
        self.pushing = False

    def reset(self, observation: Any, rng: np.random.Generator) -> None:
        self.pushing = False

    def choose(self, observation: Any) -> str:
        state = np.asarray(observation, dtype=np.float64)[None]
        if self.pushing:
            self.pushing = not bool(lost_cube(state)[0] or delivered(state)[0])
        else:
            self.pushing = bool(behind(state)[0])
        if self.pushing:
            return "push"
        away = float(np.linalg.norm(_behind_offset(state[0])[:2])) > 2 * NEAR
        low = -float(state[0, 2]) < HOVER - 2 * NEAR
        return "retreat" if away and low else "get_behind"


def make_demonstrator() -> Demonstrator:
    """The scripted push (:class:`PushScript`)."""
    return PushScript()


class NudgeCube(gym.Wrapper[Any, Any, Any, Any]):
    """Once per episode, at a random step in ``[10, 30]``, move the cube 5 to 8 cm in a
    random horizontal direction (turned away from the gripper when it would land on it),
    kept on the reachable part of the table. Seeded from ``reset(seed=...)``."""

    def __init__(self, env: gym.Env[Any, Any]) -> None:
        super().__init__(env)
        self.rng = np.random.default_rng()
        self.steps = 0
        self.at = -1

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        self.steps = 0
        self.at = int(self.rng.integers(10, 31))
        return self.env.reset(seed=seed, options=options)

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        if self.steps == self.at:
            self._nudge()
        self.steps += 1
        return self.env.step(action)

    def _nudge(self) -> None:
        sim = self.env.unwrapped.sim  # type: ignore[attr-defined]
        cube = np.asarray(sim.get_base_position("object"), dtype=np.float64)
        gripper = np.asarray(sim.get_link_position("panda", 11), dtype=np.float64)
        angle = self.rng.uniform(0.0, 2.0 * np.pi)
        shift = self.rng.uniform(0.05, 0.08) * np.array([np.cos(angle), np.sin(angle), 0.0])
        moved = cube + shift
        if np.linalg.norm((moved - gripper)[:2]) < 0.05:
            moved = cube - shift
        moved[:2] = np.clip(moved[:2], -0.2, 0.2)
        sim.set_base_pose("object", moved, np.asarray(sim.get_base_orientation("object")))


def disturb(env: gym.Env[Any, Any]) -> gym.Env[Any, Any]:
    """The task's disturbance: :class:`NudgeCube`."""
    return NudgeCube(env)
