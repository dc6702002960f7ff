"""A walk with a trap: one-step hill climbing over options stalls, a look-ahead of two
options does not (the known answer of :class:`~dynoplan.planning.SequencePlanner`)."""

from dynoplan.envs.trap.env import TrapWalkEnv
from dynoplan.envs.trap.options import (
    OPTION_NAMES,
    CorridorProgress,
    TrapDynamics,
    TrapTermination,
    make_trap_options,
)

__all__ = ["OPTION_NAMES", "CorridorProgress", "TrapDynamics", "TrapTermination",
           "TrapWalkEnv",
           "make_trap_options"]
