"""What is learned (or given): dynamics models, goal heuristics, safety regions."""

from dynoplan.models.dynamics import (
    DynamicsModel,
    StackedDynamics,
    stack_dynamics,
    trajectory_sampler,
)
from dynoplan.models.goal import GoalHeuristic
from dynoplan.models.regions import SafetyRegions

__all__ = [
    "DynamicsModel",
    "GoalHeuristic",
    "SafetyRegions",
    "StackedDynamics",
    "stack_dynamics",
    "trajectory_sampler",
]
