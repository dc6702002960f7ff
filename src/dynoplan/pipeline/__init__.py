"""The generic pipeline: DynoPlan on any Gymnasium environment with a ``Box`` observation.

collect (:mod:`~dynoplan.pipeline.collect`) -> fit (:mod:`~dynoplan.pipeline.fit`) ->
control and evaluate (:mod:`~dynoplan.pipeline.evaluate`); :func:`run_pipeline` does
all of it in one call.
"""

from dynoplan.pipeline.collect import (
    CallableDemonstrator,
    Demonstrator,
    RandomOptions,
    box_state_dim,
    collect_transitions,
    flat_state,
    make_env,
    probe_options,
    record_demonstrations,
    record_episode,
)
from dynoplan.pipeline.evaluate import (
    ControllerJob,
    ControllerSettings,
    EpisodeRecord,
    controller_names,
    evaluate_controllers,
    evaluate_many,
    make_controller,
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
    option_runs,
    option_transitions,
)
from dynoplan.pipeline.run import (
    PipelineResult,
    PipelineSettings,
    admissibility,
    demos_from_dataset,
    run_pipeline,
    start_states,
)
from dynoplan.pipeline.task import GymTask, Task, call_factory, load_object

__all__ = [
    "CallableDemonstrator",
    "ControllerJob",
    "ControllerSettings",
    "Demonstrator",
    "DynamicsFitter",
    "EpisodeRecord",
    "FitSettings",
    "FittedModels",
    "GymTask",
    "PipelineResult",
    "PipelineSettings",
    "RandomOptions",
    "StridedTermination",
    "Task",
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
    "flat_state",
    "load_object",
    "make_controller",
    "make_env",
    "option_runs",
    "option_transitions",
    "probe_options",
    "record_demonstrations",
    "record_episode",
    "results_table",
    "run_pipeline",
    "start_states",
    "summarize",
]
