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


__all__ = ["EpisodeSeed", "episode_seeds"]
