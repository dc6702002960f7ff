"""How we plan with what is learned: the n-step option MPC of Eq. 1, its look-ahead over
option sequences, and the same choice with the simulator as the model (the oracle)."""

from dynoplan.planning.option_planner import OptionPlanner, Plan, Rollouts
from dynoplan.planning.sequence_planner import SequencePlanner
from dynoplan.planning.simulator_oracle import RestorableEnv, SimulatorOracle

__all__ = ["OptionPlanner", "Plan", "RestorableEnv", "Rollouts", "SequencePlanner",
           "SimulatorOracle"]
