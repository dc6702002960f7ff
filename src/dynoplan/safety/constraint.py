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
measured one, spread growing linearly with the time ahead).
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
            ``spread[0] + spread[1] * t``.
    """

    def __init__(self, position: Callable[[FloatArray], FloatArray],
                 velocity: Callable[[], FloatArray],
                 spread: tuple[float, float] = (0.02, 0.3)) -> None:
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
        return self._p + self._v * seconds, self.spread[0] + self.spread[1] * seconds


class SeparationConstraint:
    """ISO/TS 15066 separation on predicted states (module docstring).

    Args:
        robot_points: ``robot_points(states (N, d)) -> (N, P, 3)``: points on the robot
            (the arm, not the tool point alone) in a planner state.
        human: where the person will be.
        step_seconds: seconds per model step.
        params: the constants of ``S_p``.
        spreads: how many prediction spreads are added to ``S_p``.
    """

    def __init__(self, robot_points: Callable[[FloatArray], FloatArray],
                 human: HumanMotionModel, step_seconds: float,
                 params: SeparationParameters = SeparationParameters(),
                 spreads: float = 1.0) -> None:
        if not step_seconds > 0:
            raise ValueError(f"step_seconds must be > 0, got {step_seconds}")
        self.robot_points, self.human = robot_points, human
        self.step_seconds, self.params, self.spreads = step_seconds, params, spreads

    def prepare(self, state: FloatArray) -> None:
        self.human.prepare(state)

    def unsafe(self, before: FloatArray, after: FloatArray, step: int) -> BoolArray:
        shape = after.shape[:-1]
        d = after.shape[-1]
        p0 = self.robot_points(before.reshape(-1, d))
        p1 = self.robot_points(after.reshape(-1, d))
        speed = np.linalg.norm(p1 - p0, axis=-1).max(axis=-1) / self.step_seconds  # (N,)
        hand, spread = self.human.predict(step * self.step_seconds)
        gap = np.linalg.norm(p1 - hand, axis=-1).min(axis=-1)  # (N,)
        human_speed = getattr(self.human, "speed", None)
        s_p = protective_separation(speed, human_speed, self.params) + self.spreads * spread
        out: BoolArray = ((speed >= AT_REST_SPEED) & (gap < s_p)).reshape(shape)
        return out


__all__ = ["ConstantVelocityHuman", "HumanMotionModel", "SafetyConstraint",
           "SeparationConstraint"]
