"""Seeds: one seed split into independent, reproducible streams.

Every random choice of a run derives from one integer seed through
:class:`numpy.random.SeedSequence`: :func:`episode_seeds` gives each evaluation (or
recording) episode its own seeds, so an episode depends on its index alone, not on
the episodes run before it or on which worker runs it.
"""

from dataclasses import dataclass

import numpy as np


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


BATCH_STREAM = 2**32 - 1
"""The spawn key of :func:`batch_planner_seed`'s stream (episodes use ``0, 1, ...``)."""


def batch_planner_seed(seed: int) -> np.random.SeedSequence:
    """The seed of a planner shared by a batch of episodes run side by side: derived from
    ``seed`` like :func:`episode_seeds`' streams, and independent of every one of them."""
    return np.random.SeedSequence(seed, spawn_key=(BATCH_STREAM,))


__all__ = ["BATCH_STREAM", "EpisodeSeed", "batch_planner_seed", "episode_seeds"]
