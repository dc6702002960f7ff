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
    return _min_distance(model, data, geoms_a, geoms_b, model.geom_rbound[geoms_a][:, None],
                         model.geom_rbound[geoms_b][None, :], distmax)


def _min_distance(model: mujoco.MjModel, data: mujoco.MjData, geoms_a: IntArray,
                  geoms_b: IntArray, bound_a: FloatArray, bound_b: FloatArray,
                  distmax: float, stop_below: float = -np.inf) -> float:
    """:func:`min_distance` with the bounding radii given, ``(A, 1)`` and ``(1, B)`` (a
    caller asking often about the same geoms keeps them). With ``stop_below``, the
    search ends at the first pair found closer than it and returns that pair's distance
    (for a caller that asks only whether the distance is below ``stop_below``: the
    answer is the full search's, since the pairs before are visited as it visits them)."""
    xpos = data.geom_xpos
    diff = xpos[geoms_a][:, None, :] - xpos[geoms_b][None, :, :]
    # np.linalg.norm(diff, axis=-1) computes exactly this (for real arrays), with more
    # overhead; the bounds, hence the pairs visited, are the same to the last bit
    lower = np.sqrt(np.add.reduce(diff * diff, axis=-1)) - bound_a - bound_b
    best = distmax
    if lower.min() >= best:  # no pair can be closer than the cap (a frequent answer)
        return float(best)
    order = np.argsort(lower, axis=None)
    flat_lower = lower.ravel()
    nb = len(geoms_b)
    for flat in order:
        if flat_lower[flat] >= best:
            break
        i, j = divmod(int(flat), nb)
        d = mujoco.mj_geomDistance(model, data, int(geoms_a[i]), int(geoms_b[j]), best, None)
        best = min(best, d)
        if best < stop_below:
            break
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

    Speed: a query at the joints of the previous one (a planner's validity test asks for
    the collision and then for the human distance of the same state) does not pose the
    arm and the carried gear again; only the human's hand, if it moved, is posed anew.
    The answers are exactly those of posing everything for every query.
    """

    def __init__(self, model: mujoco.MjModel) -> None:
        self.model = model
        self.data = mujoco.MjData(model)
        self.geoms = GeomSets.from_model(model)
        self._qadr = np.array([model.joint(j).qposadr[0] for j in ARM_JOINTS])
        self._arm_slices = _slices(self._qadr)
        self._gear_qadr = int(model.joint("gear_free").qposadr[0])
        self._palm = model.body("l_gripper_palm_link").id
        self._gear_in_palm: tuple[FloatArray, FloatArray] | None = None
        # the arm joints the scratch data is posed at (None: unknown) and whether the
        # hand moved since the last mj_kinematics
        self._posed: FloatArray | None = None
        self._hand_moved = False
        s = self.geoms
        # counts[g1, g2]: a penetrating contact between geoms g1 and g2 is a collision;
        # the same without the gear's contacts (ignore_gear)
        robot = s.is_robot[:, None] | s.is_robot[None, :]
        grasp = (s.is_pad[:, None] & s.is_gear[None, :]) | (s.is_gear[:, None] & s.is_pad[None, :])
        self._counts = robot & ~grasp
        self._counts_no_gear = self._counts & ~(s.is_gear[:, None] | s.is_gear[None, :])
        self._bound_human = model.geom_rbound[s.human][:, None]
        self._bound_robot = model.geom_rbound[s.robot][None, :]
        mujoco.mj_kinematics(model, self.data)

    def sync(self, data: mujoco.MjData, carry_gear: bool = False) -> None:
        """Copy positions and the human's pose from ``data``; optionally carry the gear."""
        self.data.qpos[:] = data.qpos
        self.data.mocap_pos[:] = data.mocap_pos
        self.data.mocap_quat[:] = data.mocap_quat
        mujoco.mj_kinematics(self.model, self.data)
        self._posed, self._hand_moved = None, False
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
        """Move the human's hand (3,) / (4,) ``wxyz`` in the scratch data (posed at the
        next query, or by ``mj_kinematics``)."""
        self.data.mocap_pos[0] = position
        self.data.mocap_quat[0] = quaternion
        self._hand_moved = True

    def set_arm(self, q: FloatArray) -> None:
        """Set the 12 arm joints (and the carried gear) and update the geoms' poses."""
        q = np.asarray(q, dtype=np.float64)
        posed = self._posed
        if posed is not None and q.shape == posed.shape and bool((q == posed).all()):
            # the same joints: arm and gear are where they were; pose the moved hand
            if self._hand_moved:
                mujoco.mj_kinematics(self.model, self.data)
                self._hand_moved = False
            return
        qpos = self.data.qpos
        start = 0
        for block in self._arm_slices:
            stop = start + block.stop - block.start
            qpos[block] = q[start:stop]
            start = stop
        mujoco.mj_kinematics(self.model, self.data)
        if self._gear_in_palm is not None:
            rel_pos, rel_rot = self._gear_in_palm
            palm_pos = self.data.xpos[self._palm]
            palm_rot = self.data.xmat[self._palm].reshape(3, 3)
            quat = np.empty(4)
            mujoco.mju_mat2Quat(quat, (palm_rot @ rel_rot).ravel())
            a = self._gear_qadr
            qpos[a:a + 3] = palm_pos + palm_rot @ rel_pos
            qpos[a + 3:a + 7] = quat
            mujoco.mj_kinematics(self.model, self.data)
        self._posed, self._hand_moved = q.copy(), False

    def in_collision(self, q: FloatArray, margin: float = 0.0, ignore_gear: bool = False) -> bool:
        """True if the robot at arm joints ``q`` (12,) penetrates anything by more than
        ``margin`` (m); with ``ignore_gear``, contacts of the gear do not count."""
        self.set_arm(q)
        mujoco.mj_collision(self.model, self.data)
        n = self.data.ncon
        if n == 0:
            return False
        contact = self.data.contact
        g = contact.geom[:n]
        counts = self._counts_no_gear if ignore_gear else self._counts
        return bool((counts[g[:, 0], g[:, 1]] & (contact.dist[:n] < -margin)).any())

    def human_distance(self, q: FloatArray, distmax: float = _DISTMAX,
                       stop_below: float = -np.inf) -> float:
        """Smallest robot-human distance (m) with the arms at ``q`` (12,), capped at
        ``distmax``; with ``stop_below``, some distance below it as soon as one is found
        (whether the smallest distance is below ``stop_below`` is answered exactly)."""
        self.set_arm(q)
        return _min_distance(self.model, self.data, self.geoms.human, self.geoms.robot,
                             self._bound_human, self._bound_robot, distmax, stop_below)

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
            self._hand_moved = False
            best = min(best, _min_distance(self.model, self.data, human, robot,
                                           self._bound_human, self._bound_robot, best))
        return float(best)


def _slices(indices: IntArray) -> list[slice]:
    """Consecutive runs of ``indices`` as slices, in order (``[0..5, 8..13]`` -> two)."""
    runs: list[slice] = []
    for i in indices.tolist():
        if runs and runs[-1].stop == i:
            runs[-1] = slice(runs[-1].start, i + 1)
        else:
            runs.append(slice(i, i + 1))
    return runs
