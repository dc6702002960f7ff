"""Option models that know where an option's runs end the episode in failure: the data
(runs of failed episodes), the fit (a chance, not a class-balanced score), the models
folder and the options DynoPlan plans with."""

import json

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from dynoplan.adapters import option_spec
from dynoplan.data import Episode
from dynoplan.pipeline import (
    ControllerSettings,
    FitSettings,
    FittedModels,
    PipelineSettings,
    run_pipeline,
)
from dynoplan.pipeline.evaluate import make_controller
from dynoplan.pipeline.fit_data import option_run_failures


class Cliff(gym.Env):
    """x on a line, starts in [-1, 1]; the action is added; x >= 5 succeeds, x <= -3
    falls off the cliff (terminated, no success)."""

    def __init__(self, cliff: float = -3.0):
        self.cliff = cliff
        self.observation_space = spaces.Box(-100, 100, (1,), np.float64)
        self.action_space = spaces.Box(-1, 1, (1,), np.float32)
        self.x = 0.0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x = float(self.np_random.uniform(-1, 1))
        return np.array([self.x]), {}

    def step(self, action):
        self.x += float(np.clip(np.asarray(action).reshape(-1)[0], -1, 1))
        won, fell = self.x >= 5, self.x <= self.cliff
        return np.array([self.x]), float(won), won or fell, False, {"is_success": won}


def cliff_options():
    return [option_spec("right", lambda obs: np.array([1.0], np.float32), termination=0.2),
            option_spec("left", lambda obs: np.array([-1.0], np.float32), termination=0.2)]


def test_the_runs_that_end_a_failed_episode_are_marked_failed():
    ep = Episode(observations=np.arange(6.0)[:, None], actions=np.zeros((5, 1)),
                 rewards=np.zeros(5), terminations=np.array([0, 0, 0, 0, 1], bool),
                 truncations=np.zeros(5, bool),
                 infos={"option": np.array([0, 0, 1, 1, 1]),
                        "failure": np.array([0, 0, 0, 0, 1], bool)})
    runs = option_run_failures([ep], ["a", "b"])
    assert runs["a"][0].ravel().tolist() == [0.0, 1.0] and not runs["a"][1].any()
    assert runs["b"][0].ravel().tolist() == [2.0, 3.0, 4.0] and runs["b"][1].all()
    del ep.infos["failure"]  # a demonstration: nothing failed
    assert not option_run_failures([ep], ["a", "b"])["b"][1].any()


SMALL = PipelineSettings(
    demos=3, exploration_episodes=12, exploration_option_steps=8, episodes=4, seed=2,
    fit=FitSettings(dynamics_hidden=(16, 16), dynamics_members=2, dynamics_epochs=10,
                    dynamics_min_updates=50, goal_hidden=16, goal_epochs=40,
                    region_components=1, region_slack=2.0),
    control=ControllerSettings(samples=8, max_decisions=40))


def test_the_pipeline_learns_where_an_option_falls_and_plans_with_it(tmp_path):
    out = tmp_path / "cliff"
    result = run_pipeline(gym.wrappers.TimeLimit(Cliff(), 30), cliff_options(),
                          demonstrator=lambda obs: "right", settings=SMALL, out=out)
    manifest = json.loads((out / "models" / "models.json").read_text())
    assert manifest["failure"]["file"] == "failure.safetensors"
    models = FittedModels.load(out / "models")
    assert models.failure is not None and models.failure.kinds["right"] == "always"
    run, planner = models.build(cliff_options())
    left = next(o for o in planner if o.name == "left")
    assert left.failure is not None
    near, far = left.failure.probability(np.array([[-2.5], [3.0]]))
    assert near > 0.5 > far  # a chance that falls with the distance to the cliff
    on = make_controller("dynoplan", run, models.goal, SMALL.control, planner)
    off = make_controller("dynoplan", run, models.goal,
                          ControllerSettings(samples=8, max_decisions=40,
                                             score_failures=False), planner)
    assert on.chooser.options[1].failure is not None
    assert off.chooser.options[1].failure is None
    assert result.planner_options[1].failure is not None  # what the pipeline evaluated


def test_a_task_where_nothing_fails_has_no_failure_model(tmp_path):
    out = tmp_path / "line"
    run_pipeline(gym.wrappers.TimeLimit(Cliff(cliff=-1000.0), 30), cliff_options(),
                 demonstrator=lambda obs: "right", settings=SMALL, out=out)
    assert "failure" not in json.loads((out / "models" / "models.json").read_text())
    assert FittedModels.load(out / "models").failure is None
