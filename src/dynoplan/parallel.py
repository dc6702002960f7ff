"""Map a job over independent items (episodes, collection runs), here or on Ray workers.

A job is two plain functions and one small, picklable context (paths, frozen settings):
``setup(context) -> state`` builds what a worker holds (an environment, models, a
controller) and ``run(state, item) -> result`` does one item (one seeded episode). The
map returns one result per item, in the items' order, wherever they ran:

- :data:`SERIAL` (one worker, no address): a loop in this process; Ray is not imported,
  let alone started;
- ``Workers(count=N)`` with ``N > 1``: a local Ray runtime with ``N`` CPUs, one Ray task
  per item; each worker process runs ``setup`` once per context and keeps the state for
  the items that follow (what an actor holding one environment would do, without pinning
  items to actors);
- ``Workers(address=...)``: the same tasks on an existing Ray cluster (``"auto"``,
  ``"ray://head:10001"``); every node needs this package and the context's paths.

A worker process that dies mid-item (killed, out of memory, a crash in native code) makes
Ray run that item again on another worker, up to ``Workers.retries`` times; the item's
first, unfinished attempt returns nothing, so no item is lost or counted twice. Items
must therefore be pure: results come back to the caller, which alone writes files. An
exception raised by ``run`` is not retried (it would fail again): the map re-raises it.
"""

import importlib.util
import itertools
import os
from collections import OrderedDict
from collections.abc import Callable, Hashable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, TypeVar

from dynoplan.errors import DynoplanError
from dynoplan.progress import track

C = TypeVar("C", bound=Hashable)
S = TypeVar("S")
T = TypeVar("T")
R = TypeVar("R")

WORKER_STATES = 4
"""Contexts whose state one worker process keeps at most (least recently used dropped)."""
IN_FLIGHT_PER_CPU = 2
"""Ray tasks submitted ahead per CPU of the runtime (the rest wait in the driver)."""


@dataclass(frozen=True)
class Workers:
    """Where a map runs.

    Attributes:
        count: worker processes; 1 (and no ``address``) runs in this process without Ray.
            With ``address``, the cluster's own CPUs set the parallelism and ``count``
            only needs to be >= 1.
        address: an existing Ray cluster to run on (``"auto"`` or ``"ray://host:port"``);
            None starts a local Ray runtime of ``count`` CPUs when ``count > 1``.
        retries: times Ray runs an item again after its worker died.
    """

    count: int = 1
    address: str | None = None
    retries: int = 3

    def __post_init__(self) -> None:
        if self.count < 1:
            raise DynoplanError(f"--workers must be >= 1, got {self.count}")
        if self.address is not None and not self.address.strip():
            raise DynoplanError("--ray-address must not be empty")
        if self.retries < 0:
            raise DynoplanError(f"retries must be >= 0, got {self.retries}")

    @property
    def parallel(self) -> bool:
        """True when the items run as Ray tasks."""
        return self.count > 1 or self.address is not None


SERIAL = Workers()
"""One worker: a plain loop in this process, no Ray."""

AUTO = "auto"
"""The ``--workers`` value that picks the count from the machine (:func:`auto_workers`)."""


def ray_available() -> bool:
    """Whether Ray can be imported, found without importing it (importing costs seconds)."""
    try:
        return importlib.util.find_spec("ray") is not None
    except (ImportError, ValueError):
        return False


def cpu_count() -> int:
    """CPUs this process may run on (its affinity mask where the OS has one), at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # no affinity masks (macOS, Windows)
        return max(1, os.cpu_count() or 1)


def auto_workers() -> int:
    """The ``auto`` worker count: :func:`cpu_count` when Ray is importable, else 1 (serial,
    no error: Ray is an optional extra)."""
    return cpu_count() if ray_available() else 1


def parse_workers(value: str | int, address: str | None = None) -> Workers:
    """``--workers`` (``"auto"`` or a count >= 1) and ``--ray-address`` as :class:`Workers`.

    ``"auto"`` is :func:`auto_workers`; an explicit ``1`` (and no address) is always
    serial, whether Ray is installed or not.

    Raises:
        DynoplanError: ``value`` is neither ``auto`` nor an integer >= 1.
    """
    text = str(value).strip().lower()
    if text == AUTO:
        return Workers(auto_workers(), address)
    try:
        count = int(text)
    except ValueError:
        raise DynoplanError(f"--workers must be 'auto' or a number >= 1, got "
                            f"{value!r}") from None
    return Workers(count, address)


def parallel_map(setup: Callable[[C], S], run: Callable[[S, T], R], context: C,
                 items: Sequence[T], workers: Workers = SERIAL, description: str = "",
                 progress: bool = False) -> list[R]:
    """``[run(setup(context), item) for item in items]``, on ``workers`` (module docstring).

    ``setup`` and ``run`` must be importable module-level functions (Ray ships them by
    name) and ``context`` and the items small and picklable; ``setup`` runs once per
    process and context, so ``run`` must leave the state fit for the next item.
    """
    results: list[Any] = [None] * len(items)
    for i, result in imap_unordered(setup, run, [(context, item) for item in items], workers,
                                    description, progress):
        results[i] = result
    return results


def imap_unordered(setup: Callable[[C], S], run: Callable[[S, T], R],
                   tasks: Sequence[tuple[C, T]], workers: Workers = SERIAL,
                   description: str = "", progress: bool = False) -> Iterator[tuple[int, R]]:
    """``(index, run(setup(context), item))`` of every ``(context, item)`` task as it
    finishes: in order when serial, in any order on Ray; each index exactly once. Tasks
    may differ in context (the cells of a sweep); grouping tasks of one context together
    saves set-ups. See :func:`parallel_map`."""
    if not workers.parallel:
        state: Any = None
        current: Any = None
        for i, (context, item) in enumerate(track(tasks, description, total=len(tasks),
                                                  enabled=progress)):
            if i == 0 or context != current:
                state, current = None, context  # drop the old state before building anew
                state = setup(context)
            yield i, run(state, item)
        return
    if not tasks:
        return
    with ray_session(workers):
        yield from _ray_map(setup, run, tasks, workers, description, progress)


def run_in_background(fn: Callable[..., R], args: tuple[Any, ...],
                      workers: Workers = SERIAL) -> Callable[[], R]:
    """Start ``fn(*args)`` and return a function that waits for it and returns its result
    (or raises its error).

    On parallel ``workers`` it is one Ray task, holding one CPU of the runtime (so the
    maps started meanwhile share the others), retried like a map's items if its worker
    dies; it must therefore be pure like them: a module-level function of small,
    picklable arguments whose result comes back to the caller, which writes the files.
    It needs a running Ray session (:func:`ray_session`) until the result is fetched.
    Serially, ``fn`` runs at once, in this process, before this function returns.
    """
    if not workers.parallel:
        result = fn(*args)
        return lambda: result
    ray = _import_ray()
    if not ray.is_initialized():
        raise DynoplanError("run_in_background needs a running Ray session (ray_session)")
    ref = ray.remote(max_retries=workers.retries, retry_exceptions=False)(fn).remote(*args)
    return lambda: _fetch(ref)


@contextmanager
def ray_session(workers: Workers) -> Iterator[None]:
    """Ray running for ``workers`` for the duration: a runtime already initialised (by the
    caller, a test, ``ray.init`` on a cluster node) is used and left running; otherwise one
    is started (local with ``workers.count`` CPUs, or connected to ``workers.address``) and
    shut down on exit. Nothing happens for serial ``workers``.

    Raises:
        DynoplanError: Ray is not installed, or the cluster cannot be reached.
    """
    if not workers.parallel:
        yield
        return
    ray = _import_ray()
    if ray.is_initialized():
        yield
        return
    import logging

    try:
        if workers.address is not None:
            ray.init(address=workers.address, logging_level=logging.WARNING,
                     log_to_driver=False)
        else:
            # A runtime of our own: its start-up notices are not the user's business, and
            # its workers run at the command's own priority, as the serial loop would
            # (Ray's default, nice 15, yields the CPU to every other process).
            ray.init(num_cpus=workers.count, include_dashboard=False,
                     logging_level=logging.ERROR, log_to_driver=False,
                     _system_config={"worker_niceness": 0})
    except (ConnectionError, RuntimeError, ValueError) as exc:
        where = workers.address or f"a local runtime of {workers.count} CPUs"
        raise DynoplanError(f"cannot start Ray on {where}: {exc}") from None
    try:
        yield
    finally:
        ray.shutdown()


def _import_ray() -> Any:
    try:
        import ray
    except ImportError:
        raise DynoplanError("--workers > 1 and --ray-address need Ray: pip install "
                            "'dynoplan[ray]' (or run with --workers 1)") from None
    return ray


def _ray_map(setup: Callable[[C], S], run: Callable[[S, T], R], tasks: Sequence[tuple[C, T]],
             workers: Workers, description: str, progress: bool) -> Iterator[tuple[int, R]]:
    """Tasks in flight at most :data:`IN_FLIGHT_PER_CPU` per cluster CPU (so the driver's
    bookkeeping stays small with 10^5 tasks), the rest submitted as results come in."""
    ray = _import_ray()
    remote = ray.remote(max_retries=workers.retries, retry_exceptions=False)(_run_item)
    cpus = int(ray.cluster_resources().get("CPU", workers.count))
    window = max(2, IN_FLIGHT_PER_CPU * cpus)
    refs: dict[Any, Any] = {}  # one copy of each context in the object store
    queue = iter(enumerate(tasks))
    pending: dict[Any, int] = {}

    def submit(n: int) -> None:
        for i, (context, item) in itertools.islice(queue, n):
            if context not in refs:
                refs[context] = ray.put(context)
            pending[remote.remote(setup, run, refs[context], item)] = i

    def finished() -> Iterator[tuple[int, Any]]:
        submit(window)
        try:
            while pending:
                done, _ = ray.wait(list(pending), num_returns=1)
                for ref in done:
                    i = pending.pop(ref)
                    result = _fetch(ref)
                    submit(1)
                    yield i, result
        finally:
            for ref in pending:  # an error or an interrupt: do not leave work behind
                ray.cancel(ref, force=True)

    yield from track(finished(), description, total=len(tasks), enabled=progress)


def _fetch(ref: Any) -> Any:
    """``ray.get(ref)``; a task's own exception (not a crash) is re-raised, a
    :class:`DynoplanError` as itself (one line for the user), others wrapped by Ray with
    the worker's traceback."""
    from ray.exceptions import RayTaskError

    try:
        return _import_ray().get(ref)
    except RayTaskError as exc:
        cause = exc.cause
        raise (cause if isinstance(cause, DynoplanError) else exc) from None


_states: "OrderedDict[tuple[Any, Hashable], Any]" = OrderedDict()


def _run_item(setup: Callable[[C], S], run: Callable[[S, T], R], context: C, item: T) -> R:
    """A Ray task: ``run`` on the state this worker process keeps for ``context``."""
    key = (setup, context)
    if key in _states:
        _states.move_to_end(key)
    else:
        _states[key] = setup(context)
        while len(_states) > WORKER_STATES:
            _states.popitem(last=False)
    return run(_states[key], item)


__all__ = ["AUTO", "IN_FLIGHT_PER_CPU", "SERIAL", "WORKER_STATES", "Workers", "auto_workers",
           "cpu_count", "imap_unordered", "parallel_map", "parse_workers", "ray_available",
           "ray_session", "run_in_background"]
