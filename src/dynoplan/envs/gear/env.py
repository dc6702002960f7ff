"""``dynoplan/GearAssembly-v0``: pick a compound gear with the left arm and put it on the
peg held by the right hand, while a human operator may reach into the workspace.

The state the planner uses (the paper's) is the 12 arm joint angles; the observation adds
what a learned model or a policy may want on top of it. See ``docs/gear.md``.
"""

from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
import numpy.typing as npt
from gymnasium import spaces

from dynoplan.envs.gear.collision import (
    CollisionChecker,
    GeomSets,
    count_contacts,
    min_distance,
)
from dynoplan.envs.gear.human import BEHAVIOURS, HumanSchedule, sample_schedule
from dynoplan.envs.gear.render import SceneRenderer
from dynoplan.envs.gear.scene import (
    ARM_ACTUATORS,
    ARM_JOINTS,
    FINGER_JOINTS,
    FINGER_TRAVEL,
    GRIPPER_ACTUATORS,
    TABLE_TOP_Z,
    TIMESTEP,
    build_model,
)
from dynoplan.envs.gear.task import STAGE_INDEX, STAGES, is_seated, relation, stage
from dynoplan.types import FloatArray

CONTROL_HZ = 20
SUBSTEPS = round(1.0 / (CONTROL_HZ * TIMESTEP))  # physics steps per env step (25)
CONTROL_DT = SUBSTEPS * TIMESTEP  # s
MAX_EPISODE_STEPS = 800
"""An episode's default step limit (40 s)."""

HOME_LEFT = np.array([0.6879, -0.3073, 1.55, -1.8537, 1.2697, -1.5054])
"""Left arm at rest: tool point at (0.5, 0.2, 0.95), pointing down, elbow out."""
RIGHT_HOLD = np.array([-0.6791, 0.2369, -1.8722, -1.6529, 1.3002, -0.2717])
"""Right arm holding the peg module upright in front of the robot (tool point at
(0.62, -0.08, 0.84), approach axis 60 degrees left of ``x``; found with :mod:`.kinematics`)."""
HOME_Q = np.concatenate([HOME_LEFT, RIGHT_HOLD])

GEAR_X_RANGE = (0.50, 0.68)
GEAR_Y_RANGE = (0.12, 0.38)
GEAR_YAW_RANGE = (-np.pi, np.pi)

GRIPPER_OPEN, GRIPPER_CLOSED = 0.0, 1.0

OBS_SLICES: dict[str, slice] = {
    "arm_qpos": slice(0, 12),
    "arm_qvel": slice(12, 24),
    "fingers": slice(24, 26),
    "gear_pos": slice(26, 29),
    "gear_quat": slice(29, 33),
    "peg_pos": slice(33, 36),
    "peg_quat": slice(36, 40),
    "human_pos": slice(40, 43),
    "human_quat": slice(43, 47),
    "human_vel": slice(47, 50),
}
"""Layout of the observation vector (``float64``, 50 values)."""
OBS_DIM = 50
ACT_DIM = 13


def _observation_bounds(joint_limits: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Generous finite bounds of the observation: (50,) low and high."""
    low = np.full(OBS_DIM, -5.0)
    high = np.full(OBS_DIM, 5.0)
    low[OBS_SLICES["arm_qpos"]] = joint_limits[:, 0] - 0.1
    high[OBS_SLICES["arm_qpos"]] = joint_limits[:, 1] + 0.1
    low[OBS_SLICES["arm_qvel"]], high[OBS_SLICES["arm_qvel"]] = -100.0, 100.0
    low[OBS_SLICES["fingers"]], high[OBS_SLICES["fingers"]] = -0.01, FINGER_TRAVEL + 0.01
    for quat in ("gear_quat", "peg_quat", "human_quat"):
        low[OBS_SLICES[quat]], high[OBS_SLICES[quat]] = -1.0, 1.0
    return low, high


class GearAssemblyEnv(gym.Env[FloatArray, FloatArray]):
    """Two-arm gear assembly in MuJoCo.

    Action (13,) ``float64``: position targets of the 12 arm joints (rad, within the
    joint limits, :data:`ARM_JOINTS` order), then the left gripper command in ``[0, 1]``
    (0 open, 1 closed; fingers squeeze with at most 12 N each). Targets are held for
    ``SUBSTEPS`` = 25 physics steps of 2 ms (a 20 Hz decision rate).

    Observation (50,) ``float64``, see :data:`OBS_SLICES`: arm joint angles and
    velocities, the two left finger openings (m), the gear's pose (bottom centre, ``wxyz``
    quaternion), the peg's pose (tip, quaternion; ``z`` is its axis), the human hand's
    pose and velocity.

    Reward: 1 on the step the gear becomes seated, else 0. ``terminated`` on success or
    when the gear has fallen off the table (``info["gear_dropped"]``); ``truncated``
    after ``max_episode_steps``.

    ``info``: ``stage`` (index into :data:`STAGES`), ``is_success``,
    ``min_human_distance`` (m, robot-human, after the step), ``human_contacts`` (physics
    steps in this env step with a robot-human contact), ``human_contacts_total``,
    ``robot_collisions`` (robot contacts with the table or itself after the step),
    ``pads_on_gear`` (0..2), ``insertion_depth`` (m), ``gear_tilt`` (rad), ``time`` (s),
    ``robot_speed`` (m/s, the fastest centre of the robot's colliding geoms: the arm, not
    the tool point alone) and ``human_speed`` (m/s, the hand's).

    ``reset(options=...)`` accepts ``gear_pose=(x, y, yaw)``, ``human_mode`` (one of
    :data:`~dynoplan.envs.gear.human.BEHAVIOURS`) and ``human_schedule`` (a
    :class:`HumanSchedule`).

    ``human_behaviours``: the behaviours a reset draws from, uniformly (``None``: the
    demonstrations' mix of ``away``, ``cross`` and ``block``,
    :func:`~dynoplan.envs.gear.human.sample_schedule`'s default).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": CONTROL_HZ}  # noqa: RUF012

    def __init__(self, render_mode: str | None = None,
                 max_episode_steps: int = MAX_EPISODE_STEPS,
                 width: int = 640, height: int = 480, camera: str = "overview",
                 human_behaviours: tuple[str, ...] | None = None) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        unknown = [b for b in human_behaviours or () if b not in BEHAVIOURS]
        if unknown or human_behaviours == ():
            raise ValueError(f"human_behaviours must be some of {BEHAVIOURS}, got "
                             f"{human_behaviours!r}")
        self.human_behaviours = human_behaviours
        if max_episode_steps < 1:
            raise ValueError(f"max_episode_steps must be >= 1, got {max_episode_steps}")
        self.render_mode = render_mode
        self.max_episode_steps = max_episode_steps
        self.model = build_model()
        self.data = mujoco.MjData(self.model)
        self.geoms = GeomSets.from_model(self.model)
        m = self.model
        self.arm_joint_names: tuple[str, ...] = ARM_JOINTS
        self.arm_qpos_ids = np.array([m.joint(j).qposadr[0] for j in ARM_JOINTS])
        self.arm_dof_ids = np.array([m.joint(j).dofadr[0] for j in ARM_JOINTS])
        self.arm_actuator_ids = np.array([m.actuator(a).id for a in ARM_ACTUATORS])
        self.gripper_actuator_ids = np.array([m.actuator(a).id for a in GRIPPER_ACTUATORS])
        self.finger_qpos_ids = np.array([m.joint(j).qposadr[0] for j in FINGER_JOINTS])
        self.joint_limits: FloatArray = m.jnt_range[[m.joint(j).id for j in ARM_JOINTS]].copy()
        """(12, 2) lower and upper limit of each arm joint (rad)."""
        self._gear_qadr = int(m.joint("gear_free").qposadr[0])
        self._gear_dadr = int(m.joint("gear_free").dofadr[0])
        self._gear_body = m.body("gear").id
        self._peg_tip = m.site("peg_tip").id
        self._contact_sensor = int(m.sensor_adr[m.sensor("human_contact").id])
        self._table_mask = np.zeros(m.ngeom, dtype=bool)
        self._table_mask[self.geoms.table] = True
        self._pad_masks = []
        for pad in self.geoms.pads:
            mask = np.zeros(m.ngeom, dtype=bool)
            mask[pad] = True
            self._pad_masks.append(mask)

        low = np.concatenate([self.joint_limits[:, 0], [0.0]])
        high = np.concatenate([self.joint_limits[:, 1], [1.0]])
        self._act_low, self._act_high = low, high
        self.action_space = spaces.Box(low=low, high=high, dtype=np.float64)
        self.observation_space = spaces.Box(*_observation_bounds(self.joint_limits),
                                            dtype=np.float64)

        self.width, self.height, self.camera = width, height, camera
        self._renderer: SceneRenderer | None = None
        self.schedule: HumanSchedule = sample_schedule(
            np.random.default_rng(0), np.array([0.6, 0.25]), np.zeros(3), mode="away")
        self._steps = 0
        self._contacts_total = 0
        self._min_distance_episode = np.inf

    # ----------------------------------------------------------------- Gymnasium API
    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[FloatArray, dict[str, Any]]:
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = set(options) - {"gear_pose", "human_mode", "human_schedule",
                                  *self.reset_options}
        if unknown:
            raise ValueError(f"unknown reset options {sorted(unknown)}")
        rng = self.np_random
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        d.qpos[self.arm_qpos_ids] = HOME_Q
        d.qpos[self.finger_qpos_ids] = FINGER_TRAVEL
        d.ctrl[self.arm_actuator_ids] = HOME_Q
        d.ctrl[self.gripper_actuator_ids] = GRIPPER_OPEN

        if "gear_pose" in options:
            x, y, yaw = (float(v) for v in options["gear_pose"])
        else:
            x = rng.uniform(*GEAR_X_RANGE)
            y = rng.uniform(*GEAR_Y_RANGE)
            yaw = rng.uniform(*GEAR_YAW_RANGE)
        a = self._gear_qadr
        d.qpos[a:a + 3] = (x, y, TABLE_TOP_Z)
        d.qpos[a + 3:a + 7] = (np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2))
        self._place_peg(rng, options)
        mujoco.mj_kinematics(m, d)

        if "human_schedule" in options:
            schedule = options["human_schedule"]
            if not isinstance(schedule, HumanSchedule):
                raise TypeError("human_schedule must be a HumanSchedule")
            self.schedule = schedule
        else:
            mode = options.get("human_mode")
            if mode is not None and mode not in BEHAVIOURS:
                raise ValueError(f"human_mode must be one of {BEHAVIOURS}, got {mode!r}")
            if mode is None and self.human_behaviours is not None:
                mode = self.human_behaviours[int(rng.integers(len(self.human_behaviours)))]
            self.schedule = sample_schedule(rng, np.array([x, y]),
                                            d.site_xpos[self._peg_tip].copy(), mode=mode)
        self._set_human(0.0)
        mujoco.mj_forward(m, d)
        self._steps = 0
        self._contacts_total = 0
        self._min_distance_episode = np.inf
        info = self._info(human_contacts=0)
        return self._observation(), info

    def step(self, action: FloatArray) -> tuple[FloatArray, float, bool, bool, dict[str, Any]]:
        act = np.asarray(action, dtype=np.float64)
        if act.shape != (ACT_DIM,):
            raise ValueError(f"action must have shape ({ACT_DIM},), got {act.shape}")
        if not np.all(np.isfinite(act)):
            raise ValueError("action contains NaN or infinity")
        act = np.clip(act, self._act_low, self._act_high)
        m, d = self.model, self.data
        d.ctrl[self.arm_actuator_ids] = act[:12]
        d.ctrl[self.gripper_actuator_ids] = act[12]

        t0 = d.time
        times = t0 + TIMESTEP * np.arange(1, SUBSTEPS + 1)
        hand = self.schedule.position(times)
        d.mocap_quat[0] = self.schedule.quaternion(hand[SUBSTEPS // 2])
        sensor = d.sensordata
        adr = self._contact_sensor
        contact_steps = 0
        for i in range(SUBSTEPS):
            d.mocap_pos[0] = hand[i]
            mujoco.mj_step(m, d)
            if sensor[adr] > 0:  # contacts of this physics step's state
                contact_steps += 1
        self._steps += 1
        self._contacts_total += contact_steps
        info = self._info(human_contacts=contact_steps)
        success = bool(info["is_success"])
        terminated = success or bool(info["gear_dropped"])
        truncated = (not terminated) and self._steps >= self.max_episode_steps
        if not np.all(np.isfinite(d.qpos)):
            raise RuntimeError("simulation diverged (non-finite state)")
        return self._observation(), float(success), terminated, truncated, info

    def render(self) -> npt.NDArray[np.uint8] | None:
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            self._renderer = SceneRenderer(self.model, self.width, self.height, self.camera)
        return self._renderer.render(self.data)

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def copy_state_from(self, other: "GearAssemblyEnv") -> tuple[FloatArray, dict[str, Any]]:
        """Make this env an exact copy of ``other``'s current state (physics, human
        schedule, counters), for planning with the simulator itself as the model; returns
        the observation and info there."""
        mujoco.mj_copyData(self.data, self.model, other.data)
        self.schedule = other.schedule
        self._steps = other._steps
        self._contacts_total = other._contacts_total
        self._min_distance_episode = other._min_distance_episode
        return self._observation(), self._info(human_contacts=0)

    # ------------------------------------------------------------ for planners etc.
    @property
    def time(self) -> float:
        """Simulated time since reset (s)."""
        return float(self.data.time)

    @property
    def arm_qpos(self) -> FloatArray:
        """(12,) current arm joint angles (the planner's state)."""
        return self.data.qpos[self.arm_qpos_ids].copy()

    @property
    def arm_targets(self) -> FloatArray:
        """(12,) the arms' last commanded joint targets (both arms' position actuators):
        where the robot is holding them, which under gravity is a few mrad above where
        the joints are measured."""
        return self.data.ctrl[self.arm_actuator_ids].copy()

    def collision_checker(self) -> CollisionChecker:
        """A new checker on a scratch ``MjData`` of this model (see :class:`CollisionChecker`)."""
        return CollisionChecker(self.model)

    def gear_pose(self) -> tuple[FloatArray, FloatArray]:
        """Gear bottom centre (3,) and rotation (3, 3)."""
        return (self.data.xpos[self._gear_body].copy(),
                self.data.xmat[self._gear_body].reshape(3, 3).copy())

    def peg_pose(self) -> tuple[FloatArray, FloatArray]:
        """Peg tip (3,) and rotation (3, 3) (``z``: the peg axis, pointing out of the tip)."""
        return (self.data.site_xpos[self._peg_tip].copy(),
                self.data.site_xmat[self._peg_tip].reshape(3, 3).copy())

    def set_human_schedule(self, schedule: HumanSchedule) -> tuple[FloatArray, dict[str, Any]]:
        """Replace the human's schedule mid-episode (times are absolute simulated time);
        returns the observation and info of the current state under it, without stepping."""
        self.schedule = schedule
        self._set_human(self.time)
        mujoco.mj_forward(self.model, self.data)
        return self._observation(), self._info(human_contacts=0)

    # --------------------------------------------------------------------- internals
    reset_options: tuple[str, ...] = ()
    """Further ``reset(options=...)`` keys a task variant reads (:meth:`_place_peg`)."""

    def _place_peg(self, rng: np.random.Generator, options: dict[str, Any]) -> None:
        """Where the right hand holds the peg module this episode, drawn from ``rng``
        after the gear's pose and before the human's schedule (which aims at the peg):
        here always :data:`RIGHT_HOLD`, drawing nothing; a task variant
        (:class:`~dynoplan.envs.gear.peg_pose.GearPegPoseEnv`) overrides it."""

    def _set_human(self, t: float) -> None:
        pos = self.schedule.position(t)
        self.data.mocap_pos[0] = pos
        self.data.mocap_quat[0] = self.schedule.quaternion(pos)

    def _observation(self) -> FloatArray:
        d = self.data
        a = self._gear_qadr
        peg_quat = np.empty(4)
        mujoco.mju_mat2Quat(peg_quat, d.site_xmat[self._peg_tip])
        return np.concatenate([
            d.qpos[self.arm_qpos_ids],
            d.qvel[self.arm_dof_ids],
            d.qpos[self.finger_qpos_ids],
            d.qpos[a:a + 7],
            d.site_xpos[self._peg_tip],
            peg_quat,
            d.mocap_pos[0],
            d.mocap_quat[0],
            self.schedule.velocity(float(d.time)),
        ])

    def _info(self, human_contacts: int) -> dict[str, Any]:
        m, d = self.model, self.data
        gear_pos, gear_rot = self.gear_pose()
        peg_tip, peg_rot = self.peg_pose()
        rel = relation(gear_pos, gear_rot, peg_tip, peg_rot)
        pads = sum(int(count_contacts(d, mask, self.geoms.is_gear) > 0)
                   for mask in self._pad_masks)
        on_table = bool(gear_pos[2] < TABLE_TOP_Z + 0.005 and gear_rot[2, 2] > np.cos(0.2))
        dist = min_distance(m, d, self.geoms.human, self.geoms.robot)
        self._min_distance_episode = min(self._min_distance_episode, dist)
        robot_collisions = (count_contacts(d, self.geoms.is_robot, self._table_mask)
                            + count_contacts(d, self.geoms.is_robot, self.geoms.is_robot))
        st = stage(rel, pads, on_table)
        info: dict[str, Any] = {
            "stage": st,
            "is_success": bool(is_seated(rel)),
            "min_human_distance": dist,
            "min_human_distance_episode": self._min_distance_episode,
            "human_contacts": human_contacts,
            "human_contacts_total": self._contacts_total,
            "robot_collisions": robot_collisions,
            "pads_on_gear": pads,
            "insertion_depth": rel.depth,
            "gear_tilt": rel.tilt,
            "gear_dropped": bool(gear_pos[2] < TABLE_TOP_Z - 0.2),
            "time": float(d.time),
            "robot_speed": self.robot_speed(),
            "human_speed": float(np.linalg.norm(self.schedule.velocity(float(d.time)))),
        }
        return info

    def robot_speed(self) -> float:
        """m/s: the largest linear speed of the centre of any colliding robot geom."""
        m, d = self.model, self.data
        velocity = np.empty(6)
        fastest = 0.0
        for geom in self.geoms.robot:
            mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_GEOM, int(geom), velocity, 0)
            fastest = max(fastest, float(np.linalg.norm(velocity[3:])))
        return fastest


__all__ = ["OBS_SLICES", "STAGES", "STAGE_INDEX", "GearAssemblyEnv"]
