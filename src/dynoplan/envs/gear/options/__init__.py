"""The gear options: the paper's four, their starting states, and the registry of options.

A new option is a policy file (a :class:`GearOptionPolicy`) and one call,
:func:`register_gear_option` (``docs/guide/adding-an-option.md``).
"""

from dynoplan.envs.gear.options.base import GearOptionPolicy, GearPolicyFactory, start_joints
from dynoplan.envs.gear.options.catalog import (
    GEAR_OPTIONS,
    PAPER_OPTIONS,
    gear_option,
    gear_option_names,
    register_gear_option,
    temporary_gear_options,
)
from dynoplan.envs.gear.options.registry import GearOption, OptionNetwork
from dynoplan.envs.gear.options.starts import after_pick, at_reset, before_insertion

__all__ = [
    "GEAR_OPTIONS",
    "PAPER_OPTIONS",
    "GearOption",
    "GearOptionPolicy",
    "GearPolicyFactory",
    "OptionNetwork",
    "after_pick",
    "at_reset",
    "before_insertion",
    "gear_option",
    "gear_option_names",
    "register_gear_option",
    "start_joints",
    "temporary_gear_options",
]
