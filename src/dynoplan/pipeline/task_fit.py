"""A new task on option models learned once: fit only the task's goal heuristic.

The paper: "The dynamics can be learned independently of the task, and can be used to
solve a downstream task." An *options folder* is the output of one ``dynoplan
pipeline`` run (its ``models/``: every option's dynamics ``D_w``; its ``transitions/``:
the option runs they were fitted on), or a bare models folder. :func:`run_task` reuses
those dynamics unchanged and fits, from the new task's own demonstrations,

- its goal heuristic ``G_K`` (always),
- its own initiation regions (Eq. 5; unless ``settings.fit.regions`` is off),

and, as :func:`~dynoplan.pipeline.fit.fit_models` does with a pipeline's exploration
episodes, from option runs: the goal heuristic's off-demonstration states and the regions
of options no demonstration shows. Those runs are the options folder's (its
``transitions/``, runs of the task it was fitted for) unless the task brings its own
(``run_task(runs=...)``, ``dynoplan task fit --runs DATASET``: for example the
``transitions/`` of a ``dynoplan pipeline`` run on the new task), which then replace
them; ``models.json`` records which. Then it evaluates the controllers as
:func:`~dynoplan.pipeline.run.run_pipeline` does, on the same seed streams. The result's
``models/`` is a complete models folder (the reused dynamics files are written into it,
byte for byte the models of the options folder, and ``models.json`` records where they
came from), so it loads like any other, never reading outside itself.

What the options folder learned of the options themselves travels with them: their
dynamics and, when the folder has one, the initiation learned from the options' own
outcome runs (where each option, started, reached its own end: no task's goal judged it;
:attr:`OptionModels.initiation`), which ``run_task(reuse_initiation=True)`` keeps for the
task's controllers to intersect with its own regions, as the first task's do (off by
default). What its first task learned of that task (its goal, its regions, an initiation
learned from the goal's gain over the runs, ``FitSettings.outcome_initiation``) is never
used.

A task whose options act on the environment's observations while its models read a
planner state made from them (the gear: observations of 50 values, planner states of 22)
gives that map (``planner_state``, applied to every stored observation: demonstrations,
option runs, evaluation starts), the named feature maps its models read
(``feature_maps``, for ``settings.fit.goal_features`` and ``region_features``), and, when
its controllers are its own (``own_controllers``), is evaluated by
:meth:`~dynoplan.pipeline.task.Task.make_runner` on the saved models folder, on one worker
as on several.
"""

import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from dynoplan import __version__
from dynoplan.adapters.spec import OptionSpec, as_spec
from dynoplan.data.dataset import Dataset, read_dataset, write_dataset
from dynoplan.data.episodes import OPTION_KEY, Episode
from dynoplan.data.metadata import DatasetMetadata
from dynoplan.errors import DynoplanError, DynoplanWarning
from dynoplan.io import ensure_writable_dir, write_json, write_text
from dynoplan.models.features import FeatureMap
from dynoplan.models.folder import MANIFEST_FILE, file_sha256, read_manifest
from dynoplan.options.option import Option
from dynoplan.parallel import SERIAL, Workers
from dynoplan.pipeline.admissibility import admissibility_table
from dynoplan.pipeline.collect import (
    ObservationFn,
    flat_state,
    probe_options,
    record_demonstrations,
)
from dynoplan.pipeline.evaluate import (
    composition_ratio,
    controller_names,
    option_share_table,
    planning_settings,
    results_table,
)
from dynoplan.pipeline.fit import FittedModels, named_feature_map
from dynoplan.pipeline.fit_dynamics import goal_end_gaps
from dynoplan.pipeline.fit_goal import fit_goal
from dynoplan.pipeline.fit_initiation import OutcomeModel
from dynoplan.pipeline.fit_regions import fit_option_regions
from dynoplan.pipeline.generic_stages import (
    OwnPlay,
    demos_from_dataset,
    evaluate_fitted,
    improve_fitted,
)
from dynoplan.pipeline.gym_task import StateFn, SuccessFn, task_env
from dynoplan.pipeline.improve import OwnEpisode, task_own_episodes
from dynoplan.pipeline.run_settings import PipelineSettings, jsonable, run_seeds
from dynoplan.pipeline.task import Task
from dynoplan.seeding import EpisodeSeed
from dynoplan.timing import StageClock

RUNS_FOLDER = "transitions"
"""The option runs beside ``models/`` in a pipeline run's folder."""


@dataclass
class OptionModels:
    """The options' dynamics and the runs they were fitted on (an options folder).

    Attributes:
        folder: the models folder the dynamics come from.
        models: that folder, loaded (only ``dynamics``, ``stride``, ``option_model``,
            ``state_scale`` and the :attr:`initiation` are reused).
        runs: the option runs (exploration episodes) a task's goal heuristic and regions
            are fitted with, labels indexing ``models.option_names``: those beside the
            folder (empty when it has none), or a task's own (:meth:`with_runs`).
        sha256: per option, the SHA-256 of its dynamics file in ``folder``.
        runs_source: where ``runs`` were read (a dataset folder, resolved), ``None`` for
            none or episodes given in memory.
        initiation_sha256: the SHA-256 of the folder's learned initiation file, ``None``
            when it has none.
    """

    folder: Path
    models: FittedModels
    runs: list[Episode]
    sha256: dict[str, str]
    runs_source: str | None = None
    initiation_sha256: str | None = None

    @property
    def option_names(self) -> list[str]:
        return list(self.models.option_names)

    @property
    def initiation(self) -> OutcomeModel | None:
        """The options' initiation learned from their own outcome runs, which a task
        reuses as it reuses their dynamics; ``None`` when the folder has none, or when
        its initiation judged the runs by its own task's goal heuristic (its report's
        ``outcome_initiation``, :func:`~dynoplan.pipeline.fit.fit_outcome_initiation`):
        that one says where an option helped that task, not where it works."""
        learned = self.models.learned_initiation
        if learned is None or self.models.report.get("outcome_initiation") is not None:
            return None
        return learned

    def without_initiation(self) -> "OptionModels":
        """The same folder with its learned initiation left out (the dynamics alone)."""
        return replace(self, models=replace(self.models, learned_initiation=None),
                       initiation_sha256=None)

    def with_runs(self, runs: "OptionRuns",
                  state_fn: ObservationFn = flat_state) -> "OptionModels":
        """The same dynamics with ``runs`` (:func:`read_option_runs`) in place of the
        folder's option runs: a task's own exploration of the options.

        Raises:
            DynoplanError: what :func:`read_option_runs` refuses.
        """
        episodes, source = read_option_runs(runs, self.option_names, self.models.state_dim,
                                            state_fn)
        return replace(self, runs=episodes, runs_source=source)

    def runs_record(self) -> dict[str, Any]:
        """Where the option runs came from and how many: ``{"source", "episodes",
        "steps"}`` (recorded in the task's ``models.json`` and ``summary.json``)."""
        return {"source": self.runs_source, "episodes": len(self.runs),
                "steps": sum(len(e) for e in self.runs)}

    def check_task(self, names: Sequence[str], state_dim: int | None = None) -> None:
        """Refuse a task whose options are not all in the folder, or whose planner state
        has another size than the dynamics read.

        Raises:
            DynoplanError: one line naming the missing options and the folder's.
        """
        index = self.folder / MANIFEST_FILE
        missing = [n for n in names if n not in self.models.dynamics]
        if missing:
            raise DynoplanError(
                f"{index}: the options folder has no dynamics for option(s) "
                f"{', '.join(map(repr, missing))} of this task (it has "
                f"{', '.join(self.option_names)}); fit them first: dynoplan pipeline with "
                "options that include them")
        if state_dim is not None and state_dim != self.models.state_dim:
            raise DynoplanError(
                f"{index}: the option dynamics read states of {self.models.state_dim} "
                f"values, this task's planner state has {state_dim}")


OptionRuns = str | Path | Dataset | Sequence[Episode]
"""Option runs as :func:`read_option_runs` takes them: a dataset folder, a dataset read,
or episodes."""


def read_option_runs(runs: OptionRuns, option_names: Sequence[str], state_dim: int,
                     state_fn: ObservationFn = flat_state,
                     ) -> tuple[list[Episode], str | None]:
    """Option runs (exploration episodes: every step labelled with the option that acted,
    as ``dynoplan pipeline`` writes them under ``transitions/``), checked against the
    options they are for.

    Args:
        runs: a dataset folder, a dataset (its option names are mapped onto
            ``option_names``), or episodes whose labels index ``option_names``.
        option_names: the options of the dynamics (an options folder's).
        state_dim: the planner state's size ``d`` the dynamics read.
        state_fn: the planner state of a stored observation (default: flattened).

    Returns:
        The episodes, labels indexing ``option_names``, observations ``(T+1, d)``; and
        where they were read (the dataset folder, resolved; ``None`` for episodes).

    Raises:
        DynoplanError: one line naming the dataset: a missing or malformed dataset
            (:func:`~dynoplan.data.dataset.read_dataset`), no episodes, an episode without
            option labels, an option name not among ``option_names``, states of another
            size than ``state_dim``.
    """
    dataset = read_dataset(runs) if isinstance(runs, str | Path) else runs
    path = dataset.path if isinstance(dataset, Dataset) else None
    where = f"{path}: " if path is not None else ""
    try:
        episodes = demos_from_dataset(dataset, option_names, "option run")
    except DynoplanError as error:
        raise DynoplanError(f"{where}{error}") from None
    for index, episode in enumerate(episodes):
        width = np.asarray(state_fn(episode.observations[0])).size
        if width != state_dim:
            raise DynoplanError(f"{where}option run {index} has states of {width} values, the "
                                f"option dynamics read {state_dim}")
    return episodes, None if path is None else str(Path(path).resolve())


def load_option_models(path: str | Path,
                       feature_maps: Mapping[str, FeatureMap] | None = None,
                       state_fn: ObservationFn = flat_state) -> OptionModels:
    """An options folder: a pipeline run's folder (``models/`` and ``transitions/``) or a
    models folder (no runs). ``feature_maps``: the named feature maps its models read
    (:meth:`~dynoplan.pipeline.fit.FittedModels.load`); ``state_fn``: the planner state
    of a stored observation of its runs (default: flattened).

    Raises:
        DynoplanError: one line: not a models folder, a damaged model file or manifest
            (:func:`~dynoplan.models.folder.read_manifest`), an unreadable runs dataset.
    """
    root = Path(path)
    if root.exists() and not root.is_dir():
        raise DynoplanError(f"{root}: is a file, expected an options folder")
    models_dir = root / "models" if (root / "models" / MANIFEST_FILE).is_file() else root
    retrain = "make one with dynoplan pipeline --out DIR, then pass DIR"
    manifest = read_manifest(models_dir, retrain)
    models = FittedModels.load(models_dir, feature_maps, retrain=retrain)
    sha = {name: file_sha256(file) for name, file in manifest.dynamics.items()
           if file is not None}
    folder = OptionModels(models_dir, models, [], sha, initiation_sha256=(
        None if manifest.initiation is None else file_sha256(manifest.initiation.path)))
    runs_dir = root / RUNS_FOLDER
    return (folder.with_runs(runs_dir, state_fn) if models_dir != root and runs_dir.is_dir()
            else folder)


def relabel(episodes: Sequence[Episode], names: Sequence[str],
            to: Sequence[str]) -> list[Episode]:
    """The episodes with option labels that index ``names`` made to index ``to`` (every
    name of ``names`` must be in ``to``)."""
    if list(names) == list(to):
        return list(episodes)
    mapping = np.array([list(to).index(n) for n in names])
    out = []
    for e in episodes:
        infos = dict(e.infos)
        infos[OPTION_KEY] = mapping[np.asarray(e.infos[OPTION_KEY])]
        out.append(Episode(e.observations, e.actions, e.rewards, e.terminations,
                           e.truncations, infos, e.seed))
    return out


def fit_task(options: OptionModels, specs: Sequence[OptionSpec], demos: Sequence[Episode],
             settings: PipelineSettings, seed: int, task: str = "",
             say: Callable[[str], None] | None = None,
             state_fn: ObservationFn = flat_state,
             feature_maps: Mapping[str, FeatureMap] | None = None,
             own_runs: Sequence[Episode] = (),
             region_demos: Sequence[Episode] | None = None) -> FittedModels:
    """The task's models: the options' dynamics unchanged, its own goal heuristic (and
    regions, with ``settings.fit.regions``) from ``demos`` (labels index ``specs``) and
    ``options.runs`` (as :func:`~dynoplan.pipeline.fit.fit_models` uses exploration
    episodes; give a task's own with :meth:`OptionModels.with_runs`) with ``own_runs``
    (the pieces of DynoPlan's own episodes of the improvement rounds, labels indexing
    ``specs``); the regions from ``region_demos`` when given, else ``demos``. The
    options' learned initiation (:attr:`OptionModels.initiation`) is the folder's, when it
    has one (:meth:`OptionModels.without_initiation`: none).

    The goal and regions are fitted as ``settings.fit`` says (on the task's feature maps
    ``settings.fit.goal_features`` and ``region_features`` of ``feature_maps``, when
    named), on the planner states ``state_fn`` makes of the stored observations; its
    stride and option model are the options folder's (properties of the dynamics).
    ``models.json`` records the folder, its dynamics' (and reused initiation's) SHA-256
    and the runs' source (``options_models``).

    Raises:
        DynoplanError: a task option the folder has no dynamics for, a feature map the
            task does not define.
    """
    names = [s.name for s in specs]
    options.check_task(names)
    say = say or (lambda _m: None)
    folder_names = options.option_names
    own = options.models
    fit = replace(settings.fit, stride=own.stride, option_model=own.option_model)
    fit.validate()
    goal_map = named_feature_map(fit.goal_features, feature_maps)
    region_map = named_feature_map(fit.region_features, feature_maps)
    demos_f = relabel(demos, names, folder_names)
    runs = [*options.runs, *relabel(own_runs, names, folder_names)]
    say("goal heuristic")
    started = time.perf_counter()
    goal, goal_report = fit_goal(demos_f, fit, seed, state_fn, goal_map, runs)
    goal_seconds = time.perf_counter() - started
    goal_report["end_gap"] = goal_end_gaps(
        {n: own.dynamics[n] for n in names}, goal, [*runs, *demos_f], state_fn,
        own.stride, seed, to_end=own.option_model == "end")
    regions = None
    region_report: dict[str, Any] | None = None
    if fit.regions:
        say("safety regions")
        shown = demos_f if region_demos is None else relabel(region_demos, names,
                                                             folder_names)
        regions, region_report = fit_option_regions(shown, runs, folder_names, fit, seed,
                                                    state_fn, region_map)
        region_report["options"] = regions.option_names
        for message in region_report["warnings"]:
            warnings.warn(message, DynoplanWarning, stacklevel=2)
    report: dict[str, Any] = {"settings": asdict(fit), "dynamics": own.report.get("dynamics"),
              "goal": goal_report, "regions": region_report, "outcome_initiation": None,
              "constant_dimensions": own.report.get("constant_dimensions"),
              "state_scale": own.report.get("state_scale"), "warnings": []}
    extra = {"options_models": {"folder": str(options.folder.resolve()),
                                "task": own.task, "dynamics_sha256": options.sha256,
                                **({"initiation_sha256": options.initiation_sha256}
                                   if options.initiation is not None else {}),
                                "runs": options.runs_record(),
                                **({"own_runs": {"episodes": len(own_runs),
                                                 "steps": sum(len(e) for e in own_runs)}}
                                   if own_runs else {})}}
    return FittedModels(folder_names, dict(own.dynamics), goal, regions, own.stride, report,
                        fit.regions, task, extra, learned_initiation=options.initiation,
                        seconds={"goal": goal_seconds})


def improve_task(models: FittedModels, options: OptionModels, specs: Sequence[OptionSpec],
                 demos: Sequence[Episode], settings: PipelineSettings, seeds: dict[str, int],
                 name: str, say: Callable[[str], None], env: gym.Env[Any, Any],
                 demonstrator: Any = None, state_fn: ObservationFn = flat_state,
                 feature_maps: Mapping[str, FeatureMap] | None = None,
                 task: Task | None = None, out: Path | None = None,
                 workers: Workers = SERIAL, progress: bool = False,
                 ) -> tuple[FittedModels, list[dict[str, Any]]]:
    """The task's improvement rounds (``settings.improvement``, those of
    :func:`~dynoplan.pipeline.run.run_pipeline`) on ``models`` (:func:`fit_task`'s):
    DynoPlan's own episodes on ``env`` (with ``task``: the task's own DynoPlan, rebuilt
    on ``workers`` from the round's models saved in ``out/improve/``), the
    demonstrator's from where it failed, and after each round :func:`fit_task` again
    with their pieces (``own_runs``) and successes (demonstrations); the dynamics stay
    ``options``'. ``seeds``: the run's streams (:func:`run_seeds` with ``improve``).

    Returns:
        The models ``settings.improve_keep`` says and the learning curve (``[]`` without
        rounds).
    """
    improvement = settings.improvement
    if not improvement.rounds:
        return models, []
    if task is not None and out is None:
        raise DynoplanError("the task's own improvement rounds need an output folder")
    fit_demos, own_runs = list(demos), list[Episode]()
    names = tuple(s.name for s in specs)

    def refit(_: int, own: list[OwnEpisode]) -> FittedModels:
        fit_demos.extend(e.demonstration for e in own if e.demonstration is not None)
        own_runs.extend(piece for e in own for piece in e.pieces)
        return fit_task(options, specs, fit_demos, settings, seeds["fit"], name, say,
                        state_fn, feature_maps, own_runs,
                        None if improvement.regions else demos)

    play: OwnPlay | None = None
    if task is not None and out is not None:
        played = [0]

        def play(fitted: FittedModels, batch: Sequence[EpisodeSeed],
                 explore: float) -> list[OwnEpisode]:
            played[0] += 1
            models_dir = fitted.save(out / "improve" / f"batch-{played[0]}" / "models")
            return task_own_episodes(task, models_dir,
                                     planning_settings(settings.control, fitted), names,
                                     batch, explore, workers, progress)

    return improve_fitted(models, specs, settings, seeds["improve"], lambda _s: env, refit,
                          say, demonstrator, play)


@dataclass
class TaskResult:
    """What :func:`run_task` produced (as
    :class:`~dynoplan.pipeline.generic_stages.PipelineResult`)."""

    options: list[Option]
    planner_options: list[Option]
    models: FittedModels
    demos: list[Episode]
    evaluation: dict[str, dict[str, Any]]
    summary: dict[str, Any]

    @property
    def table(self) -> str:
        return results_table(self.evaluation)


def run_task(env: str | gym.Env[Any, Any], options_models: str | Path,
             options: Sequence[OptionSpec | Option], demonstrator: Any = None,
             demos: Dataset | Sequence[Episode] | None = None,
             settings: PipelineSettings | None = None, out: str | Path | None = None,
             state_fn: StateFn | None = None, success: SuccessFn | None = None,
             progress: bool = False, status: Callable[[str], None] | None = None,
             command: str | None = None, workers: Workers = SERIAL,
             task: Task | None = None, runs: OptionRuns | None = None,
             planner_state: ObservationFn | None = None,
             feature_maps: Mapping[str, FeatureMap] | None = None,
             own_controllers: bool = False, reuse_initiation: bool = False) -> TaskResult:
    """A new task on the option dynamics of ``options_models`` (:func:`load_option_models`):
    record ``settings.demos`` demonstrations (or use ``demos``), fit the goal heuristic
    and regions (:func:`fit_task`), evaluate the controllers; arguments as
    :func:`~dynoplan.pipeline.run.run_pipeline` (``settings.exploration_*`` are not used:
    nothing is explored). The improvement rounds (``settings.improve*``, as
    :func:`~dynoplan.pipeline.run.run_pipeline`'s, with the same defaults: one round of
    DynoPlan's own episodes, exploring ones and the demonstrator's where it failed) refit
    the goal heuristic and the regions on the task's own episodes; the dynamics stay the
    folder's. With ``own_controllers`` the task's DynoPlan plays them (on ``workers``, its
    models of each round saved in ``out/improve/``); ``settings.improve = 0``: the task
    learns from its demonstrations alone.

    Args:
        runs: the task's own option runs (:func:`read_option_runs`: a dataset folder such
            as a ``dynoplan pipeline`` run's ``transitions/`` on this task, a dataset, or
            episodes; labels name or index the options folder's options), used in place of
            the folder's runs for the goal heuristic and the regions; ``None``: the
            folder's.
        planner_state: the planner state of an observation when the options act on the
            environment's observations but the models read states made from them (the
            environment is not wrapped; every stored observation goes through it);
            ``None``: the observation flattened (or ``state_fn``'s wrapped environment).
        feature_maps: the task's named feature maps, for ``settings.fit.goal_features``
            and ``region_features`` and to read the options folder's models.
        own_controllers: evaluate the task's own controllers
            (:meth:`~dynoplan.pipeline.task.Task.make_runner`, rebuilt from the saved
            models folder) on one worker as on several (needs ``task`` and ``out``);
            ``settings.controllers`` then names them.
        reuse_initiation: keep the options' initiation learned from their own outcome
            runs (:attr:`OptionModels.initiation`) when the folder has one, intersected
            with the task's regions; off by default: on the gear's downstream task it
            was no better on two seeds of three (``docs/transfer.md``).

    ``summary["task_fit"]`` says what the new task needed: its demonstrations (episodes,
    steps), the seconds to record them and to fit its models (``fit_seconds``: the goal
    heuristic, its end gaps on the dynamics and the regions; ``goal_fit_seconds``: the
    goal heuristic's fit alone, of the models kept), which options' dynamics it reused
    (and whether their learned initiation, ``reused_initiation``),
    which option runs it was fitted with (``option_runs``) and, with improvement rounds,
    their episodes and seconds (``improvement``: ``own_episodes``, ``demonstrator_episodes``,
    ``seconds``); ``summary["improvement"]`` is the learning curve.

    Raises:
        DynoplanError: a task option the folder has no dynamics for, a planner state of
            another size, option runs :func:`read_option_runs` refuses, and what
            :func:`~dynoplan.pipeline.run.run_pipeline` refuses.
    """
    from dynoplan.pipeline.collect import make_env

    settings = settings or PipelineSettings()
    settings.validate()
    if workers.parallel and (task is None or out is None or state_fn is not None
                             or success is not None):
        raise DynoplanError("a task on several workers needs a task and an output folder; "
                            "the success function and state_fn come from the task")
    if own_controllers and (task is None or out is None):
        raise DynoplanError("the task's own controllers need the task and an output folder "
                            "(they are rebuilt from the saved models)")
    observed: ObservationFn = planner_state or flat_state
    clock = StageClock(status)
    say = clock.switch
    started = time.perf_counter()
    say("options")
    option_models = load_option_models(options_models, feature_maps, observed)
    environment = task_env(make_env(env) if isinstance(env, str) else env, success, state_fn)
    specs = [as_spec(o) for o in options]
    names = [s.name for s in specs]
    option_models.check_task(names)
    seeds = run_seeds(settings.seed, settings.improve > 0)
    state_dim = probe_options(environment, options, observed, seeds["demos"])
    option_models.check_task(names, state_dim)
    if runs is not None:
        option_models = option_models.with_runs(runs, observed)
    if not reuse_initiation:
        option_models = option_models.without_initiation()
    folder = ensure_writable_dir(out) if out is not None else None
    known = controller_names(specs, demonstrator is not None)
    unknown = [c for c in settings.controllers or () if c not in known]
    if own_controllers and not settings.controllers:
        raise DynoplanError("name the task's own controllers to evaluate "
                            "(settings.controllers)")
    if unknown and not own_controllers:
        raise DynoplanError(f"unknown controller(s) {', '.join(unknown)} (known: "
                            f"{', '.join(known)})")
    t0 = time.perf_counter()
    if demos is not None:
        demo_episodes = demos_from_dataset(demos, names)
    elif demonstrator is not None:
        say("demonstrations")
        demo_episodes = record_demonstrations(environment, specs, demonstrator, settings.demos,
                                              seeds["demos"], progress=progress)
    else:
        raise DynoplanError("give a demonstrator or recorded demonstrations (demos=...)")
    demo_seconds = time.perf_counter() - t0
    t0 = time.perf_counter()
    name = task.name if task is not None else (
        environment.spec.id if environment.spec is not None else "")
    models = fit_task(option_models, specs, demo_episodes, settings, seeds["fit"], name, say,
                      observed, feature_maps)
    fit_seconds = time.perf_counter() - t0
    t0 = time.perf_counter()
    models, curve = improve_task(models, option_models, specs, demo_episodes, settings,
                                 seeds, name, say, environment, demonstrator, observed,
                                 feature_maps, task if own_controllers else None, folder,
                                 workers, progress)
    improvement_seconds = time.perf_counter() - t0
    run_options, planner_options = models.build(specs)
    admissible, notes, evaluation = evaluate_fitted(
        environment, models, run_options, planner_options, demo_episodes, settings,
        seeds["evaluation"], folder, (), say, progress, workers, task, demonstrator,
        state_fn=observed, own_controllers=own_controllers)
    task_fit = {
        "options_models": str(option_models.folder),
        "reused_dynamics": names,
        "reused_initiation": option_models.initiation is not None,
        "option_runs": option_models.runs_record(),
        "demonstrations": len(demo_episodes),
        "demonstration_steps": sum(len(e) for e in demo_episodes),
        "demonstration_seconds": demo_seconds,
        "fit_seconds": fit_seconds,
        "goal_fit_seconds": models.seconds["goal"],
        **({"improvement": {
            "own_episodes": sum(c["episodes"] + c.get("explored_episodes", 0)
                                for c in curve),
            "demonstrator_episodes": sum(c.get("demonstrator_episodes", 0) for c in curve),
            "seconds": improvement_seconds}} if curve else {}),
    }
    region_warnings = (models.report.get("regions") or {}).get("warnings", [])
    summary = {
        "dynoplan_version": __version__,
        "env_id": environment.spec.id if environment.spec is not None else None,
        "state_dim": state_dim,
        "options": names,
        "settings": jsonable(asdict(settings)),
        "seeds": seeds,
        "task_fit": task_fit,
        "demonstrations": {"episodes": len(demo_episodes),
                           "steps": sum(len(e) for e in demo_episodes)},
        "models": models.report,
        "admissibility": admissible,
        "warnings": [*region_warnings, *notes],
        "controllers": evaluation,
        "composition_ratio": composition_ratio(evaluation),
        **({"improvement": curve} if curve else {}),
        "stage_seconds": clock.rounded(3),
        "seconds": time.perf_counter() - started,
        "command": command,
    }
    if folder is not None:
        _write(folder, environment, names, demo_episodes, summary, settings)
    return TaskResult(run_options, planner_options, models, demo_episodes, evaluation, summary)


def _write(folder: Path, env: gym.Env[Any, Any], names: list[str], demos: list[Episode],
           summary: dict[str, Any], settings: PipelineSettings) -> None:
    env_id = env.spec.id if env.spec is not None else None
    slug = "".join(c if c.isalnum() or c in "-_" else "-" for c in (env_id or "env"))
    write_dataset(folder / "demos", demos,
                  DatasetMetadata(f"dynoplan/{slug}/task-demos-v0", env_id=env_id,
                                  option_names=names, seed=settings.seed))
    write_json(folder / "summary.json", summary)
    fit = summary["task_fit"]
    runs = fit["option_runs"]
    source = f"of `{runs['source']}`" if runs["source"] else "given in memory"
    runs_text = (f" and {runs['episodes']} option runs ({runs['steps']} steps, {source})"
                 if runs["episodes"] else "")
    command = summary.get("command")
    head = f"Produced by `{command}`" if command else "Produced by run_task"
    write_text(folder / "results.md",
               f"{head} ({settings.episodes} seeded episodes per controller, seed "
               f"{settings.seed}).\n\n"
               f"The option dynamics of `{fit['options_models']}`, unchanged; this task's "
               f"goal heuristic{' and regions' if settings.fit.regions else ''} from "
               f"{fit['demonstrations']} demonstrations ({fit['demonstration_steps']} steps, "
               f"recorded in {fit['demonstration_seconds']:.1f} s){runs_text}, fitted in "
               f"{fit['fit_seconds']:.1f} s.\n\n"
               f"{results_table(summary['controllers'])}\n\n"
               "Which options each controller ran (share of its environment steps):\n\n"
               f"{option_share_table(summary['controllers'])}\n\n"
               "Where each option may start (share of states inside its initiation set):"
               f"\n\n{admissibility_table(summary['admissibility'])}\n"
               + "".join(f"\n- warning: {w}" for w in summary["warnings"]))


__all__ = ["RUNS_FOLDER", "OptionModels", "OptionRuns", "TaskResult", "fit_task",
           "improve_task", "load_option_models", "read_option_runs", "relabel", "run_task"]
