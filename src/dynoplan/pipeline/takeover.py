"""The demonstrator taking over a failed episode of the controller's own where its
progress was highest: DAgger's expert labels on the learner's own states (Ross, Gordon
and Bagnell 2011), at the level of options.

An improvement round (:mod:`dynoplan.pipeline.improve`) may ask the demonstrator about
the episodes DynoPlan failed. From the episode's start the demonstrator shows how it
would have solved the task; taken over (``improve_takeover``), it shows how to go on
from where DynoPlan went wrong instead:

1. :func:`takeover_point` picks the decision of the failed episode whose state the goal
   heuristic rated highest (the last of equals), or the first hold if that came first:
   the last state DynoPlan's own progress reached before it was lost;
2. :class:`TakeOver` replays DynoPlan's own actions up to there from the same reset
   (their steps are the demonstration's detour, no one's choice for the regions;
   ``infos["interrupted"]`` where a run was cut), checks that the replay reached the
   same observation, and hands the rest of the episode to the demonstrator;
3. :func:`demonstrations_after` keeps the successes, with progress labels over the
   whole episode, as :func:`~dynoplan.pipeline.collect.demonstrations_at` keeps the
   demonstrator's own.

A task whose environment does not replay (the observation after the replayed actions
differs from the recorded one) gets no demonstration from that episode.
"""

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from dynoplan.adapters.spec import OptionSpec
from dynoplan.control.controller import EpisodeTrace
from dynoplan.data.episodes import DETOUR_KEY, INTERRUPTED_KEY, Episode
from dynoplan.errors import DynoplanError
from dynoplan.models.goal import GoalHeuristic
from dynoplan.pipeline.collect import Decision, Steering, record_episode, with_progress
from dynoplan.seeding import EpisodeSeed
from dynoplan.types import Generator

REPLAY_TOLERANCE = 1e-6
"""How far (largest absolute difference) the replayed observation may be from the
recorded one at the takeover step."""


@dataclass(frozen=True)
class Takeover:
    """Where the demonstrator takes over one of the controller's failed episodes.

    Attributes:
        step: the environment step the demonstrator's first choice acts at (0: from
            the start, as a demonstration asked at the episode's start).
        actions: ``(step, ...)`` the controller's actions before it, replayed.
        labels: ``(step,)`` the option index of each replayed step.
        interrupted: ``(step,)`` ``bool``, True at the last step of each replayed run
            that was cut short (where it stopped is not its option's end).
        observation: the recorded observation at ``step``, which the replay must reach.
    """

    step: int
    actions: np.ndarray
    labels: np.ndarray
    interrupted: np.ndarray
    observation: np.ndarray


def takeover_point(trace: EpisodeTrace, goal: GoalHeuristic) -> int:
    """The decision of ``trace`` the demonstrator takes over at (its index): among the
    decisions up to the first hold (that one included), the one whose state the goal
    heuristic's mean rates highest, the last of equals."""
    if not trace.decisions:
        raise DynoplanError("an episode without decisions has no takeover point")
    last = next((i for i, d in enumerate(trace.decisions) if d.option is None),
                len(trace.decisions) - 1)
    states = np.stack([d.state for d in trace.decisions[:last + 1]])
    progress = np.asarray(goal.mean_std(states)[0], dtype=np.float64)
    return int(last - np.argmax(progress[::-1]))


def takeover(trace: EpisodeTrace, goal: GoalHeuristic, observations: np.ndarray,
             actions: np.ndarray, labels: np.ndarray, cut: np.ndarray) -> Takeover:
    """The :class:`Takeover` of failed episode ``trace`` (:func:`takeover_point`), from
    its recorded ``observations`` ``(T + 1, ...)``, ``actions`` ``(T, ...)``, step
    ``labels`` ``(T,)`` and the runs the controller cut at a replan, ``cut`` ``(T,)``."""
    i = takeover_point(trace, goal)
    step = trace.decisions[i].env_step
    if (np.asarray(labels[:step]) < 0).any():
        raise DynoplanError("a takeover's replayed steps must all be option steps (the "
                            "takeover point comes before the first hold)")
    interrupted = np.array(cut[:step], dtype=bool)
    if step and trace.decisions[i - 1].stop_reason != "terminated":
        interrupted[-1] = True  # the takeover cuts the run that was going on
    return Takeover(step, np.asarray(actions[:step]), np.asarray(labels[:step], np.int64),
                    interrupted, np.asarray(observations[step]))


class TakeOver(Steering):
    """The controller's actions of ``takeover`` replayed, then ``demonstrator``'s choices
    (asked at every step, the replayed ones too: :class:`~dynoplan.pipeline.collect.
    Steering`). ``replayed`` says whether the replay reached the recorded observation
    (checked when the takeover step comes)."""

    def __init__(self, demonstrator: Any, takeover: Takeover, option_names: Sequence[str]
                 ) -> None:
        super().__init__(demonstrator)
        self.takeover = takeover
        self.names = list(option_names)
        self.replayed = takeover.step == 0

    def reset(self, observation: Any, rng: Generator) -> None:
        super().reset(observation, rng)
        self.replayed = self.takeover.step == 0

    def instead(self, t: int, observation: Any, choice: "str | Decision | None"
                ) -> "str | Decision | None":
        over = self.takeover
        if t == over.step and over.step:
            recorded = np.asarray(over.observation, dtype=np.float64)
            now = np.asarray(observation, dtype=np.float64)
            self.replayed = bool(now.shape == recorded.shape and np.all(
                np.abs(now - recorded) <= REPLAY_TOLERANCE))
            if not self.replayed:
                return None  # the recording ends: the environment did not replay
        if t < over.step:
            return Decision(self.names[int(over.labels[t])], action=over.actions[t])
        return choice


def demonstrations_after(env_of: Callable[[EpisodeSeed], gym.Env[Any, Any]],
                         specs: Sequence[OptionSpec], demonstrator: Any,
                         seeds: Sequence[EpisodeSeed], takeovers: Sequence[Takeover],
                         max_steps: int | None = None) -> tuple[list[Episode], int]:
    """The demonstrator's episodes taking over the controller's episodes ``seeds`` at
    ``takeovers`` (:class:`TakeOver`), each on the environment ``env_of(seed)`` the
    controller's ran on, its successes only, in order, with progress
    labels over the whole episode, the replayed steps marked as a detour
    (``infos["detour"]``) and their cut runs (``infos["interrupted"]``).

    Returns:
        The demonstrations, and how many episodes did not replay.
    """
    names = [s.name for s in specs]
    kept, unreplayed = [], 0
    for seed, over in zip(seeds, takeovers, strict=True):
        demo = TakeOver(demonstrator, over, names)
        recording = record_episode(env_of(seed), specs, demo, seed.env_seed, seed.rng(),
                                   max_steps)
        if not demo.replayed:
            unreplayed += 1
            continue
        if not recording.success:
            continue
        episode = recording.episode
        detour = np.zeros(len(episode), dtype=bool)
        detour[:over.step] = True
        interrupted = np.zeros(len(episode), dtype=bool)
        interrupted[:over.step] = over.interrupted
        episode.infos[DETOUR_KEY] = detour
        episode.infos[INTERRUPTED_KEY] = interrupted
        kept.append(with_progress(episode))
    return kept, unreplayed


__all__ = ["REPLAY_TOLERANCE", "TakeOver", "Takeover", "demonstrations_after", "takeover",
           "takeover_point"]
