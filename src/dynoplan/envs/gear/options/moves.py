"""The fast move and the cautious move: carry the held gear to the pre-insertion pose.

Both options start with the gear grasped and lifted and end at the **pre-insertion pose**:
the gear's bottom centre :data:`OFFSET_HEIGHT` above the peg tip along the peg axis, the
gear's axis on the peg's axis (where the expert's ``transport`` step ends). The goal
joints come from :func:`pre_insertion_goal` (inverse kinematics with the gear's offset in
the hand measured at the start). Both keep the gripper closed and follow their planned
left-arm path with a trapezoidal time parameterisation (:class:`JointPath`).

- :class:`FastMovePolicy` (paper option 2): one OMPL plan (RRTConnect, then path
  simplification) that ignores the human, followed at full speed. Its termination
  ``beta`` rises as the human comes close (:func:`proximity_beta`) and is 1 at the goal.
- :class:`CautiousMovePolicy` (paper option 3): plans around the human (its current and
  predicted hand poses, inflated by a clearance), replans when the human moves or blocks
  the path, and scales its speed with the predicted robot-human distance
  (speed-and-separation monitoring): full speed when clear, slower when closer, a stop
  below a distance, and a retreat when even a stopped arm would be reached. Its
  termination is 1 at the goal and 0 elsewhere.

The human prediction uses only what the observation carries (the hand's pose and
velocity, extrapolated at constant velocity), never the schedule; the robot's world
model is a :class:`CollisionChecker` synced from the env. The smallest robot-human
distance the cautious move keeps in its trials is :data:`CAUTIOUS_SAFETY_DISTANCE`.
"""

from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from dynoplan.envs.gear.env import CONTROL_DT, GRIPPER_CLOSED, HOME_Q, OBS_SLICES, GearAssemblyEnv
from dynoplan.envs.gear.grasp import ik_gear_at, quat_to_mat
from dynoplan.envs.gear.kinematics import ArmKinematics
from dynoplan.envs.gear.linearise import linearised
from dynoplan.envs.gear.options.base import GearOptionPolicy, start_joints
from dynoplan.envs.gear.options.motion import LeftArmPlanner
from dynoplan.envs.gear.scene import RIGHT_ARM_JOINTS, build_model
from dynoplan.envs.gear.state import STATE_SLICES, proximity_beta
from dynoplan.envs.gear.trajectory import JointPath, within_lag
from dynoplan.errors import DynoplanError
from dynoplan.options.termination import Termination, TerminationFromCallable
from dynoplan.types import FloatArray, Generator

FAST_MOVE_NAME = "fast_move"
"""The fast move's name (its registry record, datasets, model files, the command line)."""
CAUTIOUS_MOVE_NAME = "cautious_move"
"""The cautious move's name."""
OFFSET_HEIGHT = 0.05
"""m: the gear's bottom above the peg tip, along the peg axis, at the pre-insertion pose
(the expert's ``offset_height``)."""
GOAL_TOLERANCE = 0.015
"""m: a move succeeded when the gear's bottom centre is this close to its target."""
CAUTIOUS_SAFETY_DISTANCE = 0.03
"""m: the robot-human distance the cautious move never goes below (its stated safety
distance; measured in option trials as ``info["min_human_distance"]``). It is below the
distances the move itself aims at (:class:`CautiousConfig`) because the robot-human
distance includes the right arm and the peg module, which the option does not move: a
blocking hand alone comes within 3.9 cm of them in one of 100 seeded trials."""
_FAR_AWAY = np.array([10.0, 10.0, 10.0])  # where the fast move's planner puts the human


# ------------------------------------------------------------------------- the goal
def pre_insertion_target(peg_tip: FloatArray, peg_rot: FloatArray,
                         height: float = OFFSET_HEIGHT) -> FloatArray:
    """(3,) where the gear's bottom centre goes: ``height`` above the peg tip (3,) along the
    peg axis (the ``z`` column of ``peg_rot`` (3, 3))."""
    out: FloatArray = np.asarray(peg_tip, dtype=np.float64) + height * peg_rot[:, 2]
    return out


def pre_insertion_goal(kin: ArmKinematics, observation: FloatArray,
                       height: float = OFFSET_HEIGHT,
                       q_seed: FloatArray | None = None) -> tuple[FloatArray, FloatArray]:
    """Arm joints (12,) of the pre-insertion pose for the gear as held in ``observation``
    (50,), and the gear bottom's target point (3,).

    The gear's offset in the hand is taken from the observation (arm joints, gear pose);
    ``q_seed`` (12,) starts the IK (default: the observed arm joints).
    """
    obs = np.asarray(observation, dtype=np.float64)
    q = obs[OBS_SLICES["arm_qpos"]]
    gear_pos = obs[OBS_SLICES["gear_pos"]]
    gear_rot = quat_to_mat(obs[None, OBS_SLICES["gear_quat"]])[0]
    tip = obs[OBS_SLICES["peg_pos"]]
    peg_rot = quat_to_mat(obs[None, OBS_SLICES["peg_quat"]])[0]
    seed = q if q_seed is None else np.asarray(q_seed, dtype=np.float64)
    goal = ik_gear_at(kin, seed, q, gear_pos, gear_rot, tip, peg_rot, height)
    return goal, pre_insertion_target(tip, peg_rot, height)


class PreInsertionBeta:
    """``beta`` on planner states (N, 22): 1 when the gear's bottom is within ``near`` (m)
    of the pre-insertion target, 0 beyond ``far``, linear in between.

    The target follows the peg, whose pose is forward kinematics of the right arm's
    joints in the state (the peg module is part of the right hand); one FK per distinct
    right-arm configuration (rounded to 1e-4 rad), cached.
    """

    def __init__(self, height: float = OFFSET_HEIGHT, near: float = GOAL_TOLERANCE,
                 far: float = 0.04) -> None:
        if not 0.0 <= near < far:
            raise DynoplanError(f"need 0 <= near < far, got near={near}, far={far}")
        self.height, self.near, self.far = height, near, far
        self._model = build_model(objects=False)
        self._data = mujoco.MjData(self._model)
        self._qadr = np.array([self._model.joint(j).qposadr[0] for j in RIGHT_ARM_JOINTS])
        self._site = self._model.site("peg_tip").id
        self._cache: dict[bytes, FloatArray] = {}
        self._linear: dict[bytes, tuple[FloatArray, FloatArray]] = {}

    def target(self, q_right: FloatArray) -> FloatArray:
        """(3,) gear-bottom target for right-arm joints (6,)."""
        key = np.round(np.asarray(q_right, dtype=np.float64), 4)
        k = key.tobytes()
        hit = self._cache.get(k)
        if hit is None:
            if len(self._cache) > 4096:
                self._cache.clear()
            self._data.qpos[self._qadr] = key
            mujoco.mj_kinematics(self._model, self._data)
            rot = self._data.site_xmat[self._site].reshape(3, 3)
            hit = pre_insertion_target(self._data.site_xpos[self._site].copy(), rot,
                                       self.height)
            self._cache[k] = hit
        return hit

    def offset(self, states: FloatArray) -> FloatArray:
        """(N, 3) the gear's bottom minus its target (m) in states (N, 22).

        The right arm holds the peg still, so a batch's right-arm joints stay within a few
        mrad of each other: the target is linearised about the first row's joints rounded
        to 0.01 rad (exact FK there and central differences, cached), which is exact to
        well under a millimetre and costs no FK per row."""
        s = np.atleast_2d(np.asarray(states, dtype=np.float64))
        q = s[:, 6:12]
        q0 = np.round(q[0], 2)
        target0, jacobian = self._linearised(q0)
        targets = target0 + (q - q0) @ jacobian.T
        out: FloatArray = s[:, STATE_SLICES["gear_pos"]] - targets
        return out

    def distance(self, states: FloatArray) -> FloatArray:
        """(N,) distance (m) of the gear's bottom from its target in states (N, 22)."""
        d: FloatArray = np.linalg.norm(self.offset(states), axis=1)
        return d

    def _linearised(self, q0: FloatArray) -> tuple[FloatArray, FloatArray]:
        return linearised(self.target, q0, self._linear, 256)

    def __call__(self, states: FloatArray) -> FloatArray:
        d = self.distance(states)
        out: FloatArray = np.clip((self.far - d) / (self.far - self.near), 0.0, 1.0)
        return out


# ------------------------------------------------------------------------- shared base
class _CarryMove(GearOptionPolicy):
    """What both moves share: the goal, the held gripper, following a path, settling at
    the goal, and the option-level success test."""

    def __init__(self, env: GearAssemblyEnv, *, planner: str, time_limit: float,
                 speed: float, accel_time: float, offset_height: float,
                 settle_tolerance: float, settle_time: float) -> None:
        super().__init__(env)
        if speed <= 0 or accel_time <= 0:
            raise DynoplanError(f"speed and accel_time must be > 0, got {speed}, {accel_time}")
        self.kin = ArmKinematics()
        self.planner = LeftArmPlanner(env, planner=planner, time_limit=time_limit)
        self.speed = speed
        self.accel_time = accel_time
        self.offset_height = offset_height
        self.settle_tolerance = settle_tolerance
        self.settle_time = settle_time
        self.dt = CONTROL_DT
        self.q_cmd = env.arm_qpos
        self.goal = self.q_cmd.copy()
        self.target = np.zeros(3)
        self.path: JointPath | None = None
        self.time = 0.0
        self._settle = 0.0

    def _begin(self, observation: FloatArray) -> None:
        obs = np.asarray(observation, dtype=np.float64)
        self.plan_ms = []
        self.status = "running"
        self.time = 0.0
        self._settle = 0.0
        self.q_cmd = start_joints(self.env, obs)
        self.path = None
        self.goal, self.target = self._goal(obs)

    def _goal(self, obs: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The pre-insertion joints; if the IK seeded at the current joints lands in
        collision, seeds at the home pose are tried too."""
        goal, target = pre_insertion_goal(self.kin, obs, self.offset_height)
        self.planner.sync(carry_gear=True)
        if self.planner.is_valid(goal[:6]):
            return goal, target
        for seed_left in (HOME_Q[:6], 0.5 * (HOME_Q[:6] + goal[:6])):
            seed = np.concatenate([seed_left, obs[OBS_SLICES["arm_qpos"]][6:]])
            alt, _ = pre_insertion_goal(self.kin, obs, self.offset_height, q_seed=seed)
            if self.planner.is_valid(alt[:6]):
                return alt, target
        return goal, target

    def _plan(self, extra_valid: Any = None, ignore_human: bool = False) -> bool:
        """Plan from the commanded joints to the goal; on success the new path replaces
        the old one. Records the planning time."""
        self.planner.sync(carry_gear=True)
        if ignore_human:
            self.planner.checker.set_human(_FAR_AWAY, np.array([1.0, 0.0, 0.0, 0.0]))
        plan = self.planner.plan(self.q_cmd, self.goal[:6], carry_gear=True,
                                 extra_valid=extra_valid, sync=False)
        self.plan_ms.append(plan.plan_ms)
        if not plan.solved:
            return False
        right = self.q_cmd[6:]
        waypoints = [np.concatenate([p, right]) for p in plan.path]
        self.path = JointPath(waypoints, self.speed, self.accel_time)
        return True

    def _action(self) -> FloatArray:
        return np.concatenate([self.q_cmd, [GRIPPER_CLOSED]])

    def _settled(self, obs: FloatArray) -> bool:
        """Called once per step with the path finished: true once the arm has caught up
        with the goal (or has had ``settle_time`` to)."""
        self._settle += self.dt
        err = float(np.max(np.abs(obs[OBS_SLICES["arm_qpos"]] - self.q_cmd)))
        return err < self.settle_tolerance or self._settle >= self.settle_time

    def gear_error(self) -> float:
        """Distance (m) of the gear's bottom centre from the pre-insertion target now."""
        gear, _ = self.env.gear_pose()
        tip, rot = self.env.peg_pose()
        return float(np.linalg.norm(gear - pre_insertion_target(tip, rot, self.offset_height)))

    def succeeded(self, info: dict[str, Any]) -> bool:
        """The gear is still held (both pads on it), its bottom centre is within
        :data:`GOAL_TOLERANCE` of the pre-insertion target, the robot touches nothing."""
        return (int(info["pads_on_gear"]) >= 2 and int(info["robot_collisions"]) == 0
                and self.gear_error() <= GOAL_TOLERANCE)


# ------------------------------------------------------------------------- fast move
class FastMovePolicy(_CarryMove):
    """Paper option 2: carry the gear to the pre-insertion pose along one OMPL path that
    ignores the human, at full speed.

    ``reset`` plans (status ``"failed"`` if no plan); ``act`` follows the path; the status
    becomes ``"done"`` once the arm has settled at the goal.

    Args:
        env: the environment (its live scene is the planner's world model).
        planner, time_limit: OMPL planner name and seconds per plan.
        speed: largest joint speed (rad/s); accel_time: s from rest to full speed.
        offset_height: m of the gear's bottom above the peg tip at the goal.
        settle_tolerance: rad of tracking error below which the arm counts as arrived;
        settle_time: s after the path ends after which it counts as arrived anyway.
    """

    name = FAST_MOVE_NAME

    def __init__(self, env: GearAssemblyEnv, planner: str = "RRTConnect",
                 time_limit: float = 1.0, speed: float = 0.9, accel_time: float = 0.4,
                 offset_height: float = OFFSET_HEIGHT, settle_tolerance: float = 0.01,
                 settle_time: float = 1.0) -> None:
        super().__init__(env, planner=planner, time_limit=time_limit, speed=speed,
                         accel_time=accel_time, offset_height=offset_height,
                         settle_tolerance=settle_tolerance, settle_time=settle_time)
        self._goal_beta = PreInsertionBeta(offset_height)

    def reset(self, observation: Any, rng: Generator) -> None:
        self._begin(observation)
        if not self._plan(ignore_human=True):
            self.status = "failed"

    def act(self, observation: Any) -> FloatArray:
        obs = np.asarray(observation, dtype=np.float64)
        self.time += self.dt
        if self.status == "running" and self.path is not None:
            self.q_cmd = self.path.advance(self.dt, 1.0, obs[OBS_SLICES["arm_qpos"]])
            if self.path.finished and self._settled(obs):
                self.status = "done"
        return self._action()

    def termination(self) -> Termination:
        """``max(proximity_beta, goal beta)``: rises as the human comes close to the tool,
        and is 1 with the gear at the pre-insertion pose."""
        goal_beta = self._goal_beta

        def beta(states: FloatArray) -> FloatArray:
            out: FloatArray = np.maximum(proximity_beta(states), goal_beta(states))
            return out
        return TerminationFromCallable(beta)


# ------------------------------------------------------------------------- cautious move
@dataclass(frozen=True)
class CautiousConfig:
    """Speeds and distances of the cautious move (m, s, rad/s).

    Speed and separation: every step the robot-human distance is predicted over
    ``horizon`` s for the robot continuing along its path at a speed scale, the hand
    moving at its observed velocity. The largest scale in ``scales`` is taken whose
    predicted distance ``d`` stays above ``stop_distance`` and that is at most the ramp
    ``(d - stop_distance) / (clear_distance - stop_distance)`` (the smallest scale needs
    only the first); if none, the arm stops if a stopped arm is predicted to keep
    ``stop_distance``, else it backs away (``retreat_speed``) along the candidate
    motion with the largest predicted distance.

    Planning: the hand (at its current pose and where it is predicted
    ``predict_time`` s ahead) is an obstacle inflated by ``plan_clearance``. The arm
    replans when the hand blocks the rest of its path (closer than
    ``block_clearance``) or has moved ``replan_move`` since the last plan, at most every
    ``replan_period`` s.
    """

    speed: float = 0.9
    accel_time: float = 0.4
    retreat_speed: float = 0.8
    retreat_refresh: float = 0.2
    horizon: float = 1.0
    horizon_samples: int = 10
    clear_distance: float = 0.20
    stop_distance: float = 0.09
    scales: tuple[float, ...] = (1.0, 0.7, 0.45, 0.25)
    plan_clearance: float = 0.11
    block_clearance: float = 0.095
    predict_time: float = 0.5
    replan_move: float = 0.08
    replan_period: float = 0.5
    time_limit: float = 0.5
    settle_tolerance: float = 0.01
    settle_time: float = 1.0
    max_time: float = 30.0


class CautiousMovePolicy(_CarryMove):
    """Paper option 3: carry the gear to the pre-insertion pose while keeping clear of the
    human (see :class:`CautiousConfig` for the rules).

    ``reset`` computes the goal and tries a first plan; ``act`` replans when needed and
    moves by speed-and-separation monitoring; the status becomes ``"done"`` once the arm
    has settled at the goal, ``"failed"`` after ``max_time`` s without arriving.
    """

    name = CAUTIOUS_MOVE_NAME

    def __init__(self, env: GearAssemblyEnv, config: CautiousConfig | None = None,
                 planner: str = "RRTConnect", offset_height: float = OFFSET_HEIGHT) -> None:
        cfg = config or CautiousConfig()
        super().__init__(env, planner=planner, time_limit=cfg.time_limit, speed=cfg.speed,
                         accel_time=cfg.accel_time, offset_height=offset_height,
                         settle_tolerance=cfg.settle_tolerance, settle_time=cfg.settle_time)
        self.cfg = cfg
        self.checker = env.collision_checker()  # the robot's world model, synced each step
        self._taus = np.linspace(0.0, cfg.horizon, cfg.horizon_samples + 1)
        self._goal_beta = PreInsertionBeta(offset_height)
        self._last_plan_time = -np.inf
        self._last_plan_hand = np.zeros(3)
        self._hand = np.zeros(3)
        self._hand_quat = np.array([1.0, 0.0, 0.0, 0.0])
        self._hand_vel = np.zeros(3)
        self._retreat_goals: list[FloatArray] = []
        self._retreat_since = -np.inf
        self.carry_gear = True
        """Whether the robot's world model carries the gear in the hand (the moves always
        do; the give-way option only when it holds the gear)."""
        self.mode = "idle"
        """What the last ``act`` did: ``"move"``, ``"slow"``, ``"stop"``, ``"retreat"``,
        ``"settle"`` (at the goal) or ``"wait"`` (no path yet)."""

    # ---------------------------------------------------------------- lifecycle
    def reset(self, observation: Any, rng: Generator) -> None:
        obs = np.asarray(observation, dtype=np.float64)
        self._begin(obs)
        self._last_plan_time = -np.inf
        self._retreat_goals = []
        self._retreat_since = -np.inf
        self.mode = "idle"
        self._observe(obs)
        self._replan()

    def act(self, observation: Any) -> FloatArray:
        obs = np.asarray(observation, dtype=np.float64)
        cfg = self.cfg
        self.time += self.dt
        if self.status != "running":
            return self._action()
        if self.time > cfg.max_time:
            self.status = "failed"
            return self._action()
        self._observe(obs)
        if self._needs_plan() and self.time - self._last_plan_time >= cfg.replan_period:
            self._replan()
        self._monitor(obs)
        return self._action()

    def termination(self) -> Termination:
        """1 with the gear at the pre-insertion pose (within :data:`GOAL_TOLERANCE`),
        falling to 0 at 4 cm from it."""
        return TerminationFromCallable(self._goal_beta)

    # ---------------------------------------------------------------- the human
    def _observe(self, obs: FloatArray) -> None:
        self.checker.sync(self.env.data, carry_gear=self.carry_gear)
        self._hand = obs[OBS_SLICES["human_pos"]].copy()
        self._hand_quat = obs[OBS_SLICES["human_quat"]].copy()
        self._hand_vel = obs[OBS_SLICES["human_vel"]].copy()

    def _hands(self, taus: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Predicted hand positions (T, 3) and orientations (T, 4) ``taus`` s ahead."""
        pos = self._hand[None, :] + taus[:, None] * self._hand_vel[None, :]
        return pos, np.repeat(self._hand_quat[None, :], len(taus), axis=0)

    def _hand_times(self) -> FloatArray:
        """The times ahead (s) at which the hand is an obstacle: now and ``predict_time``
        ahead, or now alone when it is predicted where it is (at rest: the same pose
        twice gives the same answers)."""
        ahead = self._hand + self.cfg.predict_time * self._hand_vel
        return np.array([0.0] if np.array_equal(ahead, self._hand)
                        else [0.0, self.cfg.predict_time])

    def _clearance(self, qs: FloatArray, taus: FloatArray | None = None) -> float:
        """Smallest predicted robot-human distance with the arms at ``qs`` (T, 12) at
        times ``taus`` (default: the monitoring horizon), capped at 0.5 m."""
        t = self._taus if taus is None else taus
        pos, quat = self._hands(t)
        d = self.checker.human_distance_along(qs, pos, quat, cap=0.5)
        self.checker.set_human(self._hand, self._hand_quat)  # back to the observed pose
        return d

    # ---------------------------------------------------------------- planning
    def _needs_plan(self) -> bool:
        if self.path is None:
            return True
        if self.path.finished:
            return False
        moved = float(np.linalg.norm(self._hand - self._last_plan_hand))
        if moved >= self.cfg.replan_move and len(self.path.points) > 2:
            return True  # a detour around a hand that has moved: look for a better path
        return self._blocked()

    def _blocked(self) -> bool:
        """Whether the rest of the path passes closer than ``block_clearance`` to the hand
        where it is now or where it is predicted to be."""
        assert self.path is not None
        s = np.linspace(self.path.s, 1.0, 12)
        qs = np.array([self.path.at(float(v)) for v in s])
        for tau in self._hand_times():
            taus = np.full(len(qs), tau)
            if self._clearance(qs, taus) < self.cfg.block_clearance:
                return True
        return False

    def _replan(self) -> None:
        """Plan around the inflated hand (now and predicted); keep the old path if no plan
        is found (the monitor still keeps the arm clear)."""
        cfg = self.cfg
        self._last_plan_time = self.time
        self._last_plan_hand = self._hand.copy()
        poses = self._hands(self._hand_times())
        checker = self.checker
        start_clear = min(self._static_clearance(self.q_cmd, poses), cfg.plan_clearance)
        # Near the hand already: accept states no closer than the start (moving away).
        needed = min(cfg.plan_clearance, max(start_clear - 0.005, cfg.stop_distance))
        if start_clear < cfg.stop_distance:
            return

        def clear(q12: FloatArray) -> bool:
            for p, quat in zip(*poses, strict=True):
                checker.set_human(p, quat)
                d = checker.human_distance(q12, distmax=needed + 0.01, stop_below=needed)
                if d < needed:
                    return False
            return True

        old = self.path
        if not self._plan(extra_valid=clear):
            self.path = old
        checker.sync(self.env.data, carry_gear=self.carry_gear)

    def _static_clearance(self, q: FloatArray, poses: tuple[FloatArray, FloatArray]) -> float:
        d = np.inf
        for p, quat in zip(*poses, strict=True):
            self.checker.set_human(p, quat)
            d = min(d, self.checker.human_distance(q))
        self.checker.sync(self.env.data, carry_gear=self.carry_gear)
        return float(d)

    # ---------------------------------------------------------------- monitoring
    def _monitor(self, obs: FloatArray) -> None:
        """Advance along the path at the speed the predicted separation allows; stop or
        back away when the human comes too close."""
        cfg = self.cfg
        path = self.path
        q_hold = self.q_cmd.copy()
        if path is not None and not path.finished:
            for scale in cfg.scales:
                d = self._clearance(np.array([path.preview(t, scale) for t in self._taus]))
                ramp = (d - cfg.stop_distance) / (cfg.clear_distance - cfg.stop_distance)
                if d >= cfg.stop_distance and (scale <= ramp or scale == cfg.scales[-1]):
                    self.q_cmd = path.advance(self.dt, scale, obs[OBS_SLICES["arm_qpos"]])
                    self.mode = "move" if scale == cfg.scales[0] else "slow"
                    return
        hold = self._clearance(np.repeat(q_hold[None, :], len(self._taus), axis=0))
        if hold >= cfg.stop_distance:
            if path is not None:
                path.sdot = 0.0
            if path is not None and path.finished:
                self.mode = "settle"
                if self._settled(obs):
                    self.status = "done"
            else:
                self.mode = "stop" if path is not None else "wait"
            return
        self._retreat(obs)

    def _retreat(self, obs: FloatArray) -> None:
        """Back away along the candidate motion with the largest predicted clearance:
        towards home, the tool up or down, back towards the torso (level, up or down),
        away from the hand (up or down), or back to where the path started. The
        candidates' end poses are solved when a retreat begins and again every
        ``retreat_refresh`` s (from where the arm is then). The path is dropped (the arm
        replans from where it ends up). A retreat runs from its own last target, kept
        within :data:`~dynoplan.envs.gear.trajectory.MAX_LAG` of the measured joints
        (``obs``), so that a protective stop does not let it run away from the arm."""
        cfg = self.cfg
        q0 = within_lag(self.q_cmd, obs[OBS_SLICES["arm_qpos"]])
        if self.mode != "retreat" or self.time - self._retreat_since >= cfg.retreat_refresh:
            self._retreat_goals = self._retreat_candidates(q0)
            self._retreat_since = self.time
        best, best_d = None, -np.inf
        # a start already touching something (the carried gear resting on the peg) must
        # not rule out every way back: then the gear's own contacts are not counted
        scraping = self.checker.in_collision(q0)
        for goal in self._retreat_goals:
            path = JointPath([q0, goal], cfg.retreat_speed, cfg.accel_time)
            qs = np.array([path.preview(t, 1.0) for t in self._taus])
            if any(self.checker.in_collision(q, ignore_gear=scraping) for q in qs[3::3]):
                continue
            d = self._clearance(qs)
            if d > best_d:
                best, best_d = path, d
        if best is not None:
            lim = self.env.joint_limits
            self.q_cmd = np.clip(best.preview(self.dt, 1.0), lim[:, 0], lim[:, 1])
        self.path = None
        self.mode = "retreat"

    def _retreat_candidates(self, q0: FloatArray) -> list[FloatArray]:
        """End poses (12,) of the retreat motions from ``q0`` (12,)."""
        tcp, rot = self.kin.tool_pose(q0)
        away = tcp - self._hand
        away[2] = 0.0
        away = 0.12 * away / max(float(np.linalg.norm(away)), 1e-6)
        goals = [np.concatenate([HOME_Q[:6], q0[6:]])]
        for shift in (np.array([0.0, 0.0, 0.1]), np.array([-0.15, 0.0, 0.0]),
                      np.array([-0.1, 0.0, 0.08]), np.array([-0.15, 0.0, -0.06]),
                      np.array([0.0, 0.0, -0.06]),
                      away + np.array([0.0, 0.0, 0.05]), away - np.array([0.0, 0.0, 0.05])):
            goals.append(self.kin.solve(q0, tcp + shift, rot, iterations=80).q)
        if self.path is not None and self.path.s > 0:
            goals.append(self.path.at(0.0))
        return goals


__all__ = ["CAUTIOUS_MOVE_NAME", "CAUTIOUS_SAFETY_DISTANCE", "FAST_MOVE_NAME", "GOAL_TOLERANCE",
           "OFFSET_HEIGHT", "CautiousConfig", "CautiousMovePolicy", "FastMovePolicy",
           "PreInsertionBeta", "pre_insertion_goal", "pre_insertion_target"]
