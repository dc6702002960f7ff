"""Goal heuristic ``g ~ G_K(s)``: how far along the task a state is, as a distribution.

The planner scores an option by ``E[G(D^n(s))]`` (Eq. 1) and needs only samples of
``G``; a model that also knows its mean and spread can expose them through
``mean_std`` for figures.
"""

from typing import Protocol, runtime_checkable

from dynoplan.types import FloatArray, Generator


@runtime_checkable
class GoalHeuristic(Protocol):
    """A distribution over progress in ``[0, 1]`` for each state.

    Contract:
        ``sample(states, rng)`` takes ``(batch, state_dim)`` and returns ``(batch,)``
        values in ``[0, 1]``, one independent draw per state, from ``rng`` only.
        ``mean_std(states)`` returns the mean and standard deviation, each ``(batch,)``.
    """

    def sample(self, states: FloatArray, rng: Generator) -> FloatArray: ...

    def mean_std(self, states: FloatArray) -> tuple[FloatArray, FloatArray]: ...
