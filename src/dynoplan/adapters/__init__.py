"""Adapters: bring your own controllers as options, without reading dynoplan's internals.

- policies: :class:`CallablePolicy` (``fn(obs) -> action``), :class:`SB3Policy` (any
  model with Stable-Baselines3's ``predict``), :class:`MotionPlannerPolicy` (``plan``
  on start, ``track`` each waypoint), and :func:`policy_from` which picks one;
- terminations: :class:`ClassifierTermination` (``predict_proba``) and
  :func:`termination_from` (a number, a callable, a classifier);
- initiation sets: :class:`BoxRegion` and :func:`initiation_from` (a safety region, a
  callable);
- options: :func:`option_spec` (an option whose dynamics will be learned),
  :func:`make_option` (an option with a dynamics model you already have).
"""

from dynoplan.adapters.initiation import BoxRegion, initiation_from
from dynoplan.adapters.policies import (
    CallablePolicy,
    FunctionPolicy,
    MotionPlannerPolicy,
    SB3Policy,
    policy_from,
)
from dynoplan.adapters.spec import (
    OptionSpec,
    as_spec,
    check_unique_names,
    make_option,
    option_spec,
)
from dynoplan.adapters.termination import ClassifierTermination, termination_from

__all__ = [
    "BoxRegion",
    "CallablePolicy",
    "ClassifierTermination",
    "FunctionPolicy",
    "MotionPlannerPolicy",
    "OptionSpec",
    "SB3Policy",
    "as_spec",
    "check_unique_names",
    "initiation_from",
    "make_option",
    "option_spec",
    "policy_from",
    "termination_from",
]
