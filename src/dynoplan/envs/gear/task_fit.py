"""A gear task fitted on the option dynamics of an earlier ``gear run`` (issue 32):
``dynoplan gear task-fit``.

The first task (``dynoplan gear run``) learns the options' dynamics with the peg always
at one pose. The downstream task (:mod:`dynoplan.envs.gear.peg_pose`,
``dynoplan/GearPegPose-v0``) holds the peg module at another pose in every episode; same
scene, same options, same operator. :func:`gear_task_fit` solves it on a ``gear run``
folder (the *options folder*) with the library's task fit
(:func:`~dynoplan.pipeline.task_fit.run_task`): the operator records the task's own
demonstrations, only the task's goal heuristic (on the features ``peg_objects``) and
regions are fitted from them, the options folder's dynamics are used unchanged, and
DynoPlan (learned parts only) runs on seeded episodes of the task.

Output folder: ``demos/`` (the task's demonstrations, kept when a rerun finds them) and
``task/`` (:func:`~dynoplan.pipeline.task_fit.run_task`'s ``models/``, ``results.md`` and
``summary.json``, whose ``task_fit`` says how many demonstrations and seconds the task
needed). ``benchmarks/transfer/gear_peg_task.py`` compares this with dynamics retrained
on the task.
"""

import sys
from dataclasses import replace
from pathlib import Path

from dynoplan.envs.gear.controllers import GEAR_CONTROL
from dynoplan.envs.gear.features import FEATURE_MAPS, PEG_OBJECTS
from dynoplan.envs.gear.learning.settings import DEFAULT_SETTINGS, QUICK_SETTINGS
from dynoplan.envs.gear.peg_pose import PEG_WORKSPACE
from dynoplan.envs.gear.pipeline_task import GearTask
from dynoplan.envs.gear.state import PlannerState
from dynoplan.errors import DynoplanError
from dynoplan.parallel import SERIAL, Workers
from dynoplan.pipeline.run_settings import PipelineSettings, run_seeds
from dynoplan.pipeline.task_fit import TaskResult, load_option_models, run_task

DEMOS = 10
"""The task's demonstrations (the first task's number)."""
CONTROLLERS = ("dynoplan",)
"""The rows measured: DynoPlan with learned parts only (the gear's ``dynoplan``)."""


def task_settings(seed: int, episodes: int, demos: int, quick: bool,
                  controllers: tuple[str, ...] = CONTROLLERS) -> PipelineSettings:
    """How the task is fitted and evaluated: the first task's fit settings (``gear run``'s,
    or ``--quick``'s) with the goal on :data:`~dynoplan.envs.gear.features.PEG_OBJECTS`,
    and the gear's controller settings (``gear run``'s :data:`GEAR_CONTROL`, ``--quick``:
    a shorter horizon and fewer samples, as ``gear run --quick``); the improvement rounds
    are the pipeline's (``--quick``: 3 own episodes a round, as ``gear run --quick``)."""
    fit = replace(QUICK_SETTINGS if quick else DEFAULT_SETTINGS, goal_features=PEG_OBJECTS.name)
    control = (replace(GEAR_CONTROL, horizon=6, samples=32, oracle_horizon=3) if quick
               else GEAR_CONTROL)
    return PipelineSettings(demos=demos, episodes=episodes, seed=seed, fit=fit,
                            control=control, controllers=controllers,
                            improve_episodes=3 if quick else PipelineSettings.improve_episodes)


def check_options_folder(options_models: Path) -> Path:
    """The options folder's models folder, checked (one error line): its dynamics load and
    cover the task's options, its option networks are there."""
    from dynoplan.envs.gear.options.catalog import gear_option_names, network_files

    folder = load_option_models(options_models, FEATURE_MAPS, PlannerState())
    folder.check_task(list(gear_option_names()))
    missing = [f for f in network_files().values() if not (folder.folder / f).is_file()]
    if missing:
        raise DynoplanError(f"{folder.folder}: no option network {', '.join(missing)} (the "
                            "options folder of a gear run has them)")
    return folder.folder


def fit_and_evaluate(options_models: Path, networks: Path, demos: Path, out: Path,
                     settings: PipelineSettings, workers: Workers, command: str,
                     runs: Path | None = None, progress: bool = True,
                     peg_frame: bool = False, first_task: bool = False,
                     reuse_initiation: bool = False) -> TaskResult:
    """The task fit (:func:`~dynoplan.pipeline.task_fit.run_task`) of the downstream task on
    the options folder ``options_models``, its demonstrations read from ``demos``, the
    option networks from ``networks`` (``peg_frame``: the dynamics rolled in the first
    task's frame, :class:`~dynoplan.envs.gear.peg_pose.PegFrame`; ``first_task``: the
    first task instead; ``reuse_initiation``: the options' initiation learned from their
    outcome runs kept, read in that frame with ``peg_frame``); the result written into
    ``out``."""
    from dynoplan.data import read_dataset
    from dynoplan.envs.gear.operator import OptionOperator
    from dynoplan.envs.gear.options.catalog import policy_factories
    from dynoplan.io import staged_folder

    task = GearTask(peg=None if first_task else PEG_WORKSPACE, networks=networks.resolve(),
                    peg_frame=peg_frame)
    env = task.make_env()
    specs = OptionOperator(env.unwrapped, policy_factories(networks)).specs  # type: ignore[arg-type]
    with staged_folder(out) as staged:
        return run_task(env, options_models, specs, demos=read_dataset(demos),
                        settings=settings, out=staged, progress=progress,
                        status=lambda m: print(f"-- {m}", file=sys.stderr, flush=True),
                        command=command, workers=workers, task=task, runs=runs,
                        planner_state=PlannerState(), feature_maps=FEATURE_MAPS,
                        own_controllers=True, reuse_initiation=reuse_initiation)


def gear_task_fit(options_models: Path, out: Path, seed: int = 0, episodes: int = 100,
                  demos: int = DEMOS, peg_frame: bool = False, quick: bool = False,
                  workers: Workers = SERIAL, command: str = "",
                  progress: bool = True) -> TaskResult:
    """The downstream task on the ``gear run`` folder ``options_models`` (module
    docstring): ``demos`` demonstrations recorded into ``out/demos`` (kept when there),
    the task fit and ``episodes`` evaluation episodes of DynoPlan into ``out/task``; the
    episodes and the demonstrations are those of ``seed``
    (:func:`~dynoplan.pipeline.run_settings.run_seeds`).

    Raises:
        DynoplanError: (one line) an options folder that is not a gear run's, sizes below
            1, or an operator that succeeded in too few of its tries.
    """
    from dynoplan.envs.gear.demonstrations import record_demos

    if episodes < 1 or demos < 1:
        raise DynoplanError("episodes and demos must be >= 1")
    networks = check_options_folder(options_models)
    out.mkdir(parents=True, exist_ok=True)
    if not (out / "demos" / "data").exists():
        record_demos(demos, run_seeds(seed)["demos"], out / "demos", progress,
                     demonstrator="options", models=networks, workers=workers,
                     peg=PEG_WORKSPACE)
    return fit_and_evaluate(options_models, networks, out / "demos", out / "task",
                            task_settings(seed, episodes, demos, quick), workers, command,
                            progress=progress, peg_frame=peg_frame)


__all__ = ["CONTROLLERS", "DEMOS", "check_options_folder", "fit_and_evaluate",
           "gear_task_fit", "task_settings"]
