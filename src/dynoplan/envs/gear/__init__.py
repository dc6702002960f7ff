"""The two-arm gear assembly of the paper's PR2 experiment, simulated in MuJoCo.

``GearAssemblyEnv`` is registered as ``dynoplan/GearAssembly-v0`` (see
``dynoplan.envs``); ``GearExpert`` is the scripted, privileged demonstrator. The options
are in :mod:`dynoplan.envs.gear.options` (the paper's four: ``PAPER_OPTIONS`` there).
"""

from dynoplan.envs.gear.env import OBS_SLICES, GearAssemblyEnv
from dynoplan.envs.gear.task import STAGES

__all__ = ["OBS_SLICES", "STAGES", "GearAssemblyEnv"]
