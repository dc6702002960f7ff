"""Feature maps: what a learned model reads of the planner state.

A goal heuristic or a set of safety regions often reads a few features of the planner
state rather than all of it (the task's progress does not depend on where a bystander
is; a region of relative poses generalises over start positions). A
:class:`FeatureMap` is such a map with a name (recorded in a models folder, so a model
file is read back with the map it was fitted on) and one name per feature.
:class:`GoalOnFeatures` and :class:`RegionsOnFeatures` wrap a fitted model so that it
takes full planner states ``(batch, state_dim)`` like every other part of the planner.
"""

from collections.abc import Callable
from dataclasses import dataclass

from dynoplan.models.goal_network import GoalNetwork
from dynoplan.models.regions import SafetyRegions
from dynoplan.models.storage import as_states
from dynoplan.types import BoolArray, FloatArray, Generator


@dataclass(frozen=True)
class FeatureMap:
    """``states (N, state_dim) -> features (N, dim)``, with a name and one name per feature."""

    name: str
    names: tuple[str, ...]
    fn: Callable[[FloatArray], FloatArray]
    state_dim: int

    @property
    def dim(self) -> int:
        return len(self.names)

    def __call__(self, states: FloatArray) -> FloatArray:
        """``(N, state_dim)`` -> ``(N, dim)`` float64 (another shape: one clear error)."""
        out: FloatArray = self.fn(as_states(states, self.state_dim))
        return out


class _OnFeatures:
    """A model of full planner states ``(batch, state_dim)`` that reads ``features(states)``."""

    def __init__(self, features: FeatureMap) -> None:
        self.features = features

    @property
    def state_dim(self) -> int:
        return self.features.state_dim

    def _columns(self, states: FloatArray) -> FloatArray:
        return self.features(states)


class GoalOnFeatures(_OnFeatures):
    """The goal heuristic ``G(s)`` of full planner states, read through a feature map.

    Satisfies :class:`~dynoplan.models.goal.GoalHeuristic` for ``(batch, state_dim)``
    states; ``network`` sees ``features(states)``.
    """

    def __init__(self, network: GoalNetwork, features: FeatureMap) -> None:
        super().__init__(features)
        self.network = network

    def sample(self, states: FloatArray, rng: Generator) -> FloatArray:
        """One draw of ``g ~ G(s)`` per state: ``(batch, state_dim)`` -> ``(batch,)``."""
        return self.network.sample(self._columns(states), rng)

    def mean_std(self, states: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Mean and standard deviation of ``G(s)``, each ``(batch,)``."""
        return self.network.mean_std(self._columns(states))

    def interval(self, states: FloatArray, level: float = 0.9) -> tuple[FloatArray, FloatArray]:
        """Central ``level`` interval of ``G(s)``: lower and upper bounds, each ``(batch,)``."""
        return self.network.interval(self._columns(states), level)


class RegionsOnFeatures(_OnFeatures):
    """Safety regions (Eq. 5) of full planner states, read through a feature map.

    Offers what :class:`~dynoplan.options.initiation.InRegion` and the planner use
    (``option_names``, ``option_index``, ``contains``, ``contains_all``, ``log_likelihood``)
    on ``(batch, state_dim)`` states; ``regions`` sees ``features(states)``.
    """

    def __init__(self, regions: SafetyRegions, features: FeatureMap) -> None:
        super().__init__(features)
        self.regions = regions

    @property
    def option_names(self) -> list[str]:
        return self.regions.option_names

    def option_index(self, option: str | int) -> int:
        return self.regions.option_index(option)

    def log_likelihood(self, states: FloatArray, option: str | int) -> FloatArray:
        """``log L(s | k)`` of Eq. 5, ``(batch,)``."""
        return self.regions.log_likelihood(self._columns(states), option)

    def contains(self, states: FloatArray, option: str | int) -> BoolArray:
        """Whether each state lies in option ``k``'s region, ``(batch,)``."""
        return self.regions.contains(self._columns(states), option)

    def contains_all(self, states: FloatArray) -> BoolArray:
        """Membership for every option at once, ``(batch, options)``."""
        return self.regions.contains_all(self._columns(states))


__all__ = ["FeatureMap", "GoalOnFeatures", "RegionsOnFeatures"]
