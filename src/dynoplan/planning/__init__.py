"""How we plan with what is learned: the n-step option MPC of Eq. 1."""

from dynoplan.planning.option_planner import OptionPlanner, Plan, Rollouts

__all__ = ["OptionPlanner", "Plan", "Rollouts"]
