"""What the pipeline tells the user about their task: seeds that do not reproduce, constant
dimensions, weak dynamics, forced choices; and options that would end where they start."""

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from dynoplan.adapters import make_option
from dynoplan.models.neural_dynamics import MLPEnsembleDynamics
from dynoplan.models.regions import SafetyRegions
from dynoplan.options import admissible
from dynoplan.pipeline.control_settings import ControllerSettings
from dynoplan.pipeline.diagnostics import (
    constant_dimensions,
    constant_dimensions_warning,
    no_start_warning,
    seeded_reset_warning,
    sole_admissible_warnings,
    weak_dynamics_warnings,
)
from dynoplan.pipeline.evaluate import make_controller


class Drift(gym.Env):
    """x drifts; the start is drawn from the env's generator, or from a global one."""

    def __init__(self, ignore_seed=False):
        self.observation_space = spaces.Box(-10, 10, (2,), np.float64)
        self.action_space = spaces.Box(-1, 1, (1,), np.float32)
        self.ignore_seed = ignore_seed
        self.calls = 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.calls += 1
        x = self.calls if self.ignore_seed else float(self.np_random.uniform(-1, 1))
        return np.array([x, 0.0]), {}

    def step(self, action):
        return np.zeros(2), 0.0, False, False, {}


def test_a_reset_that_ignores_its_seed_is_reported_once_in_one_line():
    assert seeded_reset_warning(Drift(), 3) is None
    message = seeded_reset_warning(Drift(ignore_seed=True), 3)
    assert message is not None and "\n" not in message
    assert "two resets with seed 3 gave different observations" in message


def test_constant_dimensions_are_found_and_named():
    rng = np.random.default_rng(0)
    states = np.column_stack([rng.normal(size=50), np.full(50, 0.7), rng.normal(size=50),
                              np.zeros(50)])
    assert constant_dimensions(states) == [1, 3]
    assert "2 of the 4 state dimensions never change" in constant_dimensions_warning([1, 3], 4)
    assert constant_dimensions_warning([], 4) is None


def test_the_dynamics_keep_a_constant_dimension_still_far_from_the_data():
    rng = np.random.default_rng(0)
    s = np.column_stack([rng.normal(size=400), np.full(400, 0.5)])
    nxt = s + np.column_stack([0.1 * np.ones(400), np.zeros(400)])
    far = np.array([[8.0, 0.5]] * 64)
    moved = {}
    for keep in (True, False):
        model = MLPEnsembleDynamics(2, (16, 16), 2, seed=0)
        model.fit(s, nxt, epochs=20, seed=0, keep_still=keep)
        moved[keep] = float(np.max(np.abs(model.sample(far, rng)[:, 1] - 0.5)))
    assert moved[True] < 1e-6 < moved[False]


def test_the_regions_do_not_test_a_dimension_that_never_changes():
    rng = np.random.default_rng(1)
    x = np.column_stack([rng.normal(size=120), np.full(120, 2.0)])
    labels = np.zeros(120, dtype=np.int64)
    nudged = np.array([[0.0, 2.0 + 1e-3]])
    untested, _ = SafetyRegions.fit_heldout(x, labels, ["a"], seed=0)
    tested, _ = SafetyRegions.fit_heldout(x, labels, ["a"], seed=0, test_constant=True)
    assert untested.contains(nudged, "a")[0] and not tested.contains(nudged, "a")[0]


class Still:
    """A model that predicts no change (its error equals the no-change baseline)."""

    state_dim = 1

    def sample(self, states, rng):
        return states


def test_a_model_no_better_than_no_change_and_a_forced_choice_are_reported():
    report = {"good": {"rmse": 0.1, "no_change_rmse": 0.5},
              "weak": {"rmse": 0.6, "no_change_rmse": 0.5},
              "unknown": {"rmse": None, "no_change_rmse": None}}
    notes = weak_dynamics_warnings(report)
    assert len(notes) == 1 and "option 'weak'" in notes[0] and "'no change'" in notes[0]
    only_right = make_option("right", lambda s: 1.0, Still(), initiation=lambda s: s[:, 0] > 0)
    anywhere = make_option("left", lambda s: -1.0, Still(), initiation=lambda s: s[:, 0] <= 0)
    states = np.array([[1.0], [2.0], [3.0], [-1.0]])
    notes = sole_admissible_warnings([only_right, anywhere], states)
    assert [n.split("'")[1] for n in notes] == ["right", "left"]
    assert "at 75% of the demonstration states" in notes[0]


def test_start_states_where_no_option_may_start_are_reported():
    right = make_option("right", lambda s: 1.0, Still(), initiation=lambda s: s[:, 0] > 0)
    left = make_option("left", lambda s: -1.0, Still(), initiation=lambda s: s[:, 0] < -1)
    starts = np.array([[1.0], [2.0], [-0.5], [-2.0]])  # -0.5: neither may start
    note = no_start_warning([right, left], starts)
    assert note is not None
    assert note.startswith("no option may start at 1 of the 4 evaluation start states (25%)")
    assert no_start_warning([right, left], starts[[0, 1, 3]]) is None


def test_an_option_does_not_start_where_its_termination_is_certain():
    done_right = make_option("right", lambda s: 1.0, Still(),
                             termination=lambda s: (s[:, 0] >= 5).astype(float))
    other = make_option("left", lambda s: -1.0, Still(), termination=0.1)
    at_goal = np.array([6.0])
    for start_where_done, expected in ((False, [False, True]), (True, [True, True])):
        controller = make_controller("random", [done_right, other], goal=None,  # type: ignore
                                     settings=ControllerSettings(
                                         start_where_done=start_where_done))
        assert admissible(controller.options, at_goal).tolist() == expected
    # a running option is judged by where it may go on, not by where it would start
    controller = make_controller("random", [done_right, other], goal=None,  # type: ignore
                                 settings=ControllerSettings())
    assert controller.options[0].may_run(at_goal, running=True)
