"""Time parameterisation of joint-space paths: a polyline followed with a trapezoidal
speed profile, one target per control step."""

import numpy as np

from dynoplan.types import FloatArray

MAX_LAG = 0.1
"""rad: a path waits while the arm lags its target by more than this on some joint
(something else held the arm: a protective stop), so that it resumes where the arm is
instead of jumping to where the path would have run meanwhile."""


def within_lag(target: FloatArray, measured: FloatArray) -> FloatArray:
    """``target`` (12,) moved to within :data:`MAX_LAG` of ``measured`` (12,) on every
    joint: where a motion that runs from its own last target should start again when
    something held the arm meanwhile."""
    out: FloatArray = np.clip(target, measured - MAX_LAG, measured + MAX_LAG)
    return out


class JointPath:
    """A joint-space polyline through ``waypoints`` (K, 12) followed at a joint speed,
    with a trapezoidal profile on its arc parameter ``s`` in ``[0, 1]``."""

    def __init__(self, waypoints: list[FloatArray], speed: float, accel_time: float) -> None:
        self.points = np.asarray(waypoints, dtype=np.float64)
        seg = np.max(np.abs(np.diff(self.points, axis=0)), axis=1) if len(self.points) > 1 \
            else np.zeros(0)
        self.cum = np.concatenate([[0.0], np.cumsum(seg)])
        self.length = float(self.cum[-1])
        self.sdot_max = speed / self.length if self.length > 1e-9 else np.inf
        self.accel = self.sdot_max / accel_time if self.length > 1e-9 else np.inf
        self.s = 0.0 if self.length > 1e-9 else 1.0
        self.sdot = 0.0

    def at(self, s: float) -> FloatArray:
        if self.length <= 1e-9:
            return self.points[-1].copy()
        d = float(np.clip(s, 0.0, 1.0)) * self.length
        k = int(np.clip(np.searchsorted(self.cum, d, side="right") - 1, 0, len(self.cum) - 2))
        span = self.cum[k + 1] - self.cum[k]
        w = 0.0 if span <= 0 else (d - self.cum[k]) / span
        out: FloatArray = self.points[k] + w * (self.points[k + 1] - self.points[k])
        return out

    def advance(self, dt: float, scale: float, measured: FloatArray | None = None) -> FloatArray:
        """Move along the path for ``dt`` at ``scale`` of full speed; the new target.
        ``measured`` (12,): the joint angles now; while they lag the current target by
        more than :data:`MAX_LAG` the path waits (at rest) and the target returned is
        the path's kept within :data:`MAX_LAG` of them (:func:`within_lag`), so that the
        arm, once let go, does not leap to it."""
        if measured is not None and self.length > 1e-9:
            here = self.at(self.s)
            if float(np.max(np.abs(here - measured))) > MAX_LAG:
                self.sdot = 0.0
                return within_lag(here, measured)
        if self.length > 1e-9:
            brake = np.sqrt(2.0 * self.accel * max(1.0 - self.s, 0.0))
            target = min(self.sdot_max * scale, brake)
            step = self.accel * dt
            self.sdot = float(np.clip(target, self.sdot - step, self.sdot + step))
            self.s = min(1.0, self.s + self.sdot * dt)
            if self.s >= 1.0 - 1e-9:
                self.s, self.sdot = 1.0, 0.0
        return self.at(self.s)

    def preview(self, tau: float, scale: float) -> FloatArray:
        """Where ``advance`` would be after ``tau`` s at ``scale`` of full speed (no ramp)."""
        return self.at(self.s + min(self.sdot_max * scale, 1e9) * tau)

    @property
    def finished(self) -> bool:
        return self.s >= 1.0


__all__ = ["MAX_LAG", "JointPath", "within_lag"]
