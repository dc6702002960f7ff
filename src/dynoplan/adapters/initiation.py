"""Initiation sets ``I_w`` from a safety region, a box or a callable."""

from typing import Any

import numpy as np

from dynoplan.errors import DynoplanError
from dynoplan.models.regions import SafetyRegions
from dynoplan.options.initiation import Everywhere, Initiation, InitiationFromCallable, InRegion
from dynoplan.types import BoolArray, FloatArray


class BoxRegion:
    """The axis-aligned box ``low <= s <= high`` (bounds ``(d,)``; use ``inf`` for none)."""

    def __init__(self, low: Any, high: Any) -> None:
        self.low = np.asarray(low, dtype=np.float64).reshape(-1)
        self.high = np.asarray(high, dtype=np.float64).reshape(-1)
        if self.low.shape != self.high.shape or np.any(self.low > self.high):
            raise DynoplanError(
                f"box bounds must have one shape and low <= high, got {self.low} and {self.high}")

    def contains(self, states: FloatArray) -> BoolArray:
        x = np.asarray(states, dtype=np.float64)
        if x.shape[-1] != self.low.shape[0]:
            raise DynoplanError(
                f"states of dimension {x.shape[-1]} do not fit a box of dimension "
                f"{self.low.shape[0]}")
        return np.all((x >= self.low) & (x <= self.high), axis=-1)


def initiation_from(initiation: Any, option: str | None = None) -> Initiation:
    """Turn what the user has into an :class:`~dynoplan.options.Initiation`.

    - ``None``: everywhere (``I_w`` is the whole state space);
    - a fitted :class:`~dynoplan.models.SafetyRegions` with the ``option`` name: that
      option's region (Eq. 5, :class:`~dynoplan.options.InRegion`);
    - an ``Initiation`` (has ``contains(states)``): used as it is;
    - a callable ``fn(states (B, d)) -> (B,)`` booleans:
      :class:`~dynoplan.options.InitiationFromCallable`.

    Raises:
        DynoplanError: anything else, or regions without an option name.
    """
    if initiation is None:
        return Everywhere()
    if isinstance(initiation, SafetyRegions):  # before Initiation: it also has contains()
        if option is None:
            raise DynoplanError("an initiation from SafetyRegions needs the option name")
        return InRegion(initiation, option)
    if isinstance(initiation, Initiation):
        return initiation
    if callable(initiation):
        return InitiationFromCallable(initiation)
    raise DynoplanError(
        f"cannot make an initiation set from {type(initiation).__name__}: expected None, "
        "SafetyRegions, an Initiation, or fn(states) -> booleans")
