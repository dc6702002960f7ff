"""``dynoplan sweep CONFIG``: the gear's controllers on a grid of planner settings and seeds
over trained gear models, resumably (:mod:`dynoplan.pipeline.sweep`; the configuration:
:mod:`dynoplan.pipeline.sweep_config`): the episodes of ``gear run`` for each seed, one
row of ``gear run``'s ``results.csv`` per cell. Finished cells wait in the resume folder
beside ``OUT`` (:func:`~dynoplan.pipeline.sweep.resume_folder`) until the sweep completes;
``OUT`` changes only then, all at once."""

from collections.abc import Callable
from pathlib import Path
from typing import Any

from dynoplan.envs.gear.controllers import CONTROLLERS, GEAR_CONTROL
from dynoplan.envs.gear.evaluation import evaluation_seeds
from dynoplan.envs.gear.flat_policy import FLAT_POLICY
from dynoplan.envs.gear.pipeline_task import GearTask
from dynoplan.envs.gear.reports.results import RESULT_COLUMNS, summarise
from dynoplan.parallel import SERIAL, Workers
from dynoplan.pipeline.evaluate import EpisodeRecord
from dynoplan.pipeline.jobs import build_runner, runner_episode
from dynoplan.pipeline.sweep import SweepTask, cell_key, resume_folder
from dynoplan.pipeline.sweep import run_sweep as run_task_sweep
from dynoplan.pipeline.sweep_config import SweepConfig
from dynoplan.seeding import EpisodeSeed

GEAR_SWEEP = SweepTask(GearTask(), tuple(c for c in CONTROLLERS if c != FLAT_POLICY),
                       GEAR_CONTROL, evaluation_seeds, summarise,
                       tuple(c for c in RESULT_COLUMNS if c != "controller"))
"""The gear's sweep: every controller with a planner (not the flat policy)."""


def load_sweep_config(path: Path) -> SweepConfig:
    """The gear sweep's configuration in ``path``, checked."""
    return GEAR_SWEEP.config(path)


def run_sweep(config_path: Path, out: Path, workers: Workers = SERIAL, progress: bool = True,
              log: Callable[[str], None] = lambda _: None, *,
              setup: Callable[[Any], Any] = build_runner,
              run: Callable[[Any, EpisodeSeed], EpisodeRecord] = runner_episode,
              ) -> dict[str, Any]:
    """:func:`~dynoplan.pipeline.sweep.run_sweep` of :data:`GEAR_SWEEP`."""
    return run_task_sweep(config_path, out, GEAR_SWEEP, workers, progress, log, setup=setup,
                          run=run)


__all__ = ["GEAR_SWEEP", "cell_key", "load_sweep_config", "resume_folder", "run_sweep"]
