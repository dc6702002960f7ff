"""The whole generic pipeline in one call: collect, fit, control, evaluate.

::

    result = run_pipeline("MountainCarContinuous-v0", make_options(),
                          demonstrator=make_demonstrator(), settings=PipelineSettings())
    print(result.table)

The run also reports, per option, where it may start
(:func:`~dynoplan.pipeline.admissibility.admissibility`): the share of the evaluation
episodes' start states and of the demonstration states inside its initiation set (the
user's own, intersected with its learned region), with a warning when that is almost
nowhere or everywhere.

The generic stages are :class:`~dynoplan.pipeline.generic_stages.GenericStages`; its
settings, :class:`~dynoplan.pipeline.run_settings.PipelineSettings` (with the run's seed
streams, :func:`~dynoplan.pipeline.run_settings.run_seeds`).
"""

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, overload

import gymnasium as gym

from dynoplan.adapters.spec import OptionSpec
from dynoplan.data.dataset import Dataset
from dynoplan.data.episodes import Episode
from dynoplan.errors import DynoplanError
from dynoplan.io import ensure_writable_dir
from dynoplan.options.option import Option
from dynoplan.parallel import SERIAL, Workers
from dynoplan.pipeline.fit import (
    DynamicsFitter,
)
from dynoplan.pipeline.generic_stages import GenericStages, PipelineResult
from dynoplan.pipeline.gym_task import StateFn, SuccessFn
from dynoplan.pipeline.run_settings import PipelineSettings
from dynoplan.pipeline.task import PipelineRun, Result, Task, TaskStages
from dynoplan.timing import StageClock


def run_stages(stages: TaskStages[Any, Any, Any, Any, Result], run: PipelineRun) -> Result:
    """The one order of every run: ``stages``' hooks called once each on ``run``."""
    stages.prepare(run)
    demos = stages.demonstrations(run)
    runs = stages.option_runs(run, demos)
    models = stages.after_fit(run, stages.fit(run, demos, runs))
    return stages.report(run, stages.evaluate(run, models))


@overload
def run_pipeline(
    env: str | gym.Env[Any, Any],
    options: Sequence[OptionSpec | Option],
    demonstrator: Any = None,
    demos: Dataset | Sequence[Episode] | None = None,
    settings: PipelineSettings | None = None,
    out: str | Path | None = None,
    state_fn: StateFn | None = None,
    success: SuccessFn | None = None,
    fitter: DynamicsFitter | None = None,
    progress: bool = False,
    status: Callable[[str], None] | None = None,
    command: str | None = None,
    workers: Workers = SERIAL,
    task: Task | None = None,
    disturbed_env: gym.Env[Any, Any] | None = None,
) -> PipelineResult: ...


@overload
def run_pipeline(*, stages: TaskStages[Any, Any, Any, Any, Result],
                 out: str | Path | None = None, progress: bool = False,
                 status: Callable[[str], None] | None = None,
                 workers: Workers = SERIAL) -> Result: ...


def run_pipeline(
    env: str | gym.Env[Any, Any] | None = None,
    options: Sequence[OptionSpec | Option] = (),
    demonstrator: Any = None,
    demos: Dataset | Sequence[Episode] | None = None,
    settings: PipelineSettings | None = None,
    out: str | Path | None = None,
    state_fn: StateFn | None = None,
    success: SuccessFn | None = None,
    fitter: DynamicsFitter | None = None,
    progress: bool = False,
    status: Callable[[str], None] | None = None,
    command: str | None = None,
    workers: Workers = SERIAL,
    task: Task | None = None,
    disturbed_env: gym.Env[Any, Any] | None = None,
    stages: TaskStages[Any, Any, Any, Any, Any] | None = None,
) -> Any:
    """Collect, fit, control and evaluate on any Gymnasium environment with a Box space,
    or run a task's own ``stages``: the same stages in the same order
    (:func:`run_stages`), timed on one clock.

    Args:
        env: a Gymnasium id or an environment (a task's: ``task.make_env()``).
        options: the user's options (:func:`~dynoplan.adapters.option_spec`); the
            dynamics models of all of them are learned (those of given ``Option`` s are
            replaced).
        demonstrator: a :class:`~dynoplan.pipeline.Demonstrator` (or
            ``fn(observation) -> option name``) that records ``settings.demos``
            demonstrations; not needed when ``demos`` are given.
        demos: recorded demonstrations (a dataset or episodes) with option labels.
        settings: see :class:`~dynoplan.pipeline.run_settings.PipelineSettings`.
        out: a folder for ``summary.json``, ``results.md``, the datasets (``demos/``,
            ``transitions/``) and the models (``models/``); ``None`` writes nothing.
        state_fn: observation -> planner state ``(d,)``, the observation every part of
            the pipeline then sees, the options included; default: a ``Box`` observation
            as it is, a ``Dict`` flattened with a warning (:func:`task_env`).
        success: ``success(observation, info) -> bool`` after every step; the episode
            ends at the first success (:class:`~dynoplan.pipeline.gym_task.EndOnSuccess`);
            default: the environment's ``info["is_success"]`` at the last step, else
            ``terminated``.
        fitter: learns each option's dynamics; default: an MLP ensemble.
        progress: show progress bars on stderr.
        status: called with the name of each stage as it starts.
        command: the command line that started the run, recorded in the outputs.
        workers: where the evaluation episodes run; on several workers (Ray) each
            rebuilds the controllers from ``task`` and ``out/models``, so both are needed
            (the results are the same as on one).
        task: the same environment and options as references workers can rebuild.
        disturbed_env: the task's environment under a disturbance its user expects (a
            push, an object moved), with ``env``'s success and state functions: where
            the improvement rounds rehearse a share ``settings.improve_disturbed`` of
            their own episodes (needed only then).
        stages: a task's own stages (:class:`~dynoplan.pipeline.task.TaskStages`), run
            into ``out`` on ``workers`` instead of the generic ones
            (:class:`~dynoplan.pipeline.generic_stages.GenericStages` of the arguments
            above, then not given); what their ``report`` returns.

    Returns:
        A :class:`~dynoplan.pipeline.generic_stages.PipelineResult` (with ``stages``:
        what their ``report`` returns).

    Raises:
        DynoplanError: an observation space that does not flatten to a ``Box`` and no
            ``state_fn``, a success function that raises, options that disagree with the
            environment or each other, demonstrations without option labels, no
            demonstrator and no demonstrations, a failing demonstrator; ``stages`` with
            any other argument than ``out``, ``progress``, ``status`` and ``workers``; an
            unwritable ``out``.
    """
    if stages is None:
        if env is None:
            raise DynoplanError("give an environment and options, or a task's stages")
        stages = GenericStages(env, options, demonstrator, demos, settings, state_fn, success,
                               fitter, command, task, out, workers, disturbed_env)
    elif env is not None or options or any(
            given is not None for given in (demonstrator, demos, settings, state_fn, success,
                                            fitter, command, task, disturbed_env)):
        raise DynoplanError("a task's stages come with their own environment, options, "
                            "demonstrations and settings: give only out, progress, status "
                            "and workers with them")
    folder = ensure_writable_dir(out) if out is not None else None
    # the clock times every stage from its status message to the next
    return run_stages(stages, PipelineRun(folder, StageClock(status), workers, progress))
