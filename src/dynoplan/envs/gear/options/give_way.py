"""The give-way option: back the left arm away from a hand that has come to it.

With the safe choice (``docs/safety.md``) the controller's only answer to a hand that
comes at the arm was to hold it where it is. ``give_way`` gives it somewhere to go:

- **policy** (:class:`GiveWayPolicy`): the cautious move's retreat
  (:meth:`~dynoplan.envs.gear.options.moves.CautiousMovePolicy._retreat`: the candidate
  joint motion with the largest predicted clearance from the hand, re-solved every
  ``retreat_refresh`` s), run as an option of its own; the gripper stays as it is (a held
  gear stays held);
- **termination**: the policy is done when the hand is :data:`GIVE_WAY_CLEARANCE` clear
  of the left arm and at rest (:data:`HAND_AT_REST`), or after :data:`GIVE_WAY_TIME` s;
  ``beta`` on planner states is 1 where the hand is that far from the left arm;
- **starts** (:func:`hand_at_arm`): the gear picked, then a blocking hand that comes
  within :data:`GIVE_WAY_NEAR` of the left arm (the option's transitions and outcome
  runs start there);
- **demonstrations**: the operator (:mod:`~dynoplan.envs.gear.operator`) gives way when,
  in a seen behaviour, the hand comes within :data:`GIVE_WAY_NEAR` of the left arm, so
  that the option has its own Eq. 5 region.

:data:`GIVE_WAY` is the option's registry record; it is registered by importing
:mod:`dynoplan.envs.gear.options.give_way_option` (for example through
``DYNOPLAN_GEAR_OPTIONS``).
"""

from typing import Any

import numpy as np

from dynoplan.envs.gear.arm_points import POINTS_PER_ARM, arm_points
from dynoplan.envs.gear.env import CONTROL_DT, GRIPPER_CLOSED, OBS_SLICES, GearAssemblyEnv
from dynoplan.envs.gear.options.base import gripper_as_it_is, start_joints
from dynoplan.envs.gear.options.moves import CautiousConfig, CautiousMovePolicy
from dynoplan.envs.gear.options.preconditions import holding_gear
from dynoplan.envs.gear.options.registry import GearOption
from dynoplan.envs.gear.options.starts import StartConfig, after_pick, shifted_schedule
from dynoplan.envs.gear.state import STATE_SLICES, PlannerState
from dynoplan.options.termination import Termination, TerminationFromCallable
from dynoplan.types import FloatArray, Generator

GIVE_WAY_NAME = "give_way"
"""The option's name (its registry record, datasets, model files, the command line)."""
GIVE_WAY_CLEARANCE = 0.3
"""m: the hand this far from the left arm (:func:`left_arm_hand_distance`) ends the
give-way (``beta = 1``)."""
GIVE_WAY_NEAR = 0.25
"""m: a hand this close to the left arm is where the operator gives way, and where the
option's own runs start."""
HAND_AT_REST = 0.05
"""m/s: the hand's measured speed below which it is at rest."""
GIVE_WAY_TIME = 3.0
"""s: the give-way ends after this long, whatever the hand does."""
START_WAIT = 8.0
"""s: how long :func:`hand_at_arm` waits for the blocking hand to come to the arm."""

_LEFT = [*range(POINTS_PER_ARM), 2 * POINTS_PER_ARM]  # the left arm's points, the tool point


def left_arm_hand_distance(states: FloatArray) -> FloatArray:
    """(N,) distance (m) from the hand to the nearest point of the left arm (shoulder,
    elbow, wrist, points along the segments, the tool point; :func:`arm_points`) in
    planner states (N, 22)."""
    s = np.atleast_2d(np.asarray(states, dtype=np.float64))
    points = arm_points(s)[:, _LEFT]
    hand = s[:, None, STATE_SLICES["human_pos"]]
    out: FloatArray = np.linalg.norm(points - hand, axis=2).min(axis=1)
    return out


class GiveWayPolicy(CautiousMovePolicy):
    """Back the left arm away from the hand (the cautious move's retreat) with the
    gripper as it is, until the hand is ``clearance`` clear of the left arm and at rest,
    or for ``max_time`` s (status ``"done"`` either way; :meth:`succeeded` tells them
    apart).

    Args:
        env: the environment (its live scene is the retreat's world model).
        config: the cautious move's settings (the retreat's speed, refresh and horizon).
        clearance, max_time: :data:`GIVE_WAY_CLEARANCE`, :data:`GIVE_WAY_TIME`.
    """

    name = GIVE_WAY_NAME

    def __init__(self, env: GearAssemblyEnv, config: CautiousConfig | None = None,
                 clearance: float = GIVE_WAY_CLEARANCE, max_time: float = GIVE_WAY_TIME) -> None:
        super().__init__(env, config)
        self.clearance, self.max_time = clearance, max_time
        self.state_fn = PlannerState()
        self.gripper = GRIPPER_CLOSED
        self.held_gear = False
        self.cleared = False

    def reset(self, observation: Any, rng: Generator) -> None:
        obs = np.asarray(observation, dtype=np.float64)
        self.plan_ms = []
        self.status = "running"
        self.time = 0.0
        self.q_cmd = start_joints(self.env, obs)
        self.path = None
        self._retreat_goals = []
        self._retreat_since = -np.inf
        self.mode = "idle"
        self.gripper = gripper_as_it_is(obs)
        self.held_gear = bool(holding_gear(self.state_fn(obs)[None])[0])
        self.carry_gear = self.held_gear
        self.cleared = False
        self._observe(obs)

    def act(self, observation: Any) -> np.ndarray:
        obs = np.asarray(observation, dtype=np.float64)
        self.time += self.dt
        if self.status == "running":
            self._observe(obs)
            self.cleared = self._clear(obs)
            if self.cleared or self.time >= self.max_time:
                self.status = "done"
            else:
                self._retreat(obs)
        return np.concatenate([self.q_cmd, [self.gripper]])

    def _clear(self, obs: FloatArray) -> bool:
        """The hand :attr:`clearance` from the left arm and at rest in ``obs`` (50,)."""
        distance = float(left_arm_hand_distance(self.state_fn(obs)[None])[0])
        speed = float(np.linalg.norm(obs[OBS_SLICES["human_vel"]]))
        return distance >= self.clearance and speed < HAND_AT_REST

    def termination(self) -> Termination:
        """``beta = 1`` where the hand is :attr:`clearance` from the left arm, else 0."""
        clearance = self.clearance
        return TerminationFromCallable(
            lambda states: (left_arm_hand_distance(states) >= clearance).astype(np.float64))

    def succeeded(self, info: dict[str, Any]) -> bool:
        """It ended with the hand clear and at rest, and a gear it held is still held."""
        return self.cleared and (not self.held_gear or int(info["pads_on_gear"]) >= 2)


def hand_at_arm(env: GearAssemblyEnv, rng: Generator, config: StartConfig) -> bool:
    """Start with the gear picked (:func:`after_pick`) and a blocking hand
    (:func:`shifted_schedule`, its first event within 0.5 s) come within
    :data:`GIVE_WAY_NEAR` of the left arm, the arm held meanwhile; ``False`` if the hand
    does not come that close within :data:`START_WAIT` s."""
    if not after_pick(env, rng, config):
        return False
    obs, _ = env.set_human_schedule(shifted_schedule(env, "block", rng, (0.0, 0.5)))
    state_fn = PlannerState()
    action = np.concatenate([env.arm_targets, [GRIPPER_CLOSED]])
    for _ in range(round(START_WAIT / CONTROL_DT)):
        if float(left_arm_hand_distance(state_fn(obs)[None])[0]) < GIVE_WAY_NEAR:
            return True
        obs, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            return False
    return False


GIVE_WAY = GearOption(GIVE_WAY_NAME, GiveWayPolicy, start=hand_at_arm, human_mode="block",
                      color="#d62728", start_sets_human=True)
"""The give-way option's record (no hand-written initiation: where it may start is
learned, its Eq. 5 region and its outcomes)."""


__all__ = ["GIVE_WAY", "GIVE_WAY_CLEARANCE", "GIVE_WAY_NAME", "GIVE_WAY_NEAR", "GIVE_WAY_TIME",
           "HAND_AT_REST", "GiveWayPolicy", "hand_at_arm", "left_arm_hand_distance"]
