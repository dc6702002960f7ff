"""Turn a list of per-option objects into one batched object over an ``options`` axis.

The planner evaluates every admissible option in one array computation. A class that
can do that for a list of its instances provides a ``stack(items)`` classmethod that
returns an object whose methods take arrays with a leading ``options`` axis. When the
items are of mixed types (or the class has no ``stack``), a loop over options is used;
it is still batched over samples.
"""

from collections.abc import Callable, Sequence
from typing import Any, TypeVar

T = TypeVar("T")
S = TypeVar("S")


def stack(items: Sequence[T], fallback: Callable[[Sequence[T]], S]) -> S:
    """Stack ``items`` with their class's ``stack`` classmethod, else with ``fallback``."""
    if not items:
        raise ValueError("cannot stack an empty list")
    cls: Any = type(items[0])
    if all(type(item) is cls for item in items) and callable(getattr(cls, "stack", None)):
        stacked: S = cls.stack(list(items))
        return stacked
    return fallback(items)
