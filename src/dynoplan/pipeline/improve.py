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
  ``t / T``; the regions and the goal are fitted on it as on the demonstrator's).

The share of each round's episodes that succeeded is the learning curve
(``summary.json``'s ``improvement``).
"""

from collections.abc import Sequence
from dataclasses import dataclass
from itertools import pairwise
from typing import Any

import gymnasium as gym
import numpy as np

from dynoplan.control.controller import Controller, EpisodeTrace
from dynoplan.data.episodes import (
    FAILURE_KEY,
    INTERRUPTED_KEY,
    OPTION_KEY,
    PROGRESS_KEY,
    Episode,
)
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
    """

    success: bool
    pieces: tuple[Episode, ...]
    demonstration: Episode | None


def own_episode(recorder: StepRecorder, trace: EpisodeTrace, option_names: Sequence[str],
                env_seed: int | None) -> OwnEpisode:
    """Cut the episode ``recorder`` holds (run by the controller that produced ``trace``)
    into option pieces and, if it succeeded without holding, a demonstration."""
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
    if trace.success and ran.all() and len(labels):
        t = len(labels)
        demonstration = Episode(observations, actions, rewards, terms, truncs,
                                {OPTION_KEY: labels, INTERRUPTED_KEY: cut,
                                 PROGRESS_KEY: np.arange(1, t + 1, dtype=np.float64) / t},
                                env_seed)
    return OwnEpisode(trace.success, tuple(pieces), demonstration)


def own_episodes(env: gym.Env[Any, Any], controller: Controller,
                 seeds: Sequence[EpisodeSeed]) -> list[OwnEpisode]:
    """The controller's episodes on ``seeds`` (each reset with its ``env_seed``, every
    other choice drawn from its ``rng``), cut for the fit (:func:`own_episode`)."""
    recorder = StepRecorder(env)
    names = [o.name for o in controller.options]
    out = []
    for seed in seeds:
        trace = controller.run(recorder, seed.rng(), seed=seed.env_seed)
        out.append(own_episode(recorder, trace, names, seed.env_seed))
    return out


__all__ = ["HOLD", "OwnEpisode", "StepRecorder", "interruptions", "own_episode",
           "own_episodes", "step_labels"]
