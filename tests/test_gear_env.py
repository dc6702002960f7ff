"""The gear-assembly environment: Gymnasium contract, physics sanity, safety, determinism."""

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from dynoplan.envs import GEAR_ASSEMBLY_ID
from dynoplan.envs.gear import OBS_SLICES, STAGES, GearAssemblyEnv
from dynoplan.envs.gear.env import ACT_DIM, HOME_Q, OBS_DIM
from dynoplan.envs.gear.expert import GearExpert
from dynoplan.envs.gear.human import HumanSchedule, sample_schedule
from dynoplan.envs.gear.kinematics import ArmKinematics, downward_tool_rotation
from dynoplan.envs.gear.scene import ARM_JOINTS, TABLE_TOP_Z
from dynoplan.envs.gear.task import SEAT_DEPTH


@pytest.fixture(scope="module")
def env():
    e = GearAssemblyEnv()
    yield e
    e.close()


def hold(env, seconds, grip=0.0):
    """Keep the arms at their home targets for ``seconds``; the last step's output."""
    out = None
    for _ in range(round(seconds * 20)):
        out = env.step(np.r_[HOME_Q, grip])
    return out


def place_gear(env, position, tilt_deg=0.0):
    """Put the (free) gear's bottom centre at ``position``, tilted about world x."""
    a = env.model.joint("gear_free").qposadr[0]
    half = np.deg2rad(tilt_deg) / 2
    env.data.qpos[a:a + 3] = position
    env.data.qpos[a + 3:a + 7] = (np.cos(half), np.sin(half), 0.0, 0.0)
    env.data.qvel[env.model.joint("gear_free").dofadr[0]:][:6] = 0.0
    mujoco.mj_forward(env.model, env.data)


def test_passes_the_gymnasium_checker():
    e = gym.make(GEAR_ASSEMBLY_ID)
    check_env(e.unwrapped)
    assert e.unwrapped.observation_space.shape == (OBS_DIM,)
    assert e.unwrapped.action_space.shape == (ACT_DIM,)
    e.close()


def test_observation_layout_and_planner_interface(env):
    obs, info = env.reset(seed=3)
    assert env.observation_space.contains(obs)
    np.testing.assert_allclose(obs[OBS_SLICES["arm_qpos"]], env.arm_qpos)
    np.testing.assert_allclose(obs[OBS_SLICES["gear_pos"]], env.gear_pose()[0])
    np.testing.assert_allclose(obs[OBS_SLICES["peg_pos"]], env.peg_pose()[0])
    assert env.arm_joint_names == ARM_JOINTS and len(env.arm_actuator_ids) == 12
    assert env.joint_limits.shape == (12, 2)
    assert np.all(env.joint_limits[:, 0] < env.joint_limits[:, 1])
    assert STAGES[info["stage"]] == "on_table" and not info["is_success"]
    with pytest.raises(ValueError):
        env.step(np.zeros(12))
    with pytest.raises(ValueError):
        env.step(np.full(ACT_DIM, np.nan))


def test_gear_rests_on_the_table(env):
    env.reset(seed=1, options={"human_mode": "away"})
    start, _ = env.gear_pose()
    _, _, _, _, info = hold(env, 2.0)
    end, rot = env.gear_pose()
    assert np.linalg.norm(end - start) < 1e-3
    assert abs(end[2] - TABLE_TOP_Z) < 3e-3
    assert rot[2, 2] > np.cos(np.deg2rad(1.0))
    assert STAGES[info["stage"]] == "on_table"


def test_aligned_gear_drops_onto_the_peg_and_counts(env):
    env.reset(seed=0, options={"human_mode": "away"})
    tip, rot = env.peg_pose()
    place_gear(env, tip + rot[:, 2] * 0.01)
    _, _, terminated, _, info = hold(env, 1.5)
    assert info["is_success"] and terminated
    assert info["insertion_depth"] >= SEAT_DEPTH


@pytest.mark.parametrize(("offset", "tilt"), [(0.0, 25.0), (0.007, 0.0)])
def test_misaligned_gear_jams_and_does_not_count(env, offset, tilt):
    env.reset(seed=0, options={"human_mode": "away"})
    tip, rot = env.peg_pose()
    place_gear(env, tip + rot[:, 2] * 0.003 + np.array([offset, 0.0, 0.0]), tilt_deg=tilt)
    body = env.model.body("gear").id
    env.data.xfrc_applied[body, 2] = -2.0  # push it down with 2 N besides gravity
    _, _, _, _, info = hold(env, 1.0)
    env.data.xfrc_applied[body] = 0.0
    assert not info["is_success"]
    assert info["insertion_depth"] < SEAT_DEPTH


def test_same_seed_same_episode():
    rng = np.random.default_rng(7)
    actions = [np.r_[HOME_Q + rng.normal(0, 0.05, 12), rng.uniform()] for _ in range(15)]

    def run(seed):
        e = GearAssemblyEnv()
        obs, _ = e.reset(seed=seed)
        out = [obs] + [e.step(a)[0] for a in actions]
        return np.array(out), e.schedule

    a, sched_a = run(11)
    b, sched_b = run(11)
    c, _ = run(12)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(sched_a.positions, sched_b.positions)
    assert not np.allclose(a[0][OBS_SLICES["gear_pos"]], c[0][OBS_SLICES["gear_pos"]])


def test_robot_human_contact_is_detected(env):
    env.reset(seed=0, options={"human_mode": "away"})
    wrist = env.data.body("l_wrist_flex_link").xpos.copy()
    start = wrist + np.array([0.4, 0.0, 0.0])
    schedule = HumanSchedule(times=np.array([0.0, 1.0, 3.0]),
                             positions=np.array([start, wrist, wrist]),
                             shoulder=wrist + np.array([1.0, 0.0, 0.4]), events=("block",))
    env.reset(seed=0, options={"human_schedule": schedule})
    _, _, _, _, info = hold(env, 1.5)
    assert info["human_contacts_total"] > 0
    assert info["min_human_distance"] <= 0.0


def test_collision_checker_answers_like_the_env(env):
    env.reset(seed=2, options={"human_mode": "away"})
    checker = env.collision_checker()
    checker.sync(env.data)
    assert not checker.in_collision(HOME_Q)
    assert checker.human_distance(HOME_Q) == pytest.approx(
        env.reset(seed=2, options={"human_mode": "away"})[1]["min_human_distance"], abs=1e-9)
    kin = ArmKinematics()
    into_table = kin.solve(HOME_Q, np.array([0.55, 0.0, TABLE_TOP_Z - 0.03]),
                           downward_tool_rotation(0.0), free_roll=True).q
    assert kin.tool_pose(into_table)[0][2] < TABLE_TOP_Z
    assert checker.in_collision(into_table)
    # The checker never touches the env's own state.
    np.testing.assert_allclose(env.arm_qpos, HOME_Q)


def test_collision_checker_queries_at_the_same_joints_answer_as_posed_afresh(env):
    """The checker skips posing the arm (and the carried gear) again for a query at the
    previous query's joints; every answer equals a checker that poses everything anew."""
    env.reset(seed=4, options={"human_mode": "away"})
    fast, fresh = env.collision_checker(), env.collision_checker()
    rng = np.random.default_rng(0)
    for carry in (False, True):
        fast.sync(env.data, carry_gear=carry)
        q = HOME_Q.copy()
        for k in range(60):
            if k % 3 == 0:  # a new state, then queries at the same joints
                q = HOME_Q + rng.normal(0.0, 0.3, size=12)
            hand = np.array([0.55, 0.0, TABLE_TOP_Z + 0.15]) + rng.normal(0.0, 0.1, size=3)
            quat = rng.normal(size=4)
            quat /= np.linalg.norm(quat)
            fast.set_human(hand, quat)

            def afresh(hand=hand, quat=quat, carry=carry):
                fresh.sync(env.data, carry_gear=carry)
                fresh.set_human(hand, quat)
                return fresh

            cap = float(rng.uniform(0.05, 1.0))
            full = afresh().human_distance(q, cap)
            assert fast.human_distance(q, distmax=cap) == full
            # asked only whether it is below a threshold, the search may stop early: the
            # answer is the full search's
            below = float(rng.uniform(0.0, cap))
            assert (fast.human_distance(q, cap, stop_below=below) < below) == (full < below)
            assert fast.in_collision(q, margin=0.002) == afresh().in_collision(q, margin=0.002)
            assert fast.in_collision(q, ignore_gear=True) == afresh().in_collision(
                q, ignore_gear=True)
            np.testing.assert_array_equal(fast.data.geom_xpos, fresh.data.geom_xpos)


def test_human_schedules_keep_clear_of_the_static_robot(env):
    """The operator never walks into the right arm (which holds the peg and never moves)
    nor into the left arm waiting at the expert's retreat pose."""
    env.reset(seed=0, options={"human_mode": "away"})
    checker = env.collision_checker()
    checker.sync(env.data)
    q = HOME_Q.copy()
    q[:6] = GearExpert(env).retreat_q[:6]
    rng = np.random.default_rng(0)
    worst = np.inf
    for mode in ("cross", "block") * 8:
        gear_xy = np.array([rng.uniform(0.5, 0.68), rng.uniform(0.12, 0.38)])
        schedule = sample_schedule(rng, gear_xy, env.peg_pose()[0], mode=mode)
        for t in np.arange(0.0, schedule.times[-1], 0.1):
            hand = schedule.position(t)
            checker.set_human(hand, schedule.quaternion(hand))
            worst = min(worst, checker.human_distance(q))
    assert worst > 0.03


def test_schedule_is_piecewise_linear_and_seeded():
    a = sample_schedule(np.random.default_rng(5), np.array([0.6, 0.3]), np.array([0.6, -0.1, 0.9]),
                        mode="cross")
    b = sample_schedule(np.random.default_rng(5), np.array([0.6, 0.3]), np.array([0.6, -0.1, 0.9]),
                        mode="cross")
    np.testing.assert_array_equal(a.positions, b.positions)
    assert a.events[0] == "cross" and np.all(np.diff(a.times) > 0)
    np.testing.assert_allclose(a.position(a.times[-1] + 10.0), a.positions[-1])
    q = a.quaternion(a.position(3.0))
    assert np.linalg.norm(q) == pytest.approx(1.0)


def test_rgb_render():
    e = GearAssemblyEnv(render_mode="rgb_array", width=160, height=120)
    e.reset(seed=0)
    frame = e.render()
    assert frame.shape == (120, 160, 3) and frame.dtype == np.uint8 and frame.std() > 5
    e.close()
