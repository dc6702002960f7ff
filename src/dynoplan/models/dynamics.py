"""Forward dynamics of an option's closed loop: ``s_{t+1} ~ D_w(s_t)``.

A dynamics model predicts the next planner state when the environment runs under the
option's policy (the action is implied by the option, so it is not an input). It is
stochastic: each call draws one sample per row, using the generator it is given and no
other source of randomness.
"""

from collections.abc import Callable, Sequence
from typing import Protocol, runtime_checkable

import numpy as np

from dynoplan.stacking import stack
from dynoplan.types import FloatArray, Generator


@runtime_checkable
class DynamicsModel(Protocol):
    """One option's stochastic forward model.

    Contract:
        ``sample(states, rng)`` takes ``states`` of shape ``(batch, state_dim)`` (float64)
        and returns next states of the same shape, one independent draw per row, drawn
        from ``rng`` only. Rows may be non-finite if the model diverges; the planner
        detects and stops such samples.
    """

    @property
    def state_dim(self) -> int: ...

    def sample(self, states: FloatArray, rng: Generator) -> FloatArray: ...


class StackedDynamics(Protocol):
    """Dynamics of several options evaluated in one call.

    ``sample(states, rng)`` maps ``(options, samples, state_dim)`` to the same shape;
    slice ``o`` follows option ``o``'s model.

    A stack of models with discrete members (ensembles) may also offer
    ``trajectory_sampler(samples, rng) -> step``, a step function that keeps each
    rollout on one member for its whole length (see :func:`trajectory_sampler`).
    """

    def sample(self, states: FloatArray, rng: Generator) -> FloatArray: ...


class LoopStackedDynamics:
    """Fallback stack: one batched call per option (batched over samples)."""

    def __init__(self, models: Sequence[DynamicsModel]) -> None:
        self.models = list(models)

    def sample(self, states: FloatArray, rng: Generator) -> FloatArray:
        out = np.empty_like(states)
        for o, model in enumerate(self.models):
            out[o] = model.sample(states[o], rng)
        return out


def trajectory_sampler(dynamics: StackedDynamics, samples: int,
                       rng: Generator) -> Callable[[FloatArray], FloatArray]:
    """The step function of one batch of rollouts, ``(options, samples, d) -> same``.

    Stacks that offer ``trajectory_sampler`` keep every rollout on one ensemble member for
    its whole length (PETS's TS-infinity); for any other stack every step is a fresh
    ``dynamics.sample(states, rng)``.
    """
    own = getattr(dynamics, "trajectory_sampler", None)
    if callable(own):
        step: Callable[[FloatArray], FloatArray] = own(samples, rng)
        return step
    return lambda states: dynamics.sample(states, rng)


def stack_dynamics(models: Sequence[DynamicsModel]) -> StackedDynamics:
    """One object that advances ``(options, samples, state_dim)`` by a step.

    Uses the models' own ``stack`` classmethod when they share a class that has one
    (for example neural ensembles batched as one tensor program), else a loop over options.
    """
    return stack(models, LoopStackedDynamics)
