"""Learning what the planner needs from labelled episodes.

- per option, a dynamics model ``D_w`` on its transitions (:func:`option_transitions`,
  :func:`fit_dynamics`); by default a probabilistic MLP ensemble
  (:class:`~dynoplan.models.neural_dynamics.MLPEnsembleDynamics`), any other learner can
  be passed as a :data:`DynamicsFitter`;
- the goal heuristic ``G`` on the demonstrations' progress (:func:`fit_goal`);
- the safety regions of Eq. 5 on the demonstrations' option labels
  (:func:`fit_option_regions`): by default calibrated on held-out demonstrations
  (:meth:`~dynoplan.models.regions.SafetyRegions.fit_heldout`); an option the
  demonstrations never show gets a region from its own runs (or none), with a warning.

**Model stride.** With ``stride = k > 1`` a dynamics model predicts ``k`` environment
steps at once (``s_{t+k}`` from ``s_t`` while the option runs), so a planning horizon of
``n`` model steps looks ``n * k`` environment steps ahead with ``k`` times fewer model
calls and less compounding error. The planner then draws termination once per model
step with ``1 - (1 - beta(s))^k`` (:class:`StridedTermination`), the probability that
the option stops somewhere in those ``k`` steps when ``beta`` hardly changes over them.
"""

import os
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from dynoplan.adapters.spec import OptionSpec
from dynoplan.data.episodes import OPTION_KEY, Episode
from dynoplan.errors import DynoplanError, DynoplanWarning
from dynoplan.io import staged_folder
from dynoplan.models.dynamics import DynamicsModel, StackedDynamics
from dynoplan.models.evaluation import one_step_error
from dynoplan.models.features import FeatureMap, GoalOnFeatures, RegionsOnFeatures
from dynoplan.models.folder import (
    GOAL_FILE,
    INITIATION_FILE,
    MANIFEST_FILE,
    REGIONS_FILE,
    dynamics_file,
    read_manifest,
    write_manifest,
)
from dynoplan.models.goal_network import (
    GoalNetwork,
    GoalTrainingReport,
    evaluate_goal,
    goal_training_set,
)
from dynoplan.models.neural_dynamics import MLPEnsembleDynamics
from dynoplan.models.outcome_initiation import (
    OutcomeInitiation,
    OutcomeInitiationOnFeatures,
    fit_report_dict,
)
from dynoplan.models.regions import SafetyRegions
from dynoplan.options.initiation import AllOf, Everywhere, Initiation, InRegion
from dynoplan.options.option import Option
from dynoplan.options.termination import ConstantTermination, Termination
from dynoplan.pipeline.collect import OUTCOME_KEY, ObservationFn, flat_state
from dynoplan.types import FloatArray, IntArray

GoalModel = GoalNetwork | GoalOnFeatures
"""A goal heuristic as fitted: on the planner state, or on a named feature map of it."""
RegionsModel = SafetyRegions | RegionsOnFeatures
"""Safety regions as fitted: on the planner state, or on a named feature map of it."""
OutcomeModel = OutcomeInitiation | OutcomeInitiationOnFeatures
"""Initiation learned from outcomes as fitted: on the planner state or a feature map."""


@dataclass(frozen=True)
class FitSettings:
    """How the models are learned (recorded in the summary and in ``models.json``).

    Attributes:
        stride: environment steps per dynamics-model step (see the module docstring).
        dynamics_hidden: hidden layer widths of each option's MLP ensemble.
        dynamics_members: ensemble size.
        dynamics_epochs: training epochs of each ensemble.
        dynamics_max_updates: fewer epochs when an option has so many transitions that
            ``dynamics_epochs`` would take more gradient steps than this (at least 5;
            ``None``: no bound), which bounds the training time on large collections.
        goal_hidden: hidden width of the goal network.
        goal_members: goal ensemble size.
        goal_epochs: training epochs of the goal network.
        goal_ranking: weight of the goal network's ranking loss along demonstrations
            (:meth:`~dynoplan.models.goal_network.GoalNetwork.fit`; 0: none).
        goal_features, region_features: names of the task's feature maps the goal
            heuristic and the regions read (``None``: the planner state itself).
        regions: fit the safety regions (Eq. 5) and intersect every option's initiation
            set with its region.
        region_fit: ``"heldout"`` (default): components and thresholds chosen on
            held-out demonstrations (:meth:`SafetyRegions.fit_heldout`), so
            ``region_coverage`` is the share of *unseen* demonstration states inside;
            ``"bic"``: the paper's reading, BIC components and thresholds on the
            training states (with few demonstrations: needle-thin regions); ``"cv"``:
            BIC components, thresholds on the training states widened by what leaving
            demonstrations out shows (:func:`fit_regions_cross_validated`).
        region_coverage: share of an option's demonstration states inside its region
            (held out with ``"heldout"``, in-sample with ``"bic"`` and ``"cv"``).
        region_cv_coverage: ``"cv"``: share of left-out demonstrations' states of an
            option that its final threshold is widened to admit.
        region_slack: nats subtracted from every region threshold (widens them).
        region_components: mixture size (``None``: chosen in
            ``1..region_max_components``, by held-out likelihood or BIC).
        region_max_components: the largest mixture that may be chosen.
        region_folds: folds of whole demonstrations for ``"heldout"``.
        region_reg_covar: added to every covariance's diagonal, in units of each
            dimension's spread for ``"heldout"``, absolute for ``"cv"`` (``"bic"``: 1e-6).
        outcome_initiation: also learn where each option may start from the outcomes
            of its exploration runs (Bagaria et al. 2023; :func:`fit_outcome_initiation`)
            and intersect its initiation set with that.
        outcome_min_gain: a run is good when the goal heuristic's mean rose by more than
            this from its start to its end.
        region_undemonstrated: what an option that no demonstration shows gets:
            ``"runs"``: a region fitted (as above) on the states where it ran while
            collecting transitions, i.e. where its dynamics model has data; ``"none"``:
            no region (never admissible); ``"everywhere"``: its own initiation set
            alone (before 0.x the only behaviour). The pipeline warns either way.
    """

    stride: int = 1
    dynamics_hidden: tuple[int, ...] = (64, 64)
    dynamics_members: int = 5
    dynamics_epochs: int = 30
    dynamics_max_updates: int | None = None
    goal_hidden: int = 64
    goal_members: int = 1
    goal_epochs: int = 150
    goal_ranking: float = 0.0
    goal_features: str | None = None
    region_features: str | None = None
    regions: bool = True
    region_fit: str = "heldout"
    region_coverage: float = 0.95
    region_cv_coverage: float = 0.97
    region_slack: float = 0.0
    region_components: int | None = None
    region_max_components: int = 6
    region_folds: int = 5
    region_reg_covar: float = 1e-2
    region_undemonstrated: str = "runs"
    outcome_initiation: bool = False
    outcome_min_gain: float = 0.0

    def validate(self) -> None:
        if self.stride < 1:
            raise DynoplanError(f"stride must be >= 1, got {self.stride}")
        if self.dynamics_members < 1 or self.dynamics_epochs < 1 or not self.dynamics_hidden:
            raise DynoplanError("dynamics_members, dynamics_epochs and dynamics_hidden must "
                                "be positive")
        if self.dynamics_max_updates is not None and self.dynamics_max_updates < 1:
            raise DynoplanError(f"dynamics_max_updates must be >= 1 or None, got "
                                f"{self.dynamics_max_updates}")
        if self.goal_hidden < 1 or self.goal_members < 1 or self.goal_epochs < 1:
            raise DynoplanError("goal_hidden, goal_members and goal_epochs must be positive")
        if not self.goal_ranking >= 0.0:
            raise DynoplanError(f"goal_ranking must be >= 0, got {self.goal_ranking}")
        if not 0.0 < self.region_cv_coverage <= 1.0:
            raise DynoplanError(f"region_cv_coverage must be in (0, 1], got "
                                f"{self.region_cv_coverage}")
        if not 0.0 < self.region_coverage <= 1.0:
            raise DynoplanError(f"region_coverage must be in (0, 1], got {self.region_coverage}")
        if self.region_fit not in REGION_FITS:
            raise DynoplanError(f"region_fit must be one of {', '.join(REGION_FITS)}, got "
                                f"'{self.region_fit}'")
        if self.region_undemonstrated not in UNDEMONSTRATED:
            raise DynoplanError(f"region_undemonstrated must be one of "
                                f"{', '.join(UNDEMONSTRATED)}, got "
                                f"'{self.region_undemonstrated}'")
        if self.region_folds < 2:
            raise DynoplanError(f"region_folds must be >= 2, got {self.region_folds}")
        if self.region_reg_covar <= 0.0:
            raise DynoplanError(f"region_reg_covar must be > 0, got {self.region_reg_covar}")
        if self.region_max_components < 1 or (self.region_components is not None
                                              and self.region_components < 1):
            raise DynoplanError("region_components and region_max_components must be >= 1")


REGION_FITS = ("heldout", "bic", "cv")
"""Values of :attr:`FitSettings.region_fit`."""
UNDEMONSTRATED = ("runs", "none", "everywhere")
"""Values of :attr:`FitSettings.region_undemonstrated`."""


class DynamicsFitter(Protocol):
    """Learns one option's ``D_w``: ``fit(option, states (N, d), next_states (N, d), seed)``."""

    def __call__(self, option: str, states: FloatArray, next_states: FloatArray,
                 seed: int) -> DynamicsModel: ...


def ensemble_fitter(settings: FitSettings) -> DynamicsFitter:
    """The default :data:`DynamicsFitter`: an MLP ensemble per option (PETS-style)."""

    def fit(option: str, states: FloatArray, next_states: FloatArray,
            seed: int) -> DynamicsModel:
        model = MLPEnsembleDynamics(states.shape[1], settings.dynamics_hidden,
                                    settings.dynamics_members, option=option, seed=seed)
        model.fit(states, next_states, epochs=dynamics_epochs(len(states), settings),
                  batch_size=DYNAMICS_BATCH, seed=seed)
        return model

    return fit


DYNAMICS_BATCH = 256
"""Rows per member and gradient step of the dynamics ensembles."""


def dynamics_epochs(rows: int, settings: FitSettings) -> int:
    """Epochs of an option's ensemble on ``rows`` transitions: ``dynamics_epochs``, fewer
    (at least 5) when that would take more than ``dynamics_max_updates`` gradient steps
    (the fit holds out 10 % of the rows)."""
    if settings.dynamics_max_updates is None:
        return settings.dynamics_epochs
    batches = -(-round(0.9 * rows) // DYNAMICS_BATCH)
    return max(5, min(settings.dynamics_epochs, settings.dynamics_max_updates // batches))


def episode_states(episode: Episode, state_fn: ObservationFn = flat_state) -> FloatArray:
    """``state_fn`` of every observation of ``episode``: ``(T+1, state_dim)`` float64."""
    return np.stack([np.asarray(state_fn(o), dtype=np.float64).reshape(-1)
                     for o in episode.observations])


def option_transitions(episodes: Sequence[Episode], option_names: Sequence[str],
                       state_fn: ObservationFn = flat_state,
                       stride: int = 1) -> dict[str, tuple[FloatArray, FloatArray]]:
    """Per option, the pairs ``(s_t, s_{t+stride})`` during which only it acted.

    Returns:
        ``{name: (states (N, d), next_states (N, d))}``, ``N`` possibly 0.

    Raises:
        DynoplanError: an episode has no option labels, or labels outside the names.
    """
    found: dict[str, tuple[list[FloatArray], list[FloatArray]]] = {
        n: ([], []) for n in option_names}
    for index, episode in enumerate(episodes):
        labels = _labels(episode, index, len(option_names))
        if len(labels) < stride:
            continue
        rows = episode_states(episode, state_fn)
        windows = np.lib.stride_tricks.sliding_window_view(labels, stride)  # (T-k+1, k)
        same = (windows == windows[:, :1]).all(axis=1)
        for k, name in enumerate(option_names):
            t = np.flatnonzero(same & (windows[:, 0] == k))
            found[name][0].append(rows[t])
            found[name][1].append(rows[t + stride])
    d = None
    out: dict[str, tuple[FloatArray, FloatArray]] = {}
    for name, (s, n) in found.items():
        if s:
            out[name] = (np.concatenate(s), np.concatenate(n))
            d = out[name][0].shape[1]
    for name in option_names:
        if name not in out:
            out[name] = (np.zeros((0, d or 0)), np.zeros((0, d or 0)))
    return out


def _labels(episode: Episode, index: int, n_options: int) -> np.ndarray:
    labels = episode.infos.get(OPTION_KEY)
    if labels is None:
        known = ", ".join(sorted(episode.infos)) or "none"
        raise DynoplanError(
            f"episode {index} has no option labels (infos['{OPTION_KEY}']; its infos: "
            f"{known}): every step of a demonstration must name the option that acted")
    if labels.size and (labels.min() < 0 or labels.max() >= n_options):
        raise DynoplanError(
            f"episode {index}: option labels must lie in 0..{n_options - 1}, found "
            f"{int(labels.min())}..{int(labels.max())}")
    return labels


def fit_dynamics(transitions: dict[str, tuple[FloatArray, FloatArray]], seed: int,
                 fitter: DynamicsFitter, min_transitions: int = 10,
                 ) -> tuple[dict[str, DynamicsModel], dict[str, dict[str, Any]]]:
    """Fit one dynamics model per option and report its one-step error.

    Returns:
        The models by name, and per option ``{"transitions", "rmse", "no_change_rmse"}``
        (one-step error on its own training pairs, against predicting no change; for
        models without ``predict`` the errors are ``None``).

    Raises:
        DynoplanError: an option has fewer than ``min_transitions`` transitions.
    """
    models: dict[str, DynamicsModel] = {}
    report: dict[str, dict[str, Any]] = {}
    for k, (name, (s, nxt)) in enumerate(transitions.items()):
        if len(s) < min_transitions:
            raise DynoplanError(
                f"option '{name}': only {len(s)} transitions to learn its dynamics from "
                f"(need >= {min_transitions}); collect more episodes or lower the stride")
        model = fitter(name, s, nxt, seed + k)
        models[name] = model
        row: dict[str, Any] = {"transitions": len(s), "rmse": None, "no_change_rmse": None}
        if callable(getattr(model, "predict", None)):
            err = one_step_error(model, s, nxt)  # type: ignore[arg-type]
            row["rmse"], row["no_change_rmse"] = err.model_rmse_total, err.baseline_rmse_total
        report[name] = row
    return models, report


def fit_goal(demos: Sequence[Episode], settings: FitSettings, seed: int,
             state_fn: ObservationFn = flat_state,
             features: FeatureMap | None = None) -> tuple[GoalModel, dict[str, Any]]:
    """Fit the goal network on the demonstrations (progress ``t / T`` of each state), on
    ``features`` of the states when given (then wrapped to read full states).

    Returns the goal heuristic and ``{"states", "spearman", "mae", "coverage_90"}``
    measured on the training demonstrations.
    """
    states, progress, groups = goal_training_set(
        demos, lambda obs: _batch_states(obs, state_fn))
    x = states if features is None else features(states)
    network, _ = fit_goal_network(x, progress, groups, settings, seed)
    report = {"states": len(states), **evaluate_goal(network, x, progress)}
    return (network if features is None else GoalOnFeatures(network, features)), report


def fit_goal_network(states: FloatArray, progress: FloatArray, groups: IntArray,
                     settings: FitSettings, seed: int
                     ) -> tuple[GoalNetwork, GoalTrainingReport]:
    """The goal network as ``settings`` says, on states (or features) ``(N, d)``, their
    progress ``(N,)`` and demonstration ids ``(N,)`` (the ranking loss's pairs)."""
    return GoalNetwork.fit(states, progress, hidden=settings.goal_hidden,
                           members=settings.goal_members, epochs=settings.goal_epochs,
                           seed=seed, groups=groups, ranking=settings.goal_ranking)


def _batch_states(observations: np.ndarray, state_fn: ObservationFn) -> FloatArray:
    return np.stack([np.asarray(state_fn(o), dtype=np.float64).reshape(-1)
                     for o in observations])


def fit_regions(demos: Sequence[Episode], option_names: Sequence[str], settings: FitSettings,
                seed: int, state_fn: ObservationFn = flat_state) -> SafetyRegions:
    """Eq. 5 on the demonstrations, for the options that appear in them.

    The regions' ``option_names`` are the demonstrated options, in the given order; see
    :func:`fit_option_regions` for every option and the report.

    Raises:
        DynoplanError: a demonstration without option labels.
    """
    states, labels, groups = _labelled_states(demos, len(option_names), state_fn)
    shown = [k for k in range(len(option_names)) if np.any(labels == k)]
    regions, _ = fit_labelled_regions(states, labels, groups, [option_names[k] for k in shown],
                               shown, settings, seed)
    return regions


def fit_option_regions(demos: Sequence[Episode], transitions: Sequence[Episode],
                       option_names: Sequence[str], settings: FitSettings, seed: int,
                       state_fn: ObservationFn = flat_state,
                       features: FeatureMap | None = None,
                       ) -> tuple[RegionsModel, dict[str, Any]]:
    """The regions of every option (on ``features`` of the states when given, then
    wrapped to read full states), and what the fit measured.

    Demonstrated options: Eq. 5 on the demonstrations (``settings.region_fit``). Options
    no demonstration shows follow ``settings.region_undemonstrated``: ``"runs"`` fits
    their regions the same way on the states where they acted in ``transitions``
    (merged into one model: the same ``L(s | k)``); ``"none"``, or ``"runs"``
    with fewer than ``4 (d + 1)`` such states, makes them admissible nowhere;
    ``"everywhere"`` leaves them out of the regions (their own initiation set alone).
    Each case is said in one :class:`~dynoplan.errors.DynoplanWarning`.

    Returns:
        The regions and ``{"method", "components", "heldout_coverage", ...,
        "undemonstrated": {name: "runs" | "none" | "everywhere"}, "warnings": [...]}``.

    Raises:
        DynoplanError: a demonstration or transition episode without option labels.
    """
    names = list(option_names)
    states, labels, groups = _labelled_states(demos, len(names), state_fn)
    if features is not None:
        states = features(states)
    shown = [k for k in range(len(names)) if np.any(labels == k)]
    regions, report = fit_labelled_regions(states, labels, groups, [names[k] for k in shown], shown,
                                    settings, seed)
    unshown = [k for k in range(len(names)) if k not in shown]
    report["undemonstrated"] = {}
    report["warnings"] = []
    if not unshown:
        return _on_features(regions, features), report
    how = settings.region_undemonstrated
    nowhere: list[int] = []
    if how == "runs":
        run_states, run_labels, run_groups = _labelled_states(transitions, len(names),
                                                              state_fn)
        if features is not None and len(run_states):
            run_states = features(run_states)
        enough = 4 * (states.shape[1] + 1)
        fitted = [k for k in unshown if np.sum(run_labels == k) >= enough]
        nowhere = [k for k in unshown if k not in fitted]
        if fitted:
            keep = np.isin(run_labels, fitted)
            runs, runs_report = fit_labelled_regions(run_states[keep], run_labels[keep],
                                              run_groups[keep], [names[k] for k in fitted],
                                              fitted, settings, seed)
            regions = SafetyRegions.merge(regions, runs)
            report["from_runs"] = runs_report
            report["undemonstrated"].update({names[k]: "runs" for k in fitted})
            report["warnings"].append(
                f"option(s) {', '.join(names[k] for k in fitted)} never appear in the "
                "demonstrations: their regions come from their own exploration runs "
                "(region_undemonstrated='none' never starts them)")
    elif how == "none":
        nowhere = unshown
    else:
        report["undemonstrated"].update({names[k]: "everywhere" for k in unshown})
        report["warnings"].append(
            f"option(s) {', '.join(names[k] for k in unshown)} never appear in the "
            "demonstrations and have no region: they may start wherever their own "
            "initiation set allows")
    if nowhere:
        regions = SafetyRegions.merge(
            regions, SafetyRegions.nowhere([names[k] for k in nowhere], regions.state_dim))
        report["undemonstrated"].update({names[k]: "none" for k in nowhere})
        why = ("region_undemonstrated='none'" if how == "none" else
               f"fewer than {4 * (states.shape[1] + 1)} states of their own runs")
        report["warnings"].append(
            f"option(s) {', '.join(names[k] for k in nowhere)} never appear in the "
            f"demonstrations and get no region ({why}): they are never started")
    return _on_features(regions, features), report


def _on_features(regions: SafetyRegions, features: FeatureMap | None) -> RegionsModel:
    return regions if features is None else RegionsOnFeatures(regions, features)


def option_runs(episodes: Sequence[Episode], option_names: Sequence[str],
                state_fn: ObservationFn = flat_state,
                ) -> dict[str, tuple[FloatArray, FloatArray, np.ndarray]]:
    """Every run of every option: where it started, where it ended and how long it ran.

    A run is a maximal stretch of steps with the same option label.

    Returns:
        ``{name: (starts (R, d), ends (R, d), steps (R,))}``, ``R`` possibly 0.
    """
    found: dict[str, tuple[list[FloatArray], list[FloatArray], list[int]]] = {
        n: ([], [], []) for n in option_names}
    d = 0
    for index, episode in enumerate(episodes):
        labels = _labels(episode, index, len(option_names))
        rows = episode_states(episode, state_fn)
        d = rows.shape[1]
        cuts = np.flatnonzero(np.diff(labels)) + 1
        for start, end in zip(np.r_[0, cuts], np.r_[cuts, len(labels)], strict=True):
            name = option_names[int(labels[start])]
            found[name][0].append(rows[start])
            found[name][1].append(rows[end])
            found[name][2].append(int(end - start))
    return {n: (np.array(a).reshape(-1, d), np.array(b).reshape(-1, d),
                np.array(c, dtype=np.int64)) for n, (a, b, c) in found.items()}


def fit_outcome_initiation(transitions: Sequence[Episode], option_names: Sequence[str],
                           goal: GoalModel, settings: FitSettings, seed: int,
                           state_fn: ObservationFn = flat_state,
                           ) -> tuple[OutcomeInitiation, dict[str, Any]]:
    """Initiation sets from the options' own outcomes, for any task.

    Every run of an option in ``transitions`` (:func:`option_runs`) is labelled good when
    the goal heuristic's mean rose by more than ``settings.outcome_min_gain`` from its
    start state to its end state; one classifier per option learns ``P(good | start)``
    (:class:`~dynoplan.models.outcome_initiation.OutcomeInitiation`). An option that
    never ran has none (its initiation set is not changed).
    """
    runs = option_runs(transitions, option_names, state_fn)
    starts, outcomes = {}, {}
    for name, (begin, end, _) in runs.items():
        if len(begin):
            gain = goal.mean_std(end)[0] - goal.mean_std(begin)[0]
            starts[name], outcomes[name] = begin, gain > settings.outcome_min_gain
    if not starts:
        raise DynoplanError("no option runs to learn initiation from outcomes")
    learned, fit_report = OutcomeInitiation.fit(starts, outcomes, seed=seed)
    return learned, fit_report_dict(fit_report)


def outcome_starts(episodes: Sequence[Episode], option_names: Sequence[str],
                   states_of: Callable[[np.ndarray], FloatArray],
                   ) -> tuple[dict[str, FloatArray], dict[str, np.ndarray]]:
    """Per option, the states its outcome runs started from and their outcomes.

    ``episodes`` are outcome runs (:func:`~dynoplan.pipeline.collect.option_run` with
    ``outcomes``): one option each, ``infos["outcome"]`` ``(T,)`` the outcome of starting
    at each observation but the last. ``states_of`` maps observations ``(T, ...)`` to
    states ``(T, d)``.

    Returns:
        ``({name: states (N, d)}, {name: outcomes (N,)})``, ``N`` possibly 0.
    """
    names = list(option_names)
    states: dict[str, list[FloatArray]] = {n: [] for n in names}
    labels: dict[str, list[np.ndarray]] = {n: [] for n in names}
    d = 0
    for episode in episodes:
        if OUTCOME_KEY not in episode.infos or episode.options is None:
            raise DynoplanError(f"outcome runs need infos['{OUTCOME_KEY}'] and "
                                f"infos['{OPTION_KEY}']")
        k = int(episode.options[0])
        rows = states_of(episode.observations[:-1])
        d = rows.shape[1]
        states[names[k]].append(rows)
        labels[names[k]].append(np.asarray(episode.infos[OUTCOME_KEY], dtype=bool))
    return ({n: np.concatenate(v) if v else np.zeros((0, d)) for n, v in states.items()},
            {n: np.concatenate(v) if v else np.zeros(0, dtype=bool)
             for n, v in labels.items()})


def fit_initiation_from_outcomes(models: Path, episodes: Sequence[Episode],
                                 option_names: Sequence[str],
                                 states_of: Callable[[np.ndarray], FloatArray],
                                 features: FeatureMap | None, seed: int) -> dict[str, Any]:
    """The initiation learned from outcome runs (:func:`outcome_starts`), on the feature
    map ``features`` of the states (``None``: the states), written into the models
    folder ``models`` (``initiation.safetensors``, recorded in ``models.json``).

    Returns:
        The fit's report per option (``"options"``, with ``admissible_share``: the share
        of the runs' start states where the option is now admissible, by the learned
        initiation alone), the options ``"without_runs"``, ``"features"`` and ``"file"``.
    """
    from dynoplan.models.folder import set_initiation

    starts, ok = outcome_starts(episodes, option_names, states_of)
    x = {n: (s if features is None else features(s)) for n, s in starts.items() if len(s)}
    if not x:
        raise DynoplanError("no outcome runs to learn initiation from")
    fitted, report = OutcomeInitiation.fit(x, {n: ok[n] for n in x}, seed=seed)
    fitted.save(models / INITIATION_FILE)
    set_initiation(models, INITIATION_FILE, None if features is None else features.name)
    pooled = np.concatenate(list(x.values()))
    out = fit_report_dict(report)
    for name in out:
        out[name]["admissible_share"] = float(fitted.contains(pooled, name).mean())
    return {"options": out, "without_runs": [n for n in option_names if n not in x],
            "features": None if features is None else features.name,
            "file": str(models / INITIATION_FILE)}


def _labelled_states(episodes: Sequence[Episode], n_options: int, state_fn: ObservationFn,
                     ) -> tuple[FloatArray, np.ndarray, np.ndarray]:
    """Every state an option acted in: ``(N, d)`` states, ``(N,)`` labels and episode ids."""
    states, labels, groups = [], [], []
    for index, episode in enumerate(episodes):
        y = _labels(episode, index, n_options)
        labels.append(y)
        states.append(episode_states(episode, state_fn)[:-1])
        groups.append(np.full(len(y), index))
    if not states:
        return np.zeros((0, 0)), np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(states), np.concatenate(labels), np.concatenate(groups)


def fit_labelled_regions(states: FloatArray, labels: np.ndarray, groups: np.ndarray,
                         names: list[str], indices: list[int], settings: FitSettings,
                         seed: int) -> tuple[SafetyRegions, dict[str, Any]]:
    """Regions of the options ``indices`` (labels in ``labels`` ``(N,)``) named ``names``,
    on states ``(N, d)`` of the episodes ``groups`` ``(N,)``, fitted as
    ``settings.region_fit`` says; and what the fit measured."""
    remap = np.full(int(labels.max()) + 1 if labels.size else 1, -1)
    remap[indices] = np.arange(len(indices))
    y = remap[labels]
    if settings.region_fit == "cv":
        return fit_regions_cross_validated(
            states, y, groups, names, reg_covar=settings.region_reg_covar,
            max_components=settings.region_max_components, coverage=settings.region_coverage,
            cv_coverage=settings.region_cv_coverage, seed=seed)
    if settings.region_fit == "bic":
        regions = SafetyRegions.fit(states, y, names, n_components=settings.region_components,
                                    max_components=settings.region_max_components,
                                    coverage=settings.region_coverage,
                                    slack=settings.region_slack, seed=seed)
        return regions, {"method": "bic", "components": regions.n_components}
    return SafetyRegions.fit_heldout(states, y, names, groups,
                                     coverage=settings.region_coverage,
                                     folds=settings.region_folds,
                                     n_components=settings.region_components,
                                     max_components=settings.region_max_components,
                                     reg_covar=settings.region_reg_covar,
                                     slack=settings.region_slack, seed=seed)


def fit_regions_cross_validated(
    states: FloatArray, labels: IntArray, groups: IntArray, option_names: Sequence[str], *,
    reg_covar: float, max_components: int, coverage: float, cv_coverage: float, seed: int,
    max_folds: int = 10,
) -> tuple[SafetyRegions, dict[str, Any]]:
    """Safety regions (Eq. 5) whose thresholds are calibrated by leaving demonstrations out.

    The mixture is fitted on all states (``M`` by BIC). Then the demonstrations
    (``groups``) are dealt into at most ``max_folds`` folds (one demonstration each when
    there are few); for each fold a mixture of the same ``M`` is fitted without it, and
    for each of the fold's states of option ``k`` the shortfall
    ``threshold_k - log L(s | k)`` under that mixture is recorded. Option ``k``'s final
    threshold is lowered by the ``cv_coverage`` quantile of its shortfalls (if positive):
    the region is as wide as it needs to be for a demonstration it has not seen,
    measured on the demonstrations alone.

    Args:
        states: ``(N, d)``; labels: ``(N,)`` option indices; groups: ``(N,)`` demonstration
            ids.
    Returns:
        The regions and ``{"components", "slack_nats", "folds"}``.
    """
    regions = SafetyRegions.fit(states, labels, option_names, max_components=max_components,
                                coverage=coverage, reg_covar=reg_covar, seed=seed)
    m = regions.n_components
    ids = np.unique(groups)
    fold_of = dict(zip(ids.tolist(), np.random.default_rng(seed).permutation(len(ids)) % max_folds,
                       strict=True))
    fold_index = np.array([fold_of[g] for g in groups.tolist()])
    shortfalls: list[list[FloatArray]] = [[] for _ in option_names]
    folds = 0
    for f in np.unique(fold_index):
        keep = fold_index != f
        if len(np.unique(labels[keep])) < len(option_names):
            continue  # the fold holds every demonstration of some option
        fold = SafetyRegions.fit(states[keep], labels[keep], option_names, n_components=m,
                                 coverage=coverage, reg_covar=reg_covar, seed=seed)
        folds += 1
        for k in range(len(option_names)):
            rows = (~keep) & (labels == k)
            if rows.any():
                shortfalls[k].append(fold.log_thresholds[k] - fold.log_likelihood(states[rows], k))
    slack = np.array([max(0.0, float(np.quantile(np.concatenate(s), cv_coverage))) if s else 0.0
                      for s in shortfalls])
    regions.log_thresholds = regions.log_thresholds - slack
    return regions, {"components": m, "slack_nats": [round(float(s), 3) for s in slack],
                     "folds": folds}


class StridedTermination:
    """``1 - (1 - beta(s))^k``: the chance that an option stops within ``k`` steps."""

    def __init__(self, base: Termination, stride: int) -> None:
        self.base = base
        self.stride = int(stride)

    def probability(self, states: FloatArray) -> FloatArray:
        beta = np.asarray(self.base.probability(states), dtype=np.float64)
        return 1.0 - (1.0 - beta) ** self.stride


def strided(termination: Termination, stride: int) -> Termination:
    """The per-model-step termination for ``stride`` environment steps per model step."""
    if stride == 1:
        return termination
    if isinstance(termination, ConstantTermination):  # stays stackable
        return ConstantTermination(1.0 - (1.0 - termination.beta) ** stride)
    return StridedTermination(termination, stride)


@dataclass
class FittedModels:
    """Everything learned: per-option dynamics, the goal heuristic, the regions.

    The one in-memory form of a models folder (:mod:`dynoplan.models.folder`) for every
    task: :meth:`save` writes it, :meth:`load` reads it back.

    Attributes:
        option_names: all options, in order.
        dynamics: ``{name: D_w}``, each on planner states ``(batch, state_dim)``.
        goal: the goal heuristic ``G`` on planner states.
        regions: the fitted Eq. 5 regions on planner states (``None`` when not fitted);
            their ``option_names`` are the demonstrated options.
        stride: environment steps per model step.
        report: what fitting measured (transitions, errors, goal fit).
        use_regions: whether the regions are the options' initiation sets.
        task: the task's name (recorded in the manifest).
        extra: further manifest fields (seed, settings, ...), kept as they are.
        learned_initiation: per option ``P(ok | s)`` learned from its runs' outcomes
            (:mod:`dynoplan.models.outcome_initiation`), or ``None``.
    """

    option_names: list[str]
    dynamics: dict[str, DynamicsModel]
    goal: GoalModel
    regions: RegionsModel | None = None
    stride: int = 1
    report: dict[str, Any] = field(default_factory=dict)
    use_regions: bool = True
    task: str = ""
    extra: dict[str, Any] = field(default_factory=dict)
    learned_initiation: OutcomeModel | None = None

    @property
    def state_dim(self) -> int:
        """Size of the planner states every model is queried with."""
        return int(self.goal.state_dim)

    def region(self, name: str) -> Initiation | None:
        """Option ``name``'s learned region, or ``None`` (no region, or regions unused)."""
        if self.use_regions and self.regions is not None and name in self.regions.option_names:
            return InRegion(self.regions, name)
        return None

    def outcome(self, name: str) -> Initiation | None:
        """Option ``name``'s initiation set learned from its runs' outcomes, or ``None``."""
        learned = self.learned_initiation
        if learned is not None and name in learned.option_names:
            return InRegion(learned, name)
        return None

    def _own_and_region(self, spec: OptionSpec) -> Initiation:
        region = self.region(spec.name)
        if region is None:
            return spec.initiation
        return region if isinstance(spec.initiation, Everywhere) else AllOf(spec.initiation,
                                                                              region)

    def initiation(self, spec: OptionSpec) -> Initiation:
        """The option's own initiation set intersected with its region when it has one,
        and with its set learned from outcomes when it has one."""
        base = self._own_and_region(spec)
        outcome = self.outcome(spec.name)
        if outcome is None:
            return base
        return outcome if isinstance(base, Everywhere) else AllOf(base, outcome)

    def continuation(self, spec: OptionSpec) -> Initiation | None:
        """The option's own continuation set intersected with its region (``None``: the
        same as :meth:`initiation`). The set learned from outcomes says where to *start*:
        a running option goes on while it is in its own set and region."""
        region = self.region(spec.name)
        if spec.continuation is None:
            return self._own_and_region(spec) if self.outcome(spec.name) is not None else None
        if region is None:
            return spec.continuation
        return AllOf(spec.continuation, region)

    def build(self, specs: Sequence[OptionSpec]) -> tuple[list[Option], list[Option]]:
        """The options the controller runs and the same options as the planner sees them.

        Both lists carry the learned dynamics and the initiation sets; the planner's
        terminations are per model step (:func:`strided`).
        """
        run, plan = [], []
        for spec in specs:
            if spec.name not in self.dynamics:
                raise DynoplanError(f"no dynamics model for option '{spec.name}'")
            initiation, continuation = self.initiation(spec), self.continuation(spec)
            model = self.dynamics[spec.name]
            run.append(Option(spec.name, spec.policy, model, spec.termination, initiation,
                              continuation))
            plan.append(Option(spec.name, spec.policy, model,
                               strided(spec.termination, self.stride), initiation,
                               continuation))
        return run, plan

    def save(self, folder: str | os.PathLike[str]) -> Path:
        """Write every model file, then ``models.json`` (the manifest) into ``folder``.

        Dynamics models without a ``save`` method are listed with ``null``. The files are
        written into a folder beside ``folder`` that replaces it when complete
        (:func:`~dynoplan.io.staged_folder`): a failed save leaves the previous models.
        """
        with staged_folder(folder, keep=True) as staged:
            self._write(staged)
        return Path(folder)

    def _write(self, out: Path) -> None:
        files: dict[str, str | None] = {}
        for name, model in self.dynamics.items():
            save = getattr(model, "save", None)
            files[name] = dynamics_file(name) if callable(save) else None
            if callable(save):
                save(out / dynamics_file(name))
        network, goal_features = _unwrap_goal(self.goal)
        network.save(out / GOAL_FILE)
        regions = None
        if self.regions is not None:
            fitted, region_features = _unwrap_regions(self.regions)
            fitted.save(out / REGIONS_FILE)
            regions = (REGIONS_FILE, region_features)
        initiation = None
        if self.learned_initiation is not None:
            outcome, outcome_features = (
                (self.learned_initiation.initiation, self.learned_initiation.features.name)
                if isinstance(self.learned_initiation, OutcomeInitiationOnFeatures)
                else (self.learned_initiation, None))
            outcome.save(out / INITIATION_FILE)
            initiation = (INITIATION_FILE, outcome_features)
        write_manifest(out, task=self.task, state_dim=self.state_dim,
                       option_names=self.option_names, stride=self.stride,
                       use_regions=self.use_regions, goal=(GOAL_FILE, goal_features),
                       regions=regions, dynamics=files,
                       extra={"report": self.report, **self.extra}, initiation=initiation)

    @classmethod
    def load(cls, folder: str | os.PathLike[str],
             feature_maps: Mapping[str, FeatureMap] | None = None,
             retrain: str = "train the models again") -> "FittedModels":
        """Read a models folder (MLP-ensemble dynamics).

        Args:
            feature_maps: the task's named feature maps, for models fitted on one.
            retrain: how to make a new folder, said when the folder is missing or old.

        Raises:
            DynoplanError: one line: a missing, old or malformed manifest, a file outside
                the folder, missing or modified, or a model that does not fit the
                manifest (another option, state size or feature map).
        """
        manifest = read_manifest(folder, retrain)
        index = manifest.folder / MANIFEST_FILE
        maps = dict(feature_maps or {})

        def feature_map(name: str | None, what: str) -> FeatureMap | None:
            if name is None:
                return None
            if name not in maps:
                raise DynoplanError(f"{index}: {what} reads the feature map '{name}', which "
                                    f"this task does not define ({', '.join(maps) or 'none'})")
            if maps[name].state_dim != manifest.state_dim:
                raise DynoplanError(f"{index}: feature map '{name}' reads {maps[name].state_dim}"
                                    f" values, the manifest's state_dim is {manifest.state_dim}")
            return maps[name]

        def reads(file: Path, dim: int, fmap: FeatureMap | None) -> None:
            if fmap is not None and dim != fmap.dim:
                raise DynoplanError(f"{file}: reads {dim} features, the manifest's feature "
                                    f"map '{fmap.name}' has {fmap.dim}")
            if fmap is None and dim != manifest.state_dim:
                raise DynoplanError(f"{file}: reads {dim} values, the manifest's state_dim "
                                    f"is {manifest.state_dim}")

        goal_map = feature_map(manifest.goal.features, "the goal heuristic")
        network = GoalNetwork.load(manifest.goal.path)
        reads(manifest.goal.path, network.state_dim, goal_map)
        goal: GoalModel = network if goal_map is None else GoalOnFeatures(network, goal_map)
        regions: RegionsModel | None = None
        if manifest.regions is not None:
            region_map = feature_map(manifest.regions.features, "the safety regions")
            fitted = SafetyRegions.load(manifest.regions.path)
            reads(manifest.regions.path, fitted.state_dim, region_map)
            unknown = [n for n in fitted.option_names if n not in manifest.option_names]
            if unknown:
                raise DynoplanError(f"{manifest.regions.path}: regions of options {unknown} "
                                    f"not in the manifest's {manifest.option_names}")
            regions = fitted if region_map is None else RegionsOnFeatures(fitted, region_map)
        dynamics: dict[str, DynamicsModel] = {}
        for name, file in manifest.dynamics.items():
            if file is None:
                raise DynoplanError(f"{index}: option '{name}' has no dynamics model file")
            model = MLPEnsembleDynamics.load(file)
            if model.state_dim != manifest.state_dim or model.option != name:
                raise DynoplanError(f"{file}: a model of option '{model.option}' on "
                                    f"{model.state_dim} values, expected '{name}' on "
                                    f"{manifest.state_dim}")
            dynamics[name] = model
        learned: OutcomeModel | None = None
        if manifest.initiation is not None:
            outcome_map = feature_map(manifest.initiation.features, "the learned initiation")
            outcome = OutcomeInitiation.load(manifest.initiation.path)
            reads(manifest.initiation.path, outcome.state_dim, outcome_map)
            learned = (outcome if outcome_map is None
                       else OutcomeInitiationOnFeatures(outcome, outcome_map))
        extra = dict(manifest.extra)
        report = extra.pop("report", {})
        return cls(manifest.option_names, dynamics, goal, regions, manifest.stride,
                   report if isinstance(report, dict) else {}, manifest.use_regions,
                   manifest.task, extra, learned)

    def stacked_dynamics(self) -> StackedDynamics:
        """All options' ensembles as one ``(options, samples, state_dim)`` sampler."""
        models = [self.dynamics[n] for n in self.option_names]
        if not all(isinstance(m, MLPEnsembleDynamics) for m in models):
            raise DynoplanError("stacking needs every option's dynamics to be an MLP ensemble")
        return MLPEnsembleDynamics.stack(models)  # type: ignore[arg-type]


def _unwrap_goal(goal: GoalModel) -> tuple[GoalNetwork, str | None]:
    if isinstance(goal, GoalOnFeatures):
        return goal.network, goal.features.name
    return goal, None


def _unwrap_regions(regions: RegionsModel) -> tuple[SafetyRegions, str | None]:
    if isinstance(regions, RegionsOnFeatures):
        return regions.regions, regions.features.name
    return regions, None


def fit_models(specs: Sequence[OptionSpec], transitions: Sequence[Episode],
               demos: Sequence[Episode], settings: FitSettings, seed: int,
               state_fn: ObservationFn = flat_state,
               fitter: DynamicsFitter | None = None,
               progress: Callable[[str], None] | None = None,
               task: str = "",
               feature_maps: Mapping[str, FeatureMap] | None = None) -> FittedModels:
    """Fit dynamics (on transitions and demonstrations), goal and regions (on demonstrations).

    Args:
        progress: called with a short message before each stage (for a status line).
        task: the task's name, recorded in the models folder.
        feature_maps: the task's named feature maps (for ``settings.goal_features`` and
            ``settings.region_features``).
    """
    settings.validate()
    goal_map = named_feature_map(settings.goal_features, feature_maps)
    region_map = named_feature_map(settings.region_features, feature_maps)
    names = [s.name for s in specs]
    say = progress or (lambda _msg: None)
    say("dynamics")
    pairs = option_transitions([*transitions, *demos], names, state_fn, settings.stride)
    dynamics, dyn_report = fit_dynamics(pairs, seed, fitter or ensemble_fitter(settings))
    say("goal heuristic")
    goal, goal_report = fit_goal(demos, settings, seed, state_fn, goal_map)
    regions = None
    region_report: dict[str, Any] | None = None
    if settings.regions:
        say("safety regions")
        regions, region_report = fit_option_regions(demos, transitions, names, settings,
                                                    seed, state_fn, region_map)
        region_report["options"] = regions.option_names
        for message in region_report["warnings"]:
            warnings.warn(message, DynoplanWarning, stacklevel=2)
    learned: OutcomeInitiation | None = None
    outcome_report: dict[str, Any] | None = None
    if settings.outcome_initiation:
        say("outcome initiation")
        learned, outcome_report = fit_outcome_initiation(transitions, names, goal, settings,
                                                         seed, state_fn)
    report = {"settings": asdict(settings), "dynamics": dyn_report, "goal": goal_report,
              "regions": region_report, "outcome_initiation": outcome_report}
    return FittedModels(names, dynamics, goal, regions, settings.stride, report,
                        settings.regions, task, learned_initiation=learned)


def named_feature_map(name: str | None,
                      feature_maps: Mapping[str, FeatureMap] | None) -> FeatureMap | None:
    """The task's feature map ``name`` (``None``: none).

    Raises:
        DynoplanError: the task defines no feature map of that name.
    """
    if name is None:
        return None
    maps = dict(feature_maps or {})
    if name not in maps:
        raise DynoplanError(f"feature map '{name}': the task defines "
                            f"{', '.join(maps) or 'none'}")
    return maps[name]
