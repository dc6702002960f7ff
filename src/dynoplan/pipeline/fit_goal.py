"""The goal heuristic ``G``: a network fitted on the demonstrations' progress."""

from collections.abc import Sequence
from typing import Any

import numpy as np

from dynoplan.control.controller import flat_state
from dynoplan.data.episodes import FAILURE_KEY, Episode
from dynoplan.models.features import FeatureMap, GoalOnFeatures
from dynoplan.models.goal_network import (
    GoalNetwork,
    GoalTrainingReport,
    evaluate_goal,
    goal_training_set,
)
from dynoplan.models.regions import constant_mask
from dynoplan.pipeline.collect import ObservationFn
from dynoplan.pipeline.fit_settings import FitSettings
from dynoplan.types import BoolArray, FloatArray, IntArray

GoalModel = GoalNetwork | GoalOnFeatures
"""A goal heuristic as fitted: on the planner state, or on a named feature map of it."""


def off_demonstration_progress(states: FloatArray, progress: FloatArray, groups: IntArray,
                               off: FloatArray, radius: float,
                               decay: str = "gaussian", context: bool = False,
                               unit: str = "path") -> FloatArray:
    """Progress labels ``(M,)`` for states ``off`` ``(M, d)`` that no demonstration visited:
    the progress of the nearest demonstration state, times ``exp(-(r / R)^2)`` (``decay``
    ``"gaussian"``) or ``1 / (1 + (r / R)^2)`` (``"cauchy"``), where ``r``
    is the distance to it and ``R`` is ``radius`` demonstration steps: ``radius`` times
    the median distance between consecutive demonstration states (``unit`` ``"path"``),
    or the median distance between demonstration states ``radius`` steps apart
    (``"displacement"``; rounded to whole steps, at least one, and scaled back to
    ``radius``).

    Distances are measured with every dimension scaled by its spread over the
    demonstration states (a dimension that never changes there is left out; with
    ``context``, so is one that never changes along any demonstration,
    :func:`context_mask`). A state on a
    demonstration keeps its progress; a state the demonstrations never came near is ranked
    below the demonstrated states it is near, so that the goal heuristic does not promise
    progress where the demonstrations never went (past a goal, off a path).

    Args:
        states: ``(N, d)`` demonstration states; progress: ``(N,)``; groups: ``(N,)`` the
            demonstration of each state (consecutive rows of a group are consecutive
            steps).
    """
    from scipy.spatial import cKDTree

    keep, spread, reach = label_space(states, groups, radius, context, unit)
    if not keep.any() or len(off) == 0:
        return np.zeros(len(off))
    z = states[:, keep] / spread[keep]
    distance, nearest = cKDTree(z).query(off[:, keep] / spread[keep])
    ratio = (distance / reach) ** 2
    return progress[nearest] * (np.exp(-ratio) if decay == "gaussian" else 1.0 / (1.0 + ratio))


def label_space(states: FloatArray, groups: IntArray, radius: float, context: bool = False,
                unit: str = "path") -> tuple[BoolArray, FloatArray, float]:
    """Where :func:`off_demonstration_progress` measures distances, for the demonstration
    states ``(N, d)`` (``groups`` ``(N,)``): the dimensions it keeps ``(d,)``, every
    dimension's spread ``(d,)`` (distances are in spreads) and ``R``, the distance at
    which a label falls to ``exp(-1)`` (``radius`` demonstration steps, as ``unit``
    measures them)."""
    spread = states.std(axis=0)
    keep = ~constant_mask(states)
    if context:
        keep &= ~context_mask(states, groups)
    if not keep.any():
        return keep, spread, 1.0
    z = states[:, keep] / spread[keep]
    apart = 1 if unit == "path" else max(1, round(radius))
    same = groups[apart:] == groups[:-apart]
    steps = np.linalg.norm(z[apart:] - z[:-apart], axis=1)[same]
    step = float(np.median(steps[steps > 0])) if np.any(steps > 0) else 1.0
    return keep, spread, radius / apart * step


def states_around(states: FloatArray, groups: IntArray, copies: int, radius: float,
                  rng: np.random.Generator, context: bool = False,
                  unit: str = "path") -> FloatArray:
    """``(copies * N, d)`` states around the demonstration states ``(N, d)``: each copied
    ``copies`` times and moved by Gaussian noise of one label radius ``R``
    (:func:`label_space`) in the dimensions the labels measure (the others stay as
    shown). Labelled by :func:`off_demonstration_progress`, they tell the goal heuristic
    that progress falls away from the demonstrations in every direction, also where no
    exploration run went (past the goal, off the path)."""
    keep, spread, reach = label_space(states, groups, radius, context, unit)
    out = np.repeat(states, copies, axis=0)
    if keep.any() and len(out):
        noise = rng.standard_normal((len(out), int(keep.sum())))
        out[:, keep] += noise * (reach / np.sqrt(keep.sum())) * spread[keep]
    return out


def context_mask(states: FloatArray, groups: IntArray) -> BoolArray:
    """``(d,)`` the dimensions of the demonstration states ``(N, d)`` that stay the same
    along every demonstration (``groups`` ``(N,)``; one of a single state says nothing),
    where a goal or an object was put at the reset; all ``False`` with fewer than two
    demonstrations."""
    ids = np.unique(groups)
    rows = [states[groups == g] for g in ids]
    rows = [r for r in rows if len(r) > 1]
    if len(rows) < 2:
        return np.zeros(states.shape[1], dtype=bool)
    return np.all([constant_mask(r) for r in rows], axis=0)


def fit_goal(demos: Sequence[Episode], settings: FitSettings, seed: int,
             state_fn: ObservationFn = flat_state,
             features: FeatureMap | None = None,
             off: Sequence[Episode] = (),
             training: list[GoalTrainingReport] | None = None,
             ) -> tuple[GoalModel, dict[str, Any]]:
    """Fit the goal network on the demonstrations (progress ``t / T`` of each state), on
    ``features`` of the states when given (then wrapped to read full states).

    With ``settings.goal_off_demos``, the states of the episodes ``off`` (the exploration
    episodes) are fitted too, each labelled by :func:`off_demonstration_progress`, the
    last state of an episode that failed (``infos["failure"]``) with 0.

    Returns the goal heuristic and ``{"states", "off_demo_states", "spearman", "mae",
    "coverage_90"}``, the last three measured on the training demonstrations;
    ``training``, when given, receives the network's training report (its losses).
    """
    states, progress, groups = goal_training_set(
        demos, lambda obs: _batch_states(obs, state_fn))
    x = states if features is None else features(states)
    x_fit, p_fit, g_fit = x, progress, groups
    off_states = (np.concatenate([_batch_states(e.observations, state_fn) for e in off])
                  if settings.goal_off_demos and off else np.zeros((0, states.shape[1])))
    if len(off_states) or settings.goal_off_around:
        x_off = off_states if features is None else features(off_states)
        if settings.goal_off_around:  # after the exploration states: their rows stay
            x_off = np.concatenate([x_off, states_around(
                x, groups, settings.goal_off_around, settings.goal_off_radius,
                np.random.default_rng([seed, 11]), settings.goal_off_context,
                settings.goal_off_unit)])
        labels = off_demonstration_progress(x, progress, groups, x_off,
                                            settings.goal_off_radius,
                                            settings.goal_off_decay,
                                            settings.goal_off_context,
                                            settings.goal_off_unit)
        if len(off_states):  # where an episode failed, no progress is left
            labels[_failed_ends(off)] = 0.0
        x_fit = np.concatenate([x, x_off])
        p_fit = np.concatenate([progress, labels])
        # one group per off state: the ranking loss pairs states of one demonstration only
        g_fit = np.concatenate([groups, groups.max() + 1 + np.arange(len(x_off))])
    network, trained = fit_goal_network(x_fit, p_fit, g_fit, settings, seed)
    if training is not None:
        training.append(trained)
    report = {"states": len(states), "off_demo_states": len(x_fit) - len(x),
              **evaluate_goal(network, x, progress)}
    return (network if features is None else GoalOnFeatures(network, features)), report


def fit_goal_network(states: FloatArray, progress: FloatArray, groups: IntArray,
                     settings: FitSettings, seed: int
                     ) -> tuple[GoalNetwork, GoalTrainingReport]:
    """The goal network as ``settings`` says, on states (or features) ``(N, d)``, their
    progress ``(N,)`` and demonstration ids ``(N,)`` (the ranking loss's pairs)."""
    return GoalNetwork.fit(states, progress, hidden=settings.goal_hidden,
                           members=settings.goal_members, epochs=settings.goal_epochs,
                           seed=seed, groups=groups, ranking=settings.goal_ranking)


def _failed_ends(episodes: Sequence[Episode]) -> IntArray:
    """Rows (into all observations of ``episodes``, concatenated) of the last state of
    every episode that terminated without success (``infos["failure"]``)."""
    rows, at = [], 0
    for e in episodes:
        failure = e.infos.get(FAILURE_KEY)
        if failure is not None and len(failure) and bool(failure[-1]):
            rows.append(at + len(e))
        at += len(e) + 1
    return np.asarray(rows, dtype=np.int64)


def _batch_states(observations: np.ndarray, state_fn: ObservationFn) -> FloatArray:
    return np.stack([np.asarray(state_fn(o), dtype=np.float64).reshape(-1)
                     for o in observations])


__all__ = ["GoalModel", "context_mask", "fit_goal", "fit_goal_network",
           "off_demonstration_progress"]
