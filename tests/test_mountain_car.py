"""The second worked example: user-written options on MountainCarContinuous-v0."""

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
from examples.mountain_car.options import make_demonstrator, make_options

ENV = "MountainCarContinuous-v0"


def test_the_user_options_fit_the_environment():
    env = gym.make(ENV)
    assert probe_options(env, make_options()) == 2
    names = [o.name for o in make_options()]
    assert names == ["push_left", "push_right", "pump", "brake"]
    pump, brake = make_options()[2].policy, make_options()[3].policy
    moving_right = np.array([-0.5, 0.01])
    assert pump.act(moving_right)[0] == 1.0 and brake.act(moving_right)[0] == -1.0


def test_the_scripted_demonstrations_swing_and_reach_the_flag():
    env = gym.make(ENV)
    demos = record_demonstrations(env, make_options(), make_demonstrator(), episodes=4, seed=0,
                                  max_attempts=4)  # every attempt must succeed
    for demo in demos:
        assert demo.terminations[-1] and demo.observations[-1, 0] >= 0.45
        assert set(np.unique(demo.options)) == {0, 1}  # push_left and push_right
        assert len(demo) < 200
    # half of the demonstrations (by the episode's generator) first push right from rest
    assert {int(d.options[0]) for d in demos} == {0, 1}


@pytest.mark.slow
def test_dynoplan_reaches_the_flag_and_beats_the_single_options():
    """The README's run with 20 instead of 100 episodes per controller."""
    settings = PipelineSettings(demos=5, episodes=20, seed=0, fit=FitSettings(stride=5),
                                control=ControllerSettings(horizon=10))
    result = run_pipeline(ENV, make_options(), demonstrator=make_demonstrator(),
                          settings=settings)
    rows = result.evaluation
    assert rows["dynoplan"]["success_rate"] >= 0.95
    for name in ("push_left", "push_right", "brake"):
        assert rows[f"option:{name}"]["success_rate"] == 0.0
    assert rows["dynoplan"]["return_mean"] > rows["random"]["return_mean"]
