"""Initiation sets ``I_w``: where an option may start (and keep running)."""

from collections.abc import Callable
from typing import Protocol, runtime_checkable

import numpy as np

from dynoplan.types import BoolArray, FloatArray


@runtime_checkable
class Initiation(Protocol):
    """``contains(states)``: ``(batch, state_dim)`` -> ``(batch,)`` booleans."""

    def contains(self, states: FloatArray) -> BoolArray: ...


class Everywhere:
    """The whole state space (the paper's gear options: ``I = R^12``)."""

    def contains(self, states: FloatArray) -> BoolArray:
        return np.ones(states.shape[:-1], dtype=bool)


class InitiationFromCallable:
    """Wrap ``fn(states (batch, d)) -> (batch,)`` booleans."""

    def __init__(self, fn: Callable[[FloatArray], BoolArray]) -> None:
        self.fn = fn

    def contains(self, states: FloatArray) -> BoolArray:
        return np.asarray(self.fn(states), dtype=bool)


class RegionModel(Protocol):
    """What :class:`InRegion` needs of a region model (for example
    :class:`~dynoplan.models.regions.SafetyRegions`)."""

    def option_index(self, option: str | int) -> int: ...

    def contains(self, states: FloatArray, option: str | int) -> BoolArray: ...


class InRegion:
    """Option ``k``'s safety region from a fitted Gaussian mixture (Eq. 5)."""

    def __init__(self, regions: RegionModel, option: str) -> None:
        regions.option_index(option)  # fail early on an unknown name
        self.regions = regions
        self.option = option

    def contains(self, states: FloatArray) -> BoolArray:
        return self.regions.contains(states, self.option)
