"""Initiation sets ``I_w``: where an option may start (and keep running)."""

from collections.abc import Callable
from typing import Any, ClassVar, Protocol, runtime_checkable

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


class Nowhere:
    """The empty set: the option may start nowhere (an option with no learned initiation
    set when only learned sets count)."""

    def contains(self, states: FloatArray) -> BoolArray:
        return np.zeros(states.shape[:-1], dtype=bool)


class InitiationFromCallable:
    """Wrap ``fn(states (batch, d)) -> (batch,)`` booleans."""

    def __init__(self, fn: Callable[[FloatArray], BoolArray]) -> None:
        self.fn = fn

    def contains(self, states: FloatArray) -> BoolArray:
        return np.asarray(self.fn(states), dtype=bool)


class _Combined:
    """Initiation sets combined elementwise by ``_reduce`` (``np.all`` or ``np.any`` over
    the parts' answers)."""

    _reduce: ClassVar[Callable[..., Any]] = staticmethod(np.all)

    def __init__(self, *parts: Initiation) -> None:
        if not parts:
            raise ValueError(f"{type(self).__name__} needs at least one initiation set")
        self.parts = parts

    def contains(self, states: FloatArray) -> BoolArray:
        answers = [np.asarray(part.contains(states), dtype=bool) for part in self.parts]
        out: BoolArray = type(self)._reduce(answers, axis=0)
        return out


class AllOf(_Combined):
    """The intersection of initiation sets: a state is in it when every part contains it."""

    _reduce = staticmethod(np.all)


class AnyOf(_Combined):
    """The union of initiation sets: a state is in it when some part contains it."""

    _reduce = staticmethod(np.any)


class RegionModel(Protocol):
    """What :class:`InRegion` needs of a region model (for example
    :class:`~dynoplan.models.regions.SafetyRegions`)."""

    @property
    def option_names(self) -> list[str]:
        """The options that have a region, in order."""
        ...

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
