"""A fifth gear option, ``lift``: raise the held gear a few centimetres and hold it there.

Adding a gear option takes two steps (``docs/guide/adding-an-option.md``):

1. the policy: a :class:`~dynoplan.envs.gear.options.GearOptionPolicy` with ``reset``,
   ``act``, its termination ``beta`` and its own success test (the class below);
2. one registration: :func:`~dynoplan.envs.gear.options.register_gear_option` with where
   it may start and where its trials start (the last line).

Every stage then has the option: ``dynoplan gear option lift``, collection, a dynamics
model in ``models.json``, the controllers. Commands read it from this file when it is
named in ``DYNOPLAN_GEAR_OPTIONS``::

    DYNOPLAN_GEAR_OPTIONS=examples/gear_lift_option.py dynoplan gear option lift --trials 20
"""

from typing import Any

import numpy as np

from dynoplan.envs.gear.env import CONTROL_DT, GRIPPER_CLOSED, GearAssemblyEnv
from dynoplan.envs.gear.kinematics import ArmKinematics
from dynoplan.envs.gear.options import (
    GearOption,
    GearOptionPolicy,
    after_pick,
    register_gear_option,
    start_joints,
)
from dynoplan.envs.gear.options.preconditions import holding_gear
from dynoplan.envs.gear.scene import TABLE_TOP_Z
from dynoplan.envs.gear.state import STATE_SLICES
from dynoplan.envs.gear.trajectory import JointPath
from dynoplan.options import Termination, TerminationFromCallable
from dynoplan.types import BoolArray, FloatArray, Generator

LIFT_NAME = "lift"
"""The option's name, written here only: code elsewhere imports it."""
LIFT_Z = TABLE_TOP_Z + 0.33
"""m: the height the tool point is lifted to (the pick leaves it about 0.27 m above the
table)."""
TOOL_Z = STATE_SLICES["tool_pos"].stop - 1
"""The planner state's column of the tool point's height."""


def lifted(states: FloatArray) -> BoolArray:
    """(N, 22) planner states -> (N,): the tool point at the lift height (1 cm slack)."""
    out: BoolArray = np.atleast_2d(states)[:, TOOL_Z] >= LIFT_Z - 0.01
    return out


def may_lift(states: FloatArray) -> BoolArray:
    """(N, 22) -> (N,): where the lift may start: the gear held, not yet lifted."""
    out: BoolArray = holding_gear(states) & ~lifted(states)
    return out


class LiftPolicy(GearOptionPolicy):
    """Move the left tool point straight up to :data:`LIFT_Z` (inverse kinematics, then a
    joint-space path), keep the gripper closed, hold ``hold_time`` s, then be done."""

    name = LIFT_NAME

    def __init__(self, env: GearAssemblyEnv, speed: float = 0.5, hold_time: float = 0.5) -> None:
        super().__init__(env)
        self.kin = ArmKinematics()
        self.speed, self.hold_time = speed, hold_time
        self.path = JointPath([env.arm_targets], speed, accel_time=0.3)
        self.held = 0.0

    def reset(self, observation: Any, rng: Generator) -> None:
        q = start_joints(self.env, observation)
        position, rotation = self.kin.tool_pose(q)
        goal = self.kin.solve(q, np.array([*position[:2], max(position[2], LIFT_Z)]), rotation)
        self.status = "running" if goal.converged else "failed"
        self.path = JointPath([q, goal.q if goal.converged else q], self.speed, accel_time=0.3)
        self.held = 0.0

    def act(self, observation: Any) -> FloatArray:
        q = self.path.advance(CONTROL_DT, 1.0)
        if self.status == "running" and self.path.finished:
            self.held += CONTROL_DT
            if self.held >= self.hold_time:
                self.status = "done"
        return np.concatenate([q, [GRIPPER_CLOSED]])

    def termination(self) -> Termination:
        """``beta = 1`` once the tool point is at the lift height, else 0."""
        return TerminationFromCallable(lambda states: lifted(states).astype(np.float64))

    def succeeded(self, info: dict[str, Any]) -> bool:
        """The gear still held (both pads on it) with the tool point at the lift height."""
        position, _ = self.kin.tool_pose(self.env.arm_qpos)
        return int(info["pads_on_gear"]) >= 2 and position[2] >= LIFT_Z - 0.01


LIFT = register_gear_option(GearOption(LIFT_NAME, LiftPolicy, start=after_pick,
                                       initiation=may_lift))
