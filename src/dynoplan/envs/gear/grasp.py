"""Where the left arm must be to put the gear it holds at a pose relative to the peg.

The gear is held rigidly by the left gripper, so its bottom centre sits at a fixed offset
in the tool frame (measured once, at the configuration it is held in). To place the
gear's bottom ``height`` above the peg tip along the peg axis, with the gear's axis on
the peg's axis, the tool is rotated by the smallest rotation that takes the gear's axis
onto the peg's axis, and its position follows from the offset. The roll about the
approach axis is left free (the gear is symmetric about its axis).

Used by the scripted expert (pre-insertion pose, insertion) and by the fast and
cautious move options (their goal).
"""

import numpy as np

from dynoplan.envs.gear.kinematics import ArmKinematics
from dynoplan.types import FloatArray


def rotation_between(a: FloatArray, b: FloatArray) -> FloatArray:
    """(3, 3) smallest rotation taking unit vector ``a`` onto unit vector ``b``."""
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    s = float(np.linalg.norm(v))
    if s < 1e-12:
        return np.eye(3)
    k = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]]) / s
    angle = np.arctan2(s, c)
    out: FloatArray = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)
    return out


def ik_gear_at(kin: ArmKinematics, q_seed: FloatArray, q_held: FloatArray,
               gear_pos: FloatArray, gear_rot: FloatArray, peg_tip: FloatArray,
               peg_rot: FloatArray, height: float, iterations: int = 100) -> FloatArray:
    """Arm joints (12,) that put the held gear's bottom ``height`` (m) above the peg tip
    along the peg axis, with the gear's axis on the peg's axis.

    Args:
        kin: the kinematics to solve with.
        q_seed: (12,) start of the IK iteration (the other arm keeps its values).
        q_held: (12,) arm joints at which the gear pose below was measured (fixes the
            gear's offset in the tool frame).
        gear_pos, gear_rot: gear bottom centre (3,) and rotation (3, 3) at ``q_held``.
        peg_tip, peg_rot: peg tip (3,) and rotation (3, 3) whose ``z`` is the peg axis.
    """
    axis = peg_rot[:, 2]
    tcp, tool_rot = kin.tool_pose(q_held)
    offset = tool_rot.T @ (gear_pos - tcp)  # gear bottom in the tool frame
    target_rot = rotation_between(gear_rot[:, 2], axis) @ tool_rot
    target_tcp = peg_tip + axis * height - target_rot @ offset
    # The roll about the approach axis is left free; a second pass puts the gear's bottom
    # right for the roll found.
    q_sol = kin.solve(q_seed, target_tcp, target_rot, free_roll=True, iterations=iterations).q
    _, rot_sol = kin.tool_pose(q_sol)
    target_tcp = peg_tip + axis * height - rot_sol @ offset
    return kin.solve(q_sol, target_tcp, rot_sol, free_roll=True, iterations=iterations).q


def held_gear_position(kin: ArmKinematics, q: FloatArray, q_held: FloatArray,
                       gear_pos: FloatArray) -> FloatArray:
    """(3,) where the gear's bottom centre is at arm joints ``q`` (12,) if it stays in the
    hand as it was at ``q_held`` (12,) with its bottom at ``gear_pos`` (3,)."""
    tcp, tool_rot = kin.tool_pose(q_held)
    offset = tool_rot.T @ (gear_pos - tcp)
    tcp_q, rot_q = kin.tool_pose(q)
    out: FloatArray = tcp_q + rot_q @ offset
    return out


def quat_to_mat(quat: FloatArray) -> FloatArray:
    """``wxyz`` quaternions (N, 4) -> rotation matrices (N, 3, 3) (normalised first)."""
    q = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    out = np.empty((len(q), 3, 3))
    out[:, 0, 0] = 1 - 2 * (y * y + z * z)
    out[:, 0, 1] = 2 * (x * y - w * z)
    out[:, 0, 2] = 2 * (x * z + w * y)
    out[:, 1, 0] = 2 * (x * y + w * z)
    out[:, 1, 1] = 1 - 2 * (x * x + z * z)
    out[:, 1, 2] = 2 * (y * z - w * x)
    out[:, 2, 0] = 2 * (x * z - w * y)
    out[:, 2, 1] = 2 * (y * z + w * x)
    out[:, 2, 2] = 1 - 2 * (x * x + y * y)
    return out


__all__ = ["held_gear_position", "ik_gear_at", "quat_to_mat", "rotation_between"]
