"""The one fit (``fit_models``) on what the gear brings: option runs recorded at the
decision rate (``dynamics_runs``) and each option's spread calibrated on runs held back
from its fit (``FitSettings.dynamics_calibration``)."""

from dataclasses import replace

import numpy as np
import pytest

from dynoplan.adapters import option_spec
from dynoplan.data import Episode
from dynoplan.errors import DynoplanError
from dynoplan.pipeline import FitSettings, fit_models

NAMES = ["right", "left"]
SMALL = FitSettings(dynamics_hidden=(8,), dynamics_members=2, dynamics_epochs=2,
                    dynamics_min_updates=None, goal_hidden=8, goal_epochs=2,
                    option_model="step", regions=False)


def _run(seed: int, label: int, steps: int = 12) -> Episode:
    """One run of one option on a line: ``x`` moves by ``+-0.1`` a step, with noise."""
    rng = np.random.default_rng(seed)
    step = 0.1 if label == 0 else -0.1
    x = np.cumsum(np.r_[rng.uniform(-1, 1), step + 0.01 * rng.normal(size=steps)])
    return Episode(observations=x[:, None], actions=np.zeros((steps, 1)),
                   rewards=np.zeros(steps), terminations=np.zeros(steps, bool),
                   truncations=np.zeros(steps, bool),
                   infos={"option": np.full(steps, label),
                          "progress": np.linspace(1 / steps, 1.0, steps)},
                   seed=seed)


RUNS = [_run(seed, seed % 2) for seed in range(20)]
DEMOS = [_run(100 + seed, 0) for seed in range(3)]
SPECS = [option_spec(n, lambda obs: np.array([0.0], np.float32), termination=0.1)
         for n in NAMES]


def test_runs_at_the_decision_rate_are_one_model_step_a_row_whatever_the_stride():
    strided = fit_models(SPECS, RUNS, DEMOS, replace(SMALL, stride=3), seed=0)
    runs = fit_models(SPECS, RUNS, DEMOS, replace(SMALL, stride=3), seed=0,
                      dynamics_runs=RUNS)
    # every step of the ten runs of 'left' is a row; at stride 3, 10 of every 12 are
    assert runs.report["dynamics"]["left"]["transitions"] == 10 * 12
    assert strided.report["dynamics"]["left"]["transitions"] == 10 * 10
    # the demonstrations (all 'right') do not join the runs given
    assert runs.report["dynamics"]["right"]["transitions"] == 10 * 12
    assert strided.stride == runs.stride == 3


def test_held_back_runs_calibrate_each_options_spread():
    plain = fit_models(SPECS, RUNS, DEMOS, SMALL, seed=0, dynamics_runs=RUNS)
    calibrated = fit_models(SPECS, RUNS, DEMOS, replace(SMALL, dynamics_calibration=0.3),
                            seed=0, dynamics_runs=RUNS)
    for name in NAMES:
        row = calibrated.report["dynamics"][name]
        assert row["calibration_runs"] == 3  # 30 % of each option's ten runs (seeds)
        assert row["transitions"] == 7 * 12  # fitted on the others only
        assert len(row["std_scale"]) == 1 and row["std_scale"][0] > 0
        assert "std_scale" not in plain.report["dynamics"][name]
    states = np.array([[0.0], [0.5]])
    assert not np.allclose(calibrated.dynamics["left"].predict(states)[1],
                           plain.dynamics["left"].predict(states)[1])


def test_without_runs_given_the_transitions_are_cut_into_runs_to_hold_some_back():
    calibrated = fit_models(SPECS, RUNS, DEMOS,
                            replace(SMALL, stride=2, dynamics_calibration=0.3), seed=0)
    row = calibrated.report["dynamics"]["left"]
    assert row["calibration_runs"] > 0 and row["std_scale"] is not None


def test_episodes_of_several_options_are_cut_into_runs_before_some_are_held_back():
    """At stride 1 too: an exploration episode that runs 'right' then 'left' gives each
    option a run of its own, and each option has runs held back."""
    both = [Episode(observations=np.r_[a.observations, b.observations[1:] +
                                       a.observations[-1] - b.observations[0]],
                    actions=np.zeros((24, 1)), rewards=np.zeros(24),
                    terminations=np.zeros(24, bool), truncations=np.zeros(24, bool),
                    infos={"option": np.r_[np.zeros(12, int), np.ones(12, int)]},
                    seed=a.seed)
            for a, b in zip(RUNS[0::2], RUNS[1::2], strict=True)]
    calibrated = fit_models(SPECS, both, DEMOS, replace(SMALL, dynamics_calibration=0.3),
                            seed=0)
    for name in NAMES:
        row = calibrated.report["dynamics"][name]
        assert row["calibration_runs"] > 0 and row["std_scale"] is not None, name
    # every step of the ten episodes is one option's transition, but for the switches
    left = calibrated.report["dynamics"]["left"]
    assert left["transitions"] + 12 * left["calibration_runs"] == 10 * 12


@pytest.mark.parametrize("bad", [-0.1, 1.0, float("nan")])
def test_a_calibration_share_outside_zero_to_one_is_one_error(bad):
    with pytest.raises(DynoplanError, match="dynamics_calibration must be in"):
        replace(SMALL, dynamics_calibration=bad).validate()


def test_an_option_model_to_the_end_is_not_calibrated():
    with pytest.raises(DynoplanError, match="needs option_model='step'"):
        replace(SMALL, option_model="end", dynamics_calibration=0.2).validate()
