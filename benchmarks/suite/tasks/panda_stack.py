"""panda-gym's stack: a Franka Panda puts one cube on the table target and the other on top.

``PandaStack-v3`` (the ``panda-gym`` package, 3.0.7, PyBullet physics): two 4 cm cubes
(cube 1 blue, cube 2 green) start at random on a 30 x 30 cm patch of the table; the
targets are a random spot on the table for cube 1 and the spot 4 cm above it for cube 2.
panda-gym's success is the two cubes' positions, as one 6-vector, within 10 cm of the
targets': cube 2 lying on the table next to cube 1 passes it (4 cm too low and at
least 4 cm aside is 5.7 cm). This module registers ``PandaStackSuite-v3``, the same
environment where success (``info["is_success"]``, which terminates the episode) is each
cube within 3 cm of its own target (:class:`StackedSuccess`), with ``MAX_STEPS`` steps
(panda-gym gives 100), reset as :class:`FreshContacts` says. An action moves the gripper
by up to 5 cm per axis and opens or closes the fingers (which close along ``y``; the
gripper cannot turn).

The observation is a ``Dict``; :func:`state_fn` makes the planner state, 13 values:

========  ===================================================
0:3       cube 1 position minus gripper position (m)
3:6       cube 2 position minus gripper position (m)
6         finger opening (m)
7:10      target 1 minus cube 1 (m)
10:13     target 2 minus cube 2 (m)
========  ===================================================

The options are proportional controllers on the state. Each cube has a destination
(:func:`destination`): target 1 for cube 1; target 2 for cube 2 once cube 1 lies on
target 1, and before that a spot on the table clear of cube 1 and target 1 (cubes start
anywhere, often next to each other, or one on the other: cube 2 may then be in the way
of the fingers at cube 1 or at target 1, :func:`in_the_way`, and is set aside first).

- ``reach``: open the fingers to 5.5 cm, fly 6 cm above the next cube (cube 2 if cube 1
  is placed or cube 2 is in the way, else cube 1; chosen when the option starts), go
  down onto it; done with the gripper at a cube and the fingers open.
- ``grasp``: close the fingers (towards 2.5 cm, not all the way: see :func:`_squeeze`)
  where the gripper is; done when they hold a cube.
- ``carry``: keep the fingers closed, lift the held cube, fly it 6 cm above its
  destination, set it down there; done when it is there (1.5 cm), or has slipped out.
- ``release``: open the fingers, then rise; done when they are open and the gripper is
  5 cm clear of both cubes.
- ``press`` (the distractor): close the fingers and push straight down; stops with
  probability 0.1 per step.

The demonstrator runs each option until its job is done (a grasp that holds nothing
after 10 steps is given up), then chooses from the state: a held cube is carried, or
released at its destination; a gripper at a cube with open fingers grasps; half-closed
fingers near a cube are opened (release); otherwise it reaches. It fails when the two
cubes start side by side along ``y``, 4 to 6 cm apart: neither can be grasped, the
fingers land on the other one (2 of 100 episodes).

The disturbance (:func:`disturb`): once per episode, at a random step between 20 and
60, cube 1 is moved 3 to 5 cm across the table in a random direction, unless the
gripper holds it (as if someone bumped it, or the tower).

``reset(seed=s)`` reproduces the episode: panda-gym re-seeds its task's generator from
``seed`` on every reset (and from fresh entropy on a reset without a seed, rather than
carrying on the seeded stream), and :class:`FreshContacts` clears what PyBullet would
carry over from the previous episode.
"""

from typing import Any

import gymnasium as gym
import numpy as np

from benchmarks.suite.tasks.panda_push import FreshContacts
from dynoplan.adapters import OptionSpec, option_spec
from dynoplan.options import OptionPolicy
from dynoplan.pipeline import Demonstrator

ENV_ID = "PandaStackSuite-v3"
MAX_STEPS = 150
DISTURBANCE = ("cube 1 is moved 3-5 cm across the table once, at a random step between "
               "20 and 60, unless it is held")

CUBE1 = slice(0, 3)
CUBE2 = slice(3, 6)
FINGERS = 6
TARGET1 = slice(7, 10)
TARGET2 = slice(10, 13)
GAIN = 20.0
"""Proportional gain from a position error (m) to an action (1 = 5 cm per step); with
10, the arm creeps over the last centimetre where it is stretched out."""
HOVER = 0.06
"""m: height above a cube (or a destination) at which the gripper flies across."""
NEAR = 0.007
"""m: the gripper is at a cube within this across and within ``NEAR`` in height."""
ABOVE = 0.015
"""m: the gripper goes down once it is this close above its point, across."""
PLACED = 0.015
"""m: ``carry`` is done with the cube this close to its destination across (and 5 mm in
height)."""
STACKED = 0.03
"""m: success is each cube this close to its target."""
ON_TARGET = 0.03
"""m: cube 1 this close to target 1 lies on it (opening the fingers may shift it by a
centimetre)."""
WIDE = 0.055
"""m: how wide ``reach`` and ``release`` open the fingers (the cube is 4 cm wide)."""
GRIP = 0.025
"""m: the opening the fingers are closed towards on a cube (4 cm)."""
OPEN = 0.05
"""m: fingers wider than this are open; between 3 and 5.5 cm they are closed on a cube
(a cube turned about the vertical is wider than 4 cm across)."""
CARRY_SPEED = 0.6
"""Largest action across while carrying (3 cm per step): faster, cube 1 (2 kg) slips out."""
HELD = 0.02
"""m: a cube this close to the gripper, with the fingers closed on it, is held."""
WAY = (0.045, 0.07)
"""m: a cube closer than this along ``x`` and ``y`` to where the fingers go down is in
their way."""
ASIDE = ((-0.1, 0.0, 0.0), (-0.1, 0.1, 0.0), (-0.1, -0.1, 0.0), (0.0, 0.12, 0.0),
         (0.0, -0.12, 0.0))
"""m: where cube 2 may be set aside, from cube 1 (towards the robot first: always in
its reach); the first one well clear of target 1 is used."""
CLEAR = 0.05
"""m: ``release`` is done with the gripper this far from both cubes."""
BETA = 0.1
"""Termination probability per step of the distractor."""
BETA_RUNNING = 0.02
"""Termination probability per step of the task's options before their job is done."""


def stacked(observation: dict[str, np.ndarray]) -> bool:
    """Each cube within ``STACKED`` of its own target."""
    cubes, targets = observation["achieved_goal"], observation["desired_goal"]
    return bool(np.linalg.norm(cubes[0:3] - targets[0:3]) < STACKED
                and np.linalg.norm(cubes[3:6] - targets[3:6]) < STACKED)


class StackedSuccess(gym.Wrapper[Any, Any, Any, Any]):
    """panda-gym's stack with success (``info["is_success"]``, termination, a sparse
    reward of 0 instead of -1) only when both cubes are on their targets
    (:func:`stacked`)."""

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        observation, info = self.env.reset(**kwargs)
        return observation, {**info, "is_success": stacked(observation)}

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        observation, _, _, truncated, info = self.env.step(action)
        done = stacked(observation)
        return observation, float(done) - 1.0, done, truncated, {**info, "is_success": done}


def make_env(**kwargs: Any) -> gym.Env[Any, Any]:
    """``PandaStack-v3``'s environment (no time limit of its own) with
    :class:`StackedSuccess` and :class:`FreshContacts`."""
    from panda_gym.envs import PandaStackEnv

    return StackedSuccess(FreshContacts(PandaStackEnv(**kwargs), ("object1", "object2")))


if ENV_ID not in gym.registry:
    gym.register(ENV_ID, entry_point=make_env, max_episode_steps=MAX_STEPS)


def state_fn(observation: dict[str, np.ndarray]) -> np.ndarray:
    """The 13 values of the module docstring, from panda-gym's ``Dict`` observation."""
    robot = observation["observation"]
    gripper = robot[0:3]
    cubes = observation["achieved_goal"]
    targets = observation["desired_goal"]
    return np.concatenate([cubes[0:3] - gripper, cubes[3:6] - gripper, robot[6:7],
                           targets - cubes]).astype(np.float64)


success = None
"""The environment's own ``info["is_success"]`` (it terminates on success)."""


# ----- what the state says (all on batches of states, (B, 13)) -----

def placed1(states: np.ndarray) -> np.ndarray:
    """Booleans ``(B,)``: cube 1 lies on target 1 (within ``ON_TARGET``)."""
    return np.asarray(np.linalg.norm(states[:, TARGET1], axis=1) < ON_TARGET)


def holds(states: np.ndarray, cube: int) -> np.ndarray:
    """Booleans ``(B,)``: the fingers are closed on cube ``cube`` (1 or 2)."""
    part = CUBE1 if cube == 1 else CUBE2
    near = np.linalg.norm(states[:, part], axis=1) < HELD
    return np.asarray(near & (states[:, FINGERS] < OPEN) & (states[:, FINGERS] > 0.03))


def _blocks(offsets: np.ndarray, margin: float = 1.0) -> np.ndarray:
    """Booleans ``(B,)``: a cube at these offsets ``(B, 3)`` from a spot is in the way of
    fingers going down on that spot."""
    return np.asarray((np.abs(offsets[:, 0]) < margin * WAY[0])
                      & (np.abs(offsets[:, 1]) < margin * WAY[1]))


def in_the_way(states: np.ndarray) -> np.ndarray:
    """Booleans ``(B,)``: cube 1 is not placed and cube 2 is in the way of the fingers at
    cube 1 or at target 1 (or lies on cube 1)."""
    from_cube1 = states[:, CUBE2] - states[:, CUBE1]
    from_target1 = from_cube1 - states[:, TARGET1]
    return np.asarray(~placed1(states) & (_blocks(from_cube1) | _blocks(from_target1)))


def aside(states: np.ndarray) -> np.ndarray:
    """Offsets ``(B, 3)`` from cube 2 to where it is set aside (see ``ASIDE``)."""
    spots = states[:, CUBE1][:, None, :] + np.asarray(ASIDE)[None]  # from the gripper
    target1 = (states[:, CUBE1] + states[:, TARGET1])[:, None, :]
    clear = ~_blocks((spots - target1).reshape(-1, 3), 1.5).reshape(len(states), len(ASIDE))
    first = np.argmax(clear, axis=1)
    return np.asarray(spots[np.arange(len(states)), first] - states[:, CUBE2])


def destination(states: np.ndarray, cube: int) -> np.ndarray:
    """Offsets ``(B, 3)`` from cube ``cube`` to where it goes: target 1 for cube 1;
    target 2 for cube 2 once cube 1 is placed, else aside (:func:`aside`)."""
    if cube == 1:
        return np.asarray(states[:, TARGET1])
    return np.where(placed1(states)[:, None], states[:, TARGET2], aside(states))


def next_cube(states: np.ndarray) -> np.ndarray:
    """Ints ``(B,)``: the cube to pick next: 2 once cube 1 is placed or while cube 2 is in
    its way, else 1."""
    return np.where(placed1(states) | in_the_way(states), 2, 1)


def held_cube(states: np.ndarray) -> np.ndarray:
    """Ints ``(B,)``: the cube the fingers hold, 0 for none."""
    return np.where(holds(states, 1), 1, np.where(holds(states, 2), 2, 0))


def at_cube(states: np.ndarray) -> np.ndarray:
    """Booleans ``(B,)``: the gripper at a cube's centre (within ``NEAR``)."""
    at = np.zeros(len(states), dtype=bool)
    for part in (CUBE1, CUBE2):
        offsets = states[:, part]
        at |= (np.linalg.norm(offsets[:, :2], axis=1) < NEAR) & (
            np.abs(offsets[:, 2]) < NEAR)
    return at


def _there(offsets: np.ndarray) -> np.ndarray:
    """Booleans ``(B,)``: offsets ``(B, 3)`` within ``PLACED`` across, 5 mm in height."""
    return np.asarray((np.linalg.norm(offsets[:, :2], axis=1) < PLACED)
                      & (np.abs(offsets[:, 2]) < 0.005))


def delivered_now(states: np.ndarray) -> np.ndarray:
    """Booleans ``(B,)``: the fingers hold a cube that is at its destination."""
    there1 = _there(destination(states, 1))
    there2 = _there(destination(states, 2))
    return np.asarray((holds(states, 1) & there1) | (holds(states, 2) & there2))


def clear(states: np.ndarray) -> np.ndarray:
    """Booleans ``(B,)``: open fingers, ``CLEAR`` away from both cubes."""
    far = ((np.linalg.norm(states[:, CUBE1], axis=1) > CLEAR)
           & (np.linalg.norm(states[:, CUBE2], axis=1) > CLEAR))
    return np.asarray(far & (states[:, FINGERS] > OPEN))


# ----- the options -----

def _action(move: np.ndarray, fingers: float) -> np.ndarray:
    step = np.clip(np.asarray(move, dtype=np.float64), -1.0, 1.0)
    return np.array([*step, np.clip(fingers, -1.0, 1.0)], dtype=np.float32)


def _fingers(state: np.ndarray, width: float) -> float:
    """The finger command that asks for an opening of ``width`` (an action ``a`` asks
    for the current opening plus ``0.2 a``)."""
    return (width - float(state[FINGERS])) / 0.2


def _open(state: np.ndarray) -> float:
    """Open the fingers to ``WIDE``, not wider: wide-open fingers land on a cube next to
    the one they go for."""
    return _fingers(state, WIDE)


def _squeeze(state: np.ndarray) -> float:
    """Close the fingers towards ``GRIP``, a little less than a cube: closed all the way,
    both fingers push at full force and the cube slides between them whenever the arm
    moves along ``y``."""
    return _fingers(state, GRIP)


def _fly(offset: np.ndarray) -> np.ndarray:
    """The move to ``offset`` (m) through the point ``HOVER`` above it: climb (or sink)
    to that height, cross, then go down, correcting across on the way down; drifted more
    than ``2 ABOVE`` across, climb again (vertical moves at half speed at most: the arm
    lags its commands by a step or two and would overshoot)."""
    offset = np.asarray(offset, dtype=np.float64)
    across = float(np.linalg.norm(offset[:2]))
    if across < ABOVE:
        move = GAIN * offset
    elif across < 2 * ABOVE:
        move = GAIN * np.array([offset[0], offset[1], 0.0])
    else:
        aloft = offset + np.array([0.0, 0.0, HOVER])
        move = GAIN * aloft
        if aloft[2] > 0.02:  # too low to cross: climb first
            move[:2] = 0.0
    move[2] = np.clip(move[2], -0.5, 0.5)
    return move


class Reach(OptionPolicy):
    """Open the fingers and go down onto the next cube (:func:`next_cube`, chosen when
    the option starts), from above."""

    def __init__(self) -> None:
        self.cube = 1

    def reset(self, observation: Any, rng: np.random.Generator) -> None:
        self.cube = int(next_cube(np.asarray(observation, dtype=np.float64)[None])[0])

    def act(self, observation: Any) -> np.ndarray:
        state = np.asarray(observation, dtype=np.float64)
        return _action(_fly(state[CUBE1 if self.cube == 1 else CUBE2]), _open(state))


def grasp(state: np.ndarray) -> np.ndarray:
    """Close the fingers (:func:`_squeeze`) where the gripper is."""
    return _action(np.zeros(3), _squeeze(state))


def carry(state: np.ndarray) -> np.ndarray:
    """Keep the fingers closed (:func:`_squeeze`) and bring the held cube (else the next
    one) onto its destination, from above, at most ``CARRY_SPEED`` across."""
    states = np.asarray(state, dtype=np.float64)[None]
    cube = int(held_cube(states)[0]) or int(next_cube(states)[0])
    move = _fly(destination(states, cube)[0])
    across = float(np.linalg.norm(move[:2]))
    if across > CARRY_SPEED:
        move[:2] *= CARRY_SPEED / across
    return _action(move, _squeeze(state))


def release(state: np.ndarray) -> np.ndarray:
    """Open the fingers; once they are open, go straight up."""
    rise = 0.5 if state[FINGERS] > OPEN else 0.0
    return _action(np.array([0.0, 0.0, rise]), _open(state))


def press(state: np.ndarray) -> np.ndarray:
    """Close the fingers and push straight down."""
    return _action(np.array([0.0, 0.0, -1.0]), -1.0)


def reached(states: np.ndarray) -> np.ndarray:
    """``reach``'s termination: 1 at a cube with open fingers, else ``BETA_RUNNING``."""
    return np.where(at_cube(states) & (states[:, FINGERS] > OPEN), 1.0, BETA_RUNNING)


def grasped(states: np.ndarray) -> np.ndarray:
    """``grasp``'s termination: 1 once the fingers hold a cube."""
    return np.where(held_cube(states) > 0, 1.0, BETA_RUNNING)


def delivered(states: np.ndarray) -> np.ndarray:
    """``carry``'s termination: 1 with the held cube at its destination, or none held."""
    return np.where(delivered_now(states) | (held_cube(states) == 0), 1.0, BETA_RUNNING)


def released(states: np.ndarray) -> np.ndarray:
    """``release``'s termination: 1 with open fingers clear of both cubes."""
    return np.where(clear(states), 1.0, BETA_RUNNING)


def make_options() -> list[OptionSpec]:
    """``reach``, ``grasp``, ``carry``, ``release`` (the demonstrator's) and the
    distractor ``press``."""
    return [
        option_spec("reach", Reach(), termination=reached),
        option_spec("grasp", grasp, termination=grasped),
        option_spec("carry", carry, termination=delivered),
        option_spec("release", release, termination=released),
        option_spec("press", press, termination=BETA),
    ]


# ----- the demonstrator -----

DONE = {"reach": reached, "grasp": grasped, "carry": delivered, "release": released}
GIVE_UP = {"grasp": 10}
"""Steps after which the demonstrator gives up an option whose job is not done."""


class StackScript(Demonstrator):
    """Run each option until its job is done (its termination is 1) or it is given up
    (``GIVE_UP``), then choose the next from the state (see the module docstring)."""

    def __init__(self) -> None:
        self.current: str | None = None
        self.steps = 0

    def reset(self, observation: Any, rng: np.random.Generator) -> None:
        self.current, self.steps = None, 0

    def choose(self, observation: Any) -> str:
        states = np.asarray(observation, dtype=np.float64)[None]
        if self.current is not None:
            done = DONE[self.current](states)[0] == 1.0
            if not done and self.steps < GIVE_UP.get(self.current, MAX_STEPS):
                self.steps += 1
                return self.current
        name = self.pick(states)
        self.current, self.steps = name, 1
        return name

    @staticmethod
    def pick(states: np.ndarray) -> str:
        """The option to start in ``states`` ``(1, 13)``."""
        if held_cube(states)[0] > 0:
            return "release" if delivered_now(states)[0] else "carry"
        if at_cube(states)[0] and states[0, FINGERS] > OPEN:
            return "grasp"
        near = min(np.linalg.norm(states[0, CUBE1]), np.linalg.norm(states[0, CUBE2])) < CLEAR
        if near and states[0, FINGERS] < OPEN:
            return "release"  # a grasp that missed: open and back off first
        return "reach"


def make_demonstrator() -> Demonstrator:
    """The scripted stacking (:class:`StackScript`)."""
    return StackScript()


# ----- the disturbance -----

class BumpCube1(gym.Wrapper[Any, Any, Any, Any]):
    """Once per episode, at a random step in ``[20, 60]``, move cube 1 3 to 5 cm in a
    random horizontal direction (with cube 2 if it stands on it), unless the gripper
    holds it; the opposite direction if the cube would land on cube 2 or on the gripper,
    and no move if both would. Seeded from ``reset(seed=...)``."""

    def __init__(self, env: gym.Env[Any, Any]) -> None:
        super().__init__(env)
        self.rng = np.random.default_rng()
        self.steps = 0
        self.at = -1
        self.last: Any = None

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        self.steps = 0
        self.at = int(self.rng.integers(20, 61))
        self.last, info = self.env.reset(seed=seed, options=options)
        return self.last, info

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        if self.steps == self.at:
            self._bump(state_fn(self.last)[None])
        self.steps += 1
        self.last, reward, terminated, truncated, info = self.env.step(action)
        return self.last, reward, terminated, truncated, info

    def _bump(self, states: np.ndarray) -> None:
        angle = self.rng.uniform(0.0, 2.0 * np.pi)
        shift = self.rng.uniform(0.03, 0.05) * np.array([np.cos(angle), np.sin(angle), 0.0])
        if holds(states, 1)[0]:
            return
        cube2 = states[0, CUBE2] - states[0, CUBE1]  # from cube 1
        gripper = -states[0, CUBE1]
        on_top = bool(np.linalg.norm(cube2[:2]) < 0.02 and 0.0 < cube2[2] < 0.05
                      and not holds(states, 2)[0])
        moved = ("object1", "object2") if on_top else ("object1",)
        for move in (shift, -shift):
            lands_on_cube2 = not on_top and bool(np.all(np.abs((cube2 - move)[:2]) < 0.045))
            lands_on_gripper = bool(np.linalg.norm((gripper - move)[:2]) < 0.05
                                    and gripper[2] < 0.08)
            if not (lands_on_cube2 or lands_on_gripper):
                sim = self.env.unwrapped.sim  # type: ignore[attr-defined]
                for name in moved:
                    sim.set_base_pose(name, np.asarray(sim.get_base_position(name)) + move,
                                      np.asarray(sim.get_base_orientation(name)))
                return


def disturb(env: gym.Env[Any, Any]) -> gym.Env[Any, Any]:
    """The task's disturbance: :class:`BumpCube1`."""
    return BumpCube1(env)
