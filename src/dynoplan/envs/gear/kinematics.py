"""Forward and inverse kinematics of the arms' tool points (``l_tcp``, ``r_tcp``).

Inverse kinematics is differential IK with `mink <https://github.com/kevinzakka/mink>`_ on
the robot-only model (same kinematics as the scene, no objects): a frame task on the tool
point, a posture task that keeps the solution near the seed, joint limits, and the other
arm and the fingers frozen. The tool frame has ``x`` along the approach direction and
``y`` along the finger axis.
"""

from dataclasses import dataclass

import mink
import mujoco
import numpy as np

from dynoplan.envs.gear.scene import (
    ARM_JOINTS,
    LEFT_ARM_JOINTS,
    RIGHT_ARM_JOINTS,
    build_model,
)
from dynoplan.types import FloatArray


@dataclass(frozen=True)
class IKResult:
    """An IK solution: ``q`` (12,) arm joints, and the residual errors at the tool point."""

    q: FloatArray
    position_error: float  # m
    rotation_error: float  # rad, over the constrained rotation axes
    converged: bool


def rotation_about_z(yaw: float) -> FloatArray:
    """(3, 3) rotation by ``yaw`` about world ``z``."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def downward_tool_rotation(yaw: float) -> FloatArray:
    """(3, 3) tool rotation pointing straight down; fingers close along ``(cos, sin, 0)`` of
    ``yaw`` rotated by 90 degrees (the tool ``y`` axis is ``(-sin yaw, cos yaw, 0)``)."""
    # tool x -> world -z; tool y -> horizontal; tool z = x cross y.
    x = np.array([0.0, 0.0, -1.0])
    y = np.array([-np.sin(yaw), np.cos(yaw), 0.0])
    z = np.cross(x, y)
    return np.column_stack([x, y, z])


class ArmKinematics:
    """FK and IK of both arms on a private robot-only model (not thread-safe).

    Joint vectors are the 12 arm joints in :data:`ARM_JOINTS` order (left 6, right 6).
    """

    def __init__(self) -> None:
        self.model = build_model(objects=False)
        self.data = mujoco.MjData(self.model)
        self._qadr = np.array([self.model.joint(j).qposadr[0] for j in ARM_JOINTS])
        self._dofadr = {
            "l": [int(self.model.joint(j).dofadr[0]) for j in LEFT_ARM_JOINTS],
            "r": [int(self.model.joint(j).dofadr[0]) for j in RIGHT_ARM_JOINTS],
        }
        self.configuration = mink.Configuration(self.model)
        self._limits = [mink.ConfigurationLimit(self.model)]
        self._frozen = {
            side: mink.DofFreezingTask(
                self.model,
                dof_indices=[i for i in range(self.model.nv) if i not in self._dofadr[side]],
            )
            for side in ("l", "r")
        }
        self._posture = mink.PostureTask(self.model, cost=1e-3)

    def _set(self, q: FloatArray) -> None:
        self.data.qpos[self._qadr] = q
        mujoco.mj_kinematics(self.model, self.data)

    def tool_pose(self, q: FloatArray, side: str = "l") -> tuple[FloatArray, FloatArray]:
        """Position (3,) and rotation (3, 3) of ``{side}_tcp`` at arm joints ``q`` (12,)."""
        self._set(np.asarray(q, dtype=np.float64))
        site = self.data.site(f"{side}_tcp")
        return site.xpos.copy(), site.xmat.reshape(3, 3).copy()

    def solve(self, q_seed: FloatArray, position: FloatArray, rotation: FloatArray,
              side: str = "l", free_roll: bool = False, iterations: int = 300,
              position_tolerance: float = 5e-4, rotation_tolerance: float = 5e-3,
              posture_cost: float = 1e-3, free_axis: int | None = None,
              site: str | None = None) -> IKResult:
        """Arm joints that put ``{side}_tcp`` (or ``site``, a site the ``side`` arm moves)
        at ``position`` (3,) with ``rotation`` (3, 3).

        Args:
            q_seed: (12,) start of the iteration; the other arm keeps its values.
            free_roll: leave the rotation about the approach (tool ``x``) axis free, as for
                grasping the gear, which is symmetric about its axis.
            posture_cost: pull towards ``q_seed`` (keeps the solution near the seed).
            free_axis: leave the rotation about this tool axis (0 ``x``, 1 ``y``, 2 ``z``)
                free (``free_roll`` is ``free_axis=0``).
            site: the site to place (default ``{side}_tcp``; ``peg_tip`` for the peg the
                right hand holds).
        """
        q_seed = np.asarray(q_seed, dtype=np.float64)
        qpos = self.model.qpos0.copy()
        qpos[self._qadr] = q_seed
        self.configuration.update(qpos)
        orientation_cost = np.array([0.0 if free_roll else 1.0, 1.0, 1.0])
        if free_axis is not None:
            orientation_cost[free_axis] = 0.0
        task = mink.FrameTask(site or f"{side}_tcp", "site", position_cost=1.0,
                              orientation_cost=orientation_cost, lm_damping=1e-3)
        task.set_target(mink.SE3.from_rotation_and_translation(
            mink.SO3.from_matrix(np.asarray(rotation)), np.asarray(position)))
        self._posture.set_cost(posture_cost)
        self._posture.set_target(qpos)
        dt = 0.05
        pos_err = rot_err = np.inf
        converged = False
        for _ in range(iterations):
            err = task.compute_error(self.configuration)
            pos_err = float(np.linalg.norm(err[:3]))
            rot_err = float(np.linalg.norm(err[3:] * (orientation_cost > 0)))
            if pos_err < position_tolerance and rot_err < rotation_tolerance:
                converged = True
                break
            vel = mink.solve_ik(self.configuration, [task, self._posture], dt, "daqp",
                                damping=1e-4, limits=self._limits,
                                constraints=[self._frozen[side]])
            self.configuration.integrate_inplace(vel, dt)
        q = self.configuration.q[self._qadr].copy()
        return IKResult(q=q, position_error=pos_err, rotation_error=rot_err, converged=converged)
