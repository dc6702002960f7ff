"""Gymnasium environments of the project, registered on import.

- ``dynoplan/RandomWalk19-v0``: the 19-state random walk (paper, Simulated MDP).
- ``dynoplan/TrapWalk-v0``: a walk with a dead end that only a detour gets around, where
  one-step hill climbing over options stalls (the look-ahead's known answer).
- ``dynoplan/GearAssembly-v0``: the two-arm gear assembly in MuJoCo (paper, PR2 task).
- ``dynoplan/GearPegPose-v0``: the same scene and options, the peg module held at a
  different pose each episode (a downstream task, :mod:`dynoplan.envs.gear.peg_pose`).
"""

import gymnasium as gym

RANDOM_WALK_ID = "dynoplan/RandomWalk19-v0"
GEAR_ASSEMBLY_ID = "dynoplan/GearAssembly-v0"
TRAP_WALK_ID = "dynoplan/TrapWalk-v0"
GEAR_PEG_POSE_ID = "dynoplan/GearPegPose-v0"


def register_envs() -> None:
    """Register the project's environments (idempotent)."""
    if RANDOM_WALK_ID not in gym.registry:
        gym.register(
            id=RANDOM_WALK_ID,
            entry_point="dynoplan.envs.random_walk.env:RandomWalkEnv",
            max_episode_steps=1000,
        )
    if TRAP_WALK_ID not in gym.registry:
        gym.register(
            id=TRAP_WALK_ID,
            entry_point="dynoplan.envs.trap.env:TrapWalkEnv",
            max_episode_steps=1000,
        )
    if GEAR_ASSEMBLY_ID not in gym.registry:
        gym.register(
            id=GEAR_ASSEMBLY_ID,
            entry_point="dynoplan.envs.gear.env:GearAssemblyEnv",
        )
    if GEAR_PEG_POSE_ID not in gym.registry:
        gym.register(
            id=GEAR_PEG_POSE_ID,
            entry_point="dynoplan.envs.gear.peg_pose:GearPegPoseEnv",
        )


register_envs()
