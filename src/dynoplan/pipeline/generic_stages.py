"""The generic stages of a pipeline run (:class:`GenericStages`) on a user's environment and
options, what they produce (:class:`PipelineResult`), and the stages after a fit that
every run shares (:func:`evaluate_fitted`); :func:`~dynoplan.pipeline.run.run_pipeline`
runs them in the one order."""

import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from dynoplan import __version__
from dynoplan.adapters.spec import OptionSpec, as_spec
from dynoplan.control.controller import flat_state
from dynoplan.data.dataset import Dataset, write_dataset
from dynoplan.data.episodes import OPTION_KEY, Episode
from dynoplan.data.metadata import DatasetMetadata
from dynoplan.errors import DynoplanError, DynoplanWarning
from dynoplan.io import write_json, write_text
from dynoplan.options.option import Option
from dynoplan.parallel import SERIAL, Workers
from dynoplan.pipeline.admissibility import admissibility, admissibility_table, start_states
from dynoplan.pipeline.collect import (
    Detour,
    ObservationFn,
    collect_transitions,
    demonstrations_at,
    make_env,
    probe_options,
    record_demonstrations,
    start_choices,
    without_detour,
)
from dynoplan.pipeline.diagnostics import (
    episode_history_warning,
    no_start_warning,
    seeded_reset_warning,
    sole_admissible_warnings,
    weak_dynamics_warnings,
)
from dynoplan.pipeline.evaluate import (
    DYNOPLAN,
    composition_ratio,
    controller_names,
    evaluate_controllers,
    learned_regions,
    make_controller,
    option_share_table,
    planning_settings,
    results_table,
)
from dynoplan.pipeline.fit import (
    DynamicsFitter,
    FittedModels,
    episode_states,
    fit_models,
)
from dynoplan.pipeline.gym_task import StateFn, SuccessFn, task_env
from dynoplan.pipeline.improve import (
    OwnEpisode,
    improvement_rounds,
    learning_curve_text,
    own_episodes,
)
from dynoplan.pipeline.run_settings import (
    PipelineSettings,
    detours_seed,
    jsonable,
    run_seeds,
    starts_seed,
)
from dynoplan.pipeline.takeover import demonstrations_after
from dynoplan.pipeline.task import PipelineRun, Task
from dynoplan.seeding import EpisodeSeed, episode_seeds


@dataclass
class PipelineResult:
    """What :func:`~dynoplan.pipeline.run.run_pipeline` produced.

    Attributes:
        options: the options as the controller runs them (learned dynamics, regions).
        planner_options: the same options as the planner sees them.
        models: the learned models.
        demos: the demonstrations (option and progress labels).
        transitions: the exploration episodes (option labels).
        evaluation: one summary per controller (``success_rate``, ...).
        summary: the content of ``summary.json``.
    """

    options: list[Option]
    planner_options: list[Option]
    models: FittedModels
    demos: list[Episode]
    transitions: list[Episode]
    evaluation: dict[str, dict[str, Any]]
    summary: dict[str, Any]

    @property
    def table(self) -> str:
        """The evaluation as a markdown table."""
        return results_table(self.evaluation)

    @property
    def admissibility_table(self) -> str:
        """Where each option may start, as a markdown table
        (:func:`~dynoplan.pipeline.admissibility.admissibility`)."""
        return admissibility_table(self.summary["admissibility"])


def _env_id(env: gym.Env[Any, Any]) -> str | None:
    return env.spec.id if env.spec is not None else None


def demos_from_dataset(dataset: Dataset | Sequence[Episode], option_names: Sequence[str],
                       what: str = "demonstration") -> list[Episode]:
    """Demonstrations (or, ``what="run"``, option runs) to fit from; labels are mapped
    from the dataset's option names onto ``option_names``.

    Raises:
        DynoplanError: no episodes, an episode without option labels, a dataset option
            name that is not one of ``option_names`` (each message says ``what``).
    """
    episodes = list(dataset)
    if not episodes:
        raise DynoplanError(f"no {what}s given")
    names = list(option_names)
    mapping: np.ndarray | None = None
    if isinstance(dataset, Dataset) and dataset.metadata.option_names:
        unknown = [n for n in dataset.metadata.option_names if n not in names]
        if unknown:
            raise DynoplanError(
                f"the {what}s' option names {unknown} are not among the options "
                f"({', '.join(names)})")
        mapping = np.array([names.index(n) for n in dataset.metadata.option_names])
    out = []
    for index, episode in enumerate(episodes):
        labels = episode.infos.get(OPTION_KEY)
        if labels is None:
            raise DynoplanError(
                f"{what} {index} has no option labels (infos['{OPTION_KEY}']): the "
                "regions and dynamics need the option that chose every action")
        if mapping is not None:
            if labels.size and labels.max() >= len(mapping):
                raise DynoplanError(f"{what} {index}: option label {int(labels.max())} "
                                    f"has no name")
            infos = dict(episode.infos)
            infos[OPTION_KEY] = mapping[labels]
            episode = Episode(episode.observations, episode.actions, episode.rewards,
                              episode.terminations, episode.truncations, infos, episode.seed)
        elif labels.size and labels.max() >= len(names):
            raise DynoplanError(
                f"{what} {index}: option label {int(labels.max())} but only "
                f"{len(names)} options")
        out.append(episode)
    return out


def evaluate_fitted(environment: gym.Env[Any, Any], models: FittedModels,
                    run_options: Sequence[Option], planner_options: Sequence[Option],
                    demo_episodes: Sequence[Episode], settings: PipelineSettings,
                    evaluation_seed: int, folder: Path | None, notes: Sequence[str],
                    say: Callable[[str], None], progress: bool, workers: Workers,
                    task: Task | None, demonstrator: Any, later_notes: Sequence[str] = (),
                    stacklevel: int = 3, state_fn: ObservationFn = flat_state,
                    own_controllers: bool = False,
                    ) -> tuple[dict[str, Any], list[str], dict[str, dict[str, Any]]]:
    """The stages after a fit, the same for every run: where the options may start (its
    notes, with ``notes``, as warnings, which point ``stacklevel`` frames up: at the
    caller of the run), the models saved to ``folder/models`` (when given) and every
    controller on the evaluation episodes. ``state_fn``: the planner state of an
    observation of ``environment`` (the start states); ``own_controllers``: the task's
    controllers (:func:`~dynoplan.pipeline.evaluate.evaluate_controllers`).

    Returns:
        ``(admissibility, notes, evaluation)``:
        :func:`~dynoplan.pipeline.admissibility.admissibility`'s shares, ``notes`` and its
        notes (every warning given), and
        :func:`~dynoplan.pipeline.evaluate.evaluate_controllers`' summaries.
    """
    say("admissibility")
    starts = start_states(environment, evaluation_seed, settings.episodes, state_fn)
    admissible, where = admissibility(run_options, starts, demo_episodes, state_fn)
    stuck = no_start_warning(run_options, starts)
    notes = [*notes, *where, *([stuck] if stuck else []), *later_notes]
    for note in notes:
        warnings.warn(note, DynoplanWarning, stacklevel=stacklevel)
    models_dir = models.save(folder / "models") if folder is not None else None
    say("evaluation")
    evaluation = evaluate_controllers(environment, run_options, models.goal,
                                      planning_settings(settings.control, models),
                                      settings.episodes, evaluation_seed, planner_options,
                                      settings.controllers, progress, workers, task,
                                      models_dir, learned_regions(models), demonstrator,
                                      models.state_scale,
                                      fresh_env=None if task is None else task.make_env,
                                      own_controllers=own_controllers)
    say("")
    return admissible, notes, evaluation


OwnPlay = Callable[[FittedModels, Sequence[EpisodeSeed], float], list[OwnEpisode]]
"""How a run plays DynoPlan's own episodes on some models (``improvement_rounds``'
``play``)."""


def improve_fitted(models: FittedModels, specs: Sequence[OptionSpec],
                   settings: PipelineSettings, seed: int,
                   env_of: Callable[[EpisodeSeed], gym.Env[Any, Any]],
                   refit: Callable[[int, list[OwnEpisode]], FittedModels],
                   say: Callable[[str], None], demonstrator: Any = None,
                   play: OwnPlay | None = None
                   ) -> tuple[FittedModels, list[dict[str, Any]]]:
    """The improvement rounds (``settings.improvement``,
    :func:`~dynoplan.pipeline.improve.improvement_rounds`) of a run on ``specs``: DynoPlan
    as the evaluation builds it plays its own episodes here, each on ``env_of(seed)``,
    on the seed stream ``seed`` (``run_seeds(...)["improve"]``); ``refit`` fits again on
    them; the ``demonstrator`` (when given) runs from the starts where DynoPlan failed, or
    takes those episodes over (``settings.improve_takeover``). ``play``: how the run plays
    its own episodes instead (a task's own controllers, on workers).

    Returns:
        The models ``settings.improve_keep`` says and the learning curve.
    """
    improvement = settings.improvement

    def own_play(fitted: FittedModels, seeds: Sequence[EpisodeSeed],
                 explore: float) -> list[OwnEpisode]:
        if not seeds:
            return []
        run_options, planner_options = fitted.build(specs)
        controller = make_controller(DYNOPLAN, run_options, fitted.goal,
                                     planning_settings(settings.control, fitted),
                                     planner_options, env_of(seeds[0]).action_space,
                                     fitted.state_scale)
        return own_episodes(env_of, controller, seeds, explore,
                            fitted.goal if improvement.takeover else None)

    def demonstrate(seeds: Sequence[EpisodeSeed]) -> list[Episode]:
        return [d for s in seeds  # the demonstrator is reset at every episode
                for d in demonstrations_at(env_of(s), specs, demonstrator, [s])]

    def take_over(seeds: Sequence[EpisodeSeed], own: Sequence[OwnEpisode]
                  ) -> tuple[list[Episode], int]:
        takeovers = [e.takeover for e in own]
        if any(t is None for t in takeovers):
            raise DynoplanError("a failed own episode without its takeover point")
        return demonstrations_after(env_of, specs, demonstrator, seeds,
                                    [t for t in takeovers if t is not None])

    seeds = episode_seeds(seed, improvement.seeds) if improvement.rounds else []
    asks = demonstrator is not None
    return improvement_rounds(models, improvement, seeds, play or own_play, refit, say,
                              demonstrate if asks else None, take_over if asks else None)


class GenericStages:
    """The stages (:class:`~dynoplan.pipeline.task.TaskStages`) of a run on a user's
    environment and options: the demonstrator's episodes (or the given ones), exploration
    episodes of random options, :func:`~dynoplan.pipeline.fit.fit_models`, the
    improvement rounds, the default controllers; the result is a
    :class:`PipelineResult`. The arguments are :func:`~dynoplan.pipeline.run.run_pipeline`'s.

    Raises:
        DynoplanError: invalid ``settings``, or several workers without a task, an output
            folder and the default fitter, success function and ``state_fn`` (checked
            here, before any work).
    """

    def __init__(self, env: str | gym.Env[Any, Any], options: Sequence[OptionSpec | Option],
                 demonstrator: Any = None, demos: Dataset | Sequence[Episode] | None = None,
                 settings: PipelineSettings | None = None, state_fn: StateFn | None = None,
                 success: SuccessFn | None = None, fitter: DynamicsFitter | None = None,
                 command: str | None = None, task: Task | None = None,
                 out: str | Path | None = None, workers: Workers = SERIAL,
                 disturbed_env: gym.Env[Any, Any] | None = None) -> None:
        self.settings = settings or PipelineSettings()
        self.settings.validate()
        if self.settings.improve_disturbed > 0.0 and self.settings.improve > 0 \
                and disturbed_env is None:
            raise DynoplanError("improve_disturbed rehearses the improvement rounds under the "
                                "task's disturbance: give the disturbed environment "
                                "(disturbed_env=..., --disturbance on the command line)")
        if workers.parallel and (task is None or out is None or fitter is not None
                                 or state_fn is not None or success is not None):
            raise DynoplanError("the pipeline on several workers needs a task and an output "
                                "folder, and the default dynamics fitter; the success "
                                "function and state_fn come from the task (workers rebuild "
                                "the controllers from files)")
        self.env, self.options, self.demonstrator, self.given = env, options, demonstrator, demos
        self.state_fn, self.success, self.fitter = state_fn, success, fitter
        self.command, self.task, self.disturbed_env = command, task, disturbed_env
        self.starts: Episode | None = None  # the labelled start states (region_starts)

    def prepare(self, run: PipelineRun) -> None:
        """The environment made and the options probed in it; the controllers checked."""
        self.started = time.perf_counter()
        env = self.env
        self.environment = task_env(make_env(env) if isinstance(env, str) else env,
                                    self.success, self.state_fn)
        self.disturbed = (None if self.disturbed_env is None else
                          task_env(self.disturbed_env, self.success, self.state_fn))
        self.specs = [as_spec(o) for o in self.options]
        self.seeds = run_seeds(self.settings.seed, self.settings.improve > 0)
        self.state_dim = probe_options(self.environment, self.options, flat_state,
                                       self.seeds["demos"])
        first, second = (s.env_seed for s in episode_seeds(self.seeds["evaluation"], 2))
        reset_note = seeded_reset_warning(self.environment, first)
        history_note = (episode_history_warning(self.environment, first, second)
                        if reset_note is None else None)
        self.notes = [n for n in (reset_note, history_note) if n is not None]
        self.names = [s.name for s in self.specs]
        known = controller_names(self.specs, self.demonstrator is not None)
        unknown = [c for c in self.settings.controllers or () if c not in known]
        if unknown:  # before any work
            raise DynoplanError(f"unknown controller(s) {', '.join(unknown)} (known: "
                                f"{', '.join(known)})")

    def demonstrations(self, run: PipelineRun) -> list[Episode]:
        """The given demonstrations, else ``settings.demos`` of the demonstrator's."""
        if self.given is not None:
            self.demos = demos_from_dataset(self.given, self.names)
        elif self.demonstrator is not None:
            run.clock.switch("demonstrations")
            self.demos = record_demonstrations(self.environment, self.specs, self.demonstrator,
                                               self.settings.demos, self.seeds["demos"],
                                               progress=run.progress)
            if self.settings.demo_detours:
                run.clock.switch("demonstrations with detours")
                self.demos = [without_detour(d) for d in self.demos]
                self.demos += record_demonstrations(
                    self.environment, self.specs,
                    Detour.around(self.demonstrator, self.specs, self.demos),
                    self.settings.demo_detours, detours_seed(self.seeds["demos"]),
                    progress=run.progress)
        else:
            raise DynoplanError("give a demonstrator or recorded demonstrations (demos=...)")
        if self.settings.region_starts and self.demonstrator is not None:
            run.clock.switch("start states")
            self.starts = start_choices(self.environment, self.demonstrator, self.names,
                                        starts_seed(self.seeds["demos"]),
                                        self.settings.region_starts)
        return self.demos

    def _region_starts(self) -> list[Episode]:
        """The labelled start states the regions are widened by, when there are any
        (``settings.region_starts``)."""
        return [] if self.starts is None else [self.starts]

    def option_runs(self, run: PipelineRun, demos: list[Episode]) -> list[Episode]:
        """Exploration episodes of randomly chosen options
        (:func:`~dynoplan.pipeline.collect.collect_transitions`)."""
        run.clock.switch("option transitions")
        settings = self.settings
        self.transitions = collect_transitions(
            self.environment, self.specs, settings.exploration_episodes,
            self.seeds["exploration"], flat_state, settings.exploration_option_steps,
            progress=run.progress, demos=demos, branches=settings.exploration_branches)
        return self.transitions

    def fit(self, run: PipelineRun, demos: list[Episode], runs: list[Episode]
            ) -> FittedModels:
        """:func:`~dynoplan.pipeline.fit.fit_models`."""
        self.name = (self.task.name if self.task is not None
                     else _env_id(self.environment) or "")
        return fit_models(self.specs, runs, demos, self.settings.fit, self.seeds["fit"],
                          flat_state, self.fitter, run.clock.switch, self.name,
                          region_starts=self._region_starts())

    def after_fit(self, run: PipelineRun, models: FittedModels) -> FittedModels:
        """``settings.improve`` rounds of DynoPlan's own episodes, refitted on after each
        (:func:`improve_fitted`); the models ``settings.improve_keep`` says (the last, or
        the best on their own episodes)."""
        settings = self.settings
        improvement = settings.improvement
        fit_demos, fit_transitions = list(self.demos), list(self.transitions)

        def env(seed: EpisodeSeed) -> gym.Env[Any, Any]:
            """Where own episode ``seed`` runs: under the task's disturbance when the
            rounds rehearse it there."""
            return (self.disturbed if self.disturbed is not None
                    and improvement.rehearses(seed) else self.environment)

        def refit(_: int, own: list[OwnEpisode]) -> FittedModels:
            fit_demos.extend(e.demonstration for e in own if e.demonstration is not None)
            fit_transitions.extend(piece for e in own for piece in e.pieces)
            return fit_models(self.specs, fit_transitions, fit_demos, settings.fit,
                              self.seeds["fit"], flat_state, self.fitter, run.clock.switch,
                              self.name,
                              region_demos=fit_demos if improvement.regions else self.demos,
                              region_starts=self._region_starts())

        models, self.curve = improve_fitted(models, self.specs, settings,
                                            self.seeds.get("improve", 0), env, refit,
                                            run.clock.switch, self.demonstrator)
        self.run_options, self.planner_options = models.build(self.specs)
        return models

    def evaluate(self, run: PipelineRun, models: FittedModels) -> dict[str, dict[str, Any]]:
        """:func:`evaluate_fitted`: where the options may start, the models saved, every
        controller's summary."""
        self.models = models
        demo_states = np.concatenate([episode_states(e, flat_state)[:-1] for e in self.demos])
        self.admissible, self.notes, evaluation = evaluate_fitted(
            self.environment, models, self.run_options, self.planner_options, self.demos,
            self.settings, self.seeds["evaluation"], run.out, self.notes, run.clock.switch,
            run.progress, run.workers, self.task, self.demonstrator,
            [*weak_dynamics_warnings(models.report["dynamics"]),
             *sole_admissible_warnings(self.run_options, demo_states)],
            stacklevel=5)  # the caller of run_pipeline (through run_stages and this)
        return evaluation

    def report(self, run: PipelineRun, evaluation: dict[str, dict[str, Any]]
               ) -> PipelineResult:
        """``summary.json``, ``results.md`` and the datasets written to ``run.out``."""
        models, settings = self.models, self.settings
        region_warnings = (models.report.get("regions") or {}).get("warnings", [])
        summary = {
            "dynoplan_version": __version__,
            "env_id": _env_id(self.environment),
            "state_dim": self.state_dim,
            "options": self.names,
            "settings": jsonable(asdict(settings)),
            "seeds": self.seeds,
            "demonstrations": {"episodes": len(self.demos),
                               "steps": sum(len(e) for e in self.demos)},
            "transitions": {"episodes": len(self.transitions),
                            "steps": sum(len(e) for e in self.transitions)},
            "models": models.report,
            "admissibility": self.admissible,
            "warnings": [*region_warnings, *self.notes],
            "controllers": evaluation,
            "composition_ratio": composition_ratio(evaluation),
            **({"improvement": self.curve} if settings.improve else {}),
            "stage_seconds": run.clock.rounded(3),
            "seconds": time.perf_counter() - self.started,
            "command": self.command,
        }
        if run.out is not None:
            _write_outputs(run.out, self.environment, self.names, self.demos,
                           self.transitions, summary, settings)
        return PipelineResult(self.run_options, self.planner_options, models, self.demos,
                              self.transitions, evaluation, summary)


def _write_outputs(folder: Path, env: gym.Env[Any, Any], names: list[str],
                   demos: list[Episode], transitions: list[Episode],
                   summary: dict[str, Any], settings: PipelineSettings) -> None:
    env_id = _env_id(env)
    try:
        spec_json = env.spec.to_json() if env.spec is not None else None
    except (TypeError, ValueError):  # kwargs that JSON cannot hold
        spec_json = None
    slug = "".join(c if c.isalnum() or c in "-_" else "-" for c in (env_id or "env"))
    for sub, episodes in (("demos", demos), ("transitions", transitions)):
        meta = DatasetMetadata(f"dynoplan/{slug}/{sub}-v0", env_id=env_id, env_spec=spec_json,
                               option_names=names, seed=settings.seed,
                               observation_space=_box_or_none(env.observation_space),
                               action_space=_space_or_none(env.action_space))
        write_dataset(folder / sub, episodes, meta)
    write_json(folder / "summary.json", summary)
    command = summary.get("command")
    head = f"Produced by `{command}`" if command else "Produced by run_pipeline"
    n = settings.episodes
    ratio = summary.get("composition_ratio")
    bar = ("" if ratio is None else
           f"DynoPlan reaches {ratio:.2f} of the demonstrator's success on the same episodes "
           "(the composition ratio).\n\n")
    curve = summary.get("improvement") or []
    if curve:
        bar += learning_curve_text(curve) + "\n\n"
    write_text(folder / "results.md",
               f"{head} ({n} seeded episodes per controller, seed {settings.seed}).\n\n"
               f"{results_table(summary['controllers'])}\n\n{bar}"
               "Which options each controller ran (share of its environment steps):\n\n"
               f"{option_share_table(summary['controllers'])}\n\n"
               "Where each option may start (share of states inside its initiation set):"
               f"\n\n{admissibility_table(summary['admissibility'])}\n"
               + "".join(f"\n- warning: {w}" for w in summary["warnings"]))


def _box_or_none(space: gym.Space[Any]) -> gym.spaces.Box | None:
    return space if isinstance(space, gym.spaces.Box) else None


def _space_or_none(space: gym.Space[Any]) -> gym.spaces.Box | gym.spaces.Discrete | None:
    return space if isinstance(space, gym.spaces.Box | gym.spaces.Discrete) else None


__all__ = ["GenericStages", "OwnPlay", "PipelineResult", "demos_from_dataset", "evaluate_fitted",
           "improve_fitted"]
