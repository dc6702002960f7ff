"""The examples of environments dynoplan does not ship: a pendulum swing-up then
balance (classic control), a panda-gym pick-and-place (third-party, PyBullet)."""

import importlib.util

import gymnasium as gym
import numpy as np
import pytest

from dynoplan.pipeline import (
    ControllerSettings,
    FitSettings,
    PipelineSettings,
    probe_options,
    record_demonstrations,
    run_pipeline,
)
from examples.pendulum import options as pendulum

HAS_PANDA = importlib.util.find_spec("panda_gym") is not None
TINY = PipelineSettings(
    demos=3, exploration_episodes=4, exploration_option_steps=30, episodes=3, seed=0,
    fit=FitSettings(dynamics_hidden=(32, 32), dynamics_members=2, dynamics_epochs=5,
                    goal_hidden=16, goal_epochs=30),
    control=ControllerSettings(horizon=5, samples=8, replan_every=10))


def test_the_pendulum_succeeds_only_when_held_upright():
    env = gym.make(pendulum.ENV_ID)
    assert probe_options(env, pendulum.make_options()) == 3
    demos = record_demonstrations(env, pendulum.make_options(), pendulum.make_demonstrator(),
                                  episodes=3, seed=0, max_attempts=3)  # every attempt succeeds
    for demo in demos:
        assert demo.terminations[-1]
        last = demo.observations[-pendulum.HOLD_STEPS:]
        assert np.all(np.abs(np.arctan2(last[:, 1], last[:, 0])) < pendulum.UPRIGHT_ANGLE)
        assert set(np.unique(demo.options)) <= {0, 1}  # swing_up, balance
    # a pendulum hanging still never succeeds: the wrapper counts upright steps only
    env.reset(seed=0)
    env.unwrapped.state = np.array([np.pi, 0.0])
    for _ in range(50):
        *_, terminated, _, info = env.step(np.zeros(1, np.float32))
        assert not terminated and not info["is_success"]


@pytest.mark.slow
def test_the_pendulum_pipeline_runs_end_to_end(tmp_path):
    result = run_pipeline(pendulum.ENV_ID, pendulum.make_options(),
                          demonstrator=pendulum.make_demonstrator(), settings=TINY,
                          out=tmp_path)
    assert set(result.summary["admissibility"]) == {"swing_up", "balance", "coast", "push"}
    assert result.models.report["regions"]["undemonstrated"] == {"coast": "none",
                                                                  "push": "none"}
    assert (tmp_path / "results.md").exists()


@pytest.mark.slow
@pytest.mark.skipif(not HAS_PANDA, reason="needs panda-gym (pip install 'dynoplan[examples]')")
def test_the_panda_pipeline_runs_end_to_end(tmp_path):
    from examples.panda_pick import options as panda

    env = gym.make(panda.ENV_ID)
    assert probe_options(env, panda.make_options()) == 7
    result = run_pipeline(panda.ENV_ID, panda.make_options(),
                          demonstrator=panda.make_demonstrator(), settings=TINY, out=tmp_path)
    assert result.summary["demonstrations"]["episodes"] == 3
    assert set(result.summary["admissibility"]) == {"reach", "grasp", "carry", "retreat",
                                                    "sweep"}
