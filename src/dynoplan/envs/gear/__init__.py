"""The two-arm gear assembly of the paper's PR2 experiment, simulated in MuJoCo.

``GearAssemblyEnv`` is registered as ``dynoplan/GearAssembly-v0`` (see
``dynoplan.envs``); ``GearExpert`` is the scripted, privileged demonstrator.
"""

from dynoplan.envs.gear.env import OBS_SLICES, GearAssemblyEnv
from dynoplan.envs.gear.task import PAPER_OPTIONS, STAGES

__all__ = ["OBS_SLICES", "PAPER_OPTIONS", "STAGES", "GearAssemblyEnv"]
