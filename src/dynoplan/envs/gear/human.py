"""The human operator: a forearm and hand that move on a seeded, piecewise-linear schedule.

The operator stands across the table (shoulder near ``x = 1.6``). Its hand rests at
``REST`` (outside the robot's reach) and, on a random schedule, does up to two events:

- ``cross``: the hand sweeps across the workspace above the table, from the robot's left
  to its right or back, at a height above the right hand and the peg;
- ``block``: the hand moves to a point on the line between the gear and the peg (the
  left arm's path to the right hand), stays there for a while, then goes back.

Between events the hand rests. Speeds are drawn per event. The schedule is a list of
keyframes; the pose at any time is known in advance, so a privileged expert (or a
planner using the simulator as its model) can predict where the hand will be. A real
hand cannot change its velocity at once: every corner of the path is rounded with a
constant acceleration of :data:`HAND_ACCELERATION` (a parabolic blend, sampled every
:data:`BLEND_SAMPLE` s), so the hand's speed changes by at most about
``HAND_ACCELERATION * dt`` in ``dt`` seconds, and a runtime monitor may bound it.
The forearm points from the hand towards the operator's shoulder.

These three (:data:`HUMAN_MODES`) are the behaviours of every demonstration, collection
and default episode. Four more (:data:`UNSEEN_BEHAVIOURS`) appear in no demonstration or
training run; an evaluation selects them to test the models on behaviours they never saw:

- ``reach``: the hand reaches for the gear on the table (a few cm above it), stays
  there, and goes back;
- ``linger``: the hand goes over the peg and stays there for several seconds;
- ``fast_cross``: a crossing at the arm's height (lower than ``cross``), at 1-1.6 m/s;
- ``two_passes``: two crossings, there and back, with a short pause between them.
"""

from dataclasses import dataclass

import numpy as np

from dynoplan.envs.gear.scene import TABLE_TOP_Z
from dynoplan.types import FloatArray, Generator

REST = np.array([1.25, 0.35, 0.95])
SHOULDER_X = 1.6
SHOULDER_Z = 1.3

HUMAN_MODES = ("away", "cross", "block")
"""Episode kinds of the demonstrations, the collection and the default evaluation: no
event, at least one crossing, at least one blocking event."""

UNSEEN_BEHAVIOURS = ("reach", "linger", "fast_cross", "two_passes")
"""Behaviours no demonstration or training run shows (module docstring), for evaluation."""

BEHAVIOURS = (*HUMAN_MODES, *UNSEEN_BEHAVIOURS)
"""Every behaviour ``sample_schedule`` can draw (an episode's ``mode``)."""

SPEED_RANGE = (0.2, 0.6)  # m/s, per event
CROSS_X_RANGE = (0.6, 0.85)
CROSS_Z_RANGE = (1.03, 1.12)
CROSS_Y_ENDS = (0.6, -0.45)  # the sweep runs between these two y values
BLOCK_FRACTION_RANGE = (0.25, 0.55)  # where on the gear -> peg line, from the gear
BLOCK_Z_RANGE = (0.9, 1.02)
BLOCK_DWELL_RANGE = (1.5, 4.0)  # s
FIRST_EVENT_RANGE = (0.5, 8.0)  # s, start of the first event
GAP_RANGE = (1.0, 4.0)  # s of rest between two events
REACH_HEIGHT_RANGE = (0.04, 0.10)  # m above the table, over the gear
REACH_DWELL_RANGE = (1.0, 3.0)  # s
REACH_SPEED_RANGE = (0.4, 0.8)  # m/s
LINGER_HEIGHT_RANGE = (0.08, 0.16)  # m above the peg's tip
LINGER_DWELL_RANGE = (3.0, 6.0)  # s
FAST_CROSS_SPEED_RANGE = (1.0, 1.6)  # m/s
FAST_CROSS_Z_RANGE = (0.92, 1.0)  # the arm's height, below ``cross``
PASS_GAP_RANGE = (0.3, 1.0)  # s between the two passes
HAND_ACCELERATION = 10.0
"""m/s^2: the hand's acceleration at every corner of its path. A minimum-jerk reach of
0.5 m in 0.5 s peaks at 5.8 * 0.5 / 0.5^2 = 11.5 m/s^2 (Flash and Hogan 1985)."""
BLEND_SAMPLE = 0.005
"""s: the longest keyframe interval of a rounded corner."""


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
        mode: force ``"away"``, ``"cross"`` or ``"block"`` for the first event, or one
            of :data:`UNSEEN_BEHAVIOURS` (a single event); ``None`` draws one of
            :data:`HUMAN_MODES` with ``mode_probabilities``. After a ``cross`` or ``block``
            a second event (of either kind) follows with probability 0.3.
    """
    if mode is None:
        mode = HUMAN_MODES[int(rng.choice(3, p=np.asarray(mode_probabilities)))]
    if mode not in BEHAVIOURS:
        raise ValueError(f"unknown human mode {mode!r}; expected one of {BEHAVIOURS}")
    rest = REST + np.array([0.0, rng.uniform(-0.1, 0.1), 0.0])
    shoulder = np.array([SHOULDER_X, rest[1] - 0.15, SHOULDER_Z])
    times: list[float] = [0.0]
    points: list[FloatArray] = [rest]
    events: list[str] = []
    if mode in UNSEEN_BEHAVIOURS:
        _hold(times, points, rng.uniform(*FIRST_EVENT_RANGE))
        _unseen_event(mode, rng, times, points, gear_xy, peg_position)
        _move(times, points, rest, rng.uniform(*SPEED_RANGE))
        events.append(mode)
    elif mode != "away":
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
    t, p = rounded_corners(np.array(times), np.array(points))
    return HumanSchedule(times=t, positions=p, shoulder=shoulder, events=tuple(events))


def rounded_corners(times: FloatArray, positions: FloatArray,
                    acceleration: float = HAND_ACCELERATION,
                    sample: float = BLEND_SAMPLE) -> tuple[FloatArray, FloatArray]:
    """Keyframes ``(K,)``, ``(K, 3)`` of a piecewise-linear path -> the same path with
    every change of velocity (the hand rests before the first keyframe and after the
    last) spread over ``|dv| / acceleration`` seconds centred on its keyframe: a
    parabolic blend, sampled every ``sample`` seconds at most. The blend takes at most
    half of each segment beside it (a shorter segment accelerates faster). Times of the
    keyframes outside the blends, and the path's duration, do not change."""
    t = np.asarray(times, dtype=np.float64)
    p = np.asarray(positions, dtype=np.float64)
    durations = np.diff(t)
    velocities = np.concatenate([np.zeros((1, 3)), np.diff(p, axis=0) / durations[:, None],
                                 np.zeros((1, 3))])
    room = np.concatenate([[np.inf], durations, [np.inf]])
    out_t: list[float] = []
    out_p: list[FloatArray] = []
    for k in range(len(t)):
        v_in, v_out = velocities[k], velocities[k + 1]
        change = float(np.linalg.norm(v_out - v_in))
        tau = min(change / acceleration, room[k], room[k + 1])
        if tau <= 0.0:
            out_t.append(float(t[k]))
            out_p.append(p[k])
            continue
        n = int(np.ceil(tau / sample))
        s = np.linspace(0.0, tau, n + 1)  # time since the blend started
        blend = (p[k] + v_in * (s - tau / 2)[:, None]
                 + (v_out - v_in) / (2 * tau) * (s ** 2)[:, None])
        out_t.extend((t[k] - tau / 2 + s).tolist())
        out_p.extend(blend)
    keep = np.concatenate([[True], np.diff(out_t) > 0])  # two blends that meet
    return np.array(out_t)[keep], np.array(out_p)[keep]


def _cross(rng: Generator, times: list[float], points: list[FloatArray], speed: float,
           z_range: tuple[float, float], backwards: bool) -> None:
    """A sweep across the workspace at a height drawn from ``z_range``."""
    x = rng.uniform(*CROSS_X_RANGE)
    z = rng.uniform(*z_range)
    y0, y1 = CROSS_Y_ENDS[::-1] if backwards else CROSS_Y_ENDS
    _move(times, points, np.array([x, y0, z]), speed)
    _move(times, points, np.array([x + rng.uniform(-0.08, 0.08), y1, z]), speed)


def _unseen_event(kind: str, rng: Generator, times: list[float], points: list[FloatArray],
                  gear_xy: FloatArray, peg_position: FloatArray) -> None:
    """Append the keyframes of one of :data:`UNSEEN_BEHAVIOURS` (without the way back)."""
    if kind == "reach":
        target = np.array([gear_xy[0], gear_xy[1],
                           TABLE_TOP_Z + rng.uniform(*REACH_HEIGHT_RANGE)])
        _move(times, points, target, rng.uniform(*REACH_SPEED_RANGE))
        _hold(times, points, rng.uniform(*REACH_DWELL_RANGE))
    elif kind == "linger":
        target = np.asarray(peg_position, dtype=np.float64) + np.array(
            [0.0, 0.0, rng.uniform(*LINGER_HEIGHT_RANGE)])
        _move(times, points, target, rng.uniform(*SPEED_RANGE))
        _hold(times, points, rng.uniform(*LINGER_DWELL_RANGE))
    elif kind == "fast_cross":
        _cross(rng, times, points, rng.uniform(*FAST_CROSS_SPEED_RANGE), FAST_CROSS_Z_RANGE,
               backwards=bool(rng.random() < 0.5))
    else:  # two_passes: there and back at the same height, from where the first ended
        speed = rng.uniform(*SPEED_RANGE)
        backwards = bool(rng.random() < 0.5)
        _cross(rng, times, points, speed, CROSS_Z_RANGE, backwards)
        _hold(times, points, rng.uniform(*PASS_GAP_RANGE))
        end = points[-1]
        back = CROSS_Y_ENDS[1] if backwards else CROSS_Y_ENDS[0]
        _move(times, points, np.array([end[0] + rng.uniform(-0.08, 0.08), back, end[2]]),
              speed)
