"""Options ``o_w = (pi_w, I_w, beta_w, D_w)`` and their parts."""

from dynoplan.options.initiation import (
    AllOf,
    AnyOf,
    Everywhere,
    Initiation,
    InitiationFromCallable,
    InRegion,
)
from dynoplan.options.option import (
    FunctionPolicy,
    Option,
    OptionPolicy,
    PolicyFactory,
    admissible,
)
from dynoplan.options.termination import (
    ConstantTermination,
    StackedTermination,
    Termination,
    TerminationFromCallable,
    stack_terminations,
)

__all__ = [
    "AllOf",
    "AnyOf",
    "ConstantTermination",
    "Everywhere",
    "FunctionPolicy",
    "InRegion",
    "Initiation",
    "InitiationFromCallable",
    "Option",
    "OptionPolicy",
    "PolicyFactory",
    "StackedTermination",
    "Termination",
    "TerminationFromCallable",
    "admissible",
    "stack_terminations",
]
