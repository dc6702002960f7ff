"""The 19-state random walk of the paper's Simulated MDP experiment."""

from dynoplan.envs.random_walk.env import RandomWalkEnv
from dynoplan.envs.random_walk.models import NoisyWalkDynamics, NoisyWalkGoal
from dynoplan.envs.random_walk.options import OPTION_SPECS, make_random_walk_options

__all__ = [
    "OPTION_SPECS",
    "NoisyWalkDynamics",
    "NoisyWalkGoal",
    "RandomWalkEnv",
    "make_random_walk_options",
]
