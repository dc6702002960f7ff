"""Task geometry: the gear's pose relative to the peg, stages, success.

Everything here is read from the simulator's state (site and body poses, contacts); no
flag is ever set by hand.
"""

from dataclasses import dataclass

import numpy as np

from dynoplan.envs.gear.scene import GEAR
from dynoplan.types import FloatArray

SEAT_DEPTH = 0.035
"""Success depth (m): the gear's bottom face at least this far below the peg's tip, along
the peg's axis. The peg is 45 mm long and the gear 30 mm thick, so the whole bore is on
the peg and the gear is within 10 mm of the peg module's shoulder."""
TILT_TOLERANCE = np.deg2rad(5.0)
"""Success needs the gear's axis within this angle (rad) of the peg's axis."""
RADIAL_TOLERANCE = GEAR.bore_apothem - GEAR.peg_radius + 0.0015
"""Success needs the bore's centre within this distance (m) of the peg's axis."""
NEAR_PEG_DISTANCE = 0.05

STAGES = ("on_table", "in_hand", "near_peg", "on_peg", "seated", "loose")
"""Ground-truth task stages, in the order of the integer ``info["stage"]``:

- ``on_table``: the gear lies on the table, not held;
- ``in_hand``: both left finger pads touch the gear;
- ``near_peg``: held, with the bore's centre within 5 cm of the peg's tip;
- ``on_peg``: the peg is inside the bore (the gear's bottom is below the tip and the bore
  is around the peg axis) but not yet deep or straight enough;
- ``seated``: success (see :func:`is_seated`);
- ``loose``: none of the above (falling, tipped over, jammed off the peg, ...).
"""
STAGE_INDEX = {name: i for i, name in enumerate(STAGES)}


@dataclass(frozen=True)
class GearPegRelation:
    """The gear's pose relative to the peg."""

    depth: float  # m, gear bottom below the peg tip along the peg axis (negative: above)
    radial: float  # m, distance of the gear bottom's centre from the peg axis
    tilt: float  # rad, angle between gear axis and peg axis
    distance: float  # m, from the gear bottom's centre to the peg tip


def relation(gear_pos: FloatArray, gear_rot: FloatArray, peg_tip: FloatArray,
             peg_rot: FloatArray) -> GearPegRelation:
    """Gear (bottom centre (3,), rotation (3, 3)) relative to the peg (tip (3,), rotation
    (3, 3) whose ``z`` is the peg axis)."""
    axis = peg_rot[:, 2]
    rel = gear_pos - peg_tip
    along = float(rel @ axis)
    radial = float(np.linalg.norm(rel - along * axis))
    cos_tilt = float(np.clip(gear_rot[:, 2] @ axis, -1.0, 1.0))
    return GearPegRelation(depth=-along, radial=radial, tilt=float(np.arccos(cos_tilt)),
                           distance=float(np.linalg.norm(rel)))


def is_seated(r: GearPegRelation) -> bool:
    """Success: deep enough, straight enough and around the peg."""
    return r.depth >= SEAT_DEPTH and r.tilt <= TILT_TOLERANCE and r.radial <= RADIAL_TOLERANCE


def stage(r: GearPegRelation, pads_on_gear: int, on_table: bool) -> int:
    """Index into :data:`STAGES` for the current state."""
    if is_seated(r):
        return STAGE_INDEX["seated"]
    if r.depth > 0.0 and r.radial <= GEAR.bore_apothem:
        return STAGE_INDEX["on_peg"]
    if pads_on_gear >= 2:
        if r.distance <= NEAR_PEG_DISTANCE:
            return STAGE_INDEX["near_peg"]
        return STAGE_INDEX["in_hand"]
    if on_table:
        return STAGE_INDEX["on_table"]
    return STAGE_INDEX["loose"]
