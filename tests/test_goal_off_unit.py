"""How far the goal's labels off the demonstrations reach, in demonstration steps: along
the path, or as the displacement that many steps make."""

import numpy as np
import pytest

from dynoplan.errors import DynoplanError
from dynoplan.pipeline.config import pipeline_settings
from dynoplan.pipeline.fit_goal import off_demonstration_progress, states_around


def _jittering_demonstrations() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Three demonstrations of a cart moving from 0 to 1 (column 0) whose pole's speed
    jumps between -1 and 1 at every step (column 1, bang-bang control)."""
    states, progress, groups = [], [], []
    for g in range(3):
        t = np.linspace(0.0, 1.0, 51)
        jitter = np.where(np.arange(t.size) % 2 == g % 2, 1.0, -1.0)
        states.append(np.stack([t, jitter], axis=1))
        progress.append(t)
        groups.append(np.full(t.size, g))
    return np.concatenate(states), np.concatenate(progress), np.concatenate(groups)


def test_a_state_past_the_goal_is_labelled_lower_by_the_displacement():
    states, progress, groups = _jittering_demonstrations()
    past = np.array([[1.3, 1.0], [1.3, -1.0]])  # 0.3 past the end, the pole as shown
    path = off_demonstration_progress(states, progress, groups, past, radius=5.0)
    moved = off_demonstration_progress(states, progress, groups, past, radius=5.0,
                                       unit="displacement")
    # a step along the path is mostly the jitter, and five of them count it five times:
    # 0.3 past the end is as good as the end
    assert path.min() > 0.98
    # five steps apart, the jitter counts once (and the cart has moved 0.1)
    assert moved.max() < 0.8
    # on a demonstration, either way keeps the progress
    for unit in ("path", "displacement"):
        on = off_demonstration_progress(states, progress, groups, states[7:8], radius=5.0,
                                        unit=unit)
        assert on[0] == pytest.approx(progress[7])


def test_without_jitter_the_two_units_agree():
    t = np.linspace(0.0, 1.0, 41)
    states = np.stack([t, 2.0 * t], axis=1)
    groups = np.zeros(t.size, dtype=np.int64)
    off = np.array([[0.5, 1.2], [1.1, 2.0]])
    path = off_demonstration_progress(states, t, groups, off, radius=4.0)
    moved = off_demonstration_progress(states, t, groups, off, radius=4.0,
                                       unit="displacement")
    assert moved == pytest.approx(path, rel=1e-9)


def test_the_unit_is_a_fit_key():
    assert pipeline_settings({}).fit.goal_off_unit == "path"  # the default
    assert pipeline_settings({"fit.goal_off_unit": "displacement"}).fit.goal_off_unit \
        == "displacement"
    with pytest.raises(DynoplanError, match="goal_off_unit must be one of"):
        pipeline_settings({"fit.goal_off_unit": "miles"})


def test_states_around_the_demonstrations_fall_away_from_them():
    states, progress, groups = _jittering_demonstrations()
    states = np.concatenate([states, np.full((len(states), 1), 7.0)], axis=1)  # constant
    around = states_around(states, groups, 4, 5.0, np.random.default_rng(0),
                           unit="displacement")
    assert around.shape == (4 * len(states), 3)
    assert np.all(around[:, 2] == 7.0)  # a dimension the labels leave out stays as shown
    assert np.array_equal(around, states_around(states, groups, 4, 5.0,
                                                np.random.default_rng(0),
                                                unit="displacement"))  # seeded
    # some land past the end of the cart's travel, where no demonstration went, and
    # their labels fall with the distance from it
    past = around[around[:, 0] > 1.2]
    assert len(past) > 0
    labels = off_demonstration_progress(states, progress, groups, past, radius=5.0,
                                        unit="displacement")
    assert labels.max() < 0.9
    far = past[:, 0] > np.median(past[:, 0])
    assert labels[far].mean() < labels[~far].mean()


def test_the_goal_heuristic_fitted_with_states_around_falls_past_the_goal():
    from dynoplan.data import Episode
    from dynoplan.pipeline.fit_goal import fit_goal

    def demo(start: float) -> Episode:  # a cart from start to 1, then 5 steps at rest
        x = np.concatenate([np.linspace(start, 1.0, 21), np.ones(5)])
        t = len(x) - 1
        return Episode(observations=x[:, None], actions=np.zeros((t, 1)),
                       rewards=np.zeros(t), terminations=np.zeros(t, bool),
                       truncations=np.zeros(t, bool),
                       infos={"option": np.zeros(t, np.int64),
                              "progress": np.arange(1, t + 1) / t})

    demos = [demo(s) for s in (0.0, 0.05, 0.1, 0.15)]
    past = np.array([[1.0], [1.5], [2.0]])
    read = {}
    for around in (0, 4):
        fit = pipeline_settings({"fit.goal_off_around": around, "fit.goal_epochs": 150,
                                 "fit.goal_off_unit": "displacement"}).fit
        goal, report = fit_goal(demos, fit, seed=0)
        assert report["off_demo_states"] == around * report["states"]  # no exploration
        read[around] = goal.mean_std(past)[0]
    assert read[0][2] > 0.8  # nothing says that 2.0 is not the goal
    assert read[4][0] > 0.8 and read[4][2] < 0.5  # the mark, and well past it
    # without the exploration states, an exploration episode that failed changes nothing
    # (its last row is no row of the states around the demonstrations)
    failed = Episode(observations=np.array([[0.3], [0.2], [0.1], [0.0]]),
                     actions=np.zeros((3, 1)), rewards=np.zeros(3),
                     terminations=np.array([False, False, True]), truncations=np.zeros(3, bool),
                     infos={"option": np.zeros(3, np.int64),
                            "failure": np.array([False, False, True])})
    fit = pipeline_settings({"fit.goal_off_around": 4, "fit.goal_epochs": 150,
                             "fit.goal_off_demos": False}).fit
    alone = fit_goal(demos, fit, seed=0)[0].mean_std(past)[0]
    beside = fit_goal(demos, fit, seed=0, off=[failed])[0].mean_std(past)[0]
    assert np.array_equal(alone, beside)
