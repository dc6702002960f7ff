"""Wall seconds per named stage of a run, the one timer of ``gear run`` and the pipeline."""

from collections.abc import Callable
from time import perf_counter
from typing import Any, TypeVar

from dynoplan.parallel import SERIAL, Workers, run_in_background

T = TypeVar("T")


class StageClock:
    """Times stages by name into :attr:`seconds` (a stage named twice adds up).

    Args:
        say: called with ``label.format(name)`` as each stage starts (default: nothing).
        label: how a stage's name is announced.
    """

    def __init__(self, say: Callable[[str], None] | None = None, label: str = "{}") -> None:
        self.seconds: dict[str, float] = {}
        self._say, self._label = say, label
        self._current, self._since = "", perf_counter()

    def switch(self, name: str) -> None:
        """End the current stage and start ``name`` (``""``: none)."""
        now = perf_counter()
        if self._current:
            self._add(self._current, now - self._since)
        self._current, self._since = name, now
        if name:
            self._announce(name)

    def stage(self, name: str, fn: Callable[[], T]) -> T:
        """``fn()``, timed as stage ``name``."""
        self.switch(name)
        result = fn()
        self.switch("")
        return result

    def start(self, name: str, fn: Callable[..., T], *args: Any,
              workers: Workers = SERIAL) -> Callable[[], T]:
        """``fn(*args)`` as stage ``name``, run now on one worker, started beside the next
        stages as one Ray task on several (:func:`~dynoplan.parallel.run_in_background`);
        the returned function waits for the result and records the stage's own duration."""
        self._announce(name, " (beside the next stages)" if workers.parallel else "")
        wait = run_in_background(_timed, (fn, *args), workers)

        def finish() -> T:
            seconds, result = wait()
            self._add(name, seconds)
            return result

        return finish

    def rounded(self, digits: int) -> dict[str, float]:
        """:attr:`seconds` rounded to ``digits`` decimals."""
        return {name: round(s, digits) for name, s in self.seconds.items()}

    def _add(self, name: str, seconds: float) -> None:
        self.seconds[name] = self.seconds.get(name, 0.0) + seconds

    def _announce(self, name: str, note: str = "") -> None:
        if self._say is not None:
            self._say(self._label.format(name) + note)


WALL_CLOCK_KEYS = frozenset({"seconds", "data_seconds", "train_seconds"})
"""Keys of a training report that hold wall-clock seconds (they differ run to run)."""


def without_wall_clock(report: dict[str, Any]) -> dict[str, Any]:
    """``report`` without its :data:`WALL_CLOCK_KEYS`: what a model file stores of its
    training report, so that the same fit writes the same bytes (the times stay in the
    report returned to the caller, and in ``summary.json``)."""
    return {k: v for k, v in report.items() if k not in WALL_CLOCK_KEYS}


def _timed(fn: Callable[..., T], *args: Any) -> tuple[float, T]:
    """``(wall seconds, fn(*args))``: a stage run as one task, and how long it took."""
    t0 = perf_counter()
    result = fn(*args)
    return perf_counter() - t0, result


__all__ = ["WALL_CLOCK_KEYS", "StageClock", "without_wall_clock"]
