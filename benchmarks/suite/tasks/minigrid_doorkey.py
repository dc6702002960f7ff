"""MiniGrid's DoorKey, 6x6: fetch the key, unlock the door, walk to the goal.

The task is ``MiniGrid-DoorKey-6x6-v0`` of the ``minigrid`` package (Farama): a 6x6
grid (a 4x4 floor inside walls) split by a wall at a random column, with a locked yellow
door at a random row of it. The agent and a yellow key start at random cells left of the
wall, the green goal is the bottom-right floor cell (4, 4). The actions are
``Discrete(7)``: turn left, turn right, forward, pick up, drop, toggle, done (a no-op).
Stepping onto the goal terminates the episode (``success = None``: success is
``terminated``). The only way there is through the door, which only opens (toggle) to
an agent that carries the key: every option alone fails, the task needs all of them, in
order.

**Environment and state.** The package's observation is a ``Dict`` (a 7x7x3 egocentric
image, the direction, the mission text). This module registers :data:`ENV_ID`: the
same ``DoorKeyEnv(size=6)`` with the package's own ``FullyObsWrapper`` (the
``"image"`` entry becomes the whole 6x6 grid encoded as (object, colour, state) per
cell, the agent drawn over its cell) and a step limit of :data:`STEP_LIMIT` steps (the
package's default is 360). :func:`state_fn` reads the planner state from that image, 13
values:

========  ===============================================================
0:2       agent cell (x, y)
2:4       agent heading as a unit vector (dx, dy); y grows downwards
4         1 if the agent carries the key
5:7       key cell (the agent's cell while it is carried)
7:9       door cell
9         1 if the door is open
10        1 if the door is locked
11:13     goal cell
========  ===============================================================

The agent is drawn over the cell it stands on, so a door or goal missing from the
image is under the agent (it can only stand on an open door or on the goal), and a
missing key is carried.

**Options** (plain functions of that state; the layout, outer walls plus the wall
through the door's column, is known from the state). Navigation is a breadth-first
search over (cell, heading) with the three motion actions:

- ``go_to_key``: to a cell next to the key, facing it; ends facing it (or carrying it);
- ``pick_up``: pick up; ends when carrying the key, or when the key is not in front;
- ``go_to_door``: to a cell next to the door, facing it; ends facing it;
- ``open_door``: toggle; ends when the door is open, when it is not in front, or when
  it is locked and the agent has no key;
- ``go_to_goal``: onto the goal; ends there, or when the door is not open (no way);
- ``drop_key`` (the distractor, never demonstrated): drop what is carried; ends when
  nothing is carried or the cell in front is not free floor.

Navigation with no path (the door in the way) takes the no-op ``done`` action.

**Demonstrator** (:class:`DoorKeyDemonstrator`), reactive on the state at every step:
door open (and the goal reachable): ``go_to_goal``; carrying the key or the door closed
but unlocked: ``go_to_door``, then ``open_door`` when facing the door; otherwise
``go_to_key``, then ``pick_up`` when facing the key (also when a dropped key blocks the
one-cell-wide way to the goal).

**Disturbance** (:class:`Slippery`): the floor is slippery: each action is replaced,
with probability :data:`SLIP`, by a uniformly random one of the seven (a drop of the
key, a toggle that closes the door again, a turn), from a generator seeded by the seed
of ``reset``.
"""

from collections import deque
from typing import Any

import gymnasium as gym
import numpy as np
from minigrid.core.constants import OBJECT_TO_IDX
from minigrid.envs.doorkey import DoorKeyEnv
from minigrid.wrappers import FullyObsWrapper

from dynoplan.adapters import OptionSpec, option_spec
from dynoplan.pipeline import Demonstrator

ENV_ID = "MiniGridDoorKeyFullObs-6x6-v0"
SIZE = 6
"""Grid width and height, walls included (the floor is cells 1..4)."""
STEP_LIMIT = 100
"""Steps before an episode is cut (the package's default for 6x6 is 360)."""
SLIP = 0.1
"""Probability per step that the disturbance replaces the action by a random one."""
DISTURBANCE = f"slippery floor: each action replaced by a random one with probability {SLIP}"

LEFT, RIGHT, FORWARD, PICKUP, DROP, TOGGLE, DONE = range(7)
DIRECTIONS = ((1, 0), (0, 1), (-1, 0), (0, -1))
"""MiniGrid's headings 0..3 as (dx, dy): right, down, left, up."""

AGENT, HEADING, CARRYING, KEY, DOOR, DOOR_OPEN, DOOR_LOCKED, GOAL = (
    slice(0, 2), slice(2, 4), 4, slice(5, 7), slice(7, 9), 9, 10, slice(11, 13))
STATE_DIM = 13

Cell = tuple[int, int]


def make_env(**kwargs: Any) -> gym.Env[Any, Any]:
    """``DoorKeyEnv(size=6)`` with a :data:`STEP_LIMIT` step limit, fully observed."""
    return FullyObsWrapper(DoorKeyEnv(size=SIZE, max_steps=STEP_LIMIT, **kwargs))


if ENV_ID not in gym.registry:
    gym.register(ENV_ID, entry_point=make_env, max_episode_steps=STEP_LIMIT)


# --- the planner state ---------------------------------------------------------------------


def _find(image: np.ndarray, kind: str) -> Cell | None:
    cells = np.argwhere(image[:, :, 0] == OBJECT_TO_IDX[kind])
    return None if len(cells) == 0 else (int(cells[0][0]), int(cells[0][1]))


def state_fn(observation: dict[str, Any]) -> np.ndarray:
    """The 13 values of the module docstring, from the fully observed ``"image"``."""
    image = np.asarray(observation["image"])
    found = _find(image, "agent")
    agent = found or (0, 0)  # (0, 0): an image without an agent (a sampled observation)
    heading = 0 if found is None else int(image[found][2]) % 4
    key = _find(image, "key")
    door_cell = _find(image, "door")
    door_state = 0 if door_cell is None else int(image[door_cell][2])  # 0 open, 1, 2 locked
    goal = _find(image, "goal") or agent
    return np.array([*agent, *DIRECTIONS[heading], float(key is None), *(key or agent),
                     *(door_cell or agent), float(door_state == 0), float(door_state == 2),
                     *goal], dtype=np.float64)


# --- what the options know of the layout ---------------------------------------------------


def _cell(values: np.ndarray) -> Cell:
    return round(float(values[0])), round(float(values[1]))


def _free(state: np.ndarray, cell: Cell, goal_ok: bool) -> bool:
    """Whether the agent may stand on ``cell``: floor, not the key, the door only when
    open, the goal only when ``goal_ok``."""
    x, y = cell
    if not (1 <= x <= SIZE - 2 and 1 <= y <= SIZE - 2):
        return False
    door = _cell(state[DOOR])
    if x == door[0]:
        return cell == door and state[DOOR_OPEN] > 0.5
    if state[CARRYING] < 0.5 and cell == _cell(state[KEY]):
        return False
    return goal_ok or cell != _cell(state[GOAL])


def _heading(state: np.ndarray) -> int:
    dx, dy = (round(float(v)) for v in state[HEADING])
    return DIRECTIONS.index((dx, dy)) if (dx, dy) in DIRECTIONS else 0


def navigate(state: np.ndarray, target: Cell, onto: bool) -> int:
    """The first action of a shortest path (turns and steps) that ends on ``target``
    (``onto``) or next to it facing it; :data:`DONE` (a no-op) when there is none or the
    agent is there already."""
    action = first_action(state, target, onto)
    return DONE if action is None else action


def first_action(state: np.ndarray, target: Cell, onto: bool) -> int | None:
    """As :func:`navigate`; ``None`` when no path leads there."""
    start = (*_cell(state[AGENT]), _heading(state))

    def arrived(pose: tuple[int, int, int]) -> bool:
        x, y, d = pose
        dx, dy = DIRECTIONS[d]
        return (x, y) == target if onto else (x + dx, y + dy) == target

    if arrived(start):
        return DONE
    first: dict[tuple[int, int, int], int] = {start: DONE}
    queue = deque([start])
    while queue:
        pose = queue.popleft()
        x, y, d = pose
        dx, dy = DIRECTIONS[d]
        moves = [(LEFT, (x, y, (d - 1) % 4)), (RIGHT, (x, y, (d + 1) % 4))]
        if _free(state, (x + dx, y + dy), goal_ok=onto):
            moves.append((FORWARD, (x + dx, y + dy, d)))
        for action, nxt in moves:
            if nxt in first:
                continue
            first[nxt] = action if pose == start else first[pose]
            if arrived(nxt):
                return first[nxt]
            queue.append(nxt)
    return None


# --- batched tests on states (B, 13) --------------------------------------------------------


def _front(states: np.ndarray) -> np.ndarray:
    return np.rint(states[:, AGENT] + states[:, HEADING])


def facing_key(states: np.ndarray) -> np.ndarray:
    """The key lies in the cell in front of the agent."""
    s = np.atleast_2d(states)
    return (s[:, CARRYING] < 0.5) & np.all(_front(s) == np.rint(s[:, KEY]), axis=1)


def facing_door(states: np.ndarray) -> np.ndarray:
    """The door is the cell in front of the agent."""
    s = np.atleast_2d(states)
    return np.all(_front(s) == np.rint(s[:, DOOR]), axis=1)


def carrying(states: np.ndarray) -> np.ndarray:
    return np.atleast_2d(states)[:, CARRYING] > 0.5


def door_open(states: np.ndarray) -> np.ndarray:
    return np.atleast_2d(states)[:, DOOR_OPEN] > 0.5


def at_goal(states: np.ndarray) -> np.ndarray:
    s = np.atleast_2d(states)
    return np.all(np.rint(s[:, AGENT]) == np.rint(s[:, GOAL]), axis=1)


def front_free(states: np.ndarray) -> np.ndarray:
    """The cell in front is empty floor (where a carried key can be dropped)."""
    s = np.atleast_2d(states)
    front = _front(s)
    inside = np.all((front >= 1) & (front <= SIZE - 2), axis=1)
    on_wall = front[:, 0] == np.rint(s[:, DOOR][:, 0])
    key_there = (s[:, CARRYING] < 0.5) & np.all(front == np.rint(s[:, KEY]), axis=1)
    goal_there = np.all(front == np.rint(s[:, GOAL]), axis=1)
    return inside & ~on_wall & ~key_there & ~goal_there


# --- the options ----------------------------------------------------------------------------


def go_to_key(state: np.ndarray) -> int:
    return navigate(state, _cell(state[KEY]), onto=False)


def pick_up(state: np.ndarray) -> int:
    return PICKUP


def go_to_door(state: np.ndarray) -> int:
    return navigate(state, _cell(state[DOOR]), onto=False)


def open_door(state: np.ndarray) -> int:
    return TOGGLE


def go_to_goal(state: np.ndarray) -> int:
    return navigate(state, _cell(state[GOAL]), onto=True)


def drop_key(state: np.ndarray) -> int:
    return DROP


def go_to_key_done(states: np.ndarray) -> np.ndarray:
    return facing_key(states) | carrying(states)


def pick_up_done(states: np.ndarray) -> np.ndarray:
    return carrying(states) | ~facing_key(states)


def go_to_door_done(states: np.ndarray) -> np.ndarray:
    return facing_door(states)


def open_door_done(states: np.ndarray) -> np.ndarray:
    locked = np.atleast_2d(states)[:, DOOR_LOCKED] > 0.5
    return door_open(states) | ~facing_door(states) | (locked & ~carrying(states))


def go_to_goal_done(states: np.ndarray) -> np.ndarray:
    return at_goal(states) | ~door_open(states)


def drop_key_done(states: np.ndarray) -> np.ndarray:
    return ~carrying(states) | ~front_free(states)


def make_options() -> list[OptionSpec]:
    """The five options of the task and the distractor ``drop_key`` (module docstring)."""
    return [
        option_spec("go_to_key", go_to_key, termination=go_to_key_done),
        option_spec("pick_up", pick_up, termination=pick_up_done),
        option_spec("go_to_door", go_to_door, termination=go_to_door_done),
        option_spec("open_door", open_door, termination=open_door_done),
        option_spec("go_to_goal", go_to_goal, termination=go_to_goal_done),
        option_spec("drop_key", drop_key, termination=drop_key_done),
    ]


class DoorKeyDemonstrator(Demonstrator):
    """Key, door, goal: the option that the state calls for, at every step."""

    def choose(self, observation: Any) -> str:
        s = np.asarray(observation, dtype=np.float64)[None]
        goal = _cell(s[0, GOAL])
        if door_open(s)[0] and (carrying(s)[0] or first_action(s[0], goal, onto=True)
                                is not None):
            return "go_to_goal"
        if not door_open(s)[0] and (carrying(s)[0] or s[0, DOOR_LOCKED] < 0.5):
            return "open_door" if facing_door(s)[0] else "go_to_door"
        return "pick_up" if facing_key(s)[0] else "go_to_key"


def make_demonstrator() -> Demonstrator:
    return DoorKeyDemonstrator()


success = None
"""The environment's own: ``terminated`` (only reaching the goal terminates)."""


class Slippery(gym.Wrapper[Any, Any, Any, Any]):
    """Each action replaced, with probability ``slip``, by a uniformly random action of
    the (discrete) action space; the draws are seeded by the seed of ``reset``."""

    def __init__(self, env: gym.Env[Any, Any], slip: float = SLIP) -> None:
        super().__init__(env)
        self.slip = slip
        self.rng = np.random.default_rng()

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        seed = kwargs.get("seed")
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        return self.env.reset(**kwargs)

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        if self.rng.random() < self.slip:
            action = int(self.rng.integers(int(self.action_space.n)))  # type: ignore[attr-defined]
        return self.env.step(action)


def disturb(env: gym.Env[Any, Any]) -> gym.Env[Any, Any]:
    """The slippery floor (:class:`Slippery`)."""
    return Slippery(env)
