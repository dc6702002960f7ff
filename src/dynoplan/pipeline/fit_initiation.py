"""Initiation sets learned from the options' own outcomes (Bagaria et al. 2023): from the
goal heuristic's gain over each exploration run (:func:`fit_outcome_initiation`), or from
outcome runs (:func:`fit_initiation_from_outcomes`)."""

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from dynoplan.control.controller import flat_state
from dynoplan.data.episodes import OPTION_KEY, Episode
from dynoplan.errors import DynoplanError
from dynoplan.models.features import FeatureMap
from dynoplan.models.folder import INITIATION_FILE
from dynoplan.models.outcome_initiation import (
    OutcomeInitiation,
    OutcomeInitiationOnFeatures,
    fit_report_dict,
)
from dynoplan.pipeline.collect import OUTCOME_KEY, ObservationFn
from dynoplan.pipeline.fit_data import option_end_pairs, option_runs
from dynoplan.pipeline.fit_goal import GoalModel
from dynoplan.pipeline.fit_settings import FitSettings
from dynoplan.types import FloatArray

OutcomeModel = OutcomeInitiation | OutcomeInitiationOnFeatures
"""Initiation learned from outcomes as fitted: on the planner state or a feature map."""


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


def fit_undemonstrated_initiation(transitions: Sequence[Episode],
                                  option_names: Sequence[str], undemonstrated: Sequence[str],
                                  goal: GoalModel, settings: FitSettings, seed: int,
                                  state_fn: ObservationFn = flat_state,
                                  ) -> tuple[OutcomeInitiation | None, dict[str, Any]]:
    """Where the options no demonstration shows may start, from what their own
    exploration runs achieved (``FitSettings.region_undemonstrated="outcomes"``).

    Every state of every run of such an option that no one cut short
    (:func:`~dynoplan.pipeline.fit_data.option_end_pairs`) is a start whose outcome is
    known: the option, started there, ran to where that run ended. It is good when the
    goal heuristic's mean rose by more than ``settings.outcome_min_gain`` from the state
    to the run's end. One classifier per option learns ``P(good | s)``
    (:class:`~dynoplan.models.outcome_initiation.OutcomeInitiation`); an option whose
    runs all did (did not) is admissible everywhere (nowhere) by it, and so is one with
    no whole run (nowhere: nothing it achieved is known). The demonstrated options get
    none: their regions say where they start.

    Returns:
        The classifiers (``None`` when ``undemonstrated`` is empty) and the fit's report
        per option (``runs`` counts start states here).
    """
    if not undemonstrated:
        return None, {}
    pairs = option_end_pairs(transitions, option_names, state_fn)
    starts: dict[str, FloatArray] = {}
    outcomes: dict[str, np.ndarray] = {}
    for name in undemonstrated:
        states, ends = pairs[name]
        if len(states):
            gain = goal.mean_std(ends)[0] - goal.mean_std(states)[0]
            starts[name], outcomes[name] = states, gain > settings.outcome_min_gain
        else:  # no whole run: one "never" start makes the option admissible nowhere
            starts[name] = np.zeros((1, states.shape[1]))
            outcomes[name] = np.zeros(1, dtype=bool)
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


__all__ = ["OutcomeModel", "fit_initiation_from_outcomes", "fit_outcome_initiation",
           "fit_undemonstrated_initiation", "outcome_starts"]
