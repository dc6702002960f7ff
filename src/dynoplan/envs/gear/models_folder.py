"""A gear models folder: the one models format of :mod:`dynoplan.models.folder`.

:func:`~dynoplan.envs.gear.learning.training.train_gear_models` writes ``metrics.json``
and, through the pipeline's :meth:`~dynoplan.pipeline.fit.FittedModels.write`, one
safetensors file per model and the manifest ``models.json`` (the library's format, with
the gear's feature maps named, the fit's report and settings, and the training seed and
the planner state's names as extra fields). :func:`load_gear_models`
reads the folder back as :class:`~dynoplan.pipeline.fit.FittedModels` and checks that it
fits this version's gear assembly, so a missing, truncated, modified or mismatched file
is rejected with one error line.

The goal heuristic and the regions read named feature maps of the planner state
(:mod:`dynoplan.envs.gear.features`): the loaded models take full planner states
``(batch, 22)``.
"""

import os
from pathlib import Path

from dynoplan.envs.gear.features import FEATURE_MAPS
from dynoplan.envs.gear.options.catalog import gear_option_names
from dynoplan.envs.gear.state import DECISION_STEPS, STATE_DIM
from dynoplan.errors import DynoplanError
from dynoplan.models.folder import MANIFEST_FILE
from dynoplan.pipeline.fit import FittedModels

TASK_NAME = "gear_assembly"
METRICS_FILE = "metrics.json"
HELDOUT_DIR = "heldout-demos"
RETRAIN = "train them with 'dynoplan gear train' or 'dynoplan gear run'"


def load_gear_models(folder: str | os.PathLike[str], task: str = TASK_NAME) -> FittedModels:
    """Read the models written by
    :func:`~dynoplan.envs.gear.learning.training.train_gear_models` from ``folder`` (or a
    gear task's models fitted on an options folder,
    :func:`~dynoplan.pipeline.task_fit.run_task`: then ``task`` names it, for example
    :data:`~dynoplan.envs.gear.peg_pose.PEG_TASK_NAME`).

    Raises:
        DynoplanError: (one line) see :meth:`FittedModels.load`, and a task other than
            ``task``, a state dimension, option names or decision rate other than this
            version's gear assembly's with the registered options, or no regions.
    """
    names = list(gear_option_names())
    models = FittedModels.load(folder, FEATURE_MAPS, RETRAIN, known_options=names)
    path = Path(folder) / MANIFEST_FILE
    found = {"task": models.task, "state_dim": models.state_dim,
             "option_names": models.option_names, "stride": models.stride}
    expected = {"task": task, "state_dim": STATE_DIM, "option_names": names,
                "stride": DECISION_STEPS}
    for key, value in expected.items():
        if found[key] != value:
            raise DynoplanError(f"{path}: {key} is {found[key]!r}, the registered gear "
                                f"options give {value!r}")
    if models.regions is None or models.regions.option_names != [
            n for n in names if n in models.regions.option_names]:
        raise DynoplanError(f"{path}: the gear's safety regions must be those of the "
                            f"demonstrated options among {names}, in that order")
    return models


__all__ = ["HELDOUT_DIR", "METRICS_FILE", "RETRAIN", "TASK_NAME",
           "load_gear_models"]
