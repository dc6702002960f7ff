"""ISO/TS 15066 separation, the human behaviours no demonstration shows, and the safety
columns of the gear's evaluation."""

import csv
import json
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from typer.testing import CliRunner

from dynoplan.cli.main import app
from dynoplan.envs.gear.env import GearAssemblyEnv
from dynoplan.envs.gear.human import (
    BEHAVIOURS,
    HUMAN_MODES,
    UNSEEN_BEHAVIOURS,
    rounded_corners,
    sample_schedule,
)
from dynoplan.safety import SeparationParameters, protective_separation
from dynoplan.safety.shield import Anticipation, SeparationShield


def test_protective_separation_matches_the_formula_by_hand():
    # v_h (T_r + T_s) + v_r T_r + v_r T_s / 2 + C + Z_d + Z_r
    # = 1.0 * 0.3 + 0.5 * 0.1 + 0.5 * 0.2 / 2 + 0.05 + 0.02 + 0.01 = 0.48
    assert protective_separation(0.5, 1.0) == pytest.approx(0.48)
    # unmeasured human: ISO 13855's 1.6 m/s; a robot at rest keeps the static terms only
    assert protective_separation(0.0) == pytest.approx(1.6 * 0.3 + 0.08)
    params = SeparationParameters(reaction_time=0.2, stopping_time=0.4, intrusion=0.0,
                                  human_uncertainty=0.0, robot_uncertainty=0.0)
    speeds = protective_separation(np.array([0.0, 1.0]), np.array([2.0, 0.0]), params)
    assert speeds == pytest.approx([2.0 * 0.6, 0.2 + 0.2])
    with pytest.raises(ValueError):
        protective_separation(-0.1, 1.0)
    with pytest.raises(ValueError):
        SeparationParameters(stopping_time=float("nan"))


class _Measured(gym.Env):
    """Reports scripted (distance, robot speed, hand speed) after reset and each step, and
    remembers the actions it was given."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (1,))
    action_space = gym.spaces.Box(-1.0, 1.0, (1,))

    def __init__(self, measured):
        self.measured, self.actions, self.t = measured, [], 0

    def _info(self):
        d, v_r, v_h = self.measured[self.t]
        return {"min_human_distance": d, "robot_speed": v_r, "human_speed": v_h}

    def reset(self, *, seed=None, options=None):
        self.t = 0
        return np.zeros(1, dtype=np.float32), self._info()

    def step(self, action):
        self.actions.append(float(action[0]))
        self.t += 1
        return np.zeros(1, dtype=np.float32), 0.0, False, False, self._info()


def test_the_shield_stops_the_step_that_would_end_below_s_p():
    # no speed change allowed: the anticipated separation is d - (v_r + v_h) * 0.05 and
    # S_p(0.5 m/s, hand still) = 0.5 * 0.1 + 0.05 + 0.08 = 0.18 m, so the robot moving at
    # 0.5 m/s is stopped below 0.18 + 0.025 = 0.205 m
    exact = Anticipation(robot_acceleration=0.0, restart_speed=0.0, human_acceleration=0.0)
    env = _Measured([(1.0, 0.5, 0.0), (0.1, 0.5, 0.0), (0.1, 0.0, 0.0), (0.20, 0.5, 0.0),
                     (0.21, 0.5, 0.0), (0.21, 0.5, 0.0)])
    shield = SeparationShield(env, stop_action=lambda obs: np.array([-1.0]),
                              anticipation=exact)
    _, info = shield.reset(seed=0)
    assert info["protective_stops"] == 0
    stopped = [shield.step(np.array([0.5]))[4]["protective_stop"] for _ in range(5)]
    # step 1 starts 1 m away: runs; step 2 starts 0.1 m away moving: stopped; step 3 starts
    # at rest: runs; step 4 at 0.20 m: within S_p one period ahead (0.175 < 0.18):
    # stopped (a monitor of the measurement alone lets it through); step 5 at 0.21 m: runs
    assert stopped == [False, True, False, True, False]
    assert env.actions == [0.5, -1.0, 0.5, -1.0, 0.5]
    assert shield.stops == 2
    with pytest.raises(KeyError):
        SeparationShield(gym.make("Pendulum-v1"), lambda obs: obs).must_stop({})


def test_the_shield_anticipates_speed_changes_and_the_restart_after_a_stop():
    shield = SeparationShield(_Measured([(1.0, 0.0, 0.0)]), lambda obs: obs)
    a = shield.anticipation  # 0.05 s; +0.5 m/s robot, +0.55 m/s hand; restart 0.5 m/s
    assert a.next_speeds(0.2, 0.0, after_stop=False) == pytest.approx((0.7, 0.55))
    assert a.next_speeds(0.0, 0.3, after_stop=True) == pytest.approx((0.5, 0.85))
    # a robot at rest beside a resting hand may start (0.5 m/s) while the hand may start
    # (0.55 m/s): S_p(0.5, 0.55) = 0.165 + 0.05 + 0.05 + 0.08 = 0.345 m, one period ahead
    # 0.0525 m closer: it is held below 0.3975 m and let go above
    near = {"min_human_distance": 0.39, "robot_speed": 0.0, "human_speed": 0.0}
    far = {**near, "min_human_distance": 0.40}
    assert shield.must_stop(near) and not shield.must_stop(far)
    # after a stop the robot may restart at 0.5 m/s even if it was slower
    # S_p(0.5, 0) = 0.18 m, 0.025 m closer one period ahead
    slow = {"min_human_distance": 0.2, "robot_speed": 0.0, "human_speed": 0.0}
    calm = Anticipation(robot_acceleration=0.0, human_acceleration=0.0)
    assert SeparationShield(_Measured([(1.0, 0.0, 0.0)]), lambda obs: obs,
                            anticipation=calm).must_stop(slow, after_stop=True)
    assert not SeparationShield(_Measured([(1.0, 0.0, 0.0)]), lambda obs: obs,
                                anticipation=calm).must_stop(slow, after_stop=False)
    with pytest.raises(ValueError):
        Anticipation(control_period=-0.05)


def test_the_hand_accelerates_at_most_at_its_bound():
    gear_xy, peg = np.array([0.6, 0.35]), np.array([0.62, -0.09, 0.91])
    worst = 0.0
    for behaviour in BEHAVIOURS:
        for e in range(20):
            schedule = sample_schedule(np.random.default_rng([e, 3]), gear_xy, peg,
                                       mode=behaviour)
            times = np.arange(0.0, schedule.times[-1] + 0.2, 0.002)
            v = np.array([schedule.velocity(t) for t in times])
            worst = max(worst, float(np.linalg.norm(v[25:] - v[:-25], axis=1).max()))
    # the monitor's bound on the hand: 11 m/s^2 over a 0.05 s period
    assert 0.3 < worst <= Anticipation().human_acceleration * 0.05
    # a corner keeps its keyframe times outside the blend and ends where it was
    t, p = rounded_corners(np.array([0.0, 1.0, 2.0]),
                           np.array([[0.0, 0, 0], [0.0, 0, 0], [1.0, 0, 0]]), acceleration=10.0)
    assert t[0] == 0.0 and t[-1] == pytest.approx(2.05) and p[-1] == pytest.approx([1, 0, 0])
    # two blends of 1 m/s / 10 m/s^2 = 0.1 s, centred on 1 s and 2 s, sampled every 5 ms
    assert t[1] == pytest.approx(0.95) and np.all(np.diff(t) > 0)
    assert np.sum(np.diff(t) <= 0.005 + 1e-12) == 40


def test_the_unseen_behaviours_are_not_in_the_training_mix_and_are_deterministic():
    assert set(HUMAN_MODES) == {"away", "cross", "block"}
    assert not set(UNSEEN_BEHAVIOURS) & set(HUMAN_MODES)
    assert len(UNSEEN_BEHAVIOURS) >= 3
    gear_xy, peg = np.array([0.6, 0.35]), np.array([0.62, -0.09, 0.91])
    for behaviour in UNSEEN_BEHAVIOURS:
        a = sample_schedule(np.random.default_rng(5), gear_xy, peg, mode=behaviour)
        b = sample_schedule(np.random.default_rng(5), gear_xy, peg, mode=behaviour)
        assert a.mode == behaviour and a.events == (behaviour,)
        assert np.array_equal(a.times, b.times) and np.array_equal(a.positions, b.positions)
        assert np.all(np.diff(a.times) > 0)
        assert np.allclose(a.positions[-1], a.positions[0])  # back to rest at the end
    # what each does: reaches the gear, lingers over the peg, crosses fast, twice
    rng = np.random.default_rng(1)
    reach = sample_schedule(rng, gear_xy, peg, mode="reach")
    assert np.min(np.linalg.norm(reach.positions[:, :2] - gear_xy, axis=1)) < 1e-9
    linger = sample_schedule(rng, gear_xy, peg, mode="linger")
    over = np.linalg.norm(linger.positions[:, :2] - peg[:2], axis=1) < 1e-9
    # it stays 3-6 s, less the corners' blends (0.1 s at most)
    assert over.any() and np.max(np.diff(linger.times)[over[1:] & over[:-1]]) >= 2.9
    fast = sample_schedule(rng, gear_xy, peg, mode="fast_cross")
    speeds = np.linalg.norm(np.diff(fast.positions, axis=0), axis=1) / np.diff(fast.times)
    assert speeds.max() >= 1.0
    twice = sample_schedule(rng, gear_xy, peg, mode="two_passes")
    assert len(twice.times) >= 7  # rest, hold, two sweeps with a pause, back


def test_the_env_draws_the_given_behaviours_by_seed_and_passes_the_checker():
    env = GearAssemblyEnv(human_behaviours=UNSEEN_BEHAVIOURS)
    check_env(env)
    modes = [env.reset(seed=s)[1] and env.schedule.mode for s in range(12)]
    assert set(modes) <= set(UNSEEN_BEHAVIOURS) and len(set(modes)) >= 3
    again = [env.reset(seed=s)[1] and env.schedule.mode for s in range(12)]
    assert modes == again
    _, info = env.reset(seed=0, options={"human_mode": "linger"})
    assert env.schedule.mode == "linger"
    assert info["robot_speed"] == 0.0 and info["human_speed"] == 0.0
    env.close()
    default = GearAssemblyEnv()  # the demonstrations' mix is unchanged
    assert {default.reset(seed=s)[1] and default.schedule.mode for s in range(30)} <= set(
        HUMAN_MODES)
    default.close()
    with pytest.raises(ValueError):
        GearAssemblyEnv(human_behaviours=("dance",))
    assert set(BEHAVIOURS) == set(HUMAN_MODES) | set(UNSEEN_BEHAVIOURS)


def test_gear_evaluate_rejects_an_unknown_behaviour_in_one_line(tmp_path: Path):
    result = subprocess.run(
        [sys.executable, "-c", "from dynoplan.cli.main import main; main()", "gear",
         "evaluate", "--human", "dance", "--out", str(tmp_path / "eval")],
        capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        "dynoplan: error: --human: unknown behaviour(s) dance; expected some of away, cross, "
        "block, reach, linger, fast_cross, two_passes, 'unseen' or 'all'"]
    assert not (tmp_path / "eval").exists()


@pytest.mark.slow
def test_gear_evaluate_on_unseen_behaviours_reports_the_safety_columns(quick_gear_run: Path,
                                                                     tmp_path: Path):
    out = tmp_path / "eval"
    result = CliRunner().invoke(app, [
        "gear", "evaluate", "--models", str(quick_gear_run / "models"), "--out", str(out),
        "--controllers", "dynoplan,fixed_script", "--episodes", "4", "--human", "unseen",
        "--horizon", "6", "--samples", "32", "--workers", "1", "--quiet", "--shield"])
    assert result.exit_code == 0, result.output
    rows = list(csv.DictReader((out / "results.csv").open()))
    for row in rows:
        contacts = int(row["contacts"])
        assert int(row["contacts_moving"]) + int(row["contacts_at_rest"]) == contacts
        assert row["sp_violations_moving"].isdigit() and row["protective_stops"].isdigit()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["human"] == list(UNSEEN_BEHAVIOURS) and summary["shield"] is True
    for row in summary["results"]:
        assert set(row["by_human_mode"]) <= set(UNSEEN_BEHAVIOURS)
    episodes = json.loads((out / "episodes.json").read_text())
    assert {e["task_metrics"]["human_mode"] for e in episodes["dynoplan"]} <= set(
        UNSEEN_BEHAVIOURS)
    # gear episode replays one of them, with the same behaviours and monitor
    replay_out = tmp_path / "episode"
    result = CliRunner().invoke(app, [
        "gear", "episode", "--index", "1", "--models", str(quick_gear_run / "models"),
        "--out", str(replay_out), "--human", "unseen", "--shield", "--horizon", "6",
        "--samples", "32"])
    assert result.exit_code == 0, result.output
    replay = json.loads((replay_out / "summary.json").read_text())
    for key in ("env_seed", "success", "env_steps", "no_admissible", "options",
                "task_metrics"):
        assert replay[key] == episodes["dynoplan"][1][key], key


def test_arm_points_are_the_arms_joints_as_mujoco_places_them():
    import mujoco

    from dynoplan.envs.gear.arm_points import arm_joints, arm_points
    from dynoplan.envs.gear.scene import ARM_JOINTS, build_model
    from dynoplan.envs.gear.state import STATE_DIM

    model = build_model()
    data = mujoco.MjData(model)
    ids = [model.joint(j).qposadr[0] for j in ARM_JOINTS]
    rng = np.random.default_rng(0)
    for _ in range(10):
        q = rng.uniform(-1.0, 1.0, 12)
        data.qpos[ids] = q
        mujoco.mj_kinematics(model, data)
        for side, cols in (("l", slice(0, 6)), ("r", slice(6, 12))):
            links = ("shoulder_pan_link", "shoulder_lift_link", "elbow_flex_link",
                     "wrist_flex_link")
            truth = np.stack([data.xpos[model.body(f"{side}_{n}").id] for n in links])
            assert np.allclose(arm_joints(q[None, cols], side)[0], truth, atol=1e-9)
    states = np.zeros((4, STATE_DIM))
    assert arm_points(states).shape == (4, 21, 3)


def test_a_robot_held_or_stopped_while_the_hand_pushes_it_is_at_rest():
    from types import SimpleNamespace

    from dynoplan.envs.gear.metrics import episode_metrics

    env = GearAssemblyEnv()
    env.reset(seed=0, options={"human_mode": "reach"})
    # three steps in contact, the arm pushed to 0.2 m/s in each; S_p(0.2, 0) = 0.14 m
    infos = [{"human_contacts": 5, "robot_speed": 0.2, "human_speed": 0.0,
              "min_human_distance": 0.0, "protective_stop": stop}
             for stop in (False, False, True)]
    # the controller held in the second step
    trace = SimpleNamespace(infos=infos, decisions=[
        SimpleNamespace(option="pick", env_step=0, steps=1),
        SimpleNamespace(option=None, env_step=1, steps=1),
        SimpleNamespace(option="pick", env_step=2, steps=1)])
    metrics = episode_metrics(env, trace)  # type: ignore[arg-type]
    assert metrics["human_mode"] == "reach"
    assert (metrics["contacts_moving"], metrics["contacts_at_rest"]) == (5, 10)
    assert metrics["sp_violations_moving"] == 1 and metrics["protective_stops"] == 1
