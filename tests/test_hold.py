"""Where no option is admissible, a generic controller holds the neutral action."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

from dynoplan.adapters import make_option
from dynoplan.pipeline import ControllerSettings, make_controller, neutral_action


class Drift(gym.Env):
    """x drifts right by 0.25 a step on top of the action; starts at -1; success at x >= 5."""

    def __init__(self):
        self.observation_space = spaces.Box(-100, 100, (1,), np.float64)
        self.action_space = spaces.Box(-1, 1, (1,), np.float32)
        self.x = -1.0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x = -1.0
        return np.array([self.x]), {}

    def step(self, action):
        self.x += 0.25 + float(np.asarray(action).reshape(-1)[0])
        done = self.x >= 5
        return np.array([self.x]), float(done), done, False, {"is_success": done}


class _Still:
    state_dim = 1

    def sample(self, states, rng):
        return states.copy()


def run(settings: ControllerSettings):
    """``right`` may start only where x >= 0, so at the start nothing is admissible."""
    right = make_option("right", lambda obs: np.array([1.0], np.float32), _Still(),
                        initiation=lambda s: s[..., 0] >= 0.0)
    env = gym.wrappers.TimeLimit(Drift(), 50)
    controller = make_controller("random", [right], goal=None, settings=settings,
                                 action_space=env.action_space)
    return controller.run(env, np.random.default_rng(0), seed=0)


def test_the_controller_holds_until_an_option_is_admissible_and_then_succeeds():
    trace = run(ControllerSettings())
    holds = [d for d in trace.decisions if d.option is None]
    assert len(holds) == 4  # -1 -> 0 by the drift alone, at 0.25 a step
    assert trace.success and trace.decisions[-1].option == "right"
    # a hold is recorded like an option: env_step counts the steps taken before it
    assert [d.env_step for d in trace.decisions] == [0, 1, 2, 3, 4]


def test_without_hold_the_episode_ends_where_nothing_is_admissible():
    trace = run(ControllerSettings(hold=False))
    assert not trace.success and len(trace.decisions) == 1


@pytest.mark.parametrize(("space", "expected"), [
    (spaces.Box(-1, 1, (2,), np.float32), [0.0, 0.0]),
    (spaces.Box(np.array([0.5, -2.0]), np.array([1.0, 2.0]), dtype=np.float64), [0.5, 0.0]),
])
def test_the_neutral_action_is_zero_clipped_into_the_box(space, expected):
    action = neutral_action(space)
    assert action is not None and space.contains(action)
    np.testing.assert_allclose(action, expected)


def test_a_discrete_space_has_no_neutral_action():
    assert neutral_action(spaces.Discrete(3)) is None
