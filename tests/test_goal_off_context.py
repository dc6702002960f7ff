"""The goal's labels off the demonstrations, with and without the episode's context."""

import numpy as np
import pytest

from dynoplan.errors import DynoplanError
from dynoplan.pipeline.config import pipeline_settings
from dynoplan.pipeline.fit_goal import context_mask, off_demonstration_progress


def _demonstrations(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Four demonstrations of a hand moving from 0 to 1 (column 0), each towards a goal
    put elsewhere at the reset (column 1, the same along the demonstration), and a
    column that never changes (column 2)."""
    states, progress, groups = [], [], []
    for g, goal in enumerate([0.2, 0.9, 0.5, 0.7]):
        t = np.linspace(0.0, 1.0, 21)
        x = np.stack([t + 0.01 * rng.normal(size=t.size), np.full(t.size, goal),
                      np.full(t.size, 3.0)], axis=1)
        states.append(x)
        progress.append(t)
        groups.append(np.full(t.size, g))
    return np.concatenate(states), np.concatenate(progress), np.concatenate(groups)


def test_the_context_is_the_dimension_the_same_along_every_demonstration():
    states, _, groups = _demonstrations(np.random.default_rng(0))
    assert context_mask(states, groups).tolist() == [False, True, True]
    one = groups == 0
    assert not context_mask(states[one], groups[one]).any()  # one demonstration: no context


def test_a_state_of_another_episode_is_labelled_by_its_moving_parts():
    states, progress, groups = _demonstrations(np.random.default_rng(0))
    # halfway along, in an episode whose goal was put where no demonstration had it
    off = np.array([[0.5, -0.6, 3.0], [0.5, 1.7, 3.0]])
    plain = off_demonstration_progress(states, progress, groups, off, radius=5.0)
    mine = off_demonstration_progress(states, progress, groups, off, radius=5.0,
                                      context=True)
    assert plain.max() < 0.05  # the goal's place alone puts it far from every demonstration
    assert mine == pytest.approx([0.5, 0.5], abs=0.05)
    # a state on a demonstration keeps its progress either way
    on = off_demonstration_progress(states, progress, groups, states[5:6], radius=5.0,
                                    context=True)
    assert on[0] == pytest.approx(progress[5])


def test_the_setting_is_a_fit_key():
    assert pipeline_settings({}).fit.goal_off_context  # the default
    assert not pipeline_settings({"fit.goal_off_context": False}).fit.goal_off_context
    with pytest.raises(DynoplanError):
        pipeline_settings({"fit.goal_off_context": "maybe"})
