"""The generic pipeline: DynoPlan on any Gymnasium environment with a ``Box`` observation.

collect (:mod:`~dynoplan.pipeline.collect`) -> fit (:mod:`~dynoplan.pipeline.fit`) ->
control and evaluate (:mod:`~dynoplan.pipeline.evaluate`); :func:`run_pipeline` does
all of it in one call.
"""

from dynoplan.control.controller import flat_state
from dynoplan.pipeline.admissibility import admissibility, start_states
from dynoplan.pipeline.collect import (
    CallableDemonstrator,
    Decision,
    Demonstrator,
    RandomOptions,
    box_state_dim,
    collect_transitions,
    make_env,
    probe_options,
    record_demonstrations,
    record_episode,
)
from dynoplan.pipeline.control_settings import ControllerSettings
from dynoplan.pipeline.evaluate import (
    ControllerJob,
    ControllerVariant,
    EpisodeRecord,
    TaskControl,
    controller_names,
    evaluate_controllers,
    learned_regions,
    make_controller,
    neutral_action,
    results_table,
    summarize,
)
from dynoplan.pipeline.fit import (
    DynamicsFitter,
    FitSettings,
    FittedModels,
    StridedTermination,
    ensemble_fitter,
    fit_dynamics,
    fit_goal,
    fit_models,
    fit_option_regions,
    fit_outcome_initiation,
    fit_regions,
    fit_undemonstrated_initiation,
    option_runs,
    option_transitions,
)
from dynoplan.pipeline.generic_stages import PipelineResult, demos_from_dataset
from dynoplan.pipeline.gym_task import (
    EndOnSuccess,
    GymTask,
    StateFn,
    StateObservation,
    SuccessFn,
    call_factory,
    load_function,
    load_object,
    task_env,
)
from dynoplan.pipeline.jobs import evaluate_many
from dynoplan.pipeline.run import run_pipeline
from dynoplan.pipeline.run_settings import PipelineSettings
from dynoplan.pipeline.task import Task

__all__ = [
    "CallableDemonstrator",
    "ControllerJob",
    "ControllerSettings",
    "ControllerVariant",
    "Decision",
    "Demonstrator",
    "DynamicsFitter",
    "EndOnSuccess",
    "EpisodeRecord",
    "FitSettings",
    "FittedModels",
    "GymTask",
    "PipelineResult",
    "PipelineSettings",
    "RandomOptions",
    "StateFn",
    "StateObservation",
    "StridedTermination",
    "SuccessFn",
    "Task",
    "TaskControl",
    "admissibility",
    "box_state_dim",
    "call_factory",
    "collect_transitions",
    "controller_names",
    "demos_from_dataset",
    "ensemble_fitter",
    "evaluate_controllers",
    "evaluate_many",
    "fit_dynamics",
    "fit_goal",
    "fit_models",
    "fit_option_regions",
    "fit_outcome_initiation",
    "fit_regions",
    "fit_undemonstrated_initiation",
    "flat_state",
    "learned_regions",
    "load_function",
    "load_object",
    "make_controller",
    "make_env",
    "neutral_action",
    "option_runs",
    "option_transitions",
    "probe_options",
    "record_demonstrations",
    "record_episode",
    "results_table",
    "run_pipeline",
    "start_states",
    "summarize",
    "task_env",
]
