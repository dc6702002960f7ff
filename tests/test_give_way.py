"""The give-way option: its distance, its policy from its own start, its termination,
and the operator that demonstrates it."""

import numpy as np
import pytest

from dynoplan.envs.gear.arm_points import arm_joints
from dynoplan.envs.gear.env import CONTROL_DT, GRIPPER_CLOSED, HOME_Q, GearAssemblyEnv
from dynoplan.envs.gear.operator import OptionOperator
from dynoplan.envs.gear.options import GearOptionPolicy, temporary_gear_options
from dynoplan.envs.gear.options.catalog import GEAR_OPTIONS, PAPER_OPTIONS, reach_start
from dynoplan.envs.gear.options.give_way import (
    GIVE_WAY,
    GIVE_WAY_CLEARANCE,
    GIVE_WAY_NEAR,
    GIVE_WAY_TIME,
    GiveWayPolicy,
    left_arm_hand_distance,
)
from dynoplan.envs.gear.state import STATE_DIM, STATE_SLICES, PlannerState
from dynoplan.pipeline.collect import RunStart, record_episode


def _state(hand):
    s = np.zeros(STATE_DIM)
    s[STATE_SLICES["arm_qpos"]] = HOME_Q
    s[STATE_SLICES["tool_pos"]] = [1.5, 1.0, 2.0]  # far from the arm itself
    s[STATE_SLICES["human_pos"]] = hand
    return s


def test_the_distance_is_to_the_left_arm_not_the_tool_point_alone():
    elbow = arm_joints(HOME_Q[None, :6], "l")[0, 2]
    right_elbow = arm_joints(HOME_Q[None, 6:], "r")[0, 2]
    states = np.array([_state(elbow), _state([1.5, 1.0, 2.25]), _state(right_elbow)])
    d = left_arm_hand_distance(states)
    assert d[0] == pytest.approx(0.0, abs=1e-12)  # at the left elbow, far from the tool
    assert d[1] == pytest.approx(0.25)  # 25 cm above the tool point
    assert d[2] > 0.3  # the right arm does not count


@pytest.fixture(scope="module")
def env():
    gear_env = GearAssemblyEnv()
    yield gear_env
    gear_env.close()


def _run(env, seed):
    """A give-way from its own start: (start observation, last observation, infos, policy)."""
    with temporary_gear_options(GIVE_WAY):
        start = reach_start(env, "give_way", np.random.default_rng(seed))
    policy = GiveWayPolicy(env)
    obs = start.observation
    policy.reset(obs, np.random.default_rng(seed))
    infos, actions = [], []
    while not policy.finished():
        action = policy.act(obs)
        actions.append(action)
        obs, _, _, _, info = env.step(action)
        infos.append(info)
    return start, obs, infos, actions, policy


def test_its_start_has_a_blocking_hand_at_the_left_arm_and_the_gear_held(env):
    with temporary_gear_options(GIVE_WAY):
        start = reach_start(env, "give_way", np.random.default_rng(3))
    state = PlannerState()(start.observation)
    assert start.human_mode == env.schedule.mode == "block"  # its own schedule is kept
    assert left_arm_hand_distance(state[None])[0] < GIVE_WAY_NEAR
    assert int(start.info["pads_on_gear"]) >= 2


@pytest.mark.parametrize("seed", [1, 3])
def test_it_backs_away_without_contact_and_keeps_the_gear(env, seed):
    start, last, infos, actions, policy = _run(env, seed)
    fn = PlannerState()
    before = left_arm_hand_distance(fn(start.observation)[None])[0]
    after = left_arm_hand_distance(fn(last)[None])[0]
    assert policy.cleared and policy.succeeded(infos[-1])
    assert after >= GIVE_WAY_CLEARANCE > GIVE_WAY_NEAR > before
    assert len(infos) * CONTROL_DT <= GIVE_WAY_TIME + CONTROL_DT
    assert sum(int(i["human_contacts"]) for i in infos) == 0
    assert all(a[-1] == GRIPPER_CLOSED for a in actions)  # the gripper as it was
    assert int(infos[-1]["pads_on_gear"]) >= 2
    beta = policy.termination().probability(np.array([fn(start.observation), fn(last)]))
    assert beta.tolist() == [0.0, 1.0]


class _Still(GearOptionPolicy):
    """A stand-in for the paper's options: holds the arm, never finishes."""

    def reset(self, observation, rng):
        self.status = "running"

    def act(self, observation):
        return np.concatenate([self.env.arm_targets, [GRIPPER_CLOSED]])


class _Moving(OptionOperator):
    """The operator from a start past the pick (the gear held): it moves."""

    def reset(self, observation, rng):
        super().reset(observation, rng)
        self.phase = "move"


def test_the_operator_gives_way_when_the_hand_comes_to_the_arm_then_moves_on(env):
    with temporary_gear_options(GIVE_WAY):
        start = reach_start(env, "give_way", np.random.default_rng(1))
        factories = {name: _Still for name in PAPER_OPTIONS} | {"give_way": GiveWayPolicy}
        operator = _Moving(env, factories)
        label = GEAR_OPTIONS.index("give_way")
    assert label == len(PAPER_OPTIONS)
    recording = record_episode(env, operator.specs, operator, None, np.random.default_rng(0),
                               round(GIVE_WAY_TIME / CONTROL_DT) + 20,
                               start=RunStart(start.observation, start.info, None),
                               option_names=operator.names)
    labels = recording.episode.infos["option"].tolist()
    assert labels[0] == label
    first_other = next(i for i, k in enumerate(labels) if k != label)
    assert set(labels[first_other:]) <= {PAPER_OPTIONS.index("fast_move"),
                                        PAPER_OPTIONS.index("cautious_move")}


def test_without_the_option_registered_the_operator_never_gives_way(env):
    factories = {name: _Still for name in PAPER_OPTIONS} | {"give_way": GiveWayPolicy}
    assert "give_way" not in GEAR_OPTIONS.names()
    assert OptionOperator(env, factories).give_way is None
