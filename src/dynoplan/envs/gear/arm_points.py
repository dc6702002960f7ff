"""Points on both arms from planner states, batched: the robot's geometry for safety checks.

Each arm is a chain of six hinges at the origins of its links (axes z, y, x, y, x, y from
the torso; every link frame starts aligned with its parent's): shoulder pan at
``(0, +-0.188, 1.02)``, the lift 0.1 m along the pan link's x, the elbow 0.4 m further,
the wrist 0.321 m beyond. :func:`arm_points` returns, per state, the shoulder, the elbow,
the wrist, points spaced along the upper arm and the forearm, and the left tool point (from
the state), so that a distance to these points is a distance to the arm, not to the tool
point alone. ``tests/test_safety.py`` checks the joints against MuJoCo's kinematics.
"""

import numpy as np

from dynoplan.envs.gear.state import STATE_SLICES
from dynoplan.types import FloatArray

SHOULDER_Y = 0.188
SHOULDER_Z = 1.02
LIFT_OFFSET = 0.1
UPPER_ARM = 0.4
FOREARM = 0.321
SEGMENT_POINTS = 3
"""Points between two joints (besides the joints themselves)."""

POINTS_PER_ARM = 4 + 2 * SEGMENT_POINTS
"""Shoulder pan, lift, elbow, wrist, and the points along the two segments."""


def _rotation(axis: int, angle: FloatArray) -> FloatArray:
    """(N, 3, 3) rotations by ``angle`` (N,) about the unit ``axis`` (0: x, 1: y, 2: z)."""
    c, s = np.cos(angle), np.sin(angle)
    r = np.zeros((len(angle), 3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    r[:, axis, axis] = 1.0
    r[:, i, i] = c
    r[:, j, j] = c
    r[:, i, j] = -s
    r[:, j, i] = s
    return r


AXES = (2, 1, 0, 1, 0, 1)
"""The hinge axes of an arm's six joints, from the torso."""


def arm_joints(q: FloatArray, side: str) -> FloatArray:
    """(N, 4, 3) world positions of the shoulder pan, lift, elbow and wrist of arm
    ``side`` (``"l"`` or ``"r"``) at joint angles ``q`` (N, 6)."""
    y = SHOULDER_Y if side == "l" else -SHOULDER_Y
    return _chain(np.asarray(q, dtype=np.float64), np.full(len(q), y))


def _chain(q: FloatArray, y: FloatArray) -> FloatArray:
    """:func:`arm_joints` of rows that may belong to either arm: joint angles ``q``
    (M, 6), each row's shoulder at ``(0, y, SHOULDER_Z)`` (``y`` (M,)). Every row is
    computed on its own (one batched product per joint), so a row's joints do not depend
    on the other rows."""
    n = len(q)
    pan = np.stack([np.zeros(n), y, np.full(n, SHOULDER_Z)], axis=1)
    rot = np.broadcast_to(np.eye(3), (n, 3, 3))
    frames = []
    for k, axis in enumerate(AXES):
        rot = rot @ _rotation(axis, q[:, k])
        frames.append(rot)
    lift = pan + frames[0][:, :, 0] * LIFT_OFFSET
    elbow = lift + frames[2][:, :, 0] * UPPER_ARM
    wrist = elbow + frames[4][:, :, 0] * FOREARM
    return np.stack([pan, lift, elbow, wrist], axis=1)


def arm_points(states: FloatArray) -> FloatArray:
    """Planner states (N, 22) -> (N, 2 * POINTS_PER_ARM + 1, 3) points on both arms and
    the left tool point (m, world frame): the left arm's points, the right arm's, the
    tool point. Row by row: a state's points do not depend on the other states."""
    s = np.atleast_2d(np.asarray(states, dtype=np.float64))
    n = len(s)
    q = s[:, STATE_SLICES["arm_qpos"]]
    # both arms in one chain: rows 0..n-1 the left arm, n..2n-1 the right
    j = _chain(np.concatenate([q[:, 0:6], q[:, 6:12]]),
               np.repeat([SHOULDER_Y, -SHOULDER_Y], n))
    fractions = np.arange(1, SEGMENT_POINTS + 1) / (SEGMENT_POINTS + 1)
    upper = j[:, 1:2] + fractions[None, :, None] * (j[:, 2:3] - j[:, 1:2])
    fore = j[:, 2:3] + fractions[None, :, None] * (j[:, 3:4] - j[:, 2:3])
    per_arm = np.concatenate([j, upper, fore], axis=1)  # (2n, POINTS_PER_ARM, 3)
    points: FloatArray = np.concatenate(
        [per_arm[:n], per_arm[n:], s[:, None, STATE_SLICES["tool_pos"]]], axis=1)
    return points


__all__ = ["POINTS_PER_ARM", "arm_joints", "arm_points"]
