"""Robot-human distance, contact classification and a scratch-data collision checker.

:class:`GeomSets` names the geoms of each part of the scene. :func:`min_distance` is the
robot-human distance the environment reports every step. :class:`CollisionChecker` lets
a motion planner ask, for any 12 arm joint angles, "in collision?" and "how far from the
human?" on its own ``MjData``, without touching the environment's state.
"""

from dataclasses import dataclass

import mujoco
import numpy as np

from dynoplan.envs.gear.grasp import quat_to_mat
from dynoplan.envs.gear.scene import ARM_JOINTS
from dynoplan.types import BoolArray, FloatArray, IntArray

_DISTMAX = 1.0  # m: distances beyond this are reported as this value


def _body_subtree(model: mujoco.MjModel, root: int) -> set[int]:
    out = {root}
    for b in range(model.nbody):
        parent = b
        while parent > 0:
            parent = int(model.body_parentid[parent])
            if parent == root:
                out.add(b)
                break
    return out


@dataclass(frozen=True)
class GeomSets:
    """Geom ids (and masks over all geoms) of the scene's parts."""

    robot: IntArray  # colliding geoms of the robot, including the peg module
    human: IntArray
    gear: IntArray
    pads: IntArray  # the left gripper's two finger pads
    table: int
    is_robot: BoolArray  # (ngeom,)
    is_human: BoolArray
    is_gear: BoolArray
    is_pad: BoolArray

    @classmethod
    def from_model(cls, model: mujoco.MjModel) -> "GeomSets":
        torso = _body_subtree(model, model.body("torso").id)
        human_body = model.body("human").id
        gear_body = model.body("gear").id
        colliding = (model.geom_contype != 0) | (model.geom_conaffinity != 0)
        bodies = model.geom_bodyid
        is_robot = colliding & np.isin(bodies, list(torso))
        is_human = colliding & (bodies == human_body)
        is_gear = colliding & (bodies == gear_body)
        pads = np.array([model.geom("l_gripper_l_finger_pad").id,
                         model.geom("l_gripper_r_finger_pad").id])
        is_pad = np.zeros(model.ngeom, dtype=bool)
        is_pad[pads] = True
        return cls(robot=np.flatnonzero(is_robot), human=np.flatnonzero(is_human),
                   gear=np.flatnonzero(is_gear), pads=pads, table=model.geom("table").id,
                   is_robot=is_robot, is_human=is_human, is_gear=is_gear, is_pad=is_pad)


def min_distance(model: mujoco.MjModel, data: mujoco.MjData, geoms_a: IntArray,
                 geoms_b: IntArray, distmax: float = _DISTMAX) -> float:
    """Smallest signed distance between any geom of ``geoms_a`` and any of ``geoms_b``
    (negative when they penetrate), capped at ``distmax``.

    Pairs are visited in order of their bounding-sphere lower bound and the search stops
    when that bound exceeds the best distance found, so only a few exact
    ``mj_geomDistance`` calls are made. Needs the geoms' poses (``mj_kinematics``).
    """
    pa = data.geom_xpos[geoms_a]
    pb = data.geom_xpos[geoms_b]
    centre = np.linalg.norm(pa[:, None, :] - pb[None, :, :], axis=-1)
    lower = centre - model.geom_rbound[geoms_a][:, None] - model.geom_rbound[geoms_b][None, :]
    order = np.argsort(lower, axis=None)
    best = distmax
    nb = len(geoms_b)
    for flat in order:
        if lower.flat[flat] >= best:
            break
        i, j = divmod(int(flat), nb)
        d = mujoco.mj_geomDistance(model, data, int(geoms_a[i]), int(geoms_b[j]), best, None)
        best = min(best, d)
    return float(best)


def count_contacts(data: mujoco.MjData, mask_a: BoolArray, mask_b: BoolArray) -> int:
    """Number of active contacts between a geom in ``mask_a`` and one in ``mask_b``."""
    n = data.ncon
    if n == 0:
        return 0
    g = data.contact.geom[:n]
    a0, a1 = mask_a[g[:, 0]], mask_a[g[:, 1]]
    b0, b1 = mask_b[g[:, 0]], mask_b[g[:, 1]]
    return int(np.count_nonzero((a0 & b1) | (a1 & b0)))


class CollisionChecker:
    """Collision and human-distance queries on a private ``MjData`` of the scene.

    Usage: ``sync(env.data)`` copies the live state (objects, human); then
    ``in_collision(q)`` / ``human_distance(q)`` set the 12 arm joints ``q`` (in
    :data:`ARM_JOINTS` order) and answer. With ``sync(..., carry_gear=True)`` the gear
    follows the left gripper as it held it at sync time, as for planning with the gear
    in hand.

    "In collision" means a penetrating contact between a robot geom (arm, gripper, peg
    module) and anything (table, robot, gear, human), except the left finger pads
    against the gear, which is how the gear is held.
    """

    def __init__(self, model: mujoco.MjModel) -> None:
        self.model = model
        self.data = mujoco.MjData(model)
        self.geoms = GeomSets.from_model(model)
        self._qadr = np.array([model.joint(j).qposadr[0] for j in ARM_JOINTS])
        self._gear_qadr = int(model.joint("gear_free").qposadr[0])
        self._palm = model.body("l_gripper_palm_link").id
        self._gear_in_palm: tuple[FloatArray, FloatArray] | None = None
        mujoco.mj_kinematics(model, self.data)

    def sync(self, data: mujoco.MjData, carry_gear: bool = False) -> None:
        """Copy positions and the human's pose from ``data``; optionally carry the gear."""
        self.data.qpos[:] = data.qpos
        self.data.mocap_pos[:] = data.mocap_pos
        self.data.mocap_quat[:] = data.mocap_quat
        mujoco.mj_kinematics(self.model, self.data)
        self._gear_in_palm = None
        if carry_gear:
            palm_pos = self.data.xpos[self._palm]
            palm_rot = self.data.xmat[self._palm].reshape(3, 3)
            gear_pos = self.data.qpos[self._gear_qadr:self._gear_qadr + 3]
            gear_rot = np.empty(9)
            mujoco.mju_quat2Mat(gear_rot, self.data.qpos[self._gear_qadr + 3:self._gear_qadr + 7])
            self._gear_in_palm = (palm_rot.T @ (gear_pos - palm_pos),
                                  palm_rot.T @ gear_rot.reshape(3, 3))

    def set_human(self, position: FloatArray, quaternion: FloatArray) -> None:
        """Move the human's hand (3,) / (4,) ``wxyz`` in the scratch data."""
        self.data.mocap_pos[0] = position
        self.data.mocap_quat[0] = quaternion

    def set_arm(self, q: FloatArray) -> None:
        """Set the 12 arm joints (and the carried gear) and update the geoms' poses."""
        self.data.qpos[self._qadr] = q
        mujoco.mj_kinematics(self.model, self.data)
        if self._gear_in_palm is not None:
            rel_pos, rel_rot = self._gear_in_palm
            palm_pos = self.data.xpos[self._palm]
            palm_rot = self.data.xmat[self._palm].reshape(3, 3)
            quat = np.empty(4)
            mujoco.mju_mat2Quat(quat, (palm_rot @ rel_rot).ravel())
            a = self._gear_qadr
            self.data.qpos[a:a + 3] = palm_pos + palm_rot @ rel_pos
            self.data.qpos[a + 3:a + 7] = quat
            mujoco.mj_kinematics(self.model, self.data)

    def in_collision(self, q: FloatArray, margin: float = 0.0, ignore_gear: bool = False) -> bool:
        """True if the robot at arm joints ``q`` (12,) penetrates anything by more than
        ``margin`` (m); with ``ignore_gear``, contacts of the gear do not count."""
        self.set_arm(q)
        mujoco.mj_collision(self.model, self.data)
        n = self.data.ncon
        if n == 0:
            return False
        g = self.data.contact.geom[:n]
        dist = self.data.contact.dist[:n]
        s = self.geoms
        robot = s.is_robot[g[:, 0]] | s.is_robot[g[:, 1]]
        grasp = ((s.is_pad[g[:, 0]] & s.is_gear[g[:, 1]])
                 | (s.is_pad[g[:, 1]] & s.is_gear[g[:, 0]]))
        hit = robot & ~grasp & (dist < -margin)
        if ignore_gear:
            hit &= ~(s.is_gear[g[:, 0]] | s.is_gear[g[:, 1]])
        return bool(np.any(hit))

    def human_distance(self, q: FloatArray, distmax: float = _DISTMAX) -> float:
        """Smallest robot-human distance (m) with the arms at ``q`` (12,), capped."""
        self.set_arm(q)
        return min_distance(self.model, self.data, self.geoms.human, self.geoms.robot, distmax)

    def human_distance_along(self, qs: FloatArray, hand_positions: FloatArray,
                             hand_quaternions: FloatArray, cap: float = _DISTMAX) -> float:
        """Smallest robot-human distance over paired samples, capped at ``cap``.

        Args:
            qs: (T, 12) arm joints, for example a path sampled in time.
            hand_positions: (T, 3) the human hand's position at the same times.
            hand_quaternions: (T, 4) its ``wxyz`` orientation.

        Bounding spheres give a lower bound per sample; exact distances are computed
        only for samples whose bound is below the best distance found so far.
        """
        qs = np.atleast_2d(qs)
        robot, human = self.geoms.robot, self.geoms.human
        centres = np.empty((len(qs), len(robot), 3))
        for i, q in enumerate(qs):
            self.set_arm(q)
            centres[i] = self.data.geom_xpos[robot]
        rot = quat_to_mat(np.asarray(hand_quaternions, dtype=np.float64))  # (T, 3, 3)
        local = self.model.geom_pos[human]  # (H, 3) in the hand's frame
        human_centres = hand_positions[:, None, :] + np.einsum("tij,hj->thi", rot, local)
        gap = np.linalg.norm(centres[:, :, None, :] - human_centres[:, None, :, :], axis=-1)
        gap -= self.model.geom_rbound[robot][None, :, None]
        gap -= self.model.geom_rbound[human][None, None, :]
        lower = gap.reshape(len(qs), -1).min(axis=1)
        best = cap
        for i in np.argsort(lower):
            if lower[i] >= best:
                break
            self.set_arm(qs[i])
            self.set_human(hand_positions[i], hand_quaternions[i])
            mujoco.mj_kinematics(self.model, self.data)
            best = min(best, min_distance(self.model, self.data, human, robot, best))
        return float(best)
