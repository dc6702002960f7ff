"""Chance constraints on imagined futures: the safety part of Eq. 1.

A :class:`SafetyConstraint` says which imagined steps of a rollout are unsafe. The
:class:`~dynoplan.planning.OptionPlanner` asks it at every model step of every rollout
(while the rollout is alive); an option whose share of unsafe rollouts exceeds the risk
level ``epsilon`` is not admissible now, and Eq. 1 chooses among the rest (with none left
the controller holds: the protective stop).

:class:`SeparationConstraint` is ISO/TS 15066 speed and separation monitoring on predicted
states: a step is unsafe when the robot moves and any of its points comes closer to the
person's predicted position than the protective separation distance ``S_p`` plus the
prediction's spread. The person's motion comes from a :class:`HumanMotionModel`;
:class:`ConstantVelocityHuman` is the documented default (constant velocity from the
measured one, spread growing with the distance the hand travels).
"""

from collections.abc import Callable
from typing import Protocol

import numpy as np

from dynoplan.safety.separation import (
    AT_REST_SPEED,
    SeparationParameters,
    protective_separation,
)
from dynoplan.types import BoolArray, FloatArray


class SafetyConstraint(Protocol):
    """Which imagined steps are unsafe.

    ``prepare(state)`` is called once per decision with the current planner state
    ``(d,)``; ``unsafe(before, after, step)`` with the states ``(..., d)`` before and after
    model step ``step`` (1 for the first step after the decision) returns ``(...)`` bool.
    """

    def prepare(self, state: FloatArray) -> None: ...

    def unsafe(self, before: FloatArray, after: FloatArray, step: int) -> BoolArray: ...


class HumanMotionModel(Protocol):
    """Where the person will be: ``prepare(state)`` once per decision, then
    ``predict(seconds) -> (mean (3,), spread (m))`` for a time ahead."""

    def prepare(self, state: FloatArray) -> None: ...

    def predict(self, seconds: float) -> tuple[FloatArray, float]: ...


class ConstantVelocityHuman:
    """The hand keeps its measured velocity; the prediction's spread grows with time.

    Args:
        position: ``position(state (d,)) -> (3,)``, the hand in the planner state.
        velocity: ``velocity() -> (3,)`` m/s, the hand's measured velocity now (a sensor
            reading, not part of the planner state).
        spread: the spread (m) of a prediction ``t`` seconds ahead is
            ``spread[0] + spread[1] * speed * t``: a hand at rest is predicted where it
            is (it rests most of the time, and then the prediction is exact); a moving
            hand's prediction widens with the distance it travels.
    """

    def __init__(self, position: Callable[[FloatArray], FloatArray],
                 velocity: Callable[[], FloatArray],
                 spread: tuple[float, float] = (0.05, 1.0)) -> None:
        if min(spread) < 0 or not np.all(np.isfinite(spread)):
            raise ValueError(f"spread must be finite and >= 0, got {spread}")
        self.position, self.velocity, self.spread = position, velocity, spread
        self._p = np.zeros(3)
        self._v = np.zeros(3)

    def prepare(self, state: FloatArray) -> None:
        self._p = np.asarray(self.position(state), dtype=np.float64).reshape(3)
        self._v = np.asarray(self.velocity(), dtype=np.float64).reshape(3)

    @property
    def speed(self) -> float:
        """m/s, the measured speed of the last :meth:`prepare`."""
        return float(np.linalg.norm(self._v))

    def predict(self, seconds: float) -> tuple[FloatArray, float]:
        return (self._p + self._v * seconds,
                self.spread[0] + self.spread[1] * self.speed * seconds)


class SeparationConstraint:
    """ISO/TS 15066 separation on predicted states (module docstring).

    Args:
        robot_points: ``robot_points(states (N, d)) -> (N, P, 3)``: points on the robot
            (the arm, not the tool point alone) in a planner state; row by row (a
            state's points do not depend on the other states of the batch), so the
            constraint reuses the points of states it has seen.
        human: where the person will be.
        step_seconds: seconds per model step.
        params: the constants of ``S_p``.
        spreads: how many prediction spreads are added to ``S_p``.
        lookahead: seconds ahead that are checked; later steps are not (a prediction
            of the person seconds ahead is mostly its spread, and the controller plans
            again long before: ``S_p`` itself covers the person's approach while the
            robot reacts and stops).
    """

    def __init__(self, robot_points: Callable[[FloatArray], FloatArray],
                 human: HumanMotionModel, step_seconds: float,
                 params: SeparationParameters = SeparationParameters(),
                 spreads: float = 1.0, lookahead: float = 1.0) -> None:
        if not step_seconds > 0:
            raise ValueError(f"step_seconds must be > 0, got {step_seconds}")
        if not lookahead >= 0:
            raise ValueError(f"lookahead must be >= 0, got {lookahead}")
        self.robot_points, self.human = robot_points, human
        self.step_seconds, self.params, self.spreads = step_seconds, params, spreads
        self.lookahead = lookahead
        # the robot's points of the decision's state (1, P, 3) and of the last ``after``
        # asked about: a rollout's next ``before`` is its last ``after``, and its first
        # ``before`` is the decision's state repeated
        self._state: tuple[FloatArray, FloatArray] | None = None
        self._last: tuple[FloatArray, FloatArray] | None = None

    def prepare(self, state: FloatArray) -> None:
        self.human.prepare(state)
        s = np.asarray(state, dtype=np.float64).reshape(-1)
        self._state = (s, self.robot_points(s[None, :]))
        self._last = None

    def unsafe(self, before: FloatArray, after: FloatArray, step: int) -> BoolArray:
        shape = after.shape[:-1]
        if (step - 1) * self.step_seconds >= self.lookahead:
            return np.zeros(shape, dtype=bool)
        d = after.shape[-1]
        p0, p1 = self._points(before.reshape(-1, d), after.reshape(-1, d))
        speed = np.linalg.norm(p1 - p0, axis=-1).max(axis=-1) / self.step_seconds  # (N,)
        hand, spread = self.human.predict(step * self.step_seconds)
        gap = np.linalg.norm(p1 - hand, axis=-1).min(axis=-1)  # (N,)
        human_speed = getattr(self.human, "speed", None)
        s_p = protective_separation(speed, human_speed, self.params) + self.spreads * spread
        out: BoolArray = ((speed >= AT_REST_SPEED) & (gap < s_p)).reshape(shape)
        return out

    def _points(self, before: FloatArray, after: FloatArray) -> tuple[FloatArray, FloatArray]:
        """``robot_points`` of ``before`` and ``after`` (N, d) in one call: the rows of
        ``before`` equal to the last ``after`` (or to the decision's state) reuse its
        points, so only the others (for example rollouts put back inside their
        continuation set) are computed. The points of a state do not depend on the other
        rows, so the answer is the same to the bit."""
        n = len(before)
        known: FloatArray | None
        points: FloatArray | None
        if self._last is not None and self._last[0].shape == before.shape:
            known, points = self._last
        elif self._state is not None:
            known = np.broadcast_to(self._state[0], before.shape)
            points = np.broadcast_to(self._state[1], (n, *self._state[1].shape[1:]))
        else:
            known = points = None
        changed = (np.ones(n, dtype=bool) if known is None
                   else (known != before).any(axis=1))  # NaN counts as changed
        k = int(changed.sum())
        fresh = self.robot_points(np.concatenate([before[changed], after]))
        p1 = fresh[k:]
        self._last = (after.copy(), p1)
        if k == n:
            return fresh[:k], p1
        assert points is not None
        if k == 0:
            return points, p1
        p0 = np.array(points)
        p0[changed] = fresh[:k]
        return p0, p1


__all__ = ["ConstantVelocityHuman", "HumanMotionModel", "SafetyConstraint",
           "SeparationConstraint"]
