"""Episodes as jobs, here or on Ray workers.

A job (:class:`EpisodeJob`) is what a worker rebuilds a runner from (a controller of a
task on a models folder, :class:`~dynoplan.pipeline.evaluate.ControllerJob`); its runner
(:class:`EpisodeRunner`) runs seeded episodes. :func:`evaluate_many` and
:func:`evaluate_rows` run many jobs' episodes as one map.
"""

from collections.abc import Hashable, Mapping, Sequence
from typing import Any, Protocol

from dynoplan.parallel import SERIAL, Workers, imap_unordered
from dynoplan.seeding import EpisodeSeed


class EpisodeRunner(Protocol):
    """What a worker holds for one job: ``episode(seed)`` runs one seeded episode and
    returns a small, picklable result (an
    :class:`~dynoplan.pipeline.evaluate.EpisodeRecord`, or a task's own)."""

    def episode(self, seed: EpisodeSeed) -> Any: ...


class EpisodeJob(Hashable, Protocol):
    """A controller on seeded episodes, as a worker rebuilds it: small, frozen, hashable
    and picklable (paths, names, frozen settings); ``build()`` makes the runner (once per
    worker process and job)."""

    def build(self) -> EpisodeRunner: ...


def build_runner(job: EpisodeJob) -> EpisodeRunner:
    """``job.build()``: what a worker does once per job (the ``setup`` of
    :func:`~dynoplan.parallel.imap_unordered`)."""
    return job.build()


def runner_episode(runner: EpisodeRunner, seed: EpisodeSeed) -> Any:
    """``runner.episode(seed)``: what a worker does per episode (``run``)."""
    return runner.episode(seed)


def evaluate_many(batches: Sequence[tuple[EpisodeJob, Sequence[EpisodeSeed]]],
                  workers: Workers = SERIAL, description: str = "episodes",
                  progress: bool = False) -> list[list[Any]]:
    """Every ``(job, seeds)`` batch, as one map on ``workers``: per batch, one result per
    seed, in order. The episodes of all batches share the workers, so none waits for the
    last episode of another batch (submit the costliest batches first: on Ray the tasks
    start in the given order). An episode depends on its seed alone, so the results are
    the same on one worker or many."""
    tasks = [(job, seed) for job, seeds in batches for seed in seeds]
    results: list[Any] = [None] * len(tasks)
    for i, result in imap_unordered(build_runner, runner_episode, tasks, workers, description,
                                    progress):
        results[i] = result
    out: list[list[Any]] = []
    for _, seeds in batches:
        out.append(results[:len(seeds)])
        results = results[len(seeds):]
    return out


def evaluate_rows(rows: Mapping[str, tuple[EpisodeJob, Sequence[EpisodeSeed]]],
                  workers: Workers = SERIAL, description: str = "episodes",
                  progress: bool = False, first: Sequence[str] = ()) -> dict[str, list[Any]]:
    """Named rows (row name -> job and its seeds) as one map on ``workers``
    (:func:`evaluate_many`), the rows named in ``first`` submitted first (the costliest);
    per row, one result per seed, the rows in the given order."""
    order = sorted(rows, key=lambda name: name not in first)  # stable
    done = dict(zip(order, evaluate_many([rows[name] for name in order], workers, description,
                                         progress), strict=True))
    return {name: done[name] for name in rows}


__all__ = ["EpisodeJob", "EpisodeRunner", "build_runner", "evaluate_many", "evaluate_rows",
           "runner_episode"]
