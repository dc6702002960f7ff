"""How far the goal's labels off the demonstrations reach, in demonstration steps: along
the path, or as the displacement that many steps make."""

import numpy as np
import pytest

from dynoplan.errors import DynoplanError
from dynoplan.pipeline.config import pipeline_settings
from dynoplan.pipeline.fit_goal import off_demonstration_progress


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
