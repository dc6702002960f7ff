"""A scripted expert with privileged state that demonstrates the gear assembly.

It solves the task through the paper's four options
(:data:`~dynoplan.envs.gear.options.catalog.PAPER_OPTIONS`) and labels every action with
one:

- ``pick`` (0): move above the gear, descend, close the gripper, lift;
- ``fast_move`` (1): carry the gear to an offset above the peg (a joint-space path,
  checked for collisions with MuJoCo itself);
- ``cautious_move`` (2): any step after the pick on which the human forces the expert
  off its nominal motion: it slows down, stops, or backs away (giving way while picking
  keeps the ``pick`` label: the cautious move is a transport of the held gear, and its
  region should not cover the states before the grasp);
- ``insert`` (3): lower the gear along the peg's axis, re-aligning it every step from the
  measured gear pose, and back off and retry when it jams.

Privileged state: the expert reads the gear's and the peg's poses from the simulator and
knows the human's schedule, so it predicts the robot-human distance one second ahead
for each candidate motion (continue, slow down, stop, back off) and takes the first that
keeps its clearance. The prediction uses the same MuJoCo geometry as the environment's
safety measurement (:class:`~dynoplan.envs.gear.collision.CollisionChecker`).
"""

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from dynoplan.envs.gear.env import GRIPPER_CLOSED, GRIPPER_OPEN, HOME_Q, GearAssemblyEnv
from dynoplan.envs.gear.grasp import ik_gear_at
from dynoplan.envs.gear.kinematics import ArmKinematics, downward_tool_rotation
from dynoplan.envs.gear.scene import TABLE_TOP_Z
from dynoplan.envs.gear.task import STAGE_INDEX
from dynoplan.envs.gear.trajectory import JointPath
from dynoplan.types import FloatArray

PICK, FAST_MOVE, CAUTIOUS_MOVE, INSERT = range(4)
"""The labels of the paper's four options: their indices in the option registry, which
registers them first, in this order (the catalog checks it:
:data:`~dynoplan.envs.gear.options.catalog.PAPER_OPTIONS`)."""

_STEP_OPTION = {"approach": PICK, "descend": PICK, "close": PICK, "lift": PICK,
                "transport": FAST_MOVE, "insert": INSERT, "done": INSERT, "failed": PICK}
GRASP_TCP_HEIGHT = 0.023  # tool point above the gear's bottom when grasping (m)


@dataclass(frozen=True)
class ExpertConfig:
    """Speeds, heights and safety distances of the expert."""

    joint_speed: float = 0.9  # rad/s, largest joint speed of free moves
    fine_joint_speed: float = 0.5  # rad/s, descend and lift
    cautious_scale: float = 0.35  # fraction of the nominal speed near the human
    retreat_speed: float = 0.8  # rad/s
    accel_time: float = 0.4  # s from rest to full speed
    pregrasp_height: float = 0.08  # m above the grasp pose
    lift_height: float = 0.25  # m, gear lifted this far above the table
    offset_height: float = 0.05  # m, gear bottom above the peg tip after fast_move
    insert_speed: float = 0.04  # m/s until the gear reaches the tip
    insert_speed_slow: float = 0.015  # m/s once the peg is in the bore
    insert_final_depth: float = 0.043  # m, commanded depth (the shoulder is at 0.045)
    clear_distance: float = 0.18  # m: predicted clearance for full speed
    stop_distance: float = 0.09  # m: never plan a motion predicted closer than this
    horizon: float = 2.0  # s of prediction
    horizon_samples: int = 20
    close_time: float = 0.8  # s with the gripper closing before lifting
    max_regrasps: int = 3
    max_insert_retries: int = 4


@dataclass(frozen=True)
class ExpertAction:
    """One decision: the env ``action`` (13,), its ``option`` label and the expert's
    internal ``step`` (``approach``, ``descend``, ``close``, ``lift``, ``transport``,
    ``insert``, ``done``, ``failed``)."""

    action: FloatArray
    option: int
    step: str


def _up(height: float) -> FloatArray:
    return np.array([0.0, 0.0, height])


class GearExpert:
    """Privileged scripted demonstrator for :class:`GearAssemblyEnv`.

    Lifecycle: ``reset()`` after every ``env.reset``; then ``act(observation, info)`` once
    per step, with the observation and ``info`` of the last ``reset``/``step``; it never
    steps the env itself. Deterministic: the same env state gives the same action (it
    draws nothing at random). The demonstrations record it as a pipeline demonstrator
    that acts itself (:class:`~dynoplan.envs.gear.demonstrations.ExpertDemonstrator`).
    """

    def __init__(self, env: GearAssemblyEnv, config: ExpertConfig | None = None) -> None:
        self.env = env
        self.cfg = config or ExpertConfig()
        self.kin = ArmKinematics()
        self.checker = env.collision_checker()
        dt_env = 1.0 / env.metadata["render_fps"]
        self.dt = float(dt_env)
        self._taus = np.linspace(0.0, self.cfg.horizon, self.cfg.horizon_samples + 1)
        retreat = self.kin.solve(HOME_Q, np.array([0.3, 0.45, 1.05]),
                                 downward_tool_rotation(0.0), free_roll=True)
        self.retreat_q = retreat.q
        self.reset()

    # ---------------------------------------------------------------- lifecycle
    def reset(self) -> None:
        """Start a new episode from the env's current state."""
        self.q_cmd = self.env.arm_qpos
        self.grip = GRIPPER_OPEN
        self.regrasps = 0
        self.insert_retries = 0
        self.displaced = False
        self.path: JointPath | None = None
        self.timer = 0.0
        self.h_target = 0.0
        self.jam_timer = 0.0
        self.step = ""
        self._begin("approach")

    def act(self, observation: FloatArray, info: dict[str, Any]) -> ExpertAction:
        """The next action (13,) and its option label (the expert reads the simulator,
        not ``observation``)."""
        self.checker.sync(self.env.data, carry_gear=int(info["pads_on_gear"]) >= 2)
        self._transition(info)
        option = self._move(info)
        return ExpertAction(action=np.concatenate([self.q_cmd, [self.grip]]),
                            option=option, step=self.step)

    # ------------------------------------------------------------- the plan
    def _begin(self, step: str) -> None:
        """Enter ``step`` and plan its motion from the commanded configuration."""
        cfg = self.cfg
        self.step = step
        self.timer = 0.0
        self.displaced = False
        q = self.q_cmd
        gear, _ = self.env.gear_pose()
        down = downward_tool_rotation(0.0)
        if step == "approach":
            self.grip = GRIPPER_OPEN
            goal = self._ik(q, gear + _up(GRASP_TCP_HEIGHT + cfg.pregrasp_height), down)
            self.path = self._path([q, goal], cfg.joint_speed)
        elif step == "descend":
            goal = self._ik(q, gear + _up(GRASP_TCP_HEIGHT), down)
            self.path = self._path([q, goal], cfg.fine_joint_speed)
        elif step == "close":
            self.grip = GRIPPER_CLOSED
            self.path = self._path([q], cfg.fine_joint_speed)
        elif step == "lift":
            tcp, rot = self.kin.tool_pose(self.env.arm_qpos)
            lift = np.array([tcp[0], tcp[1], TABLE_TOP_Z + GRASP_TCP_HEIGHT + cfg.lift_height])
            goal = self._ik(q, lift, rot)
            self.path = self._path([q, goal], cfg.fine_joint_speed)
        elif step == "transport":
            goal = self._ik_gear_at(q, cfg.offset_height)
            self.path = self._path(self._collision_free([q, goal]), cfg.joint_speed)
        elif step == "insert":
            tip, rot = self.env.peg_pose()
            self.h_target = float((gear - tip) @ rot[:, 2])
            self.jam_timer = 0.0
            self.path = None
        else:  # done / failed: stay
            self.path = self._path([q], cfg.joint_speed)

    def _transition(self, info: dict[str, Any]) -> None:
        """Move to the next step when the current one is finished (or has failed)."""
        step = self.step
        pads = int(info["pads_on_gear"])
        stage = int(info["stage"])
        held = pads >= 2
        if info["is_success"]:
            if step != "done":
                self._begin("done")
            return
        if step in ("done", "failed"):
            return
        if self.displaced:  # the human pushed us off the plan: plan again from here
            resume = {"descend": "approach", "close": "approach", "insert": "transport"}
            if step == "insert" and stage == STAGE_INDEX["on_peg"]:
                resume["insert"] = "insert"  # already on the peg: carry on from here
            self._begin(resume.get(step, step))
            return
        settled = self._tracking_error() < 0.03
        if step == "approach" and self._path_done() and settled:
            self._begin("descend")
        elif step == "descend" and self._path_done() and settled:
            self._begin("close")
        elif step == "close":
            if self.timer >= self.cfg.close_time and held:
                self._begin("lift")
            elif self.timer >= 2.5 * self.cfg.close_time:
                self._regrasp()
        elif step == "lift":
            if not held:
                self._regrasp()
            elif self._path_done() and settled:
                self._begin("transport")
        elif step == "transport":
            if not held:
                self._regrasp()
            elif self._path_done() and settled:
                self._begin("insert")
        elif step == "insert" and not held and stage != STAGE_INDEX["on_peg"]:
            self._regrasp()

    def _regrasp(self) -> None:
        gear, rot = self.env.gear_pose()
        upright = rot[2, 2] > np.cos(np.deg2rad(10.0)) and gear[2] < TABLE_TOP_Z + 0.01
        self.regrasps += 1
        if self.regrasps > self.cfg.max_regrasps or not upright:
            self._begin("failed")
            return
        self.grip = GRIPPER_OPEN
        self._begin("approach")

    # ------------------------------------------------------------- the motion
    def _move(self, info: dict[str, Any]) -> int:
        """Advance the current step by one decision, giving way to the human. Returns the
        option label."""
        nominal = _STEP_OPTION[self.step]
        option = self._give_way(info, nominal)
        return PICK if nominal == PICK else option

    def _give_way(self, info: dict[str, Any], nominal: int) -> int:
        """Follow the plan, slow down, stop or back away (the first that keeps the
        clearance); ``nominal`` if the plan was followed, else ``CAUTIOUS_MOVE``."""
        cfg = self.cfg
        self.timer += self.dt
        path = self.path
        if self.step == "insert" or path is None:
            q_next = self._insert_target(info) if self.step == "insert" else self.q_cmd.copy()

            def cont(tau: float) -> FloatArray:
                return q_next
        else:
            def cont(tau: float) -> FloatArray:
                return path.preview(tau, 1.0)
        if self._clearance(cont) >= cfg.clear_distance:
            self._follow(1.0)
            return nominal
        if path is not None and not path.finished:
            def slow(tau: float) -> FloatArray:
                return path.preview(tau, cfg.cautious_scale)
            if self._clearance(slow) >= cfg.stop_distance:
                self._follow(cfg.cautious_scale)
                return CAUTIOUS_MOVE
        q_hold = self.q_cmd.copy()
        if self._clearance(lambda tau: q_hold) >= cfg.stop_distance:
            if self.step == "insert" and self._clearance(cont) >= cfg.stop_distance:
                self._follow(1.0)  # keep inserting while it stays clear
            return CAUTIOUS_MOVE
        self._retreat(info)
        return CAUTIOUS_MOVE

    def _follow(self, scale: float) -> None:
        if self.step == "insert":
            self.q_cmd = self._q_insert
        elif self.path is not None:
            self.q_cmd = self.path.advance(self.dt, scale)

    def _retreat(self, info: dict[str, Any]) -> None:
        """Back away from the human along the candidate with the best predicted clearance.

        With the gear on the peg the only way out is straight up the peg; otherwise the
        candidates are: towards the retreat pose or home, back along the path, the tool
        straight up, the tool back towards the torso.
        """
        cfg = self.cfg
        q0 = self.q_cmd.copy()
        depth = float(info["insertion_depth"])
        goals: list[FloatArray] = []
        if self.step == "insert" and depth > -0.005 and self._radial_error() < 0.01:
            goals.append(self._ik_gear_at(q0, max(-depth, 0.0) + 0.1))
        else:
            goals += [self.retreat_q, HOME_Q]
            tcp, rot = self.kin.tool_pose(q0)
            for shift in ([0.0, 0.0, 0.1], [-0.15, 0.0, 0.0], [-0.1, 0.0, 0.08]):
                goals.append(self.kin.solve(q0, tcp + np.asarray(shift), rot,
                                            iterations=80).q)
            if self.path is not None and self.path.s > 0:
                goals.append(self.path.at(0.0))
        best, best_d = None, -np.inf
        for goal in goals:
            path = JointPath([q0, goal], cfg.retreat_speed, cfg.accel_time)

            def moved(tau: float, path: JointPath = path) -> FloatArray:
                return path.preview(tau, 1.0)
            if self.checker.in_collision(moved(cfg.horizon), ignore_gear=True):
                continue
            d = self._clearance(moved)
            if d > best_d:
                best, best_d = path, d
        if best is not None:
            self.q_cmd = self._clip(best.preview(self.dt, 1.0))
        self.displaced = True

    # ------------------------------------------------------------- insertion
    def _insert_target(self, info: dict[str, Any]) -> FloatArray:
        """Lower the commanded gear height along the peg and solve for the arm."""
        cfg = self.cfg
        depth = float(info["insertion_depth"])
        radial = self._radial_error()
        # Do not enter the bore misaligned: wait above the tip until centred.
        if self.h_target <= 0.004 and depth < 0.0 and radial > 0.0012:
            self.h_target = 0.004
        else:
            speed = cfg.insert_speed if self.h_target > 0.005 else cfg.insert_speed_slow
            self.h_target = max(self.h_target - speed * self.dt, -cfg.insert_final_depth)
        # Jammed: the gear lags the command by more than 8 mm for a while -> back off.
        if -self.h_target - depth > 0.008:
            self.jam_timer += self.dt
        else:
            self.jam_timer = 0.0
        if self.jam_timer > 0.6 and self.insert_retries < cfg.max_insert_retries:
            self.insert_retries += 1
            self.jam_timer = 0.0
            self.h_target = 0.012
        self._q_insert = self._ik_gear_at(self.q_cmd, self.h_target)
        return self._q_insert

    def _radial_error(self) -> float:
        gear, _ = self.env.gear_pose()
        tip, rot = self.env.peg_pose()
        rel = gear - tip
        axis = rot[:, 2]
        return float(np.linalg.norm(rel - (rel @ axis) * axis))

    # ------------------------------------------------------------- helpers
    def _ik(self, q: FloatArray, position: FloatArray, rotation: FloatArray,
            free_roll: bool = True) -> FloatArray:
        return self.kin.solve(q, np.asarray(position, dtype=np.float64), rotation,
                              free_roll=free_roll).q

    def _ik_gear_at(self, q: FloatArray, height: float) -> FloatArray:
        """Arm joints that put the held gear's bottom ``height`` above the peg tip (along
        its axis), with the gear's axis on the peg's axis."""
        gear, gear_rot = self.env.gear_pose()
        tip, peg_rot = self.env.peg_pose()
        return ik_gear_at(self.kin, q, self.env.arm_qpos, gear, gear_rot, tip, peg_rot,
                          height)

    def _collision_free(self, waypoints: list[FloatArray]) -> list[FloatArray]:
        """``waypoints`` if their straight joint path is free for the arm carrying the
        gear, else with a raised via point in the middle."""
        self.checker.sync(self.env.data, carry_gear=True)
        q0, q1 = waypoints[0], waypoints[-1]
        if not any(self.checker.in_collision(q0 + w * (q1 - q0))
                   for w in np.linspace(0.0, 1.0, 21)):
            return waypoints
        mid = 0.5 * (q0 + q1)
        tcp, rot = self.kin.tool_pose(mid)
        via = self._ik(mid, tcp + _up(0.12), rot, free_roll=False)
        return [q0, via, q1]

    def _path(self, waypoints: list[FloatArray], speed: float) -> JointPath:
        return JointPath(waypoints, speed, self.cfg.accel_time)

    def _path_done(self) -> bool:
        return self.path is None or self.path.finished

    def _tracking_error(self) -> float:
        return float(np.max(np.abs(self.env.arm_qpos - self.q_cmd)))

    def _clip(self, q: FloatArray) -> FloatArray:
        lim = self.env.joint_limits
        out: FloatArray = np.clip(q, lim[:, 0], lim[:, 1])
        return out

    def _clearance(self, q_of_tau: Callable[[float], FloatArray]) -> float:
        """Smallest predicted robot-human distance over the horizon if the arms follow
        ``q_of_tau(tau)`` while the human follows its schedule (capped at 0.5 m)."""
        schedule = self.env.schedule
        hands = schedule.position(self.env.time + self._taus)
        qs = np.array([q_of_tau(float(tau)) for tau in self._taus])
        return self.checker.human_distance_along(qs, hands, schedule.quaternion(hands), cap=0.5)


__all__ = ["ExpertAction", "ExpertConfig", "GearExpert"]
