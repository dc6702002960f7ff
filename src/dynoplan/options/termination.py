"""Termination ``beta_w(s)``: the probability that an option stops in state ``s``.

The same object serves the real run (the controller draws a stop with probability
``beta`` after each step) and the planner's imagined rollouts (batched over samples,
and over options when stacked).
"""

from collections.abc import Callable, Sequence
from typing import Protocol, runtime_checkable

import numpy as np

from dynoplan.stacking import stack
from dynoplan.types import FloatArray, IntArray


@runtime_checkable
class Termination(Protocol):
    """``probability(states)``: ``(batch, state_dim)`` -> ``(batch,)`` in ``[0, 1]``."""

    def probability(self, states: FloatArray) -> FloatArray: ...


class StackedTermination(Protocol):
    """``probability(states)``: ``(options, samples, state_dim)`` -> ``(options, samples)``."""

    def probability(self, states: FloatArray) -> FloatArray: ...


class ConstantTermination:
    """``beta(s) = beta`` everywhere (the random walk's options)."""

    def __init__(self, beta: float) -> None:
        if not 0.0 <= beta <= 1.0:
            raise ValueError(f"beta must be in [0, 1], got {beta}")
        self.beta = float(beta)

    def probability(self, states: FloatArray) -> FloatArray:
        return np.full(states.shape[:-1], self.beta)

    @classmethod
    def stack(cls, items: Sequence["ConstantTermination"]) -> "_StackedConstant":
        return _StackedConstant(np.array([t.beta for t in items]))


class _StackedConstant:
    def __init__(self, betas: FloatArray) -> None:
        self.betas = betas  # (options,)
        self._full = np.empty((0, 0))

    def probability(self, states: FloatArray) -> FloatArray:
        if self._full.shape != states.shape[:-1]:  # built once per rollout shape
            self._full = np.repeat(self.betas[:, None], states.shape[1], axis=1)
        return self._full

    def probability_rows(self, states: FloatArray, branches: IntArray) -> FloatArray:
        """``(rows, d)`` -> ``(rows,)``; row ``i`` follows option ``branches[i]``."""
        out: FloatArray = self.betas[branches]
        return out


class TerminationFromCallable:
    """Wrap ``fn(states (batch, d)) -> (batch,)`` probabilities (or booleans)."""

    def __init__(self, fn: Callable[[FloatArray], FloatArray]) -> None:
        self.fn = fn

    def probability(self, states: FloatArray) -> FloatArray:
        return np.clip(np.asarray(self.fn(states), dtype=np.float64), 0.0, 1.0)


class _LoopStackedTermination:
    def __init__(self, items: Sequence[Termination]) -> None:
        self.items = list(items)

    def probability(self, states: FloatArray) -> FloatArray:
        return np.stack([t.probability(states[o]) for o, t in enumerate(self.items)])


def stack_terminations(items: Sequence[Termination]) -> StackedTermination:
    """One object that gives ``beta`` for ``(options, samples, state_dim)`` at once."""
    return stack(items, _LoopStackedTermination)
