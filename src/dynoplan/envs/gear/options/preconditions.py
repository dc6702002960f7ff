"""The gear options' own preconditions: conditions on planner states ``(N, 22) -> (N,)``.

Ten demonstrations cannot teach a mixture (Eq. 5) where the task's phases begin and end,
so each option also states where it may start (its initiation condition) and where it
may go on once running (its continuation condition); the controller intersects them
with the option's learned region (:mod:`dynoplan.envs.gear.controllers`):

- the two moves carry the gear: they go on while it is held (:func:`holding_gear`) and
  start only with the gear outside the insertion corridor above the peg
  (:class:`FarFromGoal`); the cautious move may also start nearer, with the hand near the
  tool (:func:`hand_near_tool`), and stands guard there;
- the pick has nothing to do once the gear is carried (:func:`not_carried`) and runs only
  with the hand clear of the tool (:func:`hand_clear_of_tool`);
- the insertion ignores the human: it starts only with the hand
  :data:`INSERT_START_CLEARANCE` from the tool (:func:`insert_may_start`) and goes on to
  :data:`INSERT_KEEP_CLEARANCE` (:func:`insert_may_go_on`).
"""

from typing import Any

import numpy as np

from dynoplan.envs.gear.scene import FINGER_TRAVEL, TABLE_TOP_Z
from dynoplan.envs.gear.state import STATE_SLICES, tool_human_distance
from dynoplan.types import BoolArray, FloatArray

HELD_GEAR_HEIGHT = 0.02
"""Gear bottom above the table (m) from which the gear counts as lifted."""
CARRIED_GEAR_HEIGHT = 0.10
"""Gear bottom above the table (m) from which the gear counts as carried: 0.1 m into the
pick's 0.25 m lift, below the gear seated on the peg (about 0.15 m) and every pose the
moves carry it through."""
PICK_CLEARANCE = 0.3
"""m: the pick (which plans and moves without regard to the human) runs only while the
human's hand is at least this far from the tool point; nearer, the robot holds still
until the hand has gone (the operator's rule for the insertion,
:data:`~dynoplan.envs.gear.operator.INSERT_CLEAR`)."""
INSERT_START_CLEARANCE = 0.55
"""m: the insertion (which ignores the human) starts only with the hand at least this far
from the tool; nearer, the cautious move stands guard at the goal and backs away if the
hand comes on. The tool point is a poor proxy of the arm: a hand crossing at the arm's
height touched the wrist with the tool point still 0.38 m away."""
INSERT_KEEP_CLEARANCE = INSERT_START_CLEARANCE - 0.05
"""m: a running insertion goes on while the hand is at least this far from the tool
(5 cm of hysteresis, so the two do not take turns at the threshold)."""
MOVE_START_DISTANCE = 0.05
"""m: a move may start only with the gear outside the insertion corridor: farther than
this from the pre-insertion pose sideways, or higher than this above it. Within it (and
anywhere below the pose, down onto the peg) the insertion has the gear; a move started
there would pull it back up off the peg (the goal heuristic scores the pre-insertion
pose above a half-done insertion, so the planner would choose that)."""


def holding_gear(states: FloatArray) -> BoolArray:
    """(N, 22) planner states -> (N,): the gripper closed and the gear lifted."""
    s = np.atleast_2d(states)
    closed = s[:, STATE_SLICES["gripper"].start] < 0.8 * FINGER_TRAVEL
    lifted = s[:, STATE_SLICES["gear_pos"].stop - 1] > TABLE_TOP_Z + HELD_GEAR_HEIGHT
    out: BoolArray = closed & lifted
    return out


def not_carried(states: FloatArray) -> BoolArray:
    """(N, 22) planner states -> (N,): the gear is not held :data:`CARRIED_GEAR_HEIGHT`
    above the table (where the pick has nothing left to do)."""
    s = np.atleast_2d(states)
    high = s[:, STATE_SLICES["gear_pos"].stop - 1] > TABLE_TOP_Z + CARRIED_GEAR_HEIGHT
    out: BoolArray = ~(holding_gear(s) & high)
    return out


def hand_clear_of_tool(states: FloatArray, distance: float = PICK_CLEARANCE) -> BoolArray:
    """(N, 22) planner states -> (N,): the hand at least ``distance`` (m) from the tool."""
    out: BoolArray = tool_human_distance(np.atleast_2d(states)) >= distance
    return out


def hand_near_tool(states: FloatArray, distance: float = INSERT_START_CLEARANCE) -> BoolArray:
    """(N, 22) planner states -> (N,): the hand nearer than ``distance`` (m) to the tool."""
    out: BoolArray = ~hand_clear_of_tool(states, distance)
    return out


def insert_may_start(states: FloatArray) -> BoolArray:
    """(N, 22) -> (N,): the hand at least :data:`INSERT_START_CLEARANCE` from the tool."""
    return hand_clear_of_tool(states, INSERT_START_CLEARANCE)


def insert_may_go_on(states: FloatArray) -> BoolArray:
    """(N, 22) -> (N,): the hand at least :data:`INSERT_KEEP_CLEARANCE` from the tool."""
    return hand_clear_of_tool(states, INSERT_KEEP_CLEARANCE)


class FarFromGoal:
    """Initiation of the moves: the gear outside the insertion corridor (more than
    ``distance`` (m) from the pre-insertion pose sideways, or more than ``distance``
    above it), ``(N, 22) -> (N,)``.

    The pre-insertion pose follows the peg (forward kinematics of the right arm, a
    private MuJoCo model built at the first call and cached)."""

    def __init__(self, distance: float = MOVE_START_DISTANCE) -> None:
        self.distance = distance
        self._goal: Any = None

    def contains(self, states: FloatArray) -> BoolArray:
        if self._goal is None:
            from dynoplan.envs.gear.options.moves import PreInsertionBeta

            self._goal = PreInsertionBeta()
        offset = self._goal.offset(states)
        sideways = np.hypot(offset[:, 0], offset[:, 1])
        out: BoolArray = (sideways > self.distance) | (offset[:, 2] > self.distance)
        return out


__all__ = [
    "CARRIED_GEAR_HEIGHT",
    "HELD_GEAR_HEIGHT",
    "INSERT_KEEP_CLEARANCE",
    "INSERT_START_CLEARANCE",
    "MOVE_START_DISTANCE",
    "PICK_CLEARANCE",
    "FarFromGoal",
    "hand_clear_of_tool",
    "hand_near_tool",
    "holding_gear",
    "insert_may_go_on",
    "insert_may_start",
    "not_carried",
]
