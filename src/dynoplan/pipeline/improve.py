"""Learning from the controller's own episodes: the improvement rounds of
:func:`~dynoplan.pipeline.run_pipeline` (``PipelineSettings.improve``).

Beyond the paper. In each round DynoPlan runs seeded episodes of its own (a seed stream
of their own, never the evaluation's) on the models fitted so far; then the models are
fitted again on everything:

- every step an option ran becomes an option transition (the dynamics' data; the goal's
  off-demonstration states), cut into pieces where the controller held; a run the
  controller cut short at a replan is marked (``infos["interrupted"]``), so that the
  option models do not learn that its option ends there;
- the last state of an episode that did not succeed (failed, ran out of time or of
  decisions) is labelled a failure (``infos["failure"]``, progress 0 for the goal);
- an episode that succeeded without holding becomes a demonstration (its progress
  ``t / T``; the regions and the goal are fitted on it as on the demonstrator's), unless
  a choice in it was an exploring chooser's random one (``improve_explore``): its
  detours are not what the progress labels say they are.

The share of each round's episodes that succeeded is the learning curve
(``summary.json``'s ``improvement``). :func:`improvement_rounds` is the one loop of every
task (the generic stages' and the gear's ``after_fit``): what a task does is how it runs
its own episodes (here, or on workers through :class:`OwnEpisodesJob`) and how it
refits on them.
"""

import copy
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from itertools import pairwise
from pathlib import Path
from typing import Any, TypeVar

import gymnasium as gym
import numpy as np

from dynoplan.control.choosers import Exploring
from dynoplan.control.controller import Controller, EpisodeTrace
from dynoplan.data.episodes import (
    FAILURE_KEY,
    INTERRUPTED_KEY,
    OPTION_KEY,
    PROGRESS_KEY,
    Episode,
)
from dynoplan.errors import DynoplanError
from dynoplan.models.goal import GoalHeuristic
from dynoplan.parallel import SERIAL, Workers
from dynoplan.pipeline.control_settings import ControllerSettings
from dynoplan.pipeline.evaluate import DYNOPLAN, ControllerJob, ControllerRunner
from dynoplan.pipeline.jobs import EpisodeJob, evaluate_many
from dynoplan.pipeline.takeover import Takeover, takeover
from dynoplan.pipeline.task import Task
from dynoplan.seeding import EpisodeSeed

HOLD = -1
"""The label of a step where no option ran (the controller held)."""


class StepRecorder(gym.Wrapper[Any, Any, Any, Any]):
    """Keeps the observations and actions of the episode running through it."""

    def __init__(self, env: gym.Env[Any, Any]) -> None:
        super().__init__(env)
        self.observations: list[Any] = []
        self.actions: list[Any] = []
        self.rewards: list[float] = []
        self.terminations: list[bool] = []
        self.truncations: list[bool] = []

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        observation, info = self.env.reset(**kwargs)
        self.observations = [observation]
        self.actions, self.rewards, self.terminations, self.truncations = [], [], [], []
        return observation, info

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = self.env.step(action)
        self.observations.append(observation)
        self.actions.append(np.asarray(action))
        self.rewards.append(float(reward))
        self.terminations.append(bool(terminated))
        self.truncations.append(bool(truncated))
        return observation, reward, terminated, truncated, info


def interruptions(trace: EpisodeTrace) -> np.ndarray:
    """``(T,)`` ``bool``: True at the last step of every option run of ``trace`` that the
    controller cut short at a replan to run another option or to hold (a replan that
    chose the same option again continues its run)."""
    cut = np.zeros(trace.env_steps, dtype=bool)
    for d, after in pairwise(trace.decisions):
        if d.option is not None and d.steps and d.stop_reason == "replan" \
                and after.option != d.option:
            cut[d.env_step + d.steps - 1] = True
    return cut


def step_labels(trace: EpisodeTrace, option_names: Sequence[str]) -> np.ndarray:
    """``(T,)`` ``int64``: the option that chose every step of ``trace`` (an index into
    ``option_names``), :data:`HOLD` where the controller held."""
    labels = np.full(trace.env_steps, HOLD, dtype=np.int64)
    for d in trace.decisions:
        if d.option is not None:
            labels[d.env_step:d.env_step + d.steps] = list(option_names).index(d.option)
    return labels


@dataclass(frozen=True)
class OwnEpisode:
    """One of the controller's own episodes, cut for the fit.

    Attributes:
        success: whether it succeeded.
        pieces: its runs of option steps (between holds) as labelled episodes; the last
            piece's last step is a failure when the episode did not succeed and that
            piece reaches its end.
        demonstration: the whole episode with progress labels when it succeeded without
            holding, else ``None``.
        takeover: where the demonstrator would take it over, when it failed and was cut
            with a goal heuristic (:func:`~dynoplan.pipeline.takeover.takeover`), else
            ``None``.
    """

    success: bool
    pieces: tuple[Episode, ...]
    demonstration: Episode | None
    takeover: Takeover | None = None


def own_episode(recorder: StepRecorder, trace: EpisodeTrace, option_names: Sequence[str],
                env_seed: int | None, goal: GoalHeuristic | None = None) -> OwnEpisode:
    """Cut the episode ``recorder`` holds (run by the controller that produced ``trace``)
    into option pieces and, if it succeeded without holding, a demonstration; if it
    failed and ``goal`` is given, with the point the demonstrator would take it over at
    (its state rated by ``goal``)."""
    labels = step_labels(trace, option_names)
    cut = interruptions(trace)
    observations = np.asarray(recorder.observations)
    if not np.issubdtype(observations.dtype, np.floating):
        observations = observations.astype(np.float64)
    actions = np.asarray(recorder.actions)
    rewards = np.asarray(recorder.rewards)
    terms = np.asarray(recorder.terminations, dtype=bool)
    truncs = np.asarray(recorder.truncations, dtype=bool)
    ran = labels != HOLD
    edges = np.flatnonzero(np.diff(np.r_[0, ran.astype(np.int8), 0]))
    pieces = []
    for start, end in zip(edges[::2], edges[1::2], strict=True):
        failure = np.zeros(end - start, dtype=bool)
        failure[-1] = end == len(labels) and not trace.success
        pieces.append(Episode(observations[start:end + 1], actions[start:end],
                              rewards[start:end], terms[start:end], truncs[start:end],
                              {OPTION_KEY: labels[start:end], FAILURE_KEY: failure,
                               INTERRUPTED_KEY: cut[start:end]},
                              env_seed))
    demonstration = None
    if trace.success and ran.all() and len(labels) \
            and not any(d.plan.explored for d in trace.decisions):
        t = len(labels)
        demonstration = Episode(observations, actions, rewards, terms, truncs,
                                {OPTION_KEY: labels, INTERRUPTED_KEY: cut,
                                 PROGRESS_KEY: np.arange(1, t + 1, dtype=np.float64) / t},
                                env_seed)
    over = None
    if goal is not None and not trace.success and trace.decisions \
            and not any(d.plan.explored for d in trace.decisions):
        over = takeover(trace, goal, observations, actions, labels, cut)
    return OwnEpisode(trace.success, tuple(pieces), demonstration, over)


class OwnEpisodeRunner:
    """A :class:`~dynoplan.pipeline.evaluate.ControllerRunner` whose episodes are recorded
    step by step and returned cut for the fit (:func:`own_episode`), the steps labelled by
    their option's index in ``option_names`` (default: the controller's options); with
    ``explore`` above 0, its controller explores around its chooser
    (:class:`~dynoplan.control.choosers.Exploring`; a copy of the controller: the runner
    given is not changed); with a ``goal``, its failed episodes carry their takeover
    point (:func:`own_episode`)."""

    def __init__(self, runner: ControllerRunner,
                 option_names: Sequence[str] | None = None, explore: float = 0.0,
                 goal: GoalHeuristic | None = None) -> None:
        self.recorder = StepRecorder(runner.env)
        controller = runner.controller
        if explore > 0.0:
            controller = copy.copy(controller)
            controller.chooser = Exploring(controller.chooser, explore)
        self.runner = replace(runner, env=self.recorder, controller=controller)
        self.names = list(option_names if option_names is not None
                          else [o.name for o in runner.controller.options])
        self.goal = goal

    def episode(self, seed: EpisodeSeed) -> OwnEpisode:
        """Episode ``seed`` (reset with its ``env_seed``, every other choice drawn from its
        ``rng``), cut for the fit."""
        return own_episode(self.recorder, self.runner.run(seed), self.names, seed.env_seed,
                           self.goal)


@dataclass(frozen=True)
class OwnEpisodesJob:
    """The controller ``job`` builds (a :class:`~dynoplan.pipeline.evaluate.ControllerJob`
    whose runner is a :class:`~dynoplan.pipeline.evaluate.ControllerRunner`) as a worker
    rebuilds it, its episodes recorded for the fit (:class:`OwnEpisodeRunner`, labels
    indexing ``option_names``)."""

    job: EpisodeJob
    option_names: tuple[str, ...]
    explore: float = 0.0

    def build(self) -> OwnEpisodeRunner:
        runner = self.job.build()
        if not isinstance(runner, ControllerRunner):
            raise DynoplanError("improvement rounds record a planning controller's episodes; "
                                f"{type(runner).__name__} is not one")
        return OwnEpisodeRunner(runner, self.option_names, self.explore)


def own_episodes(env_of: Callable[[EpisodeSeed], gym.Env[Any, Any]],
                 controller: Controller, seeds: Sequence[EpisodeSeed],
                 explore: float = 0.0, goal: GoalHeuristic | None = None
                 ) -> list[OwnEpisode]:
    """The controller's episodes on ``seeds`` here, one after another, each on the
    environment ``env_of(seed)`` (the task's, or the task's under its disturbance; one
    :class:`OwnEpisodeRunner` per environment, exploring with probability ``explore``;
    the failed ones with their takeover point by ``goal`` when given)."""
    runners: dict[int, OwnEpisodeRunner] = {}
    episodes = []
    for seed in seeds:
        env = env_of(seed)
        runner = runners.get(id(env))
        if runner is None:
            runner = runners[id(env)] = OwnEpisodeRunner(ControllerRunner(env, controller),
                                                         explore=explore, goal=goal)
        episodes.append(runner.episode(seed))
    return episodes


def task_own_episodes(task: Task, models: Path, settings: ControllerSettings,
                      option_names: Sequence[str], seeds: Sequence[EpisodeSeed],
                      explore: float = 0.0, workers: Workers = SERIAL,
                      progress: bool = False) -> list[OwnEpisode]:
    """The task's own DynoPlan (:meth:`~dynoplan.pipeline.task.Task.make_runner` on the
    models folder ``models``, planning as ``settings`` says) on ``seeds``, on
    ``workers``, each episode cut for the fit (:class:`OwnEpisodesJob`, labels indexing
    ``option_names``; exploring with probability ``explore``), in the seeds' order."""
    job = OwnEpisodesJob(ControllerJob(task, models, DYNOPLAN, settings),
                         tuple(option_names), explore)
    own: list[OwnEpisode] = evaluate_many([(job, seeds)], workers, "own episodes",
                                          progress)[0]
    return own


IMPROVE_KEEP = ("last", "best")
"""Values of :attr:`ImprovementSettings.keep`."""


@dataclass(frozen=True)
class ImprovementSettings:
    """How a run learns from its controller's own episodes before the evaluation.

    Attributes:
        rounds: rounds of DynoPlan's own episodes, each followed by a refit (0: none, the
            paper's pipeline; the default, 1, with ``keep`` ``"best"``: the composition
            suite's measurements in ``docs/suite.md``).
        episodes: DynoPlan's episodes per round.
        regions: the rounds' successes taken as demonstrations refit the safety regions
            too (``False``: the goal heuristic alone; the regions stay those of the
            demonstrator's demonstrations).
        keep: which models the evaluation uses: ``"last"``, the last refit's;
            ``"best"``, those whose own episodes succeeded most often (each round's
            episodes measure the models they ran on; one more batch of ``episodes``
            measures the last refit's; the earliest on a tie), as DAgger returns the best
            of its policies on validation (Ross, Gordon and Bagnell 2011). A refit that
            made DynoPlan worse is not kept.
        explore: above 0, each round also runs ``episodes`` exploring episodes on the
            round's models, in which at each decision, with this probability, a uniformly
            random admissible option runs instead of DynoPlan's choice
            (:class:`~dynoplan.control.choosers.Exploring`); the refit learns from them
            too (not as demonstrations), while the success of a round's models is
            measured on its episodes without exploration, as the evaluation runs (0.2,
            the default since the eighteenth round of the composition suite; 0: none).
        demos: above 0, after each round's episodes the demonstrator runs from the
            starts of the first ``demos`` of them that failed, and its successes join the
            demonstrations of the refit: demonstrations where DynoPlan fails, in the
            spirit of DAgger's expert labels on the learner's own states (5, the
            default since the eighteenth round of the composition suite; 0: none). It
            asks the demonstrator for up to ``rounds * demos`` more episodes; a task with
            recorded demonstrations alone has no demonstrator to ask, and none is asked.
        disturbed: the share of the rounds' own episodes (measured and exploring alike)
            that run under the disturbance the task declares (its disturbed
            environment), the demonstrator asked there under it too: a rehearsal of what
            the task expects to meet, as domain randomisation trains on the perturbations
            expected at run time (Tobin et al. 2017). Which episodes are is fixed by their
            index in the seed stream (:meth:`rehearses`). 0, the default: none.
        takeover: the demonstrator asked about a failed episode (``demos``) takes it
            over where DynoPlan's goal heuristic rated its state highest, after
            DynoPlan's own actions up to there are replayed from the same reset
            (:mod:`~dynoplan.pipeline.takeover`), instead of starting afresh from its
            start: DAgger's expert labels on the states the learner reached (``False``,
            the default: from the start).
    """

    rounds: int = 1
    episodes: int = 30
    regions: bool = True
    keep: str = "best"
    explore: float = 0.2
    demos: int = 5
    disturbed: float = 0.0
    takeover: bool = False

    def validate(self) -> None:
        if self.rounds < 0:
            raise DynoplanError(f"improve must be >= 0, got {self.rounds}")
        if self.episodes < 1:
            raise DynoplanError(f"improve_episodes must be >= 1, got {self.episodes}")
        if self.keep not in IMPROVE_KEEP:
            raise DynoplanError(f"improve_keep must be one of {', '.join(IMPROVE_KEEP)}, got "
                                f"'{self.keep}'")
        if not 0.0 <= self.explore <= 1.0:
            raise DynoplanError(f"improve_explore must be in [0, 1], got {self.explore}")
        if self.demos < 0:
            raise DynoplanError(f"improve_demos must be >= 0, got {self.demos}")
        if not 0.0 <= self.disturbed <= 1.0:
            raise DynoplanError(f"improve_disturbed must be in [0, 1], got {self.disturbed}")

    def rehearses(self, seed: EpisodeSeed) -> bool:
        """Whether own episode ``seed`` runs under the task's disturbance: a share
        ``disturbed`` of the stream's episodes, spread evenly over it (every second one
        at 0.5)."""
        if self.disturbed == 0.0:
            return False
        i = seed.index
        return int((i + 1) * self.disturbed) > int(i * self.disturbed)

    @property
    def batches(self) -> int:
        """Batches of own episodes: one per round, and the check of the last refit when
        the best models are kept."""
        return self.rounds + int(self.rounds > 0 and self.keep == "best")

    @property
    def seeds(self) -> int:
        """Episode seeds the rounds use: ``episodes`` per batch, then, exploring,
        ``episodes`` per round."""
        return (self.batches + (self.rounds if self.explore > 0.0 else 0)) * self.episodes


Models = TypeVar("Models")


def improvement_rounds(models: Models, settings: ImprovementSettings,
                       seeds: Sequence[EpisodeSeed],
                       play: Callable[[Models, Sequence[EpisodeSeed], float],
                                      list[OwnEpisode]],
                       refit: Callable[[int, list[OwnEpisode]], Models],
                       say: Callable[[str], None],
                       demonstrate: Callable[[Sequence[EpisodeSeed]], list[Episode]] | None
                       = None,
                       take_over: Callable[[Sequence[EpisodeSeed], Sequence[OwnEpisode]],
                                           tuple[list[Episode], int]] | None = None
                       ) -> tuple[Models, list[dict[str, Any]]]:
    """``settings.rounds`` rounds from ``models``: ``play(models, seeds, explore)`` runs
    DynoPlan on the models of the round on its ``settings.episodes`` of ``seeds``
    (``settings.seeds`` of them, a stream no other stage uses; ``explore``: the
    probability of a random choice at a decision, 0 for the episodes that measure the
    models, ``settings.explore`` for a round's exploring episodes, which come after every
    batch's seeds), then ``refit(round, own)`` fits again on everything so far and this
    round's own episodes (the task keeps what it has added); ``say`` is told of each round
    as it starts. With ``settings.demos`` above 0 and a ``demonstrate`` (the task's
    demonstrator; ``None`` for a task with recorded demonstrations alone: none is asked),
    ``demonstrate(seeds)`` (its successful episodes with progress labels) runs from the
    seeds of the first ``settings.demos`` of the round's measured episodes that failed,
    and its episodes join ``own`` as demonstrations. Which of the seeds run under the
    task's disturbance (``settings.disturbed``) is ``play``'s and ``demonstrate``'s to
    honour (:meth:`ImprovementSettings.rehearses`); the curve counts them. With
    ``settings.takeover``, ``take_over(seeds, episodes)`` asks the demonstrator instead,
    given those failed episodes (``play``'s, with their :attr:`OwnEpisode.takeover`) to
    take over; it returns the successes and how many episodes the environment did not
    replay.

    Returns:
        The models ``settings.keep`` says and the learning curve: per batch ``round``,
        ``episodes``, ``success_rate`` (of the episodes without exploration) and
        ``demonstrations_added``, with ``explored_episodes`` where the round explored,
        ``demonstrator_episodes`` where the demonstrator was asked, ``not_replayed``
        where a takeover's environment did not replay, ``disturbed_episodes`` where
        some ran under the disturbance, ``check`` on the batch that only measures the
        last refit, and ``kept`` on every entry when the best models are kept.

    Raises:
        DynoplanError: ``settings.takeover`` where the task gives no ``take_over``.
    """
    if settings.takeover and settings.demos and demonstrate is not None and take_over is None:
        raise DynoplanError("this task's improvement rounds cannot hand its episodes to the "
                            "demonstrator (improve_takeover); leave improve_takeover off")
    n = settings.episodes
    measured = settings.batches * n  # the exploring episodes' seeds come after these
    curve: list[dict[str, Any]] = []
    candidates: list[tuple[float, Models]] = []
    for r in range(settings.batches):
        last = r == settings.rounds  # the extra batch that measures the last refit
        say("improvement check" if last else f"improvement round {r + 1}")
        batch = seeds[r * n:(r + 1) * n]
        own = play(models, batch, 0.0)
        success = float(np.mean([e.success for e in own]))
        candidates.append((success, models))
        disturbed = sum(settings.rehearses(s) for s in batch)
        if last:
            curve.append({"round": r + 1, "episodes": n, "success_rate": success,
                          "demonstrations_added": 0, "check": True,
                          **({"disturbed_episodes": disturbed} if disturbed else {})})
            break
        exploring = seeds[measured + r * n:measured + (r + 1) * n]
        explored = [] if settings.explore == 0.0 else play(models, exploring,
                                                           settings.explore)
        disturbed += sum(settings.rehearses(s) for s in exploring) if explored else 0
        asked: list[EpisodeSeed] = []
        shown: list[OwnEpisode] = []
        unreplayed = 0
        if demonstrate is not None:  # the demonstrator at the batch's first failed starts
            failed = [(seed, e) for seed, e in zip(batch, own, strict=True)
                      if not e.success][:settings.demos]
            asked = [seed for seed, _ in failed]
            episodes: list[Episode] = []
            if asked and settings.takeover and take_over is not None:
                episodes, unreplayed = take_over(asked, [e for _, e in failed])
            elif asked:
                episodes = demonstrate(asked)
            shown = [OwnEpisode(True, (), episode) for episode in episodes]
        own = own + explored + shown
        curve.append({"round": r + 1, "episodes": n, "success_rate": success,
                      "demonstrations_added": sum(e.demonstration is not None for e in own),
                      **({"explored_episodes": len(explored)} if explored else {}),
                      **({"demonstrator_episodes": len(asked)} if asked else {}),
                      **({"not_replayed": unreplayed} if unreplayed else {}),
                      **({"disturbed_episodes": disturbed} if disturbed else {})})
        models = refit(r, own)
    if settings.batches > settings.rounds:  # the first of the models that succeeded most
        kept = max(range(len(candidates)), key=lambda i: (candidates[i][0], -i))
        models = candidates[kept][1]
        for i, c in enumerate(curve):
            c["kept"] = i == kept
    return models, curve


def learning_curve_text(curve: Sequence[dict[str, Any]]) -> str:
    """One sentence of ``results.md`` on the learning curve of :func:`improvement_rounds`."""
    return ("DynoPlan's success on its own episodes in each improvement round (refit on them "
            "after each): " + ", ".join(
                (f"check of the last refit: {c['success_rate']:.2f}" if c.get("check")
                 else f"round {c['round']}: {c['success_rate']:.2f} "
                      f"(+{c['demonstrations_added']} demonstrations)")
                + (" (kept)" if c.get("kept") else "") for c in curve) + ".")


__all__ = ["HOLD", "IMPROVE_KEEP", "ImprovementSettings", "OwnEpisode", "OwnEpisodeRunner",
           "OwnEpisodesJob", "StepRecorder", "improvement_rounds", "interruptions",
           "learning_curve_text",
           "own_episode", "own_episodes", "step_labels", "task_own_episodes"]
