"""The ``pick`` option: grasp the gear from the table with the left arm and lift it.

One attempt is a sequence of phases, each a time-parameterised joint path
(:class:`~dynoplan.envs.gear.trajectory.JointPath`):

1. ``move``: an OMPL plan (:class:`~dynoplan.envs.gear.options.motion.LeftArmPlanner`,
   checked by MuJoCo against the table, the robot itself, the peg module and the gear)
   from the current arm configuration to the pre-grasp pose: the tool point
   ``GRASP_TCP_HEIGHT + pregrasp_height`` above the perceived gear bottom, pointing
   down, with the roll about the approach axis left free (the gear is round);
2. ``approach``: straight down to the grasp pose (IK at a few heights, collision-checked);
   a start already on that line (within ``resume_radius``, as after an interrupted
   pick) begins here, since a plan cannot start with the fingers touching the gear;
3. ``close``: the gripper closes for ``close_time``;
4. ``lift``: straight up until the tool point is ``lift_height`` above the grasp height;
5. ``verify``: the neural grasp recogniser
   (:class:`~dynoplan.envs.gear.options.recognition.GraspRecognizer`), applied to every
   observation from the closing on, decides termination: ``P(grasped) > 0.5`` on
   ``confirm_steps`` consecutive observations with the lift finished -> ``"done"``;
   not grasped on ``confirm_steps`` consecutive observations after the lift (or no
   decision within ``verify_steps``) -> the gripper re-opens and, if the gear still
   stands on the table, the attempt is repeated (at most ``max_attempts`` in all);
   otherwise ``"failed"``.

The policy perceives the gear through the observation only (its bottom centre and
quaternion); the planner's collision model is synced from the live scene (the robot's
world model). Without a recogniser (``recognizer=None``) the option is a purely scripted
grasp that finishes when the lift is done; that mode exists to generate the recogniser's
own training data (:func:`~dynoplan.envs.gear.options.recognition.generate_grasp_data`).
"""

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from dynoplan.envs.gear.env import (
    CONTROL_DT,
    GRIPPER_CLOSED,
    GRIPPER_OPEN,
    OBS_SLICES,
    GearAssemblyEnv,
)
from dynoplan.envs.gear.expert import GRASP_TCP_HEIGHT
from dynoplan.envs.gear.kinematics import ArmKinematics, downward_tool_rotation
from dynoplan.envs.gear.options.base import GearOptionPolicy, start_joints
from dynoplan.envs.gear.options.motion import LeftArmPlanner
from dynoplan.envs.gear.options.starts import at_reset
from dynoplan.envs.gear.scene import TABLE_TOP_Z
from dynoplan.envs.gear.state import proximity_beta
from dynoplan.envs.gear.trajectory import JointPath
from dynoplan.options.termination import Termination, TerminationFromCallable
from dynoplan.types import FloatArray, Generator

PICK_NAME = "pick"
"""The option's name (its registry record, datasets, model files, the command line)."""
PICK_START = at_reset
"""Where the option starts (its registry record's ``start``): a fresh reset."""


class GraspProbability(Protocol):
    """What decides the pick's end: ``P(grasped)`` of an observation ``(50,)`` (the
    trained :class:`~dynoplan.envs.gear.options.recognition.GraspRecognizer`)."""

    def probability(self, observations: FloatArray) -> FloatArray | float: ...


LIFTED_HEIGHT = 0.03
"""The pick succeeded when the held gear's bottom is at least this far (m) above the table."""


@dataclass(frozen=True)
class PickConfig:
    """Heights, speeds and the recogniser's decision rule of the pick option."""

    pregrasp_height: float = 0.08  # m, tool point above the grasp pose before descending
    lift_height: float = 0.25  # m, tool point lifted this far above the grasp height
    joint_speed: float = 0.9  # rad/s, largest joint speed of the planned move
    fine_joint_speed: float = 0.5  # rad/s, approach and lift
    accel_time: float = 0.4  # s from rest to full speed
    close_time: float = 0.8  # s with the gripper closing before lifting
    release_time: float = 0.4  # s with the gripper opening before a new attempt
    settle_tolerance: float = 0.03  # rad, tracking error at which a path counts as reached
    cartesian_points: int = 5  # IK waypoints of the straight approach and lift
    confirm_steps: int = 3  # consecutive recogniser decisions needed
    verify_steps: int = 20  # env steps after the lift to reach a decision
    max_attempts: int = 3
    plan_time_limit: float = 1.0  # s of OMPL search per plan
    upright_tilt: float = np.deg2rad(10.0)  # rad, the gear counts as standing below this
    resume_radius: float = 0.02  # m: a start this near the approach line skips the plan


def _up(height: float) -> FloatArray:
    return np.array([0.0, 0.0, height])


def perceived_gear(observation: FloatArray) -> tuple[FloatArray, float]:
    """The gear's bottom centre (3,) and the ``z`` component of its axis (cosine of its
    tilt), read from an observation (50,)."""
    pos = np.asarray(observation[OBS_SLICES["gear_pos"]], dtype=np.float64)
    _, x, y, _ = observation[OBS_SLICES["gear_quat"]]
    axis_z = float(1.0 - 2.0 * (x * x + y * y))
    return pos, axis_z


class PickPolicy(GearOptionPolicy):
    """The pick option's policy ``pi_pick`` (see the module docstring for the phases).

    Args:
        env: the environment it plans in (collision model synced from ``env.data``).
        recognizer: the trained grasp recogniser that decides termination; ``None`` gives
            the scripted mode that finishes when the lift is done (data generation only).
        config: heights, speeds and decision rule.
        planner: the OMPL planner name (:data:`~dynoplan.envs.gear.options.motion.PLANNERS`).

    Attributes:
        phase: the current phase (``move``, ``approach``, ``close``, ``lift``, ``verify``,
            ``release``) or ``""`` once finished.
        attempts: grasp attempts started since ``reset``.
        segments: every joint path commanded since ``reset``, as ``(phase, waypoints
            (K, 12))``; all were collision-checked before being followed.
        grasp_probability: the recogniser's last ``P(grasped)`` (``nan`` before closing).
    """

    name = PICK_NAME

    def __init__(self, env: GearAssemblyEnv, recognizer: GraspProbability | None,
                 config: PickConfig | None = None, planner: str = "RRTConnect") -> None:
        super().__init__(env)
        self.recognizer = recognizer
        self.cfg = config or PickConfig()
        self.planner = LeftArmPlanner(env, planner=planner, time_limit=self.cfg.plan_time_limit)
        self.kin = ArmKinematics()
        self.phase = ""
        self.attempts = 0
        self.segments: list[tuple[str, FloatArray]] = []
        self.grasp_probability = float("nan")
        self._path: JointPath | None = None
        self._grasp_target = np.zeros(3)  # tool point at the grasp (m)
        self._q_cmd = np.zeros(12)
        self._grip = GRIPPER_OPEN
        self._timer = 0.0
        self._yes = 0
        self._no = 0

    # ------------------------------------------------------------------ contract
    def reset(self, observation: Any, rng: Generator) -> None:
        """Plan the first attempt from ``observation`` (50,). ``rng`` is unused: OMPL is
        seeded once per process (:func:`~dynoplan.envs.gear.options.motion.seed_ompl`)."""
        obs = np.asarray(observation, dtype=np.float64)
        self.plan_ms = []
        self.segments = []
        self.attempts = 0
        self.status = "running"
        self.grasp_probability = float("nan")
        self._q_cmd = start_joints(self.env, obs)
        self._grip = GRIPPER_OPEN
        if self.recognizer is not None and self._recognize(obs) > 0.5:
            self._grip = GRIPPER_CLOSED  # already holding it: only lift and confirm
            self._begin_lift(obs)
        else:
            self._begin_attempt(obs)

    def act(self, observation: Any) -> FloatArray:
        """The next action (13,): arm joint targets and the gripper command."""
        obs = np.asarray(observation, dtype=np.float64)
        if not self.finished():
            self._transition(obs)
        if not self.finished() and self._path is not None:
            self._q_cmd = self._path.advance(CONTROL_DT, 1.0, obs[OBS_SLICES["arm_qpos"]])
        self._timer += CONTROL_DT
        return np.concatenate([self._q_cmd, [self._grip]])

    def succeeded(self, info: dict[str, Any]) -> bool:
        """The gear is held by both finger pads and its bottom is >= 3 cm above the table."""
        gear, _ = self.env.gear_pose()
        return int(info["pads_on_gear"]) >= 2 and bool(gear[2] >= TABLE_TOP_Z + LIFTED_HEIGHT)

    def termination(self) -> Termination:
        """``beta_pick``: rises as the human comes close to the tool
        (:func:`~dynoplan.envs.gear.state.proximity_beta`); the grasp itself is judged on
        observations by the recogniser (:meth:`finished`)."""
        return TerminationFromCallable(proximity_beta)

    # ------------------------------------------------------------------ phases
    def _transition(self, obs: FloatArray) -> None:
        cfg = self.cfg
        phase = self.phase
        if phase in ("close", "lift", "verify"):
            self._recognize(obs)
        reached = self._path_done() and self._settled(obs)
        if phase == "move" and reached:
            self._begin_approach(obs)
        elif phase == "approach" and reached:
            self._begin("close", [self._q_cmd], GRIPPER_CLOSED)
        elif phase == "close" and self._timer >= cfg.close_time:
            self._begin_lift(obs)
        elif phase == "lift" and reached:
            self._begin("verify", [self._q_cmd], self._grip)
            self._verify()
        elif phase == "verify":
            self._verify()
        elif phase == "release" and self._timer >= cfg.release_time:
            self._begin_attempt(obs)

    def _verify(self) -> None:
        cfg = self.cfg
        if self.recognizer is None or self._yes >= cfg.confirm_steps:
            self._finish("done")
        elif self._no >= cfg.confirm_steps or self._timer >= cfg.verify_steps * CONTROL_DT:
            self._begin("release", [self._q_cmd], GRIPPER_OPEN)

    def _begin_attempt(self, obs: FloatArray) -> None:
        """Perceive the gear, plan to the pre-grasp pose and start moving there."""
        cfg = self.cfg
        gear, axis_z = perceived_gear(obs)
        standing = axis_z > np.cos(cfg.upright_tilt) and gear[2] < TABLE_TOP_Z + 0.01
        if self.attempts >= cfg.max_attempts or not standing:
            self._finish("failed")
            return
        self.attempts += 1
        q = start_joints(self.env, obs)
        self._grasp_target = gear + _up(GRASP_TCP_HEIGHT)
        tcp = self.kin.tool_pose(q)[0]
        offset = tcp - self._grasp_target
        if (np.hypot(offset[0], offset[1]) < cfg.resume_radius
                and -cfg.resume_radius < offset[2] < cfg.pregrasp_height + cfg.resume_radius):
            # started (again) with the open fingers around the gear, as when a controller
            # stopped an earlier pick there: no plan (the start touches the gear), only
            # the straight approach from here
            self._q_cmd = q
            waypoints = self._straight(q, tcp, self._grasp_target)
            self._begin("approach", waypoints, GRIPPER_OPEN, cfg.fine_joint_speed)
            return
        pregrasp = self._ik(q, self._grasp_target + _up(cfg.pregrasp_height))
        plan = self.planner.plan(q, pregrasp[:6], carry_gear=False)
        self.plan_ms.append(plan.plan_ms)
        if not plan.solved:
            self._finish("failed")
            return
        waypoints = [self.planner.full(p) for p in plan.path]
        self._begin("move", waypoints, GRIPPER_OPEN, cfg.joint_speed)

    def _begin_approach(self, obs: FloatArray) -> None:
        """Straight down from the pre-grasp pose to the grasp pose (open gripper)."""
        q = start_joints(self.env, obs)
        top = self.kin.tool_pose(self._q_cmd)[0]
        waypoints = self._straight(self._q_cmd, top, self._grasp_target)
        self.planner.sync(carry_gear=False)
        if not self.planner.path_is_valid(np.array(waypoints)[:, :6]):
            self._begin("release", [q], GRIPPER_OPEN)  # perceive and plan again
            return
        self._begin("approach", waypoints, GRIPPER_OPEN, self.cfg.fine_joint_speed)

    def _begin_lift(self, obs: FloatArray) -> None:
        """Straight up (keeping the tool's orientation) with the gripper closed."""
        q = start_joints(self.env, obs)
        tcp = self.kin.tool_pose(q)[0]
        top = np.array([tcp[0], tcp[1], TABLE_TOP_Z + GRASP_TCP_HEIGHT + self.cfg.lift_height])
        waypoints = self._straight(q, tcp, top)
        self.planner.sync(carry_gear=True)
        if not self.planner.path_is_valid(np.array(waypoints)[:, :6]):
            self._begin("release", [q], GRIPPER_OPEN)
            return
        self._begin("lift", waypoints, GRIPPER_CLOSED, self.cfg.fine_joint_speed)

    def _begin(self, phase: str, waypoints: list[FloatArray], grip: float,
               speed: float | None = None) -> None:
        self.phase = phase
        self._grip = grip
        self._timer = 0.0
        if phase not in ("lift", "verify"):  # the decisions count from the closing on
            self._yes = self._no = 0
        points = np.array(waypoints, dtype=np.float64)
        self.segments.append((phase, points))
        self._path = JointPath(list(points), speed or self.cfg.fine_joint_speed,
                               self.cfg.accel_time)

    def _finish(self, status: str) -> None:
        self.status = status
        self.phase = ""
        self._path = None

    # ------------------------------------------------------------------ helpers
    def _recognize(self, obs: FloatArray) -> float:
        """Update the consecutive grasped / not-grasped counts from one observation."""
        if self.recognizer is None:
            return float("nan")
        p = float(self.recognizer.probability(obs))
        self.grasp_probability = p
        if p > 0.5:
            self._yes, self._no = self._yes + 1, 0
        else:
            self._yes, self._no = 0, self._no + 1
        return p

    def _ik(self, q_seed: FloatArray, position: FloatArray,
            rotation: FloatArray | None = None) -> FloatArray:
        rot = downward_tool_rotation(0.0) if rotation is None else rotation
        return self.kin.solve(q_seed, position, rot, free_roll=rotation is None).q

    def _straight(self, q0: FloatArray, start: FloatArray, end: FloatArray) -> list[FloatArray]:
        """Joint waypoints (12,) moving the tool point on the segment ``start -> end``
        with the tool's orientation at ``q0`` kept (IK at ``cartesian_points`` points)."""
        _, rot = self.kin.tool_pose(q0)
        points = [q0.copy()]
        for w in np.linspace(0.0, 1.0, self.cfg.cartesian_points + 1)[1:]:
            target = start + w * (end - start)
            points.append(self.kin.solve(points[-1], target, rot, iterations=100).q)
        return points

    def _path_done(self) -> bool:
        return self._path is None or self._path.finished

    def _settled(self, obs: FloatArray) -> bool:
        err = np.max(np.abs(obs[OBS_SLICES["arm_qpos"]] - self._q_cmd))
        return bool(err < self.cfg.settle_tolerance)


__all__ = ["LIFTED_HEIGHT", "PICK_NAME", "PickConfig", "PickPolicy", "perceived_gear"]
