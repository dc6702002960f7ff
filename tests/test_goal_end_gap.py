"""The pipeline reports, per option, how far the goal's score of an imagined run's end is
from the real end's (what Eq. 1 relies on)."""

import numpy as np

from dynoplan.data import Episode
from dynoplan.pipeline.fit_dynamics import goal_end_gaps


def _run(start: float, steps: int, label: int) -> Episode:
    """One option run on a line: the state rises by 1 every environment step."""
    x = start + np.arange(steps + 1, dtype=float)
    return Episode(observations=x[:, None], actions=np.zeros((steps, 1)),
                   rewards=np.zeros(steps), terminations=np.zeros(steps, bool),
                   truncations=np.zeros(steps, bool), infos={"option": np.full(steps, label)})


class _Shift:
    """Deterministic dynamics: every model step adds ``step`` (two identical members)."""

    members = 2

    def __init__(self, step: float) -> None:
        self.step = step

    def predict(self, states):
        m = np.stack([states + self.step] * 2)
        return m, np.zeros_like(m)


class _Ramp:
    """A goal heuristic ``G(x) = x / 10``."""

    def mean_std(self, states):
        x = np.asarray(states, float)[:, 0]
        return x / 10.0, np.zeros_like(x)


def test_gap_per_option_at_the_model_stride():
    # 'up' runs 7 environment steps from 0 (3 model steps of 2, ending at x = 6) and 4
    # from 10 (2 model steps, ending at 14); 'never' has no run
    episodes = [_run(0.0, 7, 0), _run(10.0, 4, 0)]
    right = goal_end_gaps({"up": _Shift(2.0), "never": _Shift(2.0)}, _Ramp(), episodes,
                          lambda obs: obs, stride=2, seed=0)
    assert right["never"] is None
    up = right["up"]
    assert up is not None and up["runs"] == 2
    assert up["gap"] == 0.0 and up["real"] == (0.6 + 1.4) / 2
    # a model that moves half as fast falls short by 3 and 2 model steps: 0.3 and 0.2
    slow = goal_end_gaps({"up": _Shift(1.0)}, _Ramp(), episodes, lambda obs: obs, stride=2,
                         seed=0)["up"]
    assert slow is not None and np.isclose(slow["gap"], 0.25)
