"""Initiation learned from outcomes (Bagaria et al. 2023) and the planner's epistemic term."""

import numpy as np
import pytest

from dynoplan.errors import DynoplanError
from dynoplan.models.ensemble_rollouts import MemberStep
from dynoplan.models.outcome_initiation import OutcomeInitiation
from dynoplan.options import ConstantTermination, FunctionPolicy, InRegion, Option
from dynoplan.planning import OptionPlanner


def test_outcome_initiation_learns_where_an_option_ends_well(tmp_path):
    rng = np.random.default_rng(0)
    starts = rng.uniform(-1.0, 1.0, (300, 2))
    ok = starts[:, 0] > 0.2  # the known answer: the option works right of x = 0.2
    fitted, report = OutcomeInitiation.fit(
        {"reach": starts, "always": starts, "never": starts, "untried": starts[:0]},
        {"reach": ok, "always": np.ones(300, bool), "never": np.zeros(300, bool),
         "untried": ok[:0]}, seed=0)
    probe = np.array([[-0.8, 0.0], [0.0, 0.5], [0.5, -0.5], [0.9, 0.9]])
    np.testing.assert_array_equal(fitted.contains(probe, "reach"), [False, False, True, True])
    assert fitted.contains(probe, "always").all() and not fitted.contains(probe, "never").any()
    assert report.kind == {"reach": "network", "always": "always", "never": "never"}
    assert report.train_accuracy["reach"] > 0.95
    with pytest.raises(DynoplanError, match="no learned initiation for option 'untried'"):
        InRegion(fitted, "untried")  # an option without runs gets no set by default
    fitted.save(tmp_path / "initiation.safetensors")
    again = OutcomeInitiation.load(tmp_path / "initiation.safetensors")
    np.testing.assert_array_equal(again.probability(probe, "reach"),
                                  fitted.probability(probe, "reach"))


def test_an_option_that_would_finish_at_once_is_not_admissible_there():
    from dynoplan.envs.gear.state import DECISION_STEPS
    from dynoplan.pipeline.collect import run_outcomes as outcomes

    def run_outcomes(costs: np.ndarray, reached_end: bool, task_success: bool) -> np.ndarray:
        return outcomes(costs, reached_end, task_success, DECISION_STEPS)

    quick = np.zeros(DECISION_STEPS // 2, dtype=np.int64)  # ends within one decision
    assert not run_outcomes(quick, reached_end=True, task_success=False).any()
    assert run_outcomes(quick, reached_end=True, task_success=True).all()  # seated the gear
    long = np.zeros(3 * DECISION_STEPS, dtype=np.int64)
    ok = run_outcomes(long, reached_end=True, task_success=False)
    assert ok[:2 * DECISION_STEPS].all() and not ok[2 * DECISION_STEPS:].any()
    assert not run_outcomes(long, reached_end=False, task_success=False).any()
    touched = long.copy()
    touched[DECISION_STEPS] = 1  # a contact: failed from every start before it
    ok = run_outcomes(touched, reached_end=True, task_success=False)
    assert not ok[:DECISION_STEPS + 1].any() and ok[DECISION_STEPS + 1:2 * DECISION_STEPS].all()


class _Members:
    """An ensemble whose member ``k`` moves a 1-D state by ``deltas[k]`` per step."""

    def __init__(self, deltas):
        self.deltas = np.asarray(deltas, dtype=np.float64)

    @property
    def state_dim(self):
        return 1

    def sample(self, states, rng):
        return states + self.deltas[rng.integers(len(self.deltas), size=len(states))][:, None]

    @classmethod
    def stack(cls, items):
        return _Stack([m.deltas for m in items])


class _Stack:
    def __init__(self, deltas):
        self.deltas = np.stack(deltas)  # (options, members)

    def sample(self, states, rng):
        raise AssertionError("the planner keeps each rollout on one member")

    def trajectory_sampler(self, samples, rng):
        members = np.tile(np.arange(samples) % self.deltas.shape[1], (len(self.deltas), 1))
        shift = np.take_along_axis(self.deltas, members, axis=1)[..., None]
        return MemberStep(lambda states: states + shift, members)


class _Linear:
    """G(s) = s / 100."""

    def sample(self, states, rng):
        return np.clip(states[:, 0] / 100.0, 0.0, 1.0)

    def mean_std(self, states):
        return self.sample(states, None), np.zeros(len(states))


def test_the_epistemic_term_stops_an_over_confident_model_from_winning():
    # one member of "dream" promises a leap where its members disagree (unseen states);
    # "steady"'s members agree on a modest step
    options = [Option(name, FunctionPolicy(lambda o, r: 0), _Members(deltas),
                      ConstantTermination(0.0))
               for name, deltas in (("dream", [40.0, 0.0, 0.0, 0.0]),
                                    ("steady", [3.0, 3.0, 3.0, 3.0]))]
    state, rng = np.array([10.0]), np.random.default_rng(0)
    naive = OptionPlanner(options, _Linear(), horizon=1, samples=8).plan(state, rng)
    assert naive.chosen_name == "dream"  # E[G] = 0.2 against 0.13
    careful = OptionPlanner(options, _Linear(), horizon=1, samples=8,
                            epistemic=1.0).plan(state, rng)
    assert careful.chosen_name == "steady"
    assert careful.disagreements is not None
    np.testing.assert_allclose(careful.disagreements, [np.std([0.5, 0.1, 0.1, 0.1]), 0.0])
