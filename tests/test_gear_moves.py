"""The fast and cautious move options of the gear assembly (carry the gear to the
pre-insertion pose above the peg)."""

import numpy as np
import pytest

from dynoplan.envs.gear.env import ACT_DIM, GRIPPER_CLOSED, OBS_SLICES, GearAssemblyEnv
from dynoplan.envs.gear.grasp import held_gear_position
from dynoplan.envs.gear.options.catalog import reach_start
from dynoplan.envs.gear.options.moves import (
    CAUTIOUS_SAFETY_DISTANCE,
    GOAL_TOLERANCE,
    CautiousMovePolicy,
    FastMovePolicy,
    PreInsertionBeta,
)
from dynoplan.envs.gear.state import STATE_SLICES, PlannerState
from dynoplan.options.termination import Termination

STEP_CAP = 600


@pytest.fixture(scope="module")
def env():
    e = GearAssemblyEnv(max_episode_steps=10_000)
    yield e
    e.close()


def run_trial(env, policy, name, seed, trial):
    """The option trial protocol: start, reset, act until finished or the step cap."""
    rng = np.random.default_rng([seed, trial])
    start = reach_start(env, name, rng)
    policy.reset(start.observation, rng)
    obs, info = start.observation, start.info
    out = {"min_distance": info["min_human_distance"], "contacts": 0, "steps": 0,
           "modes": [], "actions": []}
    while not policy.finished() and out["steps"] < STEP_CAP:
        action = policy.act(obs)
        out["actions"].append(action)
        out["modes"].append(getattr(policy, "mode", ""))
        obs, _, terminated, truncated, info = env.step(action)
        out["steps"] += 1
        out["min_distance"] = min(out["min_distance"], info["min_human_distance"])
        out["contacts"] += info["human_contacts"]
        if terminated or truncated:
            break
    out.update(observation=obs, info=info, success=policy.succeeded(info))
    return out


def test_fast_move_plans_a_collision_free_path_and_reaches_the_offset(env):
    policy = FastMovePolicy(env)
    rng = np.random.default_rng([0, 1])
    start = reach_start(env, "fast_move", rng)
    policy.reset(start.observation, rng)
    assert policy.status == "running" and len(policy.plan_ms) == 1
    assert policy.plan_ms[0] > 0.0
    # every waypoint and every point between them is free for the arm carrying the gear
    policy.planner.sync(carry_gear=True)
    assert policy.path is not None
    assert policy.planner.path_is_valid(policy.path.points[:, :6])
    # the goal puts the held gear's bottom on its target above the peg
    q0 = start.observation[OBS_SLICES["arm_qpos"]]
    gear0 = start.observation[OBS_SLICES["gear_pos"]]
    predicted = held_gear_position(policy.kin, policy.goal, q0, gear0)
    assert np.linalg.norm(predicted - policy.target) < 0.005
    assert np.linalg.norm(gear0 - policy.target) > 0.1  # it has somewhere to go

    obs, info = start.observation, start.info
    steps = 0
    while not policy.finished() and steps < STEP_CAP:
        action = policy.act(obs)
        assert action.shape == (ACT_DIM,) and action[12] == GRIPPER_CLOSED
        obs, _, _, _, info = env.step(action)
        steps += 1
    assert policy.status == "done" and steps < 100  # about 1-2 s at full speed
    assert policy.succeeded(info)
    assert policy.gear_error() < GOAL_TOLERANCE
    assert info["pads_on_gear"] == 2 and info["stage"] > 0


def test_moves_fail_when_the_gear_is_not_at_its_target(env):
    policy = FastMovePolicy(env)
    rng = np.random.default_rng([0, 2])
    start = reach_start(env, "fast_move", rng)
    policy.reset(start.observation, rng)
    assert not policy.succeeded(start.info)  # still above the table, far from the peg


@pytest.mark.slow
@pytest.mark.parametrize("trial", [0, 6])
def test_cautious_move_keeps_its_distance_from_a_blocking_human(env, trial):
    # Seeds on which the blocking hand reaches into the arm's way (checked below).
    policy = CautiousMovePolicy(env)
    out = run_trial(env, policy, "cautious_move", 0, trial)
    assert out["contacts"] == 0
    assert out["min_distance"] >= CAUTIOUS_SAFETY_DISTANCE
    assert out["success"] and policy.status == "done"
    # the human did come into the way, and the arm gave way (stopped or backed away)
    assert out["min_distance"] < 0.2
    assert {"stop", "retreat"} & set(out["modes"])
    assert all(a[12] == GRIPPER_CLOSED for a in out["actions"])


def test_cautious_move_goes_straight_when_nobody_is_around(env):
    policy = CautiousMovePolicy(env)
    rng = np.random.default_rng([0, 3])
    start = reach_start(env, "cautious_move", rng, human_mode="away")
    policy.reset(start.observation, rng)
    obs, info = start.observation, start.info
    modes = []
    for _ in range(STEP_CAP):
        if policy.finished():
            break
        obs, _, _, _, info = env.step(policy.act(obs))
        modes.append(policy.mode)
    assert policy.status == "done" and policy.succeeded(info)
    assert "retreat" not in modes and "stop" not in modes
    assert len(modes) < 100


def test_terminations_rise_near_the_human_and_at_the_goal(env):
    fast = FastMovePolicy(env)
    cautious = CautiousMovePolicy(env)
    out = run_trial(env, fast, "fast_move", 0, 4)
    assert out["success"]
    states = PlannerState()(out["observation"])[None, :].repeat(3, axis=0)
    tool = states[0, STATE_SLICES["tool_pos"]]
    states[1, STATE_SLICES["human_pos"]] = tool + np.array([0.1, 0.0, 0.0])  # human close
    states[1, STATE_SLICES["gear_pos"]] += np.array([0.0, 0.2, 0.1])  # and off the goal
    states[2, STATE_SLICES["gear_pos"]] += np.array([0.0, 0.2, 0.1])  # off the goal alone
    fast_beta = fast.termination()
    cautious_beta = cautious.termination()
    assert isinstance(fast_beta, Termination) and isinstance(cautious_beta, Termination)
    b_fast = fast_beta.probability(states)
    b_cautious = cautious_beta.probability(states)
    assert b_fast.shape == (3,) and b_cautious.shape == (3,)
    assert b_fast[0] == pytest.approx(1.0) and b_cautious[0] == pytest.approx(1.0)  # at goal
    assert b_fast[1] > 0.5  # the human is close: the fast move should stop
    assert b_cautious[1] == 0.0  # the cautious move carries on near the human
    assert b_fast[2] == 0.0 and b_cautious[2] == 0.0  # away from the goal, nobody near


def test_pre_insertion_beta_follows_the_peg():
    beta = PreInsertionBeta(near=0.01, far=0.03)
    state = np.zeros((4, 22))
    target = beta.target(state[0, 6:12])
    state[:, STATE_SLICES["gear_pos"]] = target
    state[1, 16] += 0.02  # halfway between near and far
    state[2, 16] += 0.05
    state[3, 6] += 0.3  # the right arm (and so the peg) moved away
    b = beta(state)
    assert b[0] == pytest.approx(1.0) and b[1] == pytest.approx(0.5) and b[2] == 0.0
    assert b[3] < 0.5
