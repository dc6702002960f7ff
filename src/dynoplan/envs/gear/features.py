"""Named feature maps of planner states: what the goal heuristic and the regions read.

A learned model of the gear assembly sees a feature vector computed from the planner
state ``(N, 22)`` (:mod:`dynoplan.envs.gear.state`), chosen by name and recorded in the
models' manifest:

============  ====  ============================================================
name          size  features
============  ====  ============================================================
``task``      19    state columns 0:19: arm joints, gripper, tool point, gear (no
                    human)
``pose``      7     state columns 12:19: gripper, tool point, gear
``relative``  8     gripper; tool point minus gear (3); gear (3); tool-hand
                    distance capped at :data:`HUMAN_DISTANCE_CAP`
``objects``   7     ``relative`` without the tool-hand distance
``peg_objects`` 7   gripper; tool point minus gear (3); gear minus the peg tip (3),
                    the tip by forward kinematics of the right arm's joints
``peg_relative`` 8  ``peg_objects`` and the capped tool-hand distance
============  ====  ============================================================

``objects`` is what the goal heuristic of ``dynoplan gear run`` reads: where the task
stands does not depend on where the human is, and the goal is asked about the states the
options' dynamics imagine, which predict the tool and the gear better than the joint
angles that take the tool there. ``relative`` is what the safety regions and the
initiation learned from outcomes read. With 10 demonstrations, joint angles mislead a
region (the planning options reach one tool pose through other arm configurations), and
the gear's random start on the table spreads the pick states over an area 10
demonstrations sample thinly; the tool's offset from the gear is the same for every
start. The capped tool-hand distance lets a region learn that an option was only
demonstrated with the human away (the operator moves cautiously, or backs off, when the
hand comes near); beyond the cap, where the hand is does not matter.

``peg_objects`` is what the downstream task's goal heuristic reads
(:mod:`dynoplan.envs.gear.peg_pose`: the peg held at another pose each episode): the
gear's place relative to the peg, not in the world. The peg module is part of the right
hand, so the peg tip follows from the state's right-arm joints (:class:`PegTip`); with
the first task's fixed peg it is ``objects`` with the gear shifted by a constant.
``peg_relative`` is ``relative`` read the same way (with the fixed peg: ``relative``
with the gear shifted by a constant), for the downstream task's regions.
"""

from collections.abc import Sequence
from typing import Any

import numpy as np

from dynoplan.envs.gear.linearise import linearised
from dynoplan.envs.gear.state import STATE_DIM, STATE_NAMES, STATE_SLICES, tool_human_distance
from dynoplan.errors import DynoplanError
from dynoplan.models.features import FeatureMap
from dynoplan.types import FloatArray

HUMAN_DISTANCE_CAP = 1.0
"""m: tool-hand distances beyond this read as this (the hand is out of the way)."""


def _columns(name: str, cols: Sequence[int]) -> FeatureMap:
    idx = np.asarray(cols, dtype=np.int64)
    return FeatureMap(name, tuple(STATE_NAMES[i] for i in cols), lambda s: s[:, idx], STATE_DIM)


def _capped_hand_distance(states: FloatArray) -> FloatArray:
    """``(N, 1)``: the tool-hand distance, capped at :data:`HUMAN_DISTANCE_CAP`."""
    out: FloatArray = np.minimum(tool_human_distance(states), HUMAN_DISTANCE_CAP)[:, None]
    return out


def _relative(states: FloatArray) -> FloatArray:
    tool, gear = states[:, STATE_SLICES["tool_pos"]], states[:, STATE_SLICES["gear_pos"]]
    return np.concatenate([states[:, STATE_SLICES["gripper"]], tool - gear, gear,
                           _capped_hand_distance(states)], axis=1)


class PegTip:
    """The peg tip (3,) of right-arm joints (6,) by forward kinematics of the robot-only
    model, for batches of planner states.

    Exact at each distinct right-arm configuration rounded to :attr:`ROUND` rad
    (cached, with its Jacobian), linear in between (the right arm holds still within
    an episode, its joints within a few mrad of their targets): well under a millimetre.
    """

    ROUND = 0.01
    """rad: the grid of the exact forward kinematics."""

    def __init__(self) -> None:
        self._model: Any = None
        self._cache: dict[bytes, tuple[FloatArray, FloatArray]] = {}

    def _exact(self, q: FloatArray) -> FloatArray:
        import mujoco

        from dynoplan.envs.gear.scene import RIGHT_ARM_JOINTS, build_model

        if self._model is None:
            self._model = build_model(objects=False)
            self._data = mujoco.MjData(self._model)
            self._qadr = np.array([self._model.joint(j).qposadr[0] for j in RIGHT_ARM_JOINTS])
            self._site = self._model.site("peg_tip").id
        self._data.qpos[self._qadr] = q
        mujoco.mj_kinematics(self._model, self._data)
        out: FloatArray = self._data.site_xpos[self._site].copy()
        return out

    def _linearised(self, q0: FloatArray) -> tuple[FloatArray, FloatArray]:
        return linearised(self._exact, q0, self._cache, 4096)

    def __call__(self, q_right: FloatArray) -> FloatArray:
        """Right-arm joints (N, 6) -> peg tips (N, 3)."""
        q = np.atleast_2d(np.asarray(q_right, dtype=np.float64))
        grid = np.round(q / self.ROUND) * self.ROUND
        keys, inverse = np.unique(grid, axis=0, return_inverse=True)
        out = np.empty((len(q), 3))
        for k, q0 in enumerate(keys):
            rows = inverse.reshape(-1) == k
            tip0, jacobian = self._linearised(np.ascontiguousarray(q0))
            out[rows] = tip0 + (q[rows] - q0) @ jacobian.T
        return out


_PEG_TIP = PegTip()


def _peg_objects(states: FloatArray) -> FloatArray:
    tool, gear = states[:, STATE_SLICES["tool_pos"]], states[:, STATE_SLICES["gear_pos"]]
    tip = _PEG_TIP(states[:, STATE_SLICES["arm_qpos"]][:, 6:12])
    return np.concatenate([states[:, STATE_SLICES["gripper"]], tool - gear, gear - tip],
                          axis=1)


def _peg_relative(states: FloatArray) -> FloatArray:
    return np.concatenate([_peg_objects(states), _capped_hand_distance(states)], axis=1)


TASK = _columns("task", range(STATE_SLICES["human_pos"].start))
POSE = _columns("pose", range(STATE_SLICES["gripper"].start, STATE_SLICES["human_pos"].start))
RELATIVE = FeatureMap("relative", ("gripper", "tool_minus_gear_x", "tool_minus_gear_y",
                                   "tool_minus_gear_z", "gear_x", "gear_y", "gear_z",
                                   "tool_hand_distance"), _relative, STATE_DIM)
OBJECTS = FeatureMap("objects", RELATIVE.names[:-1], lambda s: _relative(s)[:, :-1],
                     STATE_DIM)
PEG_OBJECTS = FeatureMap("peg_objects", ("gripper", "tool_minus_gear_x", "tool_minus_gear_y",
                                         "tool_minus_gear_z", "gear_minus_peg_x",
                                         "gear_minus_peg_y", "gear_minus_peg_z"),
                         _peg_objects, STATE_DIM)
PEG_RELATIVE = FeatureMap("peg_relative", (*PEG_OBJECTS.names, "tool_hand_distance"),
                          _peg_relative, STATE_DIM)
FEATURE_MAPS: dict[str, FeatureMap] = {m.name: m for m in (TASK, POSE, RELATIVE, OBJECTS,
                                                           PEG_OBJECTS, PEG_RELATIVE)}


def feature_map(name: str) -> FeatureMap:
    """The feature map called ``name`` (one of :data:`FEATURE_MAPS`)."""
    if name not in FEATURE_MAPS:
        raise DynoplanError(f"unknown feature map {name!r}; expected one of "
                            f"{', '.join(FEATURE_MAPS)}")
    return FEATURE_MAPS[name]


__all__ = ["FEATURE_MAPS", "HUMAN_DISTANCE_CAP", "OBJECTS", "PEG_OBJECTS", "PEG_RELATIVE",
           "POSE", "RELATIVE", "TASK", "FeatureMap", "PegTip", "feature_map"]
