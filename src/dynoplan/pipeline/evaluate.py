"""Evaluating controllers built from options: the demonstrator, DynoPlan, each option
alone, random choice.

Every controller runs the same seeded episodes (:func:`~dynoplan.seeding.episode_seeds`),
so the rows of a results table differ only by the controller. The demonstrator (the
user's scripted chain of the options) is the bar: it shows what the options can do when
chained right, and DynoPlan's success is reported as a share of its success
(:func:`composition_ratio`).

Every task's controllers come from one factory, :func:`make_controller`: a
:class:`ControllerVariant` (how it chooses; the names every task has are
:func:`generic_variant`'s), the options, the goal heuristic, the
:class:`~dynoplan.pipeline.control_settings.ControllerSettings` and what the task adds
(:class:`TaskControl`: the gear's planner state, hold, termination rate, safety
constraint, simulator oracle and script).
"""

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np

from dynoplan.adapters.spec import OptionSpec, as_spec
from dynoplan.control.choosers import (
    FixedChoice,
    OptionChooser,
    RandomChoice,
    ScriptedSequence,
)
from dynoplan.control.controller import Controller, EpisodeTrace, flat_state
from dynoplan.errors import DynoplanError
from dynoplan.models.corruption import NoisyDynamics
from dynoplan.models.goal import GoalHeuristic
from dynoplan.options.initiation import Nowhere, RegionModel
from dynoplan.options.option import Option
from dynoplan.options.termination import ConstantTermination
from dynoplan.parallel import SERIAL, Workers
from dynoplan.pipeline.collect import Demonstrator, demonstrator_from, record_episode
from dynoplan.pipeline.control_settings import ControllerSettings
from dynoplan.pipeline.jobs import EpisodeJob, EpisodeRunner, evaluate_many
from dynoplan.pipeline.task import Task
from dynoplan.planning.option_planner import OptionPlanner
from dynoplan.planning.sequence_planner import SequencePlanner
from dynoplan.progress import track
from dynoplan.reports.tables import markdown_table
from dynoplan.safety.constraint import SafetyConstraint
from dynoplan.seeding import EpisodeSeed, episode_seeds
from dynoplan.types import FloatArray

if TYPE_CHECKING:
    from dynoplan.pipeline.fit import FittedModels

DYNOPLAN = "dynoplan"
RANDOM = "random"
DEMONSTRATOR = "demonstrator"
OPTION_PREFIX = "option:"


def run_episodes(env: gym.Env[Any, Any], controller: Controller, seeds: Sequence[EpisodeSeed],
                 description: str, progress: bool = True,
                 reset_options: dict[str, Any] | None = None) -> list[EpisodeTrace]:
    """One trace per seed, in order."""
    return [controller.run(env, s.rng(), seed=s.env_seed, reset_options=reset_options)
            for s in track(seeds, description, total=len(seeds), enabled=progress)]


def quantile_or_none(values: Sequence[float], q: float) -> float | None:
    """The ``q`` quantile (``inverted_cdf``: always an observed value); None if infinite."""
    if not values:
        return None
    v = float(np.quantile(np.asarray(values, dtype=np.float64), q, method="inverted_cdf"))
    return v if np.isfinite(v) else None


def planning_steps_summary(traces: Sequence[EpisodeTrace]) -> dict[str, Any]:
    """Success rate and the distribution of planning steps to reach the goal.

    An episode that never reaches the goal counts as infinitely many planning steps, so a
    quantile that falls on failures is ``None`` (JSON ``null``), not a flattering number.
    """
    steps = [float(t.planning_steps) if t.success else np.inf for t in traces]
    succeeded = [s for s in steps if np.isfinite(s)]
    return {
        "episodes": len(traces),
        "success_rate": float(np.mean([t.success for t in traces])) if traces else 0.0,
        "planning_steps_median": quantile_or_none(steps, 0.5),
        "planning_steps_p90": quantile_or_none(steps, 0.9),
        "planning_steps_max": quantile_or_none(steps, 1.0),
        "planning_steps_mean_of_successes": float(np.mean(succeeded)) if succeeded else None,
        "env_steps_median": float(np.median([t.env_steps for t in traces])) if traces else None,
    }


def controller_names(options: Sequence[Option] | Sequence[OptionSpec],
                     demonstrator: bool = False) -> list[str]:
    """``demonstrator`` (when there is one), ``dynoplan``, then ``option:<name>`` for every
    option, then ``random``."""
    return [*([DEMONSTRATOR] if demonstrator else []), DYNOPLAN,
            *(OPTION_PREFIX + o.name for o in options), RANDOM]


def composition_ratio(rows: Mapping[str, Mapping[str, Any]]) -> float | None:
    """DynoPlan's success rate as a share of the demonstrator's on the same episodes
    (``None`` without both rows, or when the demonstrator never succeeded)."""
    if DYNOPLAN not in rows or DEMONSTRATOR not in rows:
        return None
    bar = float(rows[DEMONSTRATOR]["success_rate"])
    return float(rows[DYNOPLAN]["success_rate"]) / bar if bar > 0 else None


def with_dynamics_noise(options: Sequence[Option], noise: float) -> list[Option]:
    """``options`` with Gaussian noise of std ``noise`` on every learned prediction (the
    dynamics fault; ``noise == 0``: the options as they are)."""
    if noise <= 0:
        return list(options)
    return [replace(o, dynamics=NoisyDynamics(o.dynamics, noise)) for o in options]


def neutral_action(space: gym.Space[Any]) -> FloatArray | None:
    """What a generic task does when no option is admissible: the zero action of a
    ``Box`` space, clipped into its bounds (for a velocity-controlled robot: stand
    still; for a force- or torque-controlled one: coast), held one step at a time until
    an option is admissible again; ``None`` (no neutral action known) for other spaces."""
    if not isinstance(space, gym.spaces.Box):
        return None
    return np.clip(np.zeros(space.shape), space.low, space.high).astype(space.dtype)


PLANNER = "planner"
ORACLE = "oracle"
SCRIPT = "script"
ONE_OPTION = "option"
CHOOSERS = (PLANNER, RANDOM, ORACLE, SCRIPT, ONE_OPTION)
"""How a controller chooses its options (:attr:`ControllerVariant.chooser`)."""


@dataclass(frozen=True)
class ControllerVariant:
    """A controller a task names: how it chooses an option and what it may choose.

    Attributes:
        chooser: one of :data:`CHOOSERS`: ``planner`` (DynoPlan's Eq. 1,
            :class:`~dynoplan.planning.OptionPlanner`, or
            :class:`~dynoplan.planning.SequencePlanner` at ``depth`` > 1), ``random``
            (uniform among the admissible options), ``oracle`` (the task's
            :attr:`TaskControl.oracle`), ``script`` (the task's :attr:`TaskControl.script`,
            each option run until its policy reports it is finished: its termination is
            ignored) or ``option`` (``option`` alone).
        sets: the task's name for the initiation and continuation sets the options are
            built on (the task builds the options before the factory sees them, which
            does not read this): ``own``, the options' own sets as the task builds them
            (a Gymnasium task's), or one of the task's named sets (the gear's
            :data:`~dynoplan.envs.gear.controllers.INITIATION_SETS`).
        end_inside: the planner's rollouts end at their last state inside the option's
            continuation set, whatever the settings say
            (:class:`~dynoplan.planning.OptionPlanner`).
        safe: Eq. 1 is chance-constrained by the task's safety constraint
            (:attr:`TaskControl.constraint`, at ``ControllerSettings.risk_level``).
        never: options never admissible (an ablation: the same models without an
            option's choice).
        replans: the chooser decides again every ``ControllerSettings.replan_every``
            environment steps and the options' terminations are drawn every
            :attr:`TaskControl.termination_every` steps; ``False``: it decides only when
            the option stops, and terminations are drawn every step (a script never
            replans: every call of its chooser is the script's next step).
        option: the option an ``option`` chooser runs.
    """

    chooser: str
    sets: str = "own"
    end_inside: bool = False
    safe: bool = False
    never: tuple[str, ...] = ()
    replans: bool = True
    option: str | None = None

    def __post_init__(self) -> None:
        if self.chooser not in CHOOSERS:
            raise DynoplanError(f"unknown chooser {self.chooser!r}; expected one of "
                                f"{', '.join(CHOOSERS)}")
        if (self.chooser == ONE_OPTION) != (self.option is not None):
            raise DynoplanError("an 'option' chooser names its option, and only it does")
        if self.chooser == SCRIPT and self.replans:
            raise DynoplanError("a script does not replan (replans=False)")


def generic_variant(kind: str, options: Sequence[Option]) -> ControllerVariant:
    """The controllers every task has, by the names of :func:`controller_names`:
    ``dynoplan`` (the planner, replanning), ``random`` and ``option:<name>`` (neither
    replans: the option chosen runs until it stops)."""
    if kind == DYNOPLAN:
        return ControllerVariant(PLANNER)
    if kind == RANDOM:
        return ControllerVariant(RANDOM, replans=False)
    if kind.startswith(OPTION_PREFIX):
        return ControllerVariant(ONE_OPTION, replans=False,
                                 option=kind.removeprefix(OPTION_PREFIX))
    raise DynoplanError(
        f"unknown controller '{kind}' (known: {', '.join(controller_names(options))})")


OracleMaker = Callable[[Sequence[Option], GoalHeuristic, ControllerSettings], OptionChooser]
"""``oracle(options, goal, settings) -> chooser``: a task's simulator oracle over the
controller's options (for example :class:`~dynoplan.planning.SimulatorOracle` at
``settings.oracle_horizon`` and ``settings.oracle_samples``)."""


@dataclass(frozen=True)
class TaskControl:
    """What a task gives the one controller factory (:func:`make_controller`) beyond its
    options, models and settings; the defaults are a Gymnasium task's.

    Attributes:
        state_fn: the planner state of an observation.
        hold_action: the task's action where no option is admissible, when the settings
            name none (``None``: :func:`neutral_action` of the action space).
        termination_every: environment steps between draws of an option's termination
            under a chooser that replans (the rate its learned models step at).
        record_infos: keep every step's ``info`` in the trace (for the task's metrics).
        constraint: the safety constraint of the ``safe`` variants (``None``: the task
            has none).
        oracle: the ``oracle`` chooser's maker (``None``: the task has none).
        script: the ``script`` chooser's options in order (empty: the task has none).
    """

    state_fn: Callable[[Any], FloatArray] = flat_state
    hold_action: Any = None
    termination_every: int = 1
    record_infos: bool = False
    constraint: SafetyConstraint | None = None
    oracle: OracleMaker | None = None
    script: tuple[str, ...] = ()


def make_controller(kind: str | ControllerVariant, options: Sequence[Option],
                    goal: GoalHeuristic, settings: ControllerSettings,
                    planner_options: Sequence[Option] | None = None,
                    action_space: gym.Space[Any] | None = None,
                    state_scale: FloatArray | None = None,
                    task: TaskControl = TaskControl()) -> Controller:
    """The one factory of every task's controllers.

    Args:
        kind: a :class:`ControllerVariant`, or the name of one every task has
            (:func:`generic_variant`: ``dynoplan``, ``random`` or ``option:<name>``).
        options: the options the controller runs (on the sets the variant names).
        goal: the goal heuristic (used by the planner and the oracle).
        planner_options: the options as the planner sees them (same names; they may
            carry multi-step dynamics and per-model-step terminations); default
            ``options``.
        state_scale: ``(state_dim,)`` the spread of every state coordinate over the
            fitted data (``FittedModels.state_scale``), which ``no_effect_share`` and
            ``loop_share`` scale (``None``: neither rule).
        action_space: the environment's; where no option is admissible the controller
            holds with ``settings.hold_action``, else the task's
            (``task.hold_action``), else :func:`neutral_action` of it (unless
            ``settings.hold`` is off).
        task: what the task adds (its planner state, hold, termination rate, safety
            constraint, oracle and script).

    Raises:
        DynoplanError: an unknown controller name, or a variant that needs what the task
            does not give (a safety constraint, an oracle, a script).
    """
    settings.validate()
    variant = kind if isinstance(kind, ControllerVariant) else generic_variant(kind, options)

    def as_run(o: Option) -> Option:
        if o.name in variant.never:
            o = replace(o, initiation=Nowhere(), continuation=None, fallback=None)
        if variant.chooser == SCRIPT:
            o = replace(o, termination=ConstantTermination(0.0))
        return replace(o, start_where_done=settings.start_where_done,
                       fallback=o.fallback if settings.fallback_own_sets else None,
                       failure=o.failure if settings.score_failures else None)

    options = [as_run(o) for o in options]
    if planner_options is not None:
        planner_options = [as_run(o) for o in planner_options]
    hold = hold_action(settings, action_space, task.hold_action)
    chooser: OptionChooser
    if variant.chooser == PLANNER:
        if variant.safe and task.constraint is None:
            raise DynoplanError("a safe controller needs the task's safety constraint")
        # depth 1 is OptionPlanner itself (the same decisions to the bit)
        planner = partial(OptionPlanner, widen_without_gain=settings.fallback_own_sets
                          and settings.fallback_without_gain,
                          regions_without_gain=settings.regions_without_gain) \
            if settings.depth == 1 \
            else partial(SequencePlanner, depth=settings.depth)
        chooser = planner(with_dynamics_noise(planner_options or options,
                                              settings.dynamics_noise), goal,
                          horizon=settings.horizon, samples=settings.samples,
                          risk=settings.risk, epistemic=settings.epistemic,
                          constraint=task.constraint if variant.safe else None,
                          risk_level=settings.risk_level,
                          end_inside=settings.end_inside or variant.end_inside,
                          # holding is a way to wait only where there is a hold
                          fallback_must_gain=settings.fallback_own_sets
                          and settings.fallback_must_gain and hold is not None)
    elif variant.chooser == ORACLE:
        if task.oracle is None:
            raise DynoplanError("an oracle controller needs the task's oracle")
        chooser = task.oracle(options, goal, settings)
    elif variant.chooser == RANDOM:
        chooser = RandomChoice(options)
    elif variant.chooser == SCRIPT:
        if not task.script:
            raise DynoplanError("a scripted controller needs the task's script")
        chooser = ScriptedSequence(options, task.script)
    else:
        assert variant.option is not None
        chooser = FixedChoice(options, variant.option)
    return Controller(options, chooser, state_fn=task.state_fn,
                      max_decisions=settings.max_decisions,
                      max_option_steps=settings.max_option_steps,
                      replan_every=settings.replan_every if variant.replans else None,
                      margin=settings.margin, commit=settings.commit, hold_action=hold,
                      record_infos=task.record_infos,
                      termination_every=task.termination_every if variant.replans else 1,
                      no_effect_tolerance=no_effect_tolerance(settings, state_scale),
                      loop_tolerance=None if settings.loop_share is None or state_scale is None
                      else settings.loop_share * np.asarray(state_scale, dtype=np.float64),
                      stall_progress=settings.stall_progress,
                      progress=goal_means(goal) if settings.loop_progress else None,
                      fallback_goes_on=settings.fallback_own_sets and settings.fallback_goes_on,
                      stall_goal=goal_means(goal) if settings.stall_forgets else None)


def goal_means(goal: GoalHeuristic) -> Callable[[FloatArray], FloatArray]:
    """The goal heuristic's mean at states, ``(batch, state_dim) -> (batch,)``."""
    return lambda states: goal.mean_std(states)[0]


def no_effect_tolerance(settings: ControllerSettings, state_scale: FloatArray | None
                        ) -> float | FloatArray | None:
    """The controller's no-effect tolerance: ``settings.no_effect_tolerance``, else
    ``no_effect_share`` times ``state_scale`` (one per coordinate), else ``None``."""
    if settings.no_effect_tolerance is not None:
        return settings.no_effect_tolerance
    if settings.no_effect_share is None or state_scale is None:
        return None
    return settings.no_effect_share * np.asarray(state_scale, dtype=np.float64)


def planning_settings(settings: ControllerSettings, models: "FittedModels"
                      ) -> ControllerSettings:
    """The settings a controller on ``models`` plans with: option models (``"end"``)
    predict where an option ends in one model step, so the horizon is one step."""
    return replace(settings, horizon=1) if models.option_model == "end" else settings


def hold_action(settings: ControllerSettings, action_space: gym.Space[Any] | None,
                task_hold: Any = None) -> Any:
    """The action a controller holds with (``None``: it ends the episode):
    ``settings.hold_action``, else the task's own ``task_hold``, else
    :func:`neutral_action` of ``action_space``."""
    if not settings.hold:
        return None
    if isinstance(settings.hold_action, tuple):
        return np.asarray(settings.hold_action)
    if settings.hold_action is not None:
        return settings.hold_action
    if task_hold is not None:
        return task_hold
    return None if action_space is None else neutral_action(action_space)


@dataclass(frozen=True)
class EpisodeRecord:
    """What one episode of one controller did: small and picklable (what a worker sends
    back), the one record of an evaluated episode for every task, and all that
    :func:`summarize` (or a task's own table) reads.

    Attributes:
        env_seed: the seed ``env.reset`` got.
        success, env_steps, total_reward: the episode's outcome.
        planning_steps: decisions that ran an option.
        switches: changes of option between consecutive such decisions.
        out_of_region_starts: options started outside their initiation set.
        no_admissible: decisions with no admissible option (holds).
        decision_ms: every decision's latency (ms), holds included.
        option_steps: ``(name, env steps it ran)`` per option that ran, sorted by name.
        options: every decision's option in order (``"hold"`` where none ran).
        task_metrics: what the task measures beyond these (JSON values; the gear: the
            human's behaviour, contacts, the smallest robot-human distance).
    """

    env_seed: int
    success: bool
    env_steps: int
    total_reward: float
    planning_steps: int
    switches: int
    out_of_region_starts: int
    no_admissible: int
    decision_ms: tuple[float, ...]
    option_steps: tuple[tuple[str, int], ...]
    options: tuple[str, ...] = ()
    task_metrics: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def of(cls, trace: EpisodeTrace, env_seed: int,
           task_metrics: dict[str, Any] | None = None,
           out_of_region_starts: int | None = None) -> "EpisodeRecord":
        """The record of a controller's episode.

        Args:
            task_metrics: the task's own measurements of it.
            out_of_region_starts: counted by the caller (for example against regions the
                controller did not use); default: as the controller saw its options.
        """
        ran: dict[str, int] = {}
        for d in trace.decisions:
            if d.option is not None:
                ran[d.option] = ran.get(d.option, 0) + d.steps
        outside = (trace.out_of_region_starts if out_of_region_starts is None
                   else out_of_region_starts)
        return cls(env_seed, trace.success, trace.env_steps, trace.total_reward,
                   trace.planning_steps, trace.switches, outside, trace.no_admissible,
                   tuple(1e3 * x for x in trace.latencies_s), tuple(sorted(ran.items())),
                   tuple(d.option or "hold" for d in trace.decisions),
                   dict(task_metrics or {}))


def summarize(records: Sequence[EpisodeRecord]) -> dict[str, Any]:
    """Success rate, time to success, return and decision statistics of some episodes.

    ``steps_to_success_*`` are over successful episodes only (``None`` if there are
    none); ``switches`` and ``no_admissible`` (holds) are totals over the episodes;
    latencies are per decision, in milliseconds; ``option_share`` is the fraction of all
    environment steps each option ran (options that never ran are left out). A task's
    own table adds its columns to these (the gear's ``results.csv``).
    """
    if not records:
        raise DynoplanError("no episodes to summarise")
    successes = [r.env_steps for r in records if r.success]
    latencies = [x for r in records for x in r.decision_ms]
    ran: dict[str, int] = {}
    for r in records:
        for name, steps in r.option_steps:
            ran[name] = ran.get(name, 0) + steps
    total = max(sum(ran.values()), 1)
    return {
        "episodes": len(records),
        "success_rate": float(np.mean([r.success for r in records])),
        "steps_to_success_mean": float(np.mean(successes)) if successes else None,
        "steps_to_success_median": float(np.median(successes)) if successes else None,
        "return_mean": float(np.mean([r.total_reward for r in records])),
        "env_steps_mean": float(np.mean([r.env_steps for r in records])),
        "decisions_mean": float(np.mean([r.planning_steps for r in records])),
        "switches_mean": float(np.mean([r.switches for r in records])),
        "switches": int(sum(r.switches for r in records)),
        "out_of_region_starts": int(sum(r.out_of_region_starts for r in records)),
        "no_admissible": int(sum(r.no_admissible for r in records)),
        "latency_ms_p50": quantile_or_none(latencies, 0.5),
        "latency_ms_p95": quantile_or_none(latencies, 0.95),
        "latency_ms_p99": quantile_or_none(latencies, 0.99),
        "option_share": {name: steps / total for name, steps in sorted(ran.items())},
    }


@dataclass
class ControllerRunner:
    """A controller and its environment: runs seeded episodes as :class:`EpisodeRecord`.

    Attributes:
        env: the environment (possibly wrapped, for example by a fault).
        controller: the controller.
        task_metrics: the task's own measurements of an episode, ``(env, trace) ->
            JSON values`` (``None``: none).
        regions: count option starts outside these learned regions (options without a
            region never start outside), so that a controller that ignores the regions
            is measured on the same sets as the others; ``None``: as the controller saw
            its options' initiation sets.
        before_episode: called with the episode's reset seed before it starts (for
            example to reseed a motion planner's global random generator, so that an
            episode does not depend on the episodes run before it in the process).
    """

    env: gym.Env[Any, Any]
    controller: Controller
    task_metrics: Callable[[gym.Env[Any, Any], EpisodeTrace], dict[str, Any]] | None = None
    regions: RegionModel | None = None
    before_episode: Callable[[int], None] | None = None

    def run(self, seed: EpisodeSeed, frames: list[Any] | None = None) -> EpisodeTrace:
        """The trace of episode ``seed``; with ``frames``, ``env.render()`` is appended
        after every step (``env`` made with ``render_mode="rgb_array"``)."""
        if self.before_episode is not None:
            self.before_episode(seed.env_seed)
        env = self.env if frames is None else _FrameRecorder(self.env, frames)
        return self.controller.run(env, seed.rng(), seed=seed.env_seed)

    def record(self, trace: EpisodeTrace, seed: EpisodeSeed) -> EpisodeRecord:
        """The record of ``trace``, episode ``seed`` of this runner."""
        metrics = None if self.task_metrics is None else self.task_metrics(self.env, trace)
        outside = None if self.regions is None else starts_outside(trace, self.regions)
        return EpisodeRecord.of(trace, seed.env_seed, metrics, outside)

    def episode(self, seed: EpisodeSeed) -> EpisodeRecord:
        return self.record(self.run(seed), seed)


@dataclass
class DemonstratorRunner:
    """The demonstrator's seeded episodes as :class:`EpisodeRecord` s: the options it
    chooses before every step, exactly as it demonstrates
    (:func:`~dynoplan.pipeline.collect.record_episode`), with no initiation set or region
    in its way. A *decision* is a change of option; it costs no planning (no latencies).
    Out-of-region starts are counted against ``regions`` (``None``: none).
    """

    env: gym.Env[Any, Any]
    options: Sequence[OptionSpec]
    demonstrator: Demonstrator
    regions: RegionModel | None = None

    def episode(self, seed: EpisodeSeed) -> EpisodeRecord:
        recording = record_episode(self.env, self.options, self.demonstrator, seed.env_seed,
                                   seed.rng())
        episode = recording.episode
        names = [o.name for o in self.options]
        labels = np.asarray(episode.options)
        starts = np.flatnonzero(np.r_[True, labels[1:] != labels[:-1]])
        chosen = tuple(names[int(k)] for k in labels[starts])
        states = np.asarray(episode.observations, dtype=np.float64).reshape(len(labels) + 1, -1)
        outside = (0 if self.regions is None else
                   count_outside(self.regions, zip(states[starts], chosen, strict=True)))
        steps = np.bincount(labels, minlength=len(names))
        return EpisodeRecord(
            seed.env_seed, recording.success, len(labels), float(np.sum(episode.rewards)),
            len(chosen), len(chosen) - 1, outside, 0, (),
            tuple(sorted((names[k], int(n)) for k, n in enumerate(steps) if n)), chosen)


class NoRegions:
    """A region model without regions: no option ever starts outside one (what
    out-of-region starts are counted against when no regions were fitted)."""

    @property
    def option_names(self) -> list[str]:
        return []

    def option_index(self, option: str | int) -> int:
        raise DynoplanError(f"no regions were fitted, none for option {option!r}")

    def contains(self, states: Any, option: str | int) -> Any:
        raise DynoplanError(f"no regions were fitted, none for option {option!r}")


def learned_regions(models: "FittedModels") -> RegionModel:
    """What a pipeline's out-of-region starts are counted against: the fitted regions
    of ``models`` when the options use them, else none (:class:`NoRegions`), so that a
    start outside the user's own initiation set is never counted as out of region."""
    if models.use_regions and models.regions is not None:
        return models.regions
    return NoRegions()


def starts_outside(trace: EpisodeTrace, regions: RegionModel) -> int:
    """Options of ``trace`` started outside their learned region in ``regions`` (an
    option without a region, one the demonstrations do not show, never is)."""
    return count_outside(regions, ((d.state, d.option) for d in trace.decisions
                                    if d.option is not None))


def count_outside(regions: RegionModel, starts: Iterable[tuple[FloatArray, str]]) -> int:
    """How many of the option starts ``(state (d,), option name)`` lie outside the
    option's learned region in ``regions`` (an option without a region never does)."""
    shown = set(regions.option_names)
    return sum(1 for state, name in starts
               if name in shown and not bool(regions.contains(state[None], name)[0]))


class _FrameRecorder(gym.Wrapper[Any, Any, Any, Any]):
    """Appends a rendered frame to ``frames`` after every step."""

    def __init__(self, env: gym.Env[Any, Any], frames: list[Any]) -> None:
        super().__init__(env)
        self.frames = frames

    def step(self, action: Any) -> Any:
        out = self.env.step(action)
        self.frames.append(self.env.render())
        return out


@dataclass(frozen=True)
class ControllerJob:
    """Controller ``controller`` of ``task`` on the models in ``models`` (a models folder,
    :mod:`dynoplan.models.folder`), as a worker rebuilds it
    (:meth:`~dynoplan.pipeline.task.Task.make_runner`)."""

    task: Task
    models: Path
    controller: str
    settings: ControllerSettings

    def build(self) -> EpisodeRunner:
        return self.task.make_runner(self.controller, self.models, self.settings)


def evaluate_controllers(env: gym.Env[Any, Any], options: Sequence[Option],
                         goal: GoalHeuristic, settings: ControllerSettings, episodes: int,
                         seed: int, planner_options: Sequence[Option] | None = None,
                         controllers: Sequence[str] | None = None,
                         progress: bool = False, workers: Workers = SERIAL,
                         task: Task | None = None,
                         models: Path | None = None,
                         regions: RegionModel | None = None,
                         demonstrator: Any = None,
                         state_scale: FloatArray | None = None,
                         fresh_env: Callable[[], gym.Env[Any, Any]] | None = None,
                         own_controllers: bool = False,
                         ) -> dict[str, dict[str, Any]]:
    """Run each controller on the same ``episodes`` seeded episodes; one summary each.

    ``controllers`` defaults to :func:`controller_names` (the demonstrator when one is
    given, DynoPlan, every option alone, random choice; ``demonstrator``: a
    :class:`~dynoplan.pipeline.collect.Demonstrator` or ``fn(observation) -> option
    name``, :class:`DemonstratorRunner`; ``state_scale``: see :func:`make_controller`).
    On one worker the controllers run here on
    ``env`` and ``options``; on several, every worker rebuilds them from ``task`` and the
    models folder ``models`` (:class:`ControllerJob`), which must hold the same models, and
    the table is the same. With ``own_controllers`` every worker, and one worker too,
    builds them so (a task whose controllers are its own, such as the gear's:
    ``controllers`` then names them).
    Out-of-region starts are counted against ``regions`` (:class:`ControllerRunner`; a
    task's workers count as :meth:`~dynoplan.pipeline.task.Task.make_runner` says).
    With ``fresh_env`` (an environment like ``env``, made anew at each call), each row
    runs on one fresh environment of its own, so that a row does not depend on the rows
    before it on an environment that keeps state across ``reset`` (a row evaluated alone
    is the same; :func:`~dynoplan.pipeline.diagnostics.episode_history_warning`); the
    environments are closed after the evaluation.
    """
    if episodes < 1:
        raise DynoplanError(f"episodes must be >= 1, got {episodes}")
    seeds = episode_seeds(seed, episodes)
    kinds = list(controllers or controller_names(options, demonstrator is not None))
    if DEMONSTRATOR in kinds and demonstrator is None and not own_controllers:
        raise DynoplanError("the demonstrator row needs a demonstrator")
    row_envs: list[gym.Env[Any, Any]] = []  # made here, closed here
    if workers.parallel or own_controllers:
        if task is None or models is None:
            raise DynoplanError("evaluating on several workers or with the task's own "
                                "controllers needs the task and the models folder (the "
                                "controllers are rebuilt from them)")
        jobs: list[EpisodeJob] = [ControllerJob(task, models, kind, settings)
                                  for kind in kinds]
    else:
        row_envs = [] if fresh_env is None else [fresh_env() for _ in kinds]
        jobs = [_LocalJob(DemonstratorRunner(row_env, [as_spec(o) for o in options],
                                             demonstrator_from(demonstrator),
                                             regions)) if kind == DEMONSTRATOR
                else _LocalJob(ControllerRunner(row_env, make_controller(
                    kind, options, goal, settings, planner_options, row_env.action_space,
                    state_scale), regions=regions))
                for kind, row_env in zip(kinds, row_envs or [env] * len(kinds),
                                         strict=True)]
    try:
        done = evaluate_many([(job, seeds) for job in jobs], workers,
                             f"evaluate ({len(kinds)} controllers)", progress)
    finally:
        for row_env in row_envs:
            row_env.close()
    return {kind: summarize(records) for kind, records in zip(kinds, done, strict=True)}


@dataclass(eq=False)
class _LocalJob:
    """A job whose runner is already built (one worker: this process)."""

    runner: EpisodeRunner

    def build(self) -> EpisodeRunner:
        return self.runner


_COLUMNS = ["controller", "success_rate", "steps_to_success_mean", "return_mean",
            "decisions_mean", "out_of_region_starts", "latency_ms_p50"]
_HEADERS = ["controller", "success rate", "steps to success (mean)", "return (mean)",
            "decisions (mean)", "out-of-region starts", "decision latency p50 (ms)"]


def results_table(rows: dict[str, dict[str, Any]]) -> str:
    """The evaluation as a markdown table, one row per controller."""
    return markdown_table([{"controller": name, **row} for name, row in rows.items()],
                          _COLUMNS, _HEADERS)


def option_share_table(rows: Mapping[str, Mapping[str, Any]]) -> str:
    """Which options each controller ran: the share of its environment steps per option
    (``option_share`` of :func:`summarize`), one row per controller, one column per option
    that any controller ran."""
    names = sorted({name for row in rows.values() for name in row.get("option_share", {})})
    table = [{"controller": kind, **{n: row.get("option_share", {}).get(n, 0.0)
                                     for n in names}} for kind, row in rows.items()]
    return markdown_table(table, ["controller", *names], ["controller", *names])
