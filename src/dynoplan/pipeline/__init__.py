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
    ControllerSettings,
    controller_names,
    evaluate_controllers,
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
    fit_regions,
    option_transitions,
)
from dynoplan.pipeline.run import (
    PipelineResult,
    PipelineSettings,
    call_factory,
    demos_from_dataset,
    load_object,
    run_pipeline,
)

__all__ = [
    "CallableDemonstrator",
    "ControllerSettings",
    "Demonstrator",
    "DynamicsFitter",
    "FitSettings",
    "FittedModels",
    "PipelineResult",
    "PipelineSettings",
    "RandomOptions",
    "StridedTermination",
    "box_state_dim",
    "call_factory",
    "collect_transitions",
    "controller_names",
    "demos_from_dataset",
    "ensemble_fitter",
    "evaluate_controllers",
    "fit_dynamics",
    "fit_goal",
    "fit_models",
    "fit_regions",
    "flat_state",
    "load_object",
    "make_controller",
    "make_env",
    "option_transitions",
    "probe_options",
    "record_demonstrations",
    "record_episode",
    "results_table",
    "run_pipeline",
    "summarize",
]
