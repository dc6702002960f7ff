"""Meta-World ``pick-place-v3``: a Sawyer arm picks a puck off the table and places it at a
goal in the air, with options written on Meta-World's own 39-value observation.

The task comes from Meta-World 3.1.1 (``pip install metaworld``, MuJoCo physics), made as
its README makes a single-task environment: the ``metaworld.MT1("pick-place-v3")``
benchmark gives the environment class and 50 *tasks* (puck and goal positions drawn once
with the benchmark's seed), and ``env.set_task(task)`` picks one before ``reset``. An
action moves the hand by up to 1 cm per axis and sets the gripper's effort (+1 closes,
-1 opens). Success is the environment's ``info["success"]`` (the puck within 7 cm of the
goal), a float: :func:`success` reads it. Meta-World never terminates an episode itself.

Meta-World's ``reset`` ignores its ``seed`` argument (its docstring says so), and the
``Meta-World/MT1`` Gymnasium id draws the task from a generator that ``reset(seed=...)``
does not reseed: two resets with the same seed gave different pucks and goals. This
module registers ``MetaWorldPickPlace-v3``, whose :class:`SeededTask` wrapper picks the
task from ``numpy.random.default_rng(seed)`` at ``reset(seed=seed)`` (the same seed, the
same task and the same first observation), with a limit of 120 steps (Meta-World's is
500; its scripted expert needs about 55).

The planner state is the observation as it is (no ``state_fn``). The options read

========  =====================================================
0:3       hand position (m)
3         gripper opening (1 open, about 0.45 closed on the puck)
4:7       puck position (m)
36:39     goal position (m)
========  =====================================================

Options: ``hover`` (open the gripper, go 10 cm above the puck), ``descend`` (open, go
down onto the puck), ``grasp`` (stay, close the gripper), ``carry`` (keep it closed,
bring the puck to the goal), each stopping when its job is done (else with probability
``BETA_RUNNING`` per step), and the distractor ``retreat`` (open the gripper and rise to
a fixed pose above the table), which the demonstrator never uses. The demonstrator
chains them: hover, descend, grasp, carry, starting again from ``hover`` if the puck is
lost. Disturbance: the puck is knocked 4-6 cm sideways once, at a step drawn from 10-30,
if it is still on the table.
"""

import functools
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np

from dynoplan.adapters import OptionSpec, option_spec
from dynoplan.pipeline import Demonstrator

TASK = "pick-place-v3"
ENV_ID = "MetaWorldPickPlace-v3"
MAX_STEPS = 120
BENCHMARK_SEED = 0
"""Seed of the ``metaworld.MT1`` benchmark: which 50 puck and goal positions exist."""

HAND = slice(0, 3)
GRIPPER = 3
PUCK = slice(4, 7)
GOAL = slice(36, 39)

GAIN = 10.0
"""Proportional gain from a position error (m) to an action (1 = 1 cm per step)."""
OPEN, CLOSE = -1.0, 1.0
HOVER_HEIGHT = 0.10
"""m: where ``hover`` goes above the puck."""
GRASP_HEIGHT = 0.03
"""m: where ``descend`` puts the hand above the puck's centre."""
ABOVE = 0.02
"""m: horizontal distance from hand to puck under which the hand is above the puck."""
LOW = 0.045
"""m: height of the hand above the puck under which the fingers are around it."""
HELD_GRIPPER = (0.35, 0.65)
"""Gripper opening when closed on the puck (empty, it closes to below 0.3)."""
DELIVERED = 0.03
"""m: distance from puck to goal at which ``carry`` is done."""
HOME = np.array([0.0, 0.6, 0.3])
"""Where ``retreat`` goes: above the hand's start."""
BETA_RUNNING = 0.02
"""Termination probability per step of an option whose job is not done yet."""


class SeededTask(gym.Wrapper[Any, Any, Any, Any]):
    """A Meta-World environment whose ``reset(seed=s)`` is reproducible: it sets the task
    (one of the benchmark's ``tasks``) drawn from ``default_rng(s)``, then resets.

    With ``seed=None`` it draws the next task from the generator of the last seed. The
    observation space is the one Meta-World computes once a task is set (the space it
    reports before has the goal's bounds at zero).
    """

    def __init__(self, env: gym.Env[Any, Any], tasks: list[Any]) -> None:
        super().__init__(env)
        self.tasks = list(tasks)
        self._rng = np.random.default_rng()
        self.env.unwrapped.set_task(self.tasks[0])  # type: ignore[attr-defined]
        self.observation_space = self.env.unwrapped.sawyer_observation_space  # type: ignore[attr-defined]

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        task = self.tasks[int(self._rng.integers(len(self.tasks)))]
        self.env.unwrapped.set_task(task)  # type: ignore[attr-defined]
        return self.env.reset(seed=seed, options=options)


@functools.cache
def _benchmark(task: str, benchmark_seed: int) -> Any:
    """``metaworld.MT1(task, seed=benchmark_seed)``, built once per process (it takes
    about 2 s)."""
    import metaworld

    return metaworld.MT1(task, seed=benchmark_seed)


def make_metaworld_env(task: str, benchmark_seed: int = BENCHMARK_SEED) -> gym.Env[Any, Any]:
    """One Meta-World task from its ``MT1`` benchmark, with :class:`SeededTask` (no time
    limit of its own: the registered id adds one)."""
    benchmark = _benchmark(task, benchmark_seed)
    return SeededTask(benchmark.train_classes[task](), benchmark.train_tasks)


def make_env(**kwargs: Any) -> gym.Env[Any, Any]:
    """``pick-place-v3`` with a reproducible seeded reset (``kwargs``: ``benchmark_seed``)."""
    return make_metaworld_env(TASK, **kwargs)


if ENV_ID not in gym.registry:
    gym.register(ENV_ID, entry_point=make_env, max_episode_steps=MAX_STEPS)


def success(observation: Any, info: dict[str, Any]) -> bool:
    """Meta-World's own success: ``info["success"]`` (a float, 1.0 on success)."""
    return bool(info.get("success", 0.0) >= 1.0)


state_fn = None


# --- the options -------------------------------------------------------------------------


def move_hand(observation: Any, target: np.ndarray, gripper: float) -> np.ndarray:
    """The action that moves the hand towards ``target`` (m) with the gripper's effort."""
    step = np.clip(GAIN * (target - np.asarray(observation[HAND])), -1.0, 1.0)
    return np.array([*step, gripper], dtype=np.float32)


def _over_puck(observation: Any, height: float) -> np.ndarray:
    """The point ``height`` (m) above the puck's centre."""
    return np.asarray(observation[PUCK]) + np.array([0.0, 0.0, height])


def hover(observation: Any) -> np.ndarray:
    """Open the gripper and go ``HOVER_HEIGHT`` above the puck."""
    return move_hand(observation, _over_puck(observation, HOVER_HEIGHT), OPEN)


def descend(observation: Any) -> np.ndarray:
    """Keep the gripper open and go down onto the puck (``GRASP_HEIGHT`` above its centre)."""
    return move_hand(observation, _over_puck(observation, GRASP_HEIGHT), OPEN)


def grasp(observation: Any) -> np.ndarray:
    """Stay where the hand is and close the gripper."""
    return np.array([0.0, 0.0, 0.0, CLOSE], dtype=np.float32)


def carry(observation: Any) -> np.ndarray:
    """Keep the gripper closed and move the hand so that the puck goes to the goal."""
    hand, puck = np.asarray(observation[HAND]), np.asarray(observation[PUCK])
    return move_hand(observation, np.asarray(observation[GOAL]) + (hand - puck), CLOSE)


def retreat(observation: Any) -> np.ndarray:
    """Distractor: open the gripper and rise to ``HOME``."""
    return move_hand(observation, HOME, OPEN)


def above(states: np.ndarray) -> np.ndarray:
    """The hand is above the puck (within ``ABOVE`` horizontally), states ``(B, 39)``."""
    return np.asarray(np.linalg.norm(states[:, 0:2] - states[:, 4:6], axis=1) < ABOVE)


def at_puck(states: np.ndarray) -> np.ndarray:
    """The hand is above the puck and low enough for the fingers to close around it."""
    return above(states) & (states[:, 2] - states[:, 6] < LOW)


def held(states: np.ndarray) -> np.ndarray:
    """The gripper is closed on the puck: closed to the puck's width, puck at the hand."""
    closed = (states[:, GRIPPER] > HELD_GRIPPER[0]) & (states[:, GRIPPER] < HELD_GRIPPER[1])
    return closed & above(states) & (states[:, 2] - states[:, 6] < 2 * LOW)


def delivered(states: np.ndarray) -> np.ndarray:
    """The puck is within ``DELIVERED`` of the goal."""
    return np.asarray(np.linalg.norm(states[:, 4:7] - states[:, 36:39], axis=1) < DELIVERED)


def at_home(states: np.ndarray) -> np.ndarray:
    """The hand is within 2 cm of ``HOME``."""
    return np.asarray(np.linalg.norm(states[:, 0:3] - HOME, axis=1) < 0.02)


def done_when(condition: Callable[[np.ndarray], np.ndarray],
              beta: float = BETA_RUNNING) -> Callable[[np.ndarray], np.ndarray]:
    """A termination ``beta(s)`` on states ``(B, 39)``: 1 where ``condition(states)``
    (the option's job is done), else ``beta``."""

    def termination(states: np.ndarray) -> np.ndarray:
        return np.where(condition(np.asarray(states, dtype=np.float64)), 1.0, beta)

    termination.__name__ = f"done_when_{condition.__name__}"
    return termination


def make_options() -> list[OptionSpec]:
    """Five options: ``hover``, ``descend``, ``grasp`` and ``carry`` (the task's chain),
    each done when the hand is :func:`above` the puck, :func:`at_puck`, the puck is
    :func:`held`, or :func:`delivered`; and the distractor ``retreat``, done
    :func:`at_home`."""
    return [
        option_spec("hover", hover, termination=done_when(above)),
        option_spec("descend", descend, termination=done_when(at_puck)),
        option_spec("grasp", grasp, termination=done_when(held)),
        option_spec("carry", carry, termination=done_when(delivered)),
        option_spec("retreat", retreat, termination=done_when(at_home)),
    ]


class PickPlaceScript(Demonstrator):
    """The expert: carry while the puck is held; else close the gripper if the hand is at
    the puck, descend if it is above it, and hover otherwise (so a lost puck is picked
    up again)."""

    def choose(self, observation: Any) -> str:
        s = np.asarray(observation, dtype=np.float64)[None]
        if held(s)[0]:
            return "carry"
        if at_puck(s)[0]:
            return "grasp"
        return "descend" if above(s)[0] else "hover"


def make_demonstrator() -> Demonstrator:
    """The demonstrator of this task."""
    return PickPlaceScript()


# --- the disturbance ---------------------------------------------------------------------

DISTURBANCE = ("the puck is knocked 4-6 cm sideways (random direction) once, at a step drawn "
               "from 10-30, if it is still on the table")


class OnceAtStep(gym.Wrapper[Any, Any, Any, Any]):
    """A disturbance that happens once per episode, at a step drawn from ``steps`` with a
    generator seeded from the seed of ``reset``; :meth:`disturb` says what it does (and
    draws the rest of it from ``self.rng``)."""

    def __init__(self, env: gym.Env[Any, Any], steps: tuple[int, int],
                 distance: tuple[float, float] = (0.04, 0.06)) -> None:
        super().__init__(env)
        self.steps, self.distance = steps, distance
        self.rng = np.random.default_rng()
        self._t = 0
        self._at = -1

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        self._t = 0
        self._at = int(self.rng.integers(self.steps[0], self.steps[1] + 1))
        return self.env.reset(seed=seed, options=options)

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        if self._t == self._at:
            self.disturb()
        self._t += 1
        return self.env.step(action)

    def disturb(self) -> None:
        raise NotImplementedError

    def horizontal(self) -> np.ndarray:
        """A horizontal move ``(2,)`` of a length drawn from ``distance`` in a random
        direction."""
        angle = self.rng.uniform(0.0, 2 * np.pi)
        length = self.rng.uniform(*self.distance)
        return length * np.array([np.cos(angle), np.sin(angle)])


class KnockPuck(OnceAtStep):
    """At one step drawn from ``steps``, move the puck by ``distance`` (m) in a random
    horizontal direction, at rest, if it is still on the table (below 3 cm). Seeded from
    the seed of ``reset``."""

    def __init__(self, env: gym.Env[Any, Any], steps: tuple[int, int] = (10, 30),
                 distance: tuple[float, float] = (0.04, 0.06)) -> None:
        super().__init__(env, steps, distance)

    def disturb(self) -> None:
        import mujoco

        base = self.env.unwrapped
        joint = base.data.joint("objjoint")  # type: ignore[attr-defined]
        if joint.qpos[2] > 0.03:
            return
        joint.qpos[0:2] += self.horizontal()
        joint.qvel[:] = 0.0
        mujoco.mj_forward(base.model, base.data)  # type: ignore[attr-defined]


def disturb(env: gym.Env[Any, Any]) -> gym.Env[Any, Any]:
    """The task's disturbance: :class:`KnockPuck`."""
    return KnockPuck(env)
