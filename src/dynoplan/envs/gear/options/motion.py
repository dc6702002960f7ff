"""Joint-space motion planning of the left arm with OMPL, checked by MuJoCo itself.

:class:`LeftArmPlanner` plans in the 6-D box of the left arm's joint limits (the right
arm stays where it is). A state is valid when :meth:`CollisionChecker.in_collision`
says the robot at that configuration penetrates nothing (table, itself, the peg module,
the gear unless it is held) and an optional extra test passes (for example a clearance
from the human). So the planner and the simulator agree on what a collision is.

OMPL's random generator is seeded once per process (:func:`seed_ompl`); plans are then
repeatable for the same sequence of planning calls. Independent episodes reseed it at
their start (:func:`reseed_ompl`), so an episode's plans do not depend on the episodes run
before it in the same process (serial and parallel runs agree). See
``docs/gear-options.md``.
"""

import itertools
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from dynoplan.envs.gear.collision import CollisionChecker
from dynoplan.envs.gear.env import GearAssemblyEnv
from dynoplan.errors import DynoplanError
from dynoplan.types import FloatArray

PLANNERS = ("RRTConnect", "RRTstar", "PRM", "KPIECE1", "BITstar")
CHECKS_PER_SECOND = 7000
"""Validity checks per second of search budget (this machine, unloaded: 145-170 us a
check). OMPL stops on a count of checks, not on a clock, so a plan is the same on a
loaded machine, in any worker."""
SIMPLIFY_SECONDS = 0.2
"""Path simplification budget, in seconds at :data:`CHECKS_PER_SECOND`."""
_seeded: list[int] = []


def seed_ompl(seed: int) -> None:
    """Seed OMPL's global generator; only the first call in a process takes effect
    (OMPL refuses to reseed once sampling has started), later calls are ignored."""
    from ompl import util as ou

    if not _seeded:
        # a plan that fails is reported by the option's status ("failed"); OMPL's own
        # error lines would only clutter the command line's output
        ou.setLogLevel(ou.LOG_NONE)
        ou.RNG.setSeed(int(seed) % (2**31 - 1) + 1)
        _seeded.append(seed)


def reseed_ompl(seed: int) -> None:
    """Seed OMPL's seed generator again: every planner created afterwards draws from
    ``seed`` alone, whatever was planned before in this process. Call it at the start of
    an independent episode. (OMPL logs that reseeding after sampling started is not
    deterministic; that holds only for generators that already exist, and planners here
    are created per plan, so the message is silenced.)"""
    from ompl import util as ou

    ou.setLogLevel(ou.LOG_NONE)  # as seed_ompl: failed plans show in the options' status
    ou.RNG.setSeed(int(seed) % (2**31 - 1) + 1)
    if not _seeded:
        _seeded.append(seed)


@dataclass(frozen=True)
class MotionPlan:
    """An OMPL result: ``path`` (K, 6) left-arm joints from start to goal (empty when not
    ``solved``), wall-clock ``plan_ms`` (planning plus simplification)."""

    path: FloatArray
    solved: bool
    plan_ms: float


class LeftArmPlanner:
    """Plans collision-free left-arm paths in the scene of ``env`` (one instance per env).

    Args:
        env: the environment whose model and live state (gear, human) are used.
        planner: an OMPL geometric planner name from :data:`PLANNERS`.
        time_limit: search budget per plan, in seconds at :data:`CHECKS_PER_SECOND`
            (counted in validity checks, not measured on a clock).
        resolution: motion-checking step as a fraction of the joint box's extent.
        margin: penetration (m) tolerated before a contact counts as a collision.
    """

    def __init__(self, env: GearAssemblyEnv, planner: str = "RRTConnect",
                 time_limit: float = 1.0, resolution: float = 0.004,
                 margin: float = 0.0) -> None:
        if planner not in PLANNERS:
            raise DynoplanError(f"unknown OMPL planner {planner!r}; expected one of {PLANNERS}")
        self.env = env
        self.checker: CollisionChecker = env.collision_checker()
        self.planner_name = planner
        self.time_limit = time_limit
        self.resolution = resolution
        self.margin = margin
        self.limits = env.joint_limits[:6].copy()
        self._low, self._high = self.limits[:, 0].copy(), self.limits[:, 1].copy()
        self._right = env.arm_qpos[6:]
        self._extra: Callable[[FloatArray], bool] | None = None
        self._checks = 0

    # -------------------------------------------------------------- validity
    def sync(self, carry_gear: bool) -> None:
        """Take the live scene (objects, human, right arm) from the env."""
        self.checker.sync(self.env.data, carry_gear=carry_gear)
        self._right = self.env.arm_qpos[6:]

    def full(self, q_left: FloatArray) -> FloatArray:
        """(6,) left-arm joints -> (12,) with the right arm as synced."""
        return np.concatenate([np.asarray(q_left, dtype=np.float64), self._right])

    def is_valid(self, q_left: FloatArray) -> bool:
        """The validity test OMPL uses, on (6,) left-arm joints."""
        self._checks += 1
        q = np.asarray(q_left, dtype=np.float64)
        if (q < self._low).any() or (q > self._high).any():
            return False
        full = self.full(q)
        if self.checker.in_collision(full, margin=self.margin):
            return False
        return self._extra is None or bool(self._extra(full))

    def path_is_valid(self, path: FloatArray, step: float = 0.01) -> bool:
        """Every waypoint and every point every ``step`` rad between them is valid."""
        path = np.atleast_2d(path)
        if len(path) == 0 or not self.is_valid(path[0]):
            return False
        for a, b in itertools.pairwise(path):
            n = max(2, int(np.ceil(np.max(np.abs(b - a)) / step)) + 1)
            for w in np.linspace(0.0, 1.0, n):
                if not self.is_valid(a + w * (b - a)):
                    return False
        return True

    # -------------------------------------------------------------- planning
    def plan(self, q_start: FloatArray, q_goal: FloatArray, *, carry_gear: bool,
             extra_valid: Callable[[FloatArray], bool] | None = None,
             sync: bool = True) -> MotionPlan:
        """Plan from ``q_start`` (12,) (its left arm) to ``q_goal`` (6,) left-arm joints.

        ``extra_valid(q12) -> bool`` adds a test (for example a human clearance) to
        this plan's validity checks, and to no later :meth:`is_valid` call (a caller's
        check after the plan, or in a later episode, is the scene's alone).
        An invalid goal fails the plan at once; an invalid start makes OMPL fail.
        """
        self._extra = extra_valid
        try:
            return self._plan(q_start, q_goal, carry_gear, sync)
        finally:
            self._extra = None

    def _plan(self, q_start: FloatArray, q_goal: FloatArray, carry_gear: bool,
              sync: bool) -> MotionPlan:
        from ompl import base as ob
        from ompl import geometric as og

        seed_ompl(0)
        if sync:
            self.sync(carry_gear)
        t0 = time.perf_counter()
        start = np.clip(np.asarray(q_start, dtype=np.float64)[:6], self.limits[:, 0],
                        self.limits[:, 1])
        goal = np.clip(np.asarray(q_goal, dtype=np.float64)[:6], self.limits[:, 0],
                       self.limits[:, 1])
        if not self.is_valid(goal):
            return MotionPlan(np.zeros((0, 6)), False, 1e3 * (time.perf_counter() - t0))
        space = ob.RealVectorStateSpace(6)
        bounds = ob.RealVectorBounds(6)
        for i, (lo, hi) in enumerate(self.limits):
            bounds.setLow(i, float(lo))
            bounds.setHigh(i, float(hi))
        space.setBounds(bounds)
        setup = og.SimpleSetup(space)
        setup.setStateValidityChecker(
            lambda s: self.is_valid(np.array([s[i] for i in range(6)])))
        info = setup.getSpaceInformation()
        info.setStateValidityCheckingResolution(self.resolution)
        s_state, g_state = space.allocState(), space.allocState()
        for i in range(6):
            s_state[i] = float(start[i])
            g_state[i] = float(goal[i])
        setup.setStartAndGoalStates(s_state, g_state)
        setup.setPlanner(getattr(og, self.planner_name)(info))
        status = setup.solve(self._budget(self.time_limit))
        if not bool(status) or not setup.haveExactSolutionPath():
            return MotionPlan(np.zeros((0, 6)), False, 1e3 * (time.perf_counter() - t0))
        setup.simplifySolution(self._budget(SIMPLIFY_SECONDS))
        path = setup.getSolutionPath()
        waypoints = np.array([[path.getState(k)[i] for i in range(6)]
                              for k in range(path.getStateCount())])
        waypoints[0], waypoints[-1] = start, goal
        return MotionPlan(waypoints, True, 1e3 * (time.perf_counter() - t0))

    def _budget(self, seconds: float) -> Any:
        """An OMPL termination condition: ``seconds`` worth of validity checks from now."""
        from ompl import base as ob

        stop = self._checks + max(1, round(seconds * CHECKS_PER_SECOND))
        return ob.PlannerTerminationCondition(lambda: self._checks >= stop)


__all__ = ["CHECKS_PER_SECOND", "PLANNERS", "SIMPLIFY_SECONDS", "LeftArmPlanner", "MotionPlan",
           "reseed_ompl", "seed_ompl"]
