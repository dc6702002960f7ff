"""The safety regions of Eq. 5 on the demonstrations' option labels: by default calibrated
on held-out demonstrations (:meth:`~dynoplan.models.regions.SafetyRegions.fit_heldout`);
an option the demonstrations never show gets a region from its own runs (or none), with a
warning (:func:`fit_option_regions`)."""

from collections.abc import Sequence
from typing import Any

import numpy as np

from dynoplan.control.controller import flat_state
from dynoplan.data.episodes import Episode
from dynoplan.models.features import FeatureMap, RegionsOnFeatures
from dynoplan.models.regions import SafetyRegions
from dynoplan.pipeline.collect import ObservationFn
from dynoplan.pipeline.fit_data import labelled_states
from dynoplan.pipeline.fit_settings import FitSettings
from dynoplan.types import FloatArray, IntArray

RegionsModel = SafetyRegions | RegionsOnFeatures
"""Safety regions as fitted: on the planner state, or on a named feature map of it."""


def fit_regions(demos: Sequence[Episode], option_names: Sequence[str], settings: FitSettings,
                seed: int, state_fn: ObservationFn = flat_state) -> SafetyRegions:
    """Eq. 5 on the demonstrations, for the options that appear in them.

    The regions' ``option_names`` are the demonstrated options, in the given order; see
    :func:`fit_option_regions` for every option and the report.

    Raises:
        DynoplanError: a demonstration without option labels.
    """
    states, labels, groups = labelled_states(demos, len(option_names), state_fn)
    regions, _, _ = _demonstrated_regions(states, labels, groups, list(option_names),
                                          settings, seed)
    return regions


def fit_option_regions(demos: Sequence[Episode], transitions: Sequence[Episode],
                       option_names: Sequence[str], settings: FitSettings, seed: int,
                       state_fn: ObservationFn = flat_state,
                       features: FeatureMap | None = None,
                       starts: Sequence[Episode] = (),
                       ) -> tuple[RegionsModel, dict[str, Any]]:
    """The regions of every option (on ``features`` of the states when given, then
    wrapped to read full states), and what the fit measured.

    Demonstrated options: Eq. 5 on the demonstrations (``settings.region_fit``); with
    ``starts`` (start states labelled by the demonstrator's first choice,
    :func:`~dynoplan.pipeline.collect.start_choices`), a demonstrated option's region is
    the union of that and a region of its own fitted on the start states labelled with it
    (:func:`start_regions`), so the starts widen where the option starts the task and
    nowhere else. Options
    no demonstration shows follow ``settings.region_undemonstrated``: ``"runs"`` fits
    their regions the same way on the states where they acted in ``transitions``
    (merged into one model: the same ``L(s | k)``); ``"none"``, or ``"runs"``
    with fewer than ``4 (d + 1)`` such states, makes them admissible nowhere;
    ``"everywhere"`` leaves them out of the regions (their own initiation set alone), and
    so does ``"outcomes"`` for those with a run in ``transitions`` (their initiation is
    then learned from what the runs achieved, in
    :func:`~dynoplan.pipeline.fit.fit_models`; those without any get none).
    Each case is said in one :class:`~dynoplan.errors.DynoplanWarning`.

    Returns:
        The regions and ``{"method", "components", "heldout_coverage", ...,
        "undemonstrated": {name: "runs" | "none" | "everywhere" | "outcomes"},
        "warnings": [...]}``.

    Raises:
        DynoplanError: a demonstration or transition episode without option labels.
    """
    names = list(option_names)
    states, labels, groups = labelled_states(demos, len(names), state_fn)
    if features is not None:
        states = features(states)
    if starts:
        start_states, start_labels, _ = labelled_states(starts, len(names), state_fn)
        if features is not None:
            start_states = features(start_states)
        regions, report, shown = start_regions(states, labels, groups, start_states,
                                               start_labels, names, settings, seed)
    else:
        regions, report, shown = _demonstrated_regions(states, labels, groups, names,
                                                       settings, seed)
    unshown = [k for k in range(len(names)) if k not in shown]
    report["undemonstrated"] = {}
    report["warnings"] = []
    scarce = [names[k] for k in unshown if np.any(labels == k)]
    if scarce:
        report["warnings"].append(
            f"option(s) {', '.join(scarce)} appear at fewer than {MIN_REGION_STATES} "
            "demonstration states, too few for a region: they are treated as never "
            "demonstrated")
    if not unshown:
        return _on_features(regions, features), report
    how = settings.region_undemonstrated
    nowhere: list[int] = []
    if how == "runs":
        run_states, run_labels, run_groups = labelled_states(transitions, len(names),
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
    elif how == "outcomes":
        _, run_labels, _ = labelled_states(transitions, len(names), state_fn)
        ran = [k for k in unshown if np.any(run_labels == k)]
        nowhere = [k for k in unshown if k not in ran]
        if ran:
            report["undemonstrated"].update({names[k]: "outcomes" for k in ran})
            report["warnings"].append(
                f"option(s) {', '.join(names[k] for k in ran)} never appear in the "
                "demonstrations: they may start where their own exploration runs made the "
                "goal heuristic rise")
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
               "no exploration run of their own" if how == "outcomes" else
               f"fewer than {4 * (states.shape[1] + 1)} states of their own runs")
        report["warnings"].append(
            f"option(s) {', '.join(names[k] for k in nowhere)} never appear in the "
            f"demonstrations and get no region ({why}): they start only where no "
            "option's learned set holds (control.fallback_own_sets)")
    return _on_features(regions, features), report


MIN_REGION_STATES = 2
"""The fewest demonstration states of an option that give it a region of its own (a
mixture needs two); an option shown at fewer is treated as never demonstrated."""


def _demonstrated_regions(states: FloatArray, labels: IntArray, groups: IntArray,
                          names: list[str], settings: FitSettings, seed: int
                          ) -> tuple[SafetyRegions, dict[str, Any], list[int]]:
    """Eq. 5 for the options (of ``names``) with at least :data:`MIN_REGION_STATES` of the
    demonstration states ``(N, d)`` labelled ``(N,)`` in episodes ``groups`` ``(N,)``: the
    regions, what the fit measured, and those options' indices."""
    counts = np.bincount(labels, minlength=len(names))
    shown = [k for k in range(len(names)) if counts[k] >= MIN_REGION_STATES]
    keep = np.isin(labels, shown)
    regions, report = fit_labelled_regions(states[keep], labels[keep], groups[keep],
                                           [names[k] for k in shown], shown, settings, seed)
    return regions, report, shown


START_REGION = "{} (start states)"
"""The name, in a fit's report, of an option's region fitted on the start states."""


def start_regions(states: FloatArray, labels: IntArray, groups: IntArray,
                  start_states: FloatArray, start_labels: IntArray, names: list[str],
                  settings: FitSettings, seed: int
                  ) -> tuple[SafetyRegions, dict[str, Any], list[int]]:
    """:func:`_demonstrated_regions` widened by the start states ``(S, d)`` labelled
    ``(S,)``: each demonstrated option with at least :data:`MIN_REGION_STATES` start
    states also gets a region fitted on them alone (:data:`START_REGION`, one group: its
    folds are blocks of them), in the same fit as the demonstrations' regions (one
    standardisation), and its region is the union of both
    (:meth:`~dynoplan.models.regions.SafetyRegions.joined`). Start states of an option
    the demonstrations do not show are left out (they would be its only region)."""
    counts = np.bincount(labels, minlength=len(names))
    shown = [k for k in range(len(names)) if counts[k] >= MIN_REGION_STATES]
    start_counts = np.bincount(start_labels, minlength=len(names))
    widened = [k for k in shown if start_counts[k] >= MIN_REGION_STATES]
    keep = np.isin(labels, shown)
    keep_starts = np.isin(start_labels, widened)
    pseudo = len(names) + np.asarray(start_labels[keep_starts])  # the start regions' labels
    x = np.concatenate([states[keep], start_states[keep_starts]])
    y = np.concatenate([labels[keep], pseudo])
    g = np.concatenate([groups[keep], np.full(len(pseudo), int(groups.max(initial=-1)) + 1)])
    start_names = [START_REGION.format(names[k]) for k in widened]
    regions, report = fit_labelled_regions(
        x, y, g, [names[k] for k in shown] + start_names,
        shown + [len(names) + k for k in widened], settings, seed)
    report["start_states"] = {names[k]: int(start_counts[k]) for k in widened}
    return (regions.joined({START_REGION.format(names[k]): names[k] for k in widened}),
            report, shown)


def _on_features(regions: SafetyRegions, features: FeatureMap | None) -> RegionsModel:
    return regions if features is None else RegionsOnFeatures(regions, features)

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
                                     slack=settings.region_slack, seed=seed,
                                     test_constant=not settings.constant_dimensions_still)


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


__all__ = ["MIN_REGION_STATES", "START_REGION", "RegionsModel", "fit_labelled_regions",
           "fit_option_regions", "fit_regions", "fit_regions_cross_validated",
           "start_regions"]
