"""The random walk as tasks of the generic pipeline: reach state ``j``, for several ``j``,
over one set of learned option dynamics (``docs/transfer.md``).

The paper's random walk (:mod:`dynoplan.experiments.random_walk`) plans with hand-written
noisy models. Here the same five options are a user's options
(:func:`~dynoplan.adapters.option_spec`), their dynamics are *learned* once by
``dynoplan pipeline`` on the task "reach 20", and every other task "reach j" brings only
its own goal heuristic, fitted from its own demonstrations by ``dynoplan task fit``::

    dynoplan pipeline --env dynoplan/RandomWalk19-v0 \\
        --options dynoplan.envs.random_walk.tasks:make_options \\
        --state-fn dynoplan.envs.random_walk.tasks:walk_state \\
        --success dynoplan.envs.random_walk.tasks:reach_20 --no-regions --out OPT
    dynoplan task fit --options-models OPT --env dynoplan/RandomWalk19-v0 \\
        --options dynoplan.envs.random_walk.tasks:make_options \\
        --state-fn dynoplan.envs.random_walk.tasks:walk_state \\
        --success dynoplan.envs.random_walk.tasks:reach_10 --no-regions --out REACH10

The environment is the same in every task (states 0..20, the episode ends at 20 at the
latest); only the success test differs, so the options' closed loops, and their
dynamics, are the same.
"""

from typing import Any, ClassVar

import numpy as np

import dynoplan.envs  # noqa: F401 (registers dynoplan/RandomWalk19-v0)
from dynoplan.adapters.spec import OptionSpec, option_spec
from dynoplan.envs.random_walk.env import LEFT, RIGHT
from dynoplan.envs.random_walk.options import OPTION_SPECS
from dynoplan.options.option import FunctionPolicy
from dynoplan.pipeline.collect import Demonstrator
from dynoplan.types import FloatArray, Generator

GOAL_STATES = (10, 15, 20)
"""The tasks of ``docs/transfer.md``: reach state ``j`` for each ``j``."""


def walk_state(observation: Any) -> FloatArray:
    """The planner state of the walk: its state index as one float, ``(1,)``."""
    return np.array([float(observation)], dtype=np.float64).reshape(-1)[:1]


def _act(p_right: float) -> FunctionPolicy:
    def act(_state: Any, rng: Generator) -> int:
        if p_right >= 1.0:
            return RIGHT
        if p_right <= 0.0:
            return LEFT
        return RIGHT if rng.random() < p_right else LEFT

    return FunctionPolicy(act)


def make_options() -> list[OptionSpec]:
    """The paper's five options (:data:`~dynoplan.envs.random_walk.options.OPTION_SPECS`),
    without dynamics models: the pipeline learns them."""
    return [option_spec(spec.name, _act(spec.p_right), termination=spec.beta)
            for spec in OPTION_SPECS]


class RightDemonstrator(Demonstrator):
    """Runs right-going options, each until its own termination fires (drawn from the
    episode's generator), choosing each uniformly among the three."""

    names: ClassVar[tuple[str, ...]] = tuple(s.name for s in OPTION_SPECS if s.p_right >= 1.0)
    betas: ClassVar[dict[str, float]] = {s.name: s.beta for s in OPTION_SPECS}

    def reset(self, observation: Any, rng: Generator) -> None:
        self._rng = rng
        self._current: str | None = None

    def choose(self, observation: Any) -> str:
        if self._current is not None and self._rng.random() < self.betas[self._current]:
            self._current = None
        if self._current is None:
            self._current = str(self._rng.choice(self.names))
        return self._current


def make_demonstrator() -> RightDemonstrator:
    """The demonstrator of every "reach j" task (the task's success ends its episodes)."""
    return RightDemonstrator()


def reach(goal: int) -> Any:
    """``success(observation, info)``: the walk is at state ``goal`` or beyond."""
    def success(observation: Any, _info: Any) -> bool:
        return float(observation) >= goal

    success.__name__ = f"reach_{goal}"
    return success


reach_10 = reach(10)
reach_15 = reach(15)
reach_20 = reach(20)
