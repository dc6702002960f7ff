"""The goal heuristic ``G``: a network fitted on the demonstrations' progress."""

from collections.abc import Sequence
from typing import Any

import numpy as np

from dynoplan.data.episodes import Episode
from dynoplan.models.features import FeatureMap, GoalOnFeatures
from dynoplan.models.goal_network import (
    GoalNetwork,
    GoalTrainingReport,
    evaluate_goal,
    goal_training_set,
)
from dynoplan.pipeline.collect import ObservationFn, flat_state
from dynoplan.pipeline.fit_settings import FitSettings
from dynoplan.types import FloatArray, IntArray

GoalModel = GoalNetwork | GoalOnFeatures
"""A goal heuristic as fitted: on the planner state, or on a named feature map of it."""


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


__all__ = ["GoalModel", "fit_goal", "fit_goal_network"]
