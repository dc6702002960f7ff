"""Each option's dynamics ``D_w`` (see :mod:`dynoplan.pipeline.fit` for the model stride):
:func:`fit_dynamics` with a :data:`DynamicsFitter`, by default an MLP ensemble
(:func:`ensemble_fitter`); the planner's per-model-step termination (:func:`strided`)."""

from collections.abc import Mapping, Sequence
from typing import Any, Protocol

import numpy as np

from dynoplan.data.episodes import Episode
from dynoplan.errors import DynoplanError
from dynoplan.models.dynamics import DynamicsModel
from dynoplan.models.evaluation import one_step_error, option_end_gap
from dynoplan.models.goal import GoalHeuristic
from dynoplan.models.neural_dynamics import MLPEnsembleDynamics
from dynoplan.models.trainer import TrainingReport
from dynoplan.options.termination import ConstantTermination, Termination
from dynoplan.pipeline.collect import ObservationFn
from dynoplan.pipeline.fit_data import option_runs, split_runs
from dynoplan.pipeline.fit_settings import FitSettings
from dynoplan.types import FloatArray


class DynamicsFitter(Protocol):
    """Learns one option's ``D_w``: ``fit(option, states (N, d), next_states (N, d), seed)``."""

    def __call__(self, option: str, states: FloatArray, next_states: FloatArray,
                 seed: int) -> DynamicsModel: ...


def fit_ensemble(option: str, states: FloatArray, next_states: FloatArray, seed: int,
                 settings: FitSettings) -> tuple[MLPEnsembleDynamics, TrainingReport]:
    """Option ``option``'s MLP ensemble (PETS-style) fitted on its transitions ``states``
    ``(N, d)`` -> ``next_states`` ``(N, d)``: ``settings.dynamics_hidden`` and
    ``dynamics_members``, :func:`dynamics_epochs` epochs of :data:`DYNAMICS_BATCH` rows,
    weights and draws seeded from ``seed`` alone (the same model for the same pairs and
    ``seed`` on one machine, under
    :func:`~dynoplan.models.trainer.deterministic_training`). Returns the model and what
    its training did (losses per epoch, the kept epoch)."""
    model = MLPEnsembleDynamics(states.shape[1], settings.dynamics_hidden,
                                settings.dynamics_members, option=option, seed=seed)
    report = model.fit(states, next_states, epochs=dynamics_epochs(len(states), settings),
                       batch_size=DYNAMICS_BATCH, seed=seed,
                       keep_still=settings.constant_dimensions_still)
    return model, report


def ensemble_fitter(settings: FitSettings,
                    reports: dict[str, TrainingReport] | None = None) -> DynamicsFitter:
    """The default :data:`DynamicsFitter`: an MLP ensemble per option
    (:func:`fit_ensemble`); ``reports``, when given, receives each option's
    :class:`~dynoplan.models.trainer.TrainingReport` by its name."""

    def fit(option: str, states: FloatArray, next_states: FloatArray,
            seed: int) -> DynamicsModel:
        model, report = fit_ensemble(option, states, next_states, seed, settings)
        if reports is not None:
            reports[option] = report
        return model

    return fit


DYNAMICS_BATCH = 256
"""Rows per member and gradient step of the dynamics ensembles."""


def dynamics_epochs(rows: int, settings: FitSettings) -> int:
    """Epochs of an option's ensemble on ``rows`` transitions: ``dynamics_epochs``, more
    when that would take fewer than ``dynamics_min_updates`` gradient steps, fewer (at
    least 5) when it would take more than ``dynamics_max_updates`` (the fit holds out
    10 % of the rows)."""
    batches = max(1, -(-round(0.9 * rows) // DYNAMICS_BATCH))
    epochs = settings.dynamics_epochs
    if settings.dynamics_min_updates is not None:
        epochs = max(epochs, -(-settings.dynamics_min_updates // batches))
    if settings.dynamics_max_updates is None:
        return epochs
    return max(5, min(epochs, settings.dynamics_max_updates // batches))

def fit_dynamics(transitions: dict[str, tuple[FloatArray, FloatArray]], seed: int,
                 fitter: DynamicsFitter, min_transitions: int = 10,
                 calibration: Mapping[str, tuple[FloatArray, FloatArray]] | None = None,
                 remedy: str = "collect more episodes or lower the stride",
                 ) -> tuple[dict[str, DynamicsModel], dict[str, dict[str, Any]]]:
    """Fit one dynamics model per option and report its one-step error.

    Args:
        transitions: per option its pairs ``(states (N, d), next_states (N, d))``; the
            ``k``-th option's model is fitted from seed ``seed + k``.
        calibration: per option, pairs ``(N, d)`` its model was not fitted on (whole
            held-back runs: :func:`calibration_split`) that rescale its predicted spread
            (``calibrate(states, next_states, CALIBRATION_LEVEL)``) when there are at
            least ``min_transitions`` of them and the model can be calibrated.
        remedy: what the error of too few transitions tells the user to do.

    Returns:
        The models by name, and per option ``{"transitions", "rmse", "no_change_rmse"}``
        (one-step error on its own training pairs, against predicting no change; for
        models without ``predict`` the errors are ``None``); with ``calibration`` also
        ``"std_scale"``: the ``(d,)`` factors of the spread as a list, or ``None`` (not
        calibrated).

    Raises:
        DynoplanError: an option has fewer than ``min_transitions`` transitions.
    """
    models: dict[str, DynamicsModel] = {}
    report: dict[str, dict[str, Any]] = {}
    for k, (name, (s, nxt)) in enumerate(transitions.items()):
        if len(s) < min_transitions:
            raise DynoplanError(
                f"option '{name}': only {len(s)} transitions to learn its dynamics from "
                f"(need >= {min_transitions}); {remedy}")
        model = fitter(name, s, nxt, seed + k)
        models[name] = model
        row: dict[str, Any] = {"transitions": len(s), "rmse": None, "no_change_rmse": None}
        if calibration is not None:
            held_s, held_next = calibration.get(name, (s[:0], nxt[:0]))
            calibrate = getattr(model, "calibrate", None)
            row["std_scale"] = (
                np.asarray(calibrate(held_s, held_next, CALIBRATION_LEVEL)).tolist()
                if callable(calibrate) and len(held_s) >= min_transitions else None)
        if callable(getattr(model, "predict", None)):
            err = one_step_error(model, s, nxt)  # type: ignore[arg-type]
            row["rmse"], row["no_change_rmse"] = err.model_rmse_total, err.baseline_rmse_total
        report[name] = row
    return models, report

CALIBRATION_LEVEL = 0.9
"""The central interval a calibrated model's spread covers that share of held-back next
states with, per dimension (:meth:`~dynoplan.models.neural_dynamics.MLPEnsembleDynamics.
calibrate`)."""


def calibration_split(episodes: Sequence[Episode], option_names: Sequence[str],
                      fraction: float, seed: int, min_groups: int = 4,
                      ) -> dict[str, tuple[list[Episode], list[Episode]]]:
    """Per option, its runs split into those its dynamics are fitted on and those held
    back to calibrate the model's spread (:func:`fit_dynamics`'s ``calibration``).

    Each episode is one run of the option of its first label. Of option ``k``'s runs,
    ``fraction`` are held back, grouped by their ``seed``
    (:func:`~dynoplan.pipeline.fit_data.split_runs`, drawn from generator
    ``[seed, 4, k]``); none when its runs come from fewer than ``min_groups`` seeds.

    Returns:
        ``{name: (fitted runs, held-back runs)}`` for every option, in order.
    """
    out: dict[str, tuple[list[Episode], list[Episode]]] = {}
    for k, name in enumerate(option_names):
        own = [e for e in episodes if e.options is not None and int(e.options[0]) == k]
        out[name] = (split_runs(own, fraction, np.random.default_rng([seed, 4, k]))
                     if len({e.seed for e in own}) >= min_groups else (own, []))
    return out


class StridedTermination:
    """``1 - (1 - beta(s))^k``: the chance that an option stops within ``k`` steps."""

    def __init__(self, base: Termination, stride: int) -> None:
        self.base = base
        self.stride = int(stride)

    def probability(self, states: FloatArray) -> FloatArray:
        beta = np.asarray(self.base.probability(states), dtype=np.float64)
        return 1.0 - (1.0 - beta) ** self.stride


GAP_ROLLOUTS = 16
"""Model rollouts per option run in :func:`goal_end_gaps`."""


def goal_end_gaps(dynamics: Mapping[str, DynamicsModel], goal: GoalHeuristic,
                  episodes: Sequence[Episode], state_fn: ObservationFn, stride: int,
                  seed: int, to_end: bool = False) -> dict[str, dict[str, Any] | None]:
    """Per option, how far the goal's score of each recorded run's imagined end is from
    that of its real end (:func:`~dynoplan.models.evaluation.option_end_gap`: what Eq. 1
    relies on), over the runs of ``episodes`` (:func:`option_runs` at the model's
    ``stride``; ``to_end``: option models, one model step to a run's end). ``None`` for
    an option without runs or whose model has no ``predict``.
    """
    runs = option_runs(episodes, list(dynamics), state_fn, stride)
    rng = np.random.default_rng([seed, 5])
    out: dict[str, dict[str, Any] | None] = {}
    for name, model in dynamics.items():
        starts, ends, steps = runs[name]
        if to_end:
            steps = np.minimum(steps, 1)
        out[name] = (option_end_gap(model, starts, ends, steps,  # type: ignore[arg-type]
                                    lambda s: goal.mean_std(s)[0], GAP_ROLLOUTS, rng)
                     if callable(getattr(model, "predict", None)) and len(starts) else None)
    return out


def strided(termination: Termination, stride: int) -> Termination:
    """The per-model-step termination for ``stride`` environment steps per model step."""
    if stride == 1:
        return termination
    if isinstance(termination, ConstantTermination):  # stays stackable
        return ConstantTermination(1.0 - (1.0 - termination.beta) ** stride)
    return StridedTermination(termination, stride)


__all__ = ["CALIBRATION_LEVEL", "DYNAMICS_BATCH", "GAP_ROLLOUTS", "DynamicsFitter",
           "StridedTermination", "calibration_split", "dynamics_epochs", "ensemble_fitter",
           "fit_dynamics", "fit_ensemble", "goal_end_gaps", "strided"]
