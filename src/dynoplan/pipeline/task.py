"""Tasks: what the one pipeline needs to know of an environment, and what a task does at
each of its stages.

A *task* names an environment and the options that act in it, in a form that any worker
process can rebuild from (references, not live objects): the pipeline's stages take a
task, and the evaluation ships it to Ray workers, which rebuild the environment, the
options and the controller from it and from the models folder
(:class:`~dynoplan.pipeline.evaluate.ControllerJob`).

:class:`~dynoplan.pipeline.gym_task.GymTask` is the task of a user's Gymnasium
environment with user-written options;
:class:`~dynoplan.envs.gear.pipeline_task.GearTask` is the gear assembly's.

A run of :func:`~dynoplan.pipeline.run.run_pipeline` goes through the same stages in the
same order for every task (:class:`TaskStages`): what is done at each stage is the
task's. A user's environment and options get the generic stages
(:class:`~dynoplan.pipeline.generic_stages.GenericStages`: a demonstrator's episodes, exploration
episodes of random options, :func:`~dynoplan.pipeline.fit.fit_models`, the default
controllers); the gear assembly brings its own
(:class:`~dynoplan.envs.gear.pipeline_stages.GearStages`: its option networks, its operator's
demonstrations, option runs from each option's own starts, the models measured on
held-out trials, the flat PPO baseline and outcome initiation, the oracle and the
variant rows, the faults and the video).
"""

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, TypeVar

import gymnasium as gym

from dynoplan.parallel import SERIAL, Workers
from dynoplan.pipeline.control_settings import ControllerSettings
from dynoplan.pipeline.jobs import EpisodeRunner
from dynoplan.timing import StageClock


class Task(Protocol):
    """What a stage of the pipeline rebuilds, here or on a worker.

    A task is small, frozen and hashable (workers keep what they built per task), and
    picklable (it is shipped to them).
    """

    @property
    def name(self) -> str:
        """Shown in tables and recorded in summaries."""
        ...

    def make_env(self) -> gym.Env[Any, Any]:
        """A new instance of the task's environment, which defines success: an episode
        succeeded when its last step's ``info["is_success"]`` says so, else when it
        terminated (a task with a success function wraps its environment in
        :class:`~dynoplan.pipeline.gym_task.EndOnSuccess`, as
        :func:`~dynoplan.pipeline.gym_task.task_env` does)."""
        ...

    def make_runner(self, controller: str, models: Path,
                    settings: ControllerSettings) -> EpisodeRunner:
        """Controller ``controller`` on a new environment, built from the models folder
        ``models``: what runs and records the task's seeded episodes (an
        :class:`~dynoplan.pipeline.jobs.EpisodeRunner`, usually a
        :class:`~dynoplan.pipeline.evaluate.ControllerRunner`)."""
        ...


@dataclass(frozen=True)
class PipelineRun:
    """What every stage of one run is given.

    Attributes:
        out: the run's output folder (``None``: the run writes nothing).
        clock: the run's one timer: each stage times itself on it by name
            (:meth:`~dynoplan.timing.StageClock.stage`, ``switch`` or ``start``).
        workers: where the episodes of the run's stages run.
        progress: show progress bars on stderr.
    """

    out: Path | None
    clock: StageClock
    workers: Workers = SERIAL
    progress: bool = False


Demos = TypeVar("Demos")
Runs = TypeVar("Runs")
Models = TypeVar("Models")
Evaluation = TypeVar("Evaluation")
Result = TypeVar("Result", covariant=True)


class TaskStages(Protocol[Demos, Runs, Models, Evaluation, Result]):
    """What a task does at each stage of :func:`~dynoplan.pipeline.run.run_pipeline`,
    which calls the methods once each, in this order, with the same :class:`PipelineRun`;
    what one stage returns is what the next is given (its type is the task's: episodes
    in memory, or the folder a stage wrote them to).

    A stages object belongs to one run: it may keep what later stages or the summary
    need. Each stage raises :class:`~dynoplan.errors.DynoplanError` (one line) on input
    it cannot use, before any work where it can.
    """

    def prepare(self, run: PipelineRun) -> None:
        """Check the run's input, and fit what the demonstrator needs before it can act
        (the gear: its option networks)."""
        ...

    def demonstrations(self, run: PipelineRun) -> Demos:
        """The demonstrations, with option labels (recorded by the task's demonstrator,
        or given)."""
        ...

    def option_runs(self, run: PipelineRun, demos: Demos) -> Runs:
        """The options' runs the dynamics are learned from (where each starts is the
        task's)."""
        ...

    def fit(self, run: PipelineRun, demos: Demos, runs: Runs) -> Models:
        """The goal heuristic, the safety regions and every option's dynamics."""
        ...

    def after_fit(self, run: PipelineRun, models: Models) -> Models:
        """The task's further fit steps on the fitted models (the generic pipeline's
        improvement rounds; the gear's figures of the fit, flat baseline and
        initiation learned from outcome runs); the models the evaluation uses."""
        ...

    def evaluate(self, run: PipelineRun, models: Models) -> Evaluation:
        """Every controller on the same seeded episodes, the task's extra rows among
        them."""
        ...

    def report(self, run: PipelineRun, evaluation: Evaluation) -> Result:
        """The task's further report sections, the outputs written to ``run.out`` and
        what :func:`~dynoplan.pipeline.run.run_pipeline` returns."""
        ...


__all__ = ["PipelineRun", "Task", "TaskStages"]
