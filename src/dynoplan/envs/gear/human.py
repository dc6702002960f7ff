"""The human operator: a forearm and hand that move on a seeded, piecewise-linear schedule.

The operator stands across the table (shoulder near ``x = 1.6``). Its hand rests at
``REST`` (outside the robot's reach) and, on a random schedule, does up to two events:

- ``cross``: the hand sweeps across the workspace above the table, from the robot's left
  to its right or back, at a height above the right hand and the peg;
- ``block``: the hand moves to a point on the line between the gear and the peg (the
  left arm's path to the right hand), stays there for a while, then goes back.

Between events the hand rests. Speeds are drawn per event. The schedule is a list of
keyframes; the pose at any time is known in advance, so a privileged expert (or a
planner using the simulator as its model) can predict where the hand will be.
The forearm points from the hand towards the operator's shoulder.
"""

from dataclasses import dataclass

import numpy as np

from dynoplan.types import FloatArray, Generator

REST = np.array([1.25, 0.35, 0.95])
SHOULDER_X = 1.6
SHOULDER_Z = 1.3

HUMAN_MODES = ("away", "cross", "block")
"""Episode kinds: no event, at least one crossing, at least one blocking event."""

SPEED_RANGE = (0.2, 0.6)  # m/s, per event
CROSS_X_RANGE = (0.6, 0.85)
CROSS_Z_RANGE = (1.03, 1.12)
CROSS_Y_ENDS = (0.6, -0.45)  # the sweep runs between these two y values
BLOCK_FRACTION_RANGE = (0.25, 0.55)  # where on the gear -> peg line, from the gear
BLOCK_Z_RANGE = (0.9, 1.02)
BLOCK_DWELL_RANGE = (1.5, 4.0)  # s
FIRST_EVENT_RANGE = (0.5, 8.0)  # s, start of the first event
GAP_RANGE = (1.0, 4.0)  # s of rest between two events


@dataclass(frozen=True)
class HumanSchedule:
    """Keyframes of the hand: ``times`` (K,) increasing, ``positions`` (K, 3).

    ``events`` names the events in order (``"cross"`` or ``"block"``); ``shoulder``
    (3,) is the point the forearm points at.
    """

    times: FloatArray
    positions: FloatArray
    shoulder: FloatArray
    events: tuple[str, ...]

    @property
    def mode(self) -> str:
        """``"away"`` with no event, else the kind of the first event."""
        return self.events[0] if self.events else "away"

    def position(self, t: float | FloatArray) -> FloatArray:
        """Hand position at time(s) ``t``: (3,) for a scalar, (N, 3) for (N,) times."""
        t_arr = np.atleast_1d(np.asarray(t, dtype=np.float64))
        out = np.stack([np.interp(t_arr, self.times, self.positions[:, i]) for i in range(3)],
                       axis=-1)
        return out[0] if np.ndim(t) == 0 else out

    def velocity(self, t: float) -> FloatArray:
        """(3,) hand velocity at time ``t`` (right derivative)."""
        k = int(np.searchsorted(self.times, t, side="right"))
        if k <= 0 or k >= len(self.times):
            return np.zeros(3)
        dt = self.times[k] - self.times[k - 1]
        return (self.positions[k] - self.positions[k - 1]) / dt

    def quaternion(self, position: FloatArray) -> FloatArray:
        """``wxyz`` orientation of the hand at ``position`` ((3,) -> (4,), (N, 3) -> (N, 4)):
        its ``x`` axis (the forearm's direction) points at the shoulder."""
        return forearm_quaternion(position, self.shoulder)


def forearm_quaternion(position: FloatArray, shoulder: FloatArray) -> FloatArray:
    """``wxyz`` rotation(s) whose ``x`` axis points from ``position`` to ``shoulder``, with
    the ``y`` axis horizontal: (4,) for a (3,) position, (N, 4) for (N, 3) positions."""
    x = shoulder - np.asarray(position, dtype=np.float64)
    x = x / np.linalg.norm(x, axis=-1, keepdims=True)
    yaw = np.arctan2(x[..., 1], x[..., 0])
    pitch = -np.arcsin(np.clip(x[..., 2], -1.0, 1.0))
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    # q = q_z(yaw) * q_y(pitch)
    out: FloatArray = np.stack([cy * cp, -sy * sp, cy * sp, sy * cp], axis=-1)
    return out


def _move(times: list[float], points: list[FloatArray], target: FloatArray,
          speed: float) -> None:
    """Append a straight move from the last keyframe to ``target`` at ``speed``."""
    dist = float(np.linalg.norm(target - points[-1]))
    times.append(times[-1] + max(dist / speed, 1e-3))
    points.append(np.asarray(target, dtype=np.float64))


def _hold(times: list[float], points: list[FloatArray], duration: float) -> None:
    times.append(times[-1] + duration)
    points.append(points[-1].copy())


def sample_schedule(rng: Generator, gear_xy: FloatArray, peg_position: FloatArray,
                    mode: str | None = None,
                    mode_probabilities: tuple[float, float, float] = (0.2, 0.4, 0.4)
                    ) -> HumanSchedule:
    """Draw a schedule.

    Args:
        rng: the only source of randomness.
        gear_xy: (2,) where the gear lies on the table.
        peg_position: (3,) the peg's tip (the end of the left arm's path).
        mode: force ``"away"``, ``"cross"`` or ``"block"`` for the first event; ``None``
            draws it with ``mode_probabilities``. A second event (of either kind) follows
            the first with probability 0.3.
    """
    if mode is None:
        mode = HUMAN_MODES[int(rng.choice(3, p=np.asarray(mode_probabilities)))]
    if mode not in HUMAN_MODES:
        raise ValueError(f"unknown human mode {mode!r}; expected one of {HUMAN_MODES}")
    rest = REST + np.array([0.0, rng.uniform(-0.1, 0.1), 0.0])
    shoulder = np.array([SHOULDER_X, rest[1] - 0.15, SHOULDER_Z])
    times: list[float] = [0.0]
    points: list[FloatArray] = [rest]
    events: list[str] = []
    if mode != "away":
        kinds = [mode]
        if rng.random() < 0.3:
            kinds.append(str(rng.choice(["cross", "block"])))
        _hold(times, points, rng.uniform(*FIRST_EVENT_RANGE))
        for i, kind in enumerate(kinds):
            if i > 0:
                _hold(times, points, rng.uniform(*GAP_RANGE))
            speed = rng.uniform(*SPEED_RANGE)
            if kind == "cross":
                x = rng.uniform(*CROSS_X_RANGE)
                z = rng.uniform(*CROSS_Z_RANGE)
                y0, y1 = CROSS_Y_ENDS if rng.random() < 0.5 else CROSS_Y_ENDS[::-1]
                _move(times, points, np.array([x, y0, z]), speed)
                _move(times, points, np.array([x + rng.uniform(-0.08, 0.08), y1, z]), speed)
            else:
                lam = rng.uniform(*BLOCK_FRACTION_RANGE)
                xy = gear_xy + lam * (peg_position[:2] - gear_xy)
                target = np.array([xy[0], xy[1], rng.uniform(*BLOCK_Z_RANGE)])
                _move(times, points, target, speed)
                _hold(times, points, rng.uniform(*BLOCK_DWELL_RANGE))
            _move(times, points, rest, speed)
            events.append(kind)
    return HumanSchedule(times=np.array(times), positions=np.array(points),
                         shoulder=shoulder, events=tuple(events))
