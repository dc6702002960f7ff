"""The random walk: environment, noisy models, the reproduction's headline behaviour."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from dynoplan.envs import RANDOM_WALK_ID
from dynoplan.envs.random_walk import NoisyWalkDynamics, NoisyWalkGoal, RandomWalkEnv
from dynoplan.experiments.random_walk import RandomWalkSettings, make_walk_controller
from dynoplan.pipeline.evaluate import planning_steps_summary, run_episodes
from dynoplan.seeding import episode_seeds


def test_env_passes_the_gymnasium_checker():
    check_env(gym.make(RANDOM_WALK_ID).unwrapped, skip_render_check=False)


def test_walk_semantics():
    env = RandomWalkEnv()
    obs, _ = env.reset(seed=0)
    assert obs == 0
    obs, r, term, _, _ = env.step(0)
    assert obs == 0 and r == 0 and not term  # a left step at 0 stays at 0
    env.reset(options={"start_state": 19})
    obs, r, term, _, info = env.step(1)
    assert obs == 20 and r == 1.0 and term and info["is_success"]
    with pytest.raises(ValueError):
        env.reset(options={"start_state": 20})


def test_noise_free_models_are_exact():
    x = np.arange(21, dtype=float)[:, None]
    rng = np.random.default_rng(0)
    np.testing.assert_array_equal(NoisyWalkDynamics(1.0, 0.0).sample(x, rng)[:, 0],
                                  np.r_[np.arange(1, 21), 20])
    np.testing.assert_array_equal(NoisyWalkDynamics(0.0, 0.0).sample(x, rng)[:, 0],
                                  np.r_[0, np.arange(0, 19), 20])
    np.testing.assert_allclose(NoisyWalkGoal(0.0).sample(x, rng), np.arange(21) / 20)


def test_mispredictions_happen_at_the_stated_rate_and_are_always_wrong():
    x = np.full((200_000, 1), 5.0)
    pred = NoisyWalkDynamics(1.0, 0.2).sample(x, np.random.default_rng(0))[:, 0]
    wrong = pred != 6.0
    assert abs(wrong.mean() - 0.2) < 0.005
    values, counts = np.unique(pred[wrong], return_counts=True)
    assert set(values) == set(range(21)) - {6}  # every wrong state, uniformly
    assert counts.min() > 0.8 * counts.mean()
    goal = NoisyWalkGoal(0.3)
    samples = goal.sample(x, np.random.default_rng(1))
    mean, std = goal.mean_std(x[:1])
    assert abs(samples.mean() - mean[0]) < 0.005 and abs(samples.std() - std[0]) < 0.005


def test_dynoplan_beats_every_single_option_and_random_choice():
    settings = RandomWalkSettings(episodes=200, seed=3)
    env = gym.make(RANDOM_WALK_ID)
    seeds = episode_seeds(settings.seed, settings.episodes)

    def mean_steps(kind):
        controller = make_walk_controller(kind, 0.2, settings)
        summary = planning_steps_summary(run_episodes(env, controller, seeds, "", False))
        return summary

    planner = mean_steps("dynoplan")
    assert planner["success_rate"] == 1.0
    assert planner["planning_steps_median"] <= 5
    random = mean_steps("random")
    assert random["planning_steps_median"] > planner["planning_steps_median"]
    assert mean_steps("option:left_0.5")["success_rate"] == 0.0
    assert mean_steps("option:right_0.9")["planning_steps_median"] > 10


def test_more_episodes_than_run_side_by_side_run_in_batches(monkeypatch):
    """The walk's episodes run in lockstep by default, at most LOCKSTEP_EPISODES at a time
    (memory stays bounded): 23 episodes in batches of 10 all reach the goal."""
    import dynoplan.experiments.random_walk as walk

    monkeypatch.setattr(walk, "LOCKSTEP_EPISODES", 10)
    settings = RandomWalkSettings(episodes=23, seed=4)
    assert settings.lockstep
    seeds = episode_seeds(settings.seed, settings.episodes)
    traces = walk.run_lockstep(make_walk_controller("dynoplan", 0.2, settings), 0.2,
                               settings, seeds)
    assert len(traces) == 23 and all(t.success and t.planning_steps > 0 for t in traces)
