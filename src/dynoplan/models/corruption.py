"""Fault injection for models: dynamics whose predictions are corrupted by noise.

Used to test that a controller recovers when its models are wrong (it replans from the
state it actually reaches).
"""

from collections.abc import Callable, Sequence

import numpy as np

from dynoplan.models.dynamics import (
    DynamicsModel,
    StackedDynamics,
    stack_dynamics,
    trajectory_sampler,
)
from dynoplan.types import FloatArray, Generator


class NoisyDynamics:
    """``base``'s prediction plus Gaussian noise of standard deviation ``std`` (a scalar
    or one value per state dimension), drawn from the planner's generator."""

    def __init__(self, base: DynamicsModel, std: float | FloatArray) -> None:
        self.base = base
        self.std = np.broadcast_to(np.asarray(std, dtype=np.float64), (base.state_dim,)).copy()
        if np.any(self.std < 0) or not np.all(np.isfinite(self.std)):
            raise ValueError("noise std must be finite and >= 0")

    @property
    def state_dim(self) -> int:
        return self.base.state_dim

    def sample(self, states: FloatArray, rng: Generator) -> FloatArray:
        out: FloatArray = self.base.sample(states, rng) + rng.normal(size=states.shape) * self.std
        return out

    @classmethod
    def stack(cls, items: Sequence["NoisyDynamics"]) -> "_StackedNoisy":
        return _StackedNoisy(stack_dynamics([i.base for i in items]),
                             np.stack([i.std for i in items]))


class _StackedNoisy:
    def __init__(self, base: StackedDynamics, std: FloatArray) -> None:
        self.base = base
        self.std = std  # (options, state_dim)

    def sample(self, states: FloatArray, rng: Generator) -> FloatArray:
        noise = rng.normal(size=states.shape) * self.std[:, None, :]
        out: FloatArray = self.base.sample(states, rng) + noise
        return out

    def trajectory_sampler(self, samples: int,
                           rng: Generator) -> Callable[[FloatArray], FloatArray]:
        """The base stack's rollout steps (members kept per rollout), plus the noise."""
        base = trajectory_sampler(self.base, samples, rng)

        def step(states: FloatArray) -> FloatArray:
            noise = rng.normal(size=states.shape) * self.std[:, None, :]
            out: FloatArray = base(states) + noise
            return out
        return step


__all__ = ["NoisyDynamics"]
