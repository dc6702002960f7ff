"""The paper's five random-walk options.

(1-3) step right, with ``beta`` = 0.9, 0.5, 0.2; (4) a uniformly random step; (5) step
left with ``beta`` = 0.5. The paper gives no ``beta`` for the random option: we use 0.5.
The planner is not told which option is best; it finds out from the models.
"""

from dataclasses import dataclass
from typing import Any

from dynoplan.envs.random_walk.env import LEFT, RIGHT
from dynoplan.envs.random_walk.models import NoisyWalkDynamics
from dynoplan.options.option import FunctionPolicy, Option
from dynoplan.options.termination import ConstantTermination
from dynoplan.types import Generator


@dataclass(frozen=True)
class WalkOptionSpec:
    name: str
    p_right: float
    beta: float


OPTION_SPECS: tuple[WalkOptionSpec, ...] = (
    WalkOptionSpec("right_0.9", 1.0, 0.9),
    WalkOptionSpec("right_0.5", 1.0, 0.5),
    WalkOptionSpec("right_0.2", 1.0, 0.2),
    WalkOptionSpec("random", 0.5, 0.5),
    WalkOptionSpec("left_0.5", 0.0, 0.5),
)


def _policy(p_right: float) -> FunctionPolicy:
    if p_right >= 1.0:
        return FunctionPolicy(lambda _obs, _rng: RIGHT)
    if p_right <= 0.0:
        return FunctionPolicy(lambda _obs, _rng: LEFT)

    def act(_obs: Any, rng: Generator) -> int:
        return RIGHT if rng.random() < p_right else LEFT

    return FunctionPolicy(act)


def make_random_walk_options(noise: float = 0.2, goal_state: int = 20) -> list[Option]:
    """The five options, each with a noisy dynamics model (misprediction ``noise``)."""
    return [
        Option(
            name=spec.name,
            policy=_policy(spec.p_right),
            dynamics=NoisyWalkDynamics(spec.p_right, noise, goal_state),
            termination=ConstantTermination(spec.beta),
        )
        for spec in OPTION_SPECS
    ]
