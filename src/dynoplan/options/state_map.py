"""Options on their own state spaces (the paper: "The state space of different options can
be different, as long as there exists a direct or learnable mapping between S_i and S_j
for some part of the space").

An option may declare a :class:`StateMap`: ``to_option(planner_states) -> option_states``
and ``to_planner(planner_states, option_states) -> planner_states``, the part of the
planner state the option changes and how to put it back. Its dynamics ``D_w`` are then a
model of the option's own state (fitted on ``to_option`` of the planner states of its
runs), and the planner rolls it in that space, one step at a time::

    z_t = to_option(s_t);   z_{t+1} ~ D_w(z_t);   s_{t+1} = to_planner(s_t, z_{t+1})

Termination, initiation and the goal heuristic read the planner state ``s`` (the task's
space), so each option is rolled in its own space and scored in the task's.
:class:`MappedDynamics` is that loop body as a dynamics model on planner states; the
coordinates the map leaves out stay as they are during the option's rollout.
"""

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from dynoplan.models.dynamics import (
    DynamicsModel,
    LoopStackedDynamics,
    StackedDynamics,
    stack_dynamics,
    trajectory_sampler,
)
from dynoplan.types import FloatArray, Generator


@runtime_checkable
class StateMap(Protocol):
    """The map between the planner state and an option's own state.

    Contract: ``to_option`` maps ``(..., planner_dim)`` to ``(..., option_dim)``;
    ``to_planner(planner_states (..., planner_dim), option_states (..., option_dim))``
    returns planner states ``(..., planner_dim)``: ``planner_states`` with the part the
    option changes replaced by ``option_states``. Round trip:
    ``to_planner(s, to_option(s)) == s``. Both are deterministic.
    """

    @property
    def planner_dim(self) -> int: ...

    @property
    def option_dim(self) -> int: ...

    def to_option(self, states: FloatArray) -> FloatArray: ...

    def to_planner(self, planner_states: FloatArray, option_states: FloatArray
                   ) -> FloatArray: ...


@dataclass(frozen=True)
class IdentityMap:
    """The option's state is the planner state."""

    dim: int

    @property
    def planner_dim(self) -> int:
        return self.dim

    @property
    def option_dim(self) -> int:
        return self.dim

    def to_option(self, states: FloatArray) -> FloatArray:
        return np.asarray(states, dtype=np.float64)

    def to_planner(self, planner_states: FloatArray, option_states: FloatArray
                   ) -> FloatArray:
        return np.asarray(option_states, dtype=np.float64)


@dataclass(frozen=True)
class CoordinateMap:
    """The option's state is some coordinates of the planner state (``indices``, in that
    order); the others are not changed by the option."""

    planner_dim: int
    indices: tuple[int, ...]

    def __post_init__(self) -> None:
        idx = tuple(int(i) for i in self.indices)
        if not idx or len(set(idx)) != len(idx) or not all(
                0 <= i < self.planner_dim for i in idx):
            raise ValueError(f"indices must be distinct coordinates in [0, {self.planner_dim})"
                             f", got {self.indices}")
        object.__setattr__(self, "indices", idx)

    @property
    def option_dim(self) -> int:
        return len(self.indices)

    def to_option(self, states: FloatArray) -> FloatArray:
        return np.asarray(states, dtype=np.float64)[..., list(self.indices)]

    def to_planner(self, planner_states: FloatArray, option_states: FloatArray
                   ) -> FloatArray:
        out = np.array(planner_states, dtype=np.float64)
        out[..., list(self.indices)] = option_states
        return out


class MappedDynamics:
    """An option's dynamics on its own state as a dynamics model on planner states:
    ``sample(s) = to_planner(s, D_w.sample(to_option(s)))``.

    Stacks (``(options, samples, planner_dim)``) run the options' own models as one stack
    when they have the same option state size (and then draw from the generator exactly
    as the models' own stack does), else one option after another.
    """

    def __init__(self, dynamics: DynamicsModel, state_map: StateMap) -> None:
        own = getattr(dynamics, "state_dim", state_map.option_dim)
        if own != state_map.option_dim:
            raise ValueError(f"dynamics on {own} values, the state map's option state has "
                             f"{state_map.option_dim}")
        self.dynamics = dynamics
        self.state_map = state_map

    @property
    def state_dim(self) -> int:
        return int(self.state_map.planner_dim)

    def sample(self, states: FloatArray, rng: Generator) -> FloatArray:
        """``(batch, planner_dim)`` -> ``(batch, planner_dim)``."""
        z = self.dynamics.sample(self.state_map.to_option(states), rng)
        return self.state_map.to_planner(states, z)

    @property
    def members(self) -> int:
        """The inner model's ensemble members (for held-out reports,
        :mod:`dynoplan.models.evaluation`)."""
        members = getattr(self.dynamics, "members", None)
        if members is None:
            raise TypeError("the inner dynamics model has no ensemble members")
        return int(members)

    def predict(self, states: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Every member's Gaussian of the next planner state: ``(batch, planner_dim)`` ->
        means and variances ``(members, batch, planner_dim)``. Defined for a
        :class:`CoordinateMap` over a model with ``predict``: the option's coordinates
        are the inner model's Gaussian, the others stay as they are (variance 0), as
        :meth:`sample` leaves them.

        Raises:
            TypeError: another map, or an inner model without ``predict``.
        """
        inner = getattr(self.dynamics, "predict", None)
        if not isinstance(self.state_map, CoordinateMap) or inner is None:
            raise TypeError("predict needs a CoordinateMap over a model with predict")
        s = np.asarray(states, dtype=np.float64)
        means_z, variances_z = inner(self.state_map.to_option(s))
        idx = list(self.state_map.indices)
        means = np.repeat(s[None], len(means_z), axis=0)
        variances = np.zeros_like(means)
        means[..., idx] = means_z
        variances[..., idx] = variances_z
        return means, variances

    @classmethod
    def stack(cls, items: Sequence["MappedDynamics"]) -> StackedDynamics:
        if len({m.state_map.option_dim for m in items}) != 1:
            return LoopStackedDynamics(items)
        return _MappedStack(stack_dynamics([m.dynamics for m in items]),
                            [m.state_map for m in items])


class _MappedStack:
    def __init__(self, inner: StackedDynamics, maps: Sequence[StateMap]) -> None:
        self.inner = inner
        self.maps = list(maps)

    def _to_option(self, states: FloatArray) -> FloatArray:
        return np.stack([m.to_option(states[o]) for o, m in enumerate(self.maps)])

    def _to_planner(self, states: FloatArray, z: FloatArray) -> FloatArray:
        return np.stack([m.to_planner(states[o], z[o]) for o, m in enumerate(self.maps)])

    def sample(self, states: FloatArray, rng: Generator) -> FloatArray:
        return self._to_planner(states, self.inner.sample(self._to_option(states), rng))

    def trajectory_sampler(self, samples: int, rng: Generator) -> "_MappedStep":
        return _MappedStep(self, trajectory_sampler(self.inner, samples, rng))


class _MappedStep:
    """The inner stack's step function in the options' own spaces; ``members`` (which
    ensemble member each rollout follows) is the inner step's."""

    def __init__(self, stack: _MappedStack, step: Callable[[FloatArray], FloatArray]) -> None:
        self.stack = stack
        self.step = step

    @property
    def members(self) -> Any:
        return getattr(self.step, "members", None)

    def __call__(self, states: FloatArray) -> FloatArray:
        return self.stack._to_planner(states, self.step(self.stack._to_option(states)))


def on_option_state(pairs: tuple[FloatArray, FloatArray], state_map: StateMap | None
                    ) -> tuple[FloatArray, FloatArray]:
    """Transition pairs ``(states, next_states)`` of planner states ``(N, planner_dim)`` on
    an option's own state (``(N, option_dim)`` each), what its dynamics are fitted on;
    ``None``: the pairs as they are."""
    if state_map is None:
        return pairs
    return state_map.to_option(pairs[0]), state_map.to_option(pairs[1])


def planner_dynamics(dynamics: DynamicsModel, state_map: StateMap | None) -> DynamicsModel:
    """``dynamics`` on planner states: as it is without a map, else :class:`MappedDynamics`."""
    return dynamics if state_map is None else MappedDynamics(dynamics, state_map)


__all__ = ["CoordinateMap", "IdentityMap", "MappedDynamics", "StateMap", "on_option_state",
           "planner_dynamics"]
