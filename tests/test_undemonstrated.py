"""Options the demonstrations never show: never admissible under their learned sets by
default (the paper's Eq. 5: no components, no region), or a region from their own runs."""

import numpy as np
import pytest

from dynoplan.adapters import option_spec
from dynoplan.data import Episode
from dynoplan.errors import DynoplanWarning
from dynoplan.pipeline import FitSettings, fit_option_regions


def _episode(states, label):
    n = len(states) - 1
    return Episode(observations=np.asarray(states, float)[:, None], actions=np.zeros((n, 1)),
                   rewards=np.zeros(n), terminations=np.zeros(n, bool),
                   truncations=np.zeros(n, bool), infos={"option": np.full(n, label)})


# demonstrations: option 0 ('right') acts around x = 2.5; exploration: option 1 ('left')
# ran around x = -5 only; option 2 ('idle') never ran anywhere.
_RNG = np.random.default_rng(0)
DEMOS = [_episode(_RNG.normal(2.5, 1.0, 30), 0) for _ in range(5)]
RUNS = [_episode(_RNG.normal(-5.0, 1.0, 30), 1) for _ in range(5)]
NAMES = ["right", "left", "idle"]


def test_undemonstrated_option_gets_no_region_by_default():
    regions, report = fit_option_regions(DEMOS, RUNS, NAMES, FitSettings(), seed=0)
    assert report["undemonstrated"] == {"left": "none", "idle": "none"}
    assert not regions.contains(np.array([[-5.0], [2.5]]), "left").any()


def test_undemonstrated_option_gets_a_region_from_its_own_runs():
    regions, report = fit_option_regions(DEMOS, RUNS, NAMES,
                                         FitSettings(region_undemonstrated="runs"), seed=0)
    assert report["undemonstrated"] == {"left": "runs", "idle": "none"}
    assert len(report["warnings"]) == 2
    xs = np.linspace(-20.0, 20.0, 401)[:, None]
    left = regions.contains(xs, "left")
    assert left[(xs[:, 0] > -5.5) & (xs[:, 0] < -4.5)].all()  # where it ran
    assert not left[xs[:, 0] > 0.0].any() and left.mean() < 0.5  # not everywhere
    assert not regions.contains(xs, "idle").any()  # no runs: never admissible


def test_an_option_shown_at_one_demonstration_state_is_treated_as_never_demonstrated():
    # a distractor that ran for one step of an episode taken as a demonstration (the
    # improvement rounds' successes): one state is too few for a mixture
    once = _episode([2.0, 2.1], 1)
    regions, report = fit_option_regions([*DEMOS, once], RUNS, NAMES, FitSettings(), seed=0)
    assert report["undemonstrated"] == {"left": "none", "idle": "none"}
    assert any("fewer than 2 demonstration states" in w for w in report["warnings"])
    assert not regions.contains(np.array([[2.0], [-5.0]]), "left").any()
    assert regions.contains(np.array([[2.5]]), "right")[0]


def test_the_other_policies_are_settings():
    none, _ = fit_option_regions(DEMOS, RUNS, NAMES,
                                 FitSettings(region_undemonstrated="none"), seed=0)
    assert not none.contains(np.array([[-5.0]]), "left")[0]
    everywhere, report = fit_option_regions(DEMOS, RUNS, NAMES,
                                            FitSettings(region_undemonstrated="everywhere"),
                                            seed=0)
    assert everywhere.option_names == ["right"]
    assert report["undemonstrated"] == {"left": "everywhere", "idle": "everywhere"}


def test_the_fitted_initiation_set_of_an_undemonstrated_option_is_not_everywhere():
    from dynoplan.pipeline import fit_models

    specs = [option_spec(n, lambda obs: np.array([0.0], np.float32), termination=0.1)
             for n in NAMES]
    settings = FitSettings(dynamics_hidden=(8,), dynamics_members=1, dynamics_epochs=1,
                           goal_hidden=8, goal_epochs=1, region_undemonstrated="runs")
    idle_runs = [_episode(_RNG.normal(11.0, 0.5, 30), 2)]
    with pytest.warns(DynoplanWarning, match="never appear in the demonstrations"):
        models = fit_models(specs, [*RUNS, *idle_runs], DEMOS, settings, seed=0)
    xs = np.linspace(-20.0, 20.0, 401)[:, None]
    for spec in specs[1:]:
        share = models.initiation(spec).contains(xs).mean()
        assert 0.0 < share < 0.5, (spec.name, share)


class _Ramp:
    """A goal heuristic ``G(x) = x / 10`` on 1-D states."""

    state_dim = 1

    def mean_std(self, states):
        x = np.asarray(states, float)[:, 0]
        return x / 10.0, np.zeros_like(x)


def test_outcome_initiation_learns_where_runs_made_progress():
    """Known answer: 'right' gains from x < 0 and loses from x > 2 (a wall)."""
    from dynoplan.pipeline import fit_outcome_initiation, option_runs

    rng = np.random.default_rng(0)
    episodes = []
    for _ in range(40):
        x0 = rng.uniform(-5.0, 5.0)
        end = x0 + 1.0 if x0 < 1.0 else x0 - 0.5
        states = np.linspace(x0, end, 4)  # one run of 3 steps of option 0
        episodes.append(_episode(np.r_[states, states[-1]], 0))
        episodes[-1].infos["option"][-1] = 1  # then one step of option 1
    runs = option_runs(episodes, ["right", "stay"])
    assert runs["right"][0].shape == (40, 1) and (runs["right"][2] == 3).all()
    learned, report = fit_outcome_initiation(episodes, ["right", "stay"], _Ramp(),
                                             FitSettings(), seed=0)
    assert report["right"]["kind"] == "network" and report["stay"]["kind"] == "never"
    assert learned.contains(np.array([[-3.0], [-1.0]]), "right").all()
    assert not learned.contains(np.array([[3.0], [4.0]]), "right").any()


def test_an_undemonstrated_option_may_start_where_its_runs_made_the_goal_rise():
    """``region_undemonstrated="outcomes"``, known answer: the undemonstrated 'left'
    lowers ``G(x) = x / 10`` where it ran from x < -2 (it moves left) and raises it from
    x > 6 (there a wall turns it right): admissible there only; 'idle' never ran whole,
    so it is admissible nowhere. The demonstrated 'right' keeps its region."""
    from dynoplan.pipeline import fit_undemonstrated_initiation

    rng = np.random.default_rng(1)
    runs = []
    for _ in range(30):
        x0 = rng.uniform(-8.0, -2.0)
        runs.append(_episode(np.linspace(x0, x0 - 1.0, 5), 1))
        x0 = rng.uniform(6.5, 9.0)
        runs.append(_episode(np.linspace(x0, x0 + 1.0, 5), 1))
    regions, report = fit_option_regions(DEMOS, runs, NAMES,
                                         FitSettings(region_undemonstrated="outcomes"),
                                         seed=0)
    assert report["undemonstrated"] == {"left": "outcomes", "idle": "none"}
    assert regions.option_names == ["right", "idle"]  # 'left': no region, its outcomes
    assert not regions.contains(np.array([[11.0]]), "idle")[0]
    learned, fit = fit_undemonstrated_initiation(runs, NAMES, ["left", "idle"], _Ramp(),
                                                 FitSettings(), seed=0)
    assert fit["left"]["kind"] == "network" and fit["idle"]["kind"] == "never"
    assert learned.contains(np.array([[7.0], [8.5]]), "left").all()
    assert not learned.contains(np.array([[-6.0], [-3.0]]), "left").any()
    assert not learned.contains(np.array([[7.0], [-3.0]]), "idle").any()


def test_fit_models_gives_the_undemonstrated_option_its_learned_initiation():
    from dynoplan.pipeline import fit_models

    specs = [option_spec(n, lambda obs: np.array([0.0], np.float32), termination=0.1)
             for n in NAMES]
    settings = FitSettings(dynamics_hidden=(8,), dynamics_members=1, dynamics_epochs=1,
                           goal_hidden=8, goal_epochs=1, region_undemonstrated="outcomes",
                           option_model="step")
    cut = _episode(_RNG.normal(11.0, 0.5, 30), 2)  # 'idle' ran, but the explorer cut it
    cut.infos["interrupted"] = np.r_[np.zeros(28, bool), True]
    with pytest.warns(DynoplanWarning, match="made the goal heuristic rise"):
        models = fit_models(specs, [*RUNS, cut], DEMOS, settings, seed=0)
    assert models.learned_initiation is not None
    assert models.learned_initiation.option_names == ["left", "idle"]
    assert models.report["outcome_initiation"]["left"]["runs"] == 5 * 29
    assert models.report["outcome_initiation"]["idle"]["kind"] == "never"
    xs = np.linspace(-20.0, 20.0, 401)[:, None]
    assert not models.initiation(specs[2]).contains(xs).any()  # idle: no whole run
