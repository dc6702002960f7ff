"""The planner's state of the gear assembly and the decision rate of the learned models.

The paper plans on the 12 arm joint angles. Here the state adds what the goal heuristic,
the safety regions and the termination conditions need to tell situations apart that
the arm joints alone confuse (the gear still on the table or in the hand; the human away
or in the way):

=========  =====  ==========================================================
slice      size   meaning
=========  =====  ==========================================================
0:12       12     arm joint angles (rad), left arm then right arm
12         1      left gripper opening: mean finger travel (m, 0..0.045)
13:16      3      left tool point (``l_tcp``) position (m, world frame)
16:19      3      gear bottom centre (m)
19:22      3      human hand position (m)
=========  =====  ==========================================================

The learned dynamics models predict this state :data:`DECISION_STEPS` environment steps
ahead (one "decision" of 0.5 s); the controller replans at that period.
"""

import numpy as np

from dynoplan.envs.gear.env import CONTROL_DT, OBS_DIM, OBS_SLICES
from dynoplan.envs.gear.kinematics import ArmKinematics
from dynoplan.types import FloatArray

STATE_DIM = 22
STATE_SLICES: dict[str, slice] = {
    "arm_qpos": slice(0, 12),
    "gripper": slice(12, 13),
    "tool_pos": slice(13, 16),
    "gear_pos": slice(16, 19),
    "human_pos": slice(19, 22),
}
STATE_NAMES: tuple[str, ...] = (
    *(f"q{i}" for i in range(12)), "gripper", "tool_x", "tool_y", "tool_z",
    "gear_x", "gear_y", "gear_z", "human_x", "human_y", "human_z")
DECISION_STEPS = 10
"""Environment steps per planner step (0.5 s at 20 Hz)."""
DECISION_DT = DECISION_STEPS * CONTROL_DT


class PlannerState:
    """Observation (50,) or (N, 50) -> planner state (22,) or (N, 22).

    Holds a private forward-kinematics model for the tool point, so one instance serves
    one thread.
    """

    def __init__(self) -> None:
        self._kin = ArmKinematics()

    def __call__(self, observation: FloatArray) -> FloatArray:
        obs = np.asarray(observation, dtype=np.float64)
        single = obs.ndim == 1
        obs2 = np.atleast_2d(obs)
        if obs2.shape[1] != OBS_DIM:
            raise ValueError(f"gear observations have {OBS_DIM} values, got {obs2.shape[1]}")
        out = np.empty((len(obs2), STATE_DIM))
        out[:, STATE_SLICES["arm_qpos"]] = obs2[:, OBS_SLICES["arm_qpos"]]
        out[:, 12] = obs2[:, OBS_SLICES["fingers"]].mean(axis=1)
        for i, row in enumerate(obs2):
            out[i, STATE_SLICES["tool_pos"]] = self._kin.tool_pose(row[OBS_SLICES["arm_qpos"]])[0]
        out[:, STATE_SLICES["gear_pos"]] = obs2[:, OBS_SLICES["gear_pos"]]
        out[:, STATE_SLICES["human_pos"]] = obs2[:, OBS_SLICES["human_pos"]]
        return out[0] if single else out


def tool_human_distance(states: FloatArray) -> FloatArray:
    """(N,) distance (m) between the left tool point and the human hand in planner states
    (N, 22): a cheap proxy of the robot-human distance for termination conditions."""
    s = np.atleast_2d(states)
    d: FloatArray = np.linalg.norm(s[:, STATE_SLICES["tool_pos"]] - s[:, STATE_SLICES["human_pos"]],
                                   axis=1)
    return d


def proximity_beta(states: FloatArray, near: float = 0.2, far: float = 0.45,
                   beta_max: float = 0.9) -> FloatArray:
    """Termination probability that rises as the human comes close (the paper's
    "inversely proportional to closeness"): 0 beyond ``far`` (m), ``beta_max`` within
    ``near``, linear in between. (N, 22) -> (N,)."""
    d = tool_human_distance(states)
    out: FloatArray = beta_max * np.clip((far - d) / (far - near), 0.0, 1.0)
    return out


__all__ = ["DECISION_DT", "DECISION_STEPS", "STATE_DIM", "STATE_NAMES", "STATE_SLICES",
           "PlannerState", "proximity_beta", "tool_human_distance"]
