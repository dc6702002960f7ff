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
"""

from collections.abc import Sequence

import numpy as np

from dynoplan.envs.gear.state import STATE_DIM, STATE_NAMES, STATE_SLICES, tool_human_distance
from dynoplan.errors import DynoplanError
from dynoplan.models.features import FeatureMap
from dynoplan.types import FloatArray

HUMAN_DISTANCE_CAP = 1.0
"""m: tool-hand distances beyond this read as this (the hand is out of the way)."""


def _columns(name: str, cols: Sequence[int]) -> FeatureMap:
    idx = np.asarray(cols, dtype=np.int64)
    return FeatureMap(name, tuple(STATE_NAMES[i] for i in cols), lambda s: s[:, idx], STATE_DIM)


def _relative(states: FloatArray) -> FloatArray:
    tool, gear = states[:, STATE_SLICES["tool_pos"]], states[:, STATE_SLICES["gear_pos"]]
    human = np.minimum(tool_human_distance(states), HUMAN_DISTANCE_CAP)
    return np.concatenate([states[:, STATE_SLICES["gripper"]], tool - gear, gear,
                           human[:, None]], axis=1)


TASK = _columns("task", range(STATE_SLICES["human_pos"].start))
POSE = _columns("pose", range(STATE_SLICES["gripper"].start, STATE_SLICES["human_pos"].start))
RELATIVE = FeatureMap("relative", ("gripper", "tool_minus_gear_x", "tool_minus_gear_y",
                                   "tool_minus_gear_z", "gear_x", "gear_y", "gear_z",
                                   "tool_hand_distance"), _relative, STATE_DIM)
OBJECTS = FeatureMap("objects", RELATIVE.names[:-1], lambda s: _relative(s)[:, :-1],
                     STATE_DIM)
FEATURE_MAPS: dict[str, FeatureMap] = {m.name: m for m in (TASK, POSE, RELATIVE, OBJECTS)}


def feature_map(name: str) -> FeatureMap:
    """The feature map called ``name`` (one of :data:`FEATURE_MAPS`)."""
    if name not in FEATURE_MAPS:
        raise DynoplanError(f"unknown feature map {name!r}; expected one of "
                            f"{', '.join(FEATURE_MAPS)}")
    return FEATURE_MAPS[name]


__all__ = ["FEATURE_MAPS", "HUMAN_DISTANCE_CAP", "OBJECTS", "POSE", "RELATIVE", "TASK",
           "FeatureMap", "feature_map"]
