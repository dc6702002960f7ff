"""Registers the give-way option (:data:`~dynoplan.envs.gear.options.give_way.GIVE_WAY`)
after the paper's four: import this module, or name it in ``DYNOPLAN_GEAR_OPTIONS``::

    DYNOPLAN_GEAR_OPTIONS=dynoplan.envs.gear.options.give_way_option dynoplan gear run

It is not in the default option set (``docs/safety.md`` has what it measured).
"""

from dynoplan.envs.gear.options.catalog import register_gear_option
from dynoplan.envs.gear.options.give_way import GIVE_WAY

register_gear_option(GIVE_WAY)
