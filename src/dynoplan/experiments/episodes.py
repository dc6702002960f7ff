"""Running many seeded episodes of a controller and summarising them."""

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

from dynoplan.control.controller import Controller, EpisodeTrace
from dynoplan.progress import track


@dataclass(frozen=True)
class EpisodeSeed:
    """Seeds of one episode: ``env_seed`` for ``env.reset``, ``rng`` for everything else."""

    index: int
    env_seed: int
    sequence: np.random.SeedSequence

    def rng(self) -> np.random.Generator:
        return np.random.default_rng(self.sequence)


def episode_seeds(seed: int, episodes: int) -> list[EpisodeSeed]:
    """Independent per-episode seeds derived from one seed (stable under reordering)."""
    children = np.random.SeedSequence(seed).spawn(episodes)
    return [EpisodeSeed(i, int(c.generate_state(1)[0]), c) for i, c in enumerate(children)]


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
