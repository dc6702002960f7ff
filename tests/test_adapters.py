"""Adapters: a user's callables, SB3 models, planners and classifiers become options."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

from dynoplan import DynoplanError
from dynoplan.adapters import (
    BoxRegion,
    CallablePolicy,
    ClassifierTermination,
    MotionPlannerPolicy,
    OptionSpec,
    SB3Policy,
    initiation_from,
    make_option,
    option_spec,
    policy_from,
    termination_from,
)
from dynoplan.control import Controller, FixedChoice
from dynoplan.models import SafetyRegions
from dynoplan.options import (
    ConstantTermination,
    Everywhere,
    InitiationFromCallable,
    InRegion,
    TerminationFromCallable,
)


class Plane(gym.Env):
    """A point in the plane; the action (clipped to [-1, 1]) is added; success at x >= 5."""

    def __init__(self):
        self.observation_space = spaces.Box(-50, 50, (2,), np.float64)
        self.action_space = spaces.Box(-1, 1, (2,), np.float64)
        self.p = np.zeros(2)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.p = np.zeros(2)
        return self.p.copy(), {}

    def step(self, action):
        self.p = self.p + np.clip(np.asarray(action, dtype=np.float64).reshape(2), -1, 1)
        done = bool(self.p[0] >= 5)
        return self.p.copy(), float(done), done, False, {"is_success": done}


class Still:
    """A dynamics model that predicts no motion (enough to run the controller)."""

    state_dim = 2

    def sample(self, states, rng):
        return np.array(states, dtype=np.float64)


def _run(option, steps=50, seed=0, decisions=None):
    controller = Controller([option], FixedChoice([option], option.name),
                            max_decisions=decisions or steps)
    return controller.run(gym.wrappers.TimeLimit(Plane(), steps), np.random.default_rng(seed),
                          seed=seed)


def test_option_from_a_callable_reaches_the_goal():
    option = make_option("east", lambda obs: np.array([1.0, 0.0]), Still(), termination=0.5)
    assert isinstance(option.policy, CallablePolicy)
    assert isinstance(option.termination, ConstantTermination)
    assert isinstance(option.initiation, Everywhere)
    trace = _run(option)
    assert trace.success and trace.env_steps == 5


def test_policy_from_picks_the_adapter_and_rejects_other_things():
    class Model:
        def predict(self, obs, deterministic=True):
            return np.array([1.0, 0.0]), None

    assert isinstance(policy_from(Model()), SB3Policy)
    assert isinstance(policy_from(lambda obs: 0), CallablePolicy)
    with pytest.raises(DynoplanError, match="cannot make a policy from int"):
        policy_from(3)
    with pytest.raises(DynoplanError, match="no predict"):
        SB3Policy(object())


def test_duck_typed_predict_gets_deterministic_and_observation_transform():
    calls = []

    class Model:
        def predict(self, obs, deterministic=False):
            calls.append((obs.copy(), deterministic))
            return np.array([1.0, 0.0]), None

    policy = SB3Policy(Model(), obs_fn=lambda obs: obs * 2)
    action = policy.act(np.array([1.0, 2.0]))
    assert np.array_equal(action, [1.0, 0.0])
    assert np.array_equal(calls[0][0], [2.0, 4.0]) and calls[0][1] is True


def test_recurrent_predict_keeps_its_state_until_reset():
    seen = []

    class Recurrent:
        def predict(self, obs, state=None, episode_start=None, deterministic=True):
            seen.append((state, bool(episode_start[0])))
            return np.zeros(2), (0 if state is None else state + 1)

    policy = SB3Policy(Recurrent(), recurrent=True)
    policy.reset(None, np.random.default_rng(0))
    for _ in range(3):
        policy.act(np.zeros(2))
    policy.reset(None, np.random.default_rng(0))
    policy.act(np.zeros(2))
    assert seen == [(None, True), (0, False), (1, False), (None, True)]


def test_a_real_stable_baselines3_model_runs_as_an_option():
    sb3 = pytest.importorskip("stable_baselines3")
    env = Plane()
    model = sb3.PPO("MlpPolicy", env, n_steps=32, batch_size=32, n_epochs=1, seed=0,
                    device="cpu", policy_kwargs={"net_arch": [8]})
    model.learn(32)
    option = make_option("ppo", model, Still(), termination=0.0)
    assert isinstance(option.policy, SB3Policy)
    trace = _run(option, steps=10)
    assert trace.env_steps == 10  # ran every step with the model's actions
    obs = np.array([0.5, -0.5])
    expected, _ = model.predict(obs, deterministic=True)
    assert np.array_equal(option.act(obs), expected)


def _line_planner(goal):
    def plan(start):
        return [np.array([x, 0.0]) for x in np.arange(start[0] + 1.0, goal + 0.5, 1.0)]

    return plan


def _track(obs, waypoint):
    return np.clip(np.asarray(waypoint) - obs, -1, 1)


def test_motion_planner_policy_follows_the_path_and_finishes():
    policy = MotionPlannerPolicy(_line_planner(3.0), _track, tolerance=1e-6)
    option = make_option("planned", policy, Still(), termination=0.0)
    trace = _run(option, steps=20, decisions=1)
    assert not trace.success  # the path ends at x = 3, before the goal at 5
    decision = trace.decisions[0]
    assert decision.stop_reason == "terminated"
    # three waypoints, one step each, then one step to notice the last one is reached
    assert decision.steps == 4 and np.allclose(decision.state_after, [3.0, 0.0])
    assert policy.progress == (3, 3)


def test_motion_planner_failure_finishes_at_once_with_the_hold_action():
    policy = MotionPlannerPolicy(lambda start: None, _track, hold_action=np.zeros(2))
    policy.reset(np.zeros(2), np.random.default_rng(0))
    assert policy.finished()
    assert np.array_equal(policy.act(np.zeros(2)), np.zeros(2))


def test_motion_planner_gives_up_when_stuck_and_reseeds_repeatably():
    seeds = []
    policy = MotionPlannerPolicy(lambda start: [np.array([10.0, 0.0])],
                                 lambda obs, w: np.zeros(2), max_steps_per_waypoint=3,
                                 reseed=seeds.append)
    policy.reset(np.zeros(2), np.random.default_rng(7))
    for _ in range(3):
        policy.act(np.zeros(2))
        assert not policy.finished()
    policy.act(np.zeros(2))
    assert policy.finished()
    policy.reset(np.zeros(2), np.random.default_rng(7))
    assert len(seeds) == 2 and seeds[0] == seeds[1]


def test_motion_planner_rejects_waypoints_of_another_shape():
    policy = MotionPlannerPolicy(lambda start: [np.zeros(3)], _track)
    policy.reset(np.zeros(2), np.random.default_rng(0))
    with pytest.raises(DynoplanError, match=r"reached=\.\.\."):
        policy.act(np.zeros(2))


def test_classifier_termination_from_a_sklearn_classifier():
    from sklearn.linear_model import LogisticRegression

    x = np.linspace(0, 10, 101)[:, None].repeat(2, axis=1)
    y = np.where(x[:, 0] >= 5, "done", "busy")
    clf = LogisticRegression().fit(x, y)
    beta = ClassifierTermination(clf, stop_class="done")
    p = beta.probability(np.array([[0.0, 0.0], [5.0, 5.0], [10.0, 10.0]]))
    assert p.shape == (3,) and p[0] < 0.05 < 0.95 < p[2] and np.all(np.diff(p) > 0)
    hard = ClassifierTermination(clf, stop_class="done", threshold=0.5)
    assert hard.probability(np.array([[1.0, 1.0], [9.0, 9.0]])).tolist() == [0.0, 1.0]
    numeric = LogisticRegression().fit(x, (x[:, 0] >= 5).astype(int))
    assert isinstance(termination_from(numeric), ClassifierTermination)
    with pytest.raises(DynoplanError, match="not one of the classifier's classes"):
        ClassifierTermination(clf, stop_class=1)


def test_classifier_termination_from_a_probability_callable_and_bad_shapes():
    beta = ClassifierTermination(lambda s: np.stack([1 - s[:, 0], s[:, 0]], axis=1))
    assert np.allclose(beta.probability(np.array([[0.25, 0.0]])), [0.25])
    broken = ClassifierTermination(lambda s: np.zeros(len(s) + 1))
    with pytest.raises(DynoplanError, match="returned shape"):
        broken.probability(np.zeros((2, 2)))
    with pytest.raises(DynoplanError, match="no predict_proba"):
        ClassifierTermination(3)


def test_termination_from_numbers_callables_and_nonsense():
    assert termination_from(None).probability(np.zeros((2, 2))).tolist() == [0.0, 0.0]
    assert termination_from(0.25).beta == 0.25
    assert isinstance(termination_from(lambda s: s[:, 0] > 0), TerminationFromCallable)
    for bad, message in ((1.5, r"in \[0, 1\]"), (True, "not a bool"), ("x", "cannot make")):
        with pytest.raises(DynoplanError, match=message):
            termination_from(bad)


def test_initiation_from_regions_boxes_and_callables():
    rng = np.random.default_rng(0)
    states = np.concatenate([rng.normal(0, 0.3, (100, 2)), rng.normal(5, 0.3, (100, 2))])
    labels = np.repeat([0, 1], 100)
    regions = SafetyRegions.fit(states, labels, ["near", "far"], n_components=2)
    near = initiation_from(regions, "near")
    assert isinstance(near, InRegion)
    assert near.contains(np.array([[0.0, 0.0], [5.0, 5.0]])).tolist() == [True, False]
    with pytest.raises(DynoplanError, match="needs the option name"):
        initiation_from(regions)
    assert isinstance(initiation_from(None), Everywhere)
    assert isinstance(initiation_from(lambda s: s[:, 0] > 0), InitiationFromCallable)
    box = BoxRegion([0, -np.inf], [1, np.inf])
    assert initiation_from(box) is box
    assert box.contains(np.array([[0.5, 9.0], [2.0, 0.0]])).tolist() == [True, False]
    with pytest.raises(DynoplanError, match="dimension"):
        box.contains(np.zeros((1, 3)))
    with pytest.raises(DynoplanError, match="cannot make an initiation"):
        initiation_from(42)


def test_option_spec_becomes_an_option_with_learned_dynamics():
    spec = option_spec("east", lambda obs: np.array([1.0, 0.0]), termination=0.1,
                       initiation=lambda s: s[:, 0] < 4)
    assert isinstance(spec, OptionSpec)
    option = spec.with_dynamics(Still())
    assert option.can_start(np.array([0.0, 0.0])) and not option.can_start(np.array([4.5, 0]))
    with pytest.raises(DynoplanError, match="not a dynamics model"):
        make_option("east", lambda obs: 0, dynamics=object())
    with pytest.raises(DynoplanError, match="option name"):
        option_spec("two words", lambda obs: 0)
