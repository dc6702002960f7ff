"""What every gear option policy provides on top of :class:`~dynoplan.options.OptionPolicy`.

A gear option policy acts on the environment's observation (50,) and returns its action
(13,). Planning options (pick, fast and cautious moves) also read the live scene through
the env they were built on (a collision checker synced from ``env.data``: the robot's
world model, holding nothing the observation does not also carry); they never step the
env themselves.
"""

from typing import Any

import numpy as np

from dynoplan.envs.gear.env import OBS_SLICES, GearAssemblyEnv
from dynoplan.envs.gear.scene import FINGER_TRAVEL
from dynoplan.options import OptionPolicy, PolicyFactory
from dynoplan.options.termination import Termination
from dynoplan.types import FloatArray


class GearOptionPolicy(OptionPolicy):
    """Base of the four gear option policies.

    Attributes:
        env: the environment the policy plans in.
        plan_ms: wall-clock milliseconds of every motion-planning call since ``reset``
            (empty for options that do not plan).
        status: ``"running"``, ``"done"`` (its work is finished) or ``"failed"`` (it
            gave up, for example no plan was found).
    """

    name = ""

    def __init__(self, env: GearAssemblyEnv) -> None:
        self.env = env
        self.plan_ms: list[float] = []
        self.status = "idle"

    def finished(self) -> bool:
        return self.status in ("done", "failed")

    def succeeded(self, info: dict[str, Any]) -> bool:
        """Whether the option achieved its own goal, judged from the simulator's ``info``
        after its last step (used by option trials, not by the controller)."""
        raise NotImplementedError

    def termination(self) -> Termination:
        """``beta_w`` on planner states (N, 22) (:mod:`dynoplan.envs.gear.state`)."""
        raise NotImplementedError


def start_joints(env: GearAssemblyEnv, observation: Any) -> FloatArray:
    """(12,) the joints an option starts from: the left arm as measured in
    ``observation`` (50,), the right arm (which holds the peg module and never moves in
    the task) at its last commanded targets. Its measured angles sag under gravity below
    its targets, so an option commanding them would lower the peg a little at every
    start (7 cm over an episode of 50 decisions before this rule)."""
    obs = np.asarray(observation, dtype=np.float64)
    out: FloatArray = np.concatenate([obs[OBS_SLICES["arm_qpos"]][:6], env.arm_targets[6:]])
    return out


def gripper_as_it_is(observation: FloatArray) -> float:
    """The gripper command that keeps the left gripper as it is in ``observation``
    ((50,)): 1 (closed) when its fingers are closed past 80 % of their travel, else 0."""
    fingers = np.asarray(observation, dtype=np.float64)[OBS_SLICES["fingers"]]
    return 1.0 if float(fingers.mean()) < 0.8 * FINGER_TRAVEL else 0.0


__all__ = ["GearOptionPolicy", "gripper_as_it_is", "start_joints"]


GearPolicyFactory = PolicyFactory[GearAssemblyEnv, GearOptionPolicy]
"""Builds a gear option's policy bound to one environment."""
