"""The MuJoCo scene of the gear assembly: a PR2-like robot, a table, a gear, a peg, a human.

The scene is written as an MJCF string by :func:`scene_xml` and compiled by
:func:`build_model`. Every size is in metres, every angle in radians. The world frame has
``x`` pointing away from the robot over the table, ``z`` up, and the robot's torso at the
origin.

Collision groups (``contype`` / ``conaffinity`` bits) decide who touches whom:

====================  =====  ==================================================
group                  bit   collides with
====================  =====  ==================================================
table (box), floor       1   robot, gear rim, gear feet
robot (links, peg)       2   table, robot, gear rim, human
gear rim (ring boxes)    4   robot (fingers, peg module, arms), table
human (forearm, hand)    8   robot only
gear feet (3 pads)      16   table only
====================  =====  ==================================================

The gear rests on the table on three small pads under its large disc that stand 1 mm
proud of it: 3 contacts instead of the 60 or so a ring of boxes would make, which keeps
stepping fast. The ring boxes still collide with the table, so a tilted or dropped gear
lands on its rim.
"""

from dataclasses import dataclass

import mujoco
import numpy as np

TIMESTEP = 0.002  # physics step (s)

TABLE_TOP_Z = 0.72
TABLE_CENTER_XY = (0.78, 0.0)
TABLE_HALF_XY = (0.38, 0.6)

SHOULDER_Y = 0.188  # PR2 shoulder offset from the torso's mid-plane
SHOULDER_Z = 1.02
UPPER_ARM_LENGTH = 0.4  # shoulder lift -> elbow (PR2)
FOREARM_LENGTH = 0.321  # elbow -> wrist flex (PR2)
FINGER_BASE_X = 0.14  # wrist -> finger pads' base, along the approach axis
FINGER_LENGTH = 0.04
TCP_X = FINGER_BASE_X + FINGER_LENGTH - 0.01  # tool point: 1 cm behind the fingertips
FINGER_TRAVEL = 0.045  # each finger's opening from the gripper's mid-plane (m)

ARM_JOINT_SUFFIXES = (
    "shoulder_pan",
    "shoulder_lift",
    "upper_arm_roll",
    "elbow_flex",
    "forearm_roll",
    "wrist_flex",
)
LEFT_ARM_JOINTS = tuple(f"l_{s}_joint" for s in ARM_JOINT_SUFFIXES)
RIGHT_ARM_JOINTS = tuple(f"r_{s}_joint" for s in ARM_JOINT_SUFFIXES)
ARM_JOINTS = LEFT_ARM_JOINTS + RIGHT_ARM_JOINTS
"""The 12 arm joints in state order: left arm (6), then right arm (6)."""
FINGER_JOINTS = ("l_gripper_l_finger_joint", "l_gripper_r_finger_joint")
ARM_ACTUATORS = tuple(j.removesuffix("_joint") for j in ARM_JOINTS)
GRIPPER_ACTUATORS = ("l_gripper_l_finger", "l_gripper_r_finger")

# PR2 joint limits (rad). The forearm roll is continuous on the PR2; here it is limited
# to one turn, centred so that the "flipped wrist" of top grasps (roll = +-pi) is inside,
# so that planners get a bounded box.
_PAN_LEFT = (-0.7146, 2.2854)
_ROLL_LEFT = (-0.8, 3.9)
_LIMITS_COMMON = {
    "shoulder_lift": (-0.5236, 1.3963),
    "elbow_flex": (-2.3213, 0.0),
    "forearm_roll": (-0.5 * np.pi, 1.5 * np.pi),
    "wrist_flex": (-2.0944, 0.0),
}


def joint_limits(side: str) -> dict[str, tuple[float, float]]:
    """PR2 limits of one arm's six joints, keyed by suffix (``side`` is ``"l"`` or ``"r"``)."""
    mirror = side == "r"
    pan = (-_PAN_LEFT[1], -_PAN_LEFT[0]) if mirror else _PAN_LEFT
    roll = (-_ROLL_LEFT[1], -_ROLL_LEFT[0]) if mirror else _ROLL_LEFT
    fore = _LIMITS_COMMON["forearm_roll"]
    return {
        "shoulder_pan": pan,
        "shoulder_lift": _LIMITS_COMMON["shoulder_lift"],
        "upper_arm_roll": roll,
        "elbow_flex": _LIMITS_COMMON["elbow_flex"],
        "forearm_roll": (-fore[1], -fore[0]) if mirror else fore,
        "wrist_flex": _LIMITS_COMMON["wrist_flex"],
    }


# Position-servo stiffness per joint (N m / rad); critically damped by ``dampratio``.
_KP = {
    "shoulder_pan": 600.0,
    "shoulder_lift": 600.0,
    "upper_arm_roll": 300.0,
    "elbow_flex": 300.0,
    "forearm_roll": 80.0,
    "wrist_flex": 80.0,
}
_FORCE = {
    "shoulder_pan": 60.0,
    "shoulder_lift": 80.0,
    "upper_arm_roll": 40.0,
    "elbow_flex": 40.0,
    "forearm_roll": 15.0,
    "wrist_flex": 15.0,
}
GRIP_KP = 400.0  # finger servo stiffness (N/m)
GRIP_FORCE = 12.0  # finger force limit (N)
GRIP_CLOSED_TARGET = -0.01  # finger target when fully closed: squeezes what it holds


@dataclass(frozen=True)
class GearGeometry:
    """The compound gear and the peg (m). The gear frame's origin is the bottom centre
    of the large disc, its ``z`` axis the gear axis (the bore's axis)."""

    segments: int = 16
    bore_apothem: float = 0.0105
    large_radius: float = 0.040
    large_thickness: float = 0.010
    small_radius: float = 0.022
    small_thickness: float = 0.020
    peg_radius: float = 0.008
    peg_length: float = 0.045
    density: float = 640.0  # the ring boxes overlap near the bore: 640 kg/m3 gives ~70 g

    @property
    def height(self) -> float:
        return self.large_thickness + self.small_thickness

    @property
    def clearance(self) -> float:
        """Radial gap between the peg and the bore's flat faces."""
        return self.bore_apothem - self.peg_radius


GEAR = GearGeometry()

# The peg module, in the right gripper's palm frame (x = approach, y = finger axis, z up).
PEG_BLOCK_CENTER = (0.16, 0.0, 0.0)
PEG_BLOCK_HALF = (0.026, 0.02, 0.026)
PEG_BASE_Z = PEG_BLOCK_CENTER[2] + PEG_BLOCK_HALF[2]

HUMAN_HAND_HALF = (0.045, 0.04, 0.013)
HUMAN_FOREARM_RADIUS = 0.035
HUMAN_FOREARM_LENGTH = 0.26


def _f(values: tuple[float, ...] | list[float] | np.ndarray) -> str:
    return " ".join(f"{float(v):.6g}" for v in values)


def _ring(name: str, inner: float, outer: float, z0: float, thickness: float, n: int,
          cls: str) -> str:
    """A ring of ``n`` boxes: a hollow disc whose bore is a regular n-gon of apothem ``inner``."""
    half_radial = (outer - inner) / 2
    half_tangential = outer * np.tan(np.pi / n) + 1e-4
    r_mid = inner + half_radial
    parts = []
    for k in range(n):
        a = 2 * np.pi * k / n
        pos = (r_mid * np.cos(a), r_mid * np.sin(a), z0 + thickness / 2)
        parts.append(
            f'<geom name="{name}_{k}" class="{cls}" type="box" pos="{_f(pos)}" '
            f'euler="0 0 {a:.6g}" size="{_f((half_radial, half_tangential, thickness / 2))}"/>'
        )
    return "\n".join(parts)


def _arm(side: str) -> str:
    """One 6-DoF PR2-like arm with its gripper. The right gripper holds the peg module."""
    sign = 1.0 if side == "l" else -1.0
    lim = joint_limits(side)

    def joint(suffix: str, axis: str) -> str:
        lo, hi = lim[suffix]
        return (f'<joint name="{side}_{suffix}_joint" class="arm" axis="{axis}" '
                f'range="{lo:.6g} {hi:.6g}"/>')

    if side == "l":
        fingers = f"""
            <body name="l_gripper_l_finger" pos="{FINGER_BASE_X} 0 0">
              <joint name="l_gripper_l_finger_joint" class="finger" axis="0 1 0"/>
              <geom name="l_gripper_l_finger_pad" class="pad"
                    pos="{FINGER_LENGTH / 2} 0.004 0" size="{FINGER_LENGTH / 2} 0.004 0.011"/>
              <geom class="robot" type="box" pos="-0.008 0.012 0" size="0.008 0.012 0.011"/>
            </body>
            <body name="l_gripper_r_finger" pos="{FINGER_BASE_X} 0 0">
              <joint name="l_gripper_r_finger_joint" class="finger" axis="0 -1 0"/>
              <geom name="l_gripper_r_finger_pad" class="pad"
                    pos="{FINGER_LENGTH / 2} -0.004 0" size="{FINGER_LENGTH / 2} 0.004 0.011"/>
              <geom class="robot" type="box" pos="-0.008 -0.012 0" size="0.008 0.012 0.011"/>
            </body>"""
    else:
        bx, by, bz = PEG_BLOCK_CENTER
        hx, hy, hz = PEG_BLOCK_HALF
        g = GEAR
        fingers = f"""
            <geom name="r_gripper_l_finger_pad" class="robot" type="box"
                  pos="{FINGER_BASE_X + FINGER_LENGTH / 2} {hy + 0.004} 0"
                  size="{FINGER_LENGTH / 2} 0.004 0.011"/>
            <geom name="r_gripper_r_finger_pad" class="robot" type="box"
                  pos="{FINGER_BASE_X + FINGER_LENGTH / 2} {-hy - 0.004} 0"
                  size="{FINGER_LENGTH / 2} 0.004 0.011"/>
            <body name="peg_module" pos="{bx} {by} {bz}">
              <geom name="peg_block" class="robot" type="box" size="{hx} {hy} {hz}"
                    rgba="0.25 0.45 0.75 1" mass="0.15"/>
              <geom name="peg" class="robot" type="capsule" rgba="0.8 0.8 0.85 1" mass="0.02"
                    fromto="0 0 {hz - 0.004} 0 0 {hz + g.peg_length - g.peg_radius}"
                    size="{g.peg_radius}"/>
              <site name="peg_base" pos="0 0 {hz}" size="0.004"/>
              <site name="peg_tip" pos="0 0 {hz + g.peg_length}" size="0.004"/>
            </body>"""
    return f"""
    <body name="{side}_shoulder_pan_link" pos="0 {sign * SHOULDER_Y} {SHOULDER_Z}" gravcomp="1">
      {joint("shoulder_pan", "0 0 1")}
      <geom class="robot" type="cylinder" size="0.085 0.09" rgba="0.3 0.3 0.32 1"/>
      <body name="{side}_shoulder_lift_link" pos="0.1 0 0" gravcomp="1">
        {joint("shoulder_lift", "0 1 0")}
        <geom class="robot" type="sphere" size="0.07"/>
        <body name="{side}_upper_arm_roll_link" gravcomp="1">
          {joint("upper_arm_roll", "1 0 0")}
          <geom class="robot" type="capsule" fromto="0.07 0 0 0.33 0 0" size="0.055"/>
          <body name="{side}_elbow_flex_link" pos="{UPPER_ARM_LENGTH} 0 0" gravcomp="1">
            {joint("elbow_flex", "0 1 0")}
            <geom class="robot" type="sphere" size="0.048" rgba="0.3 0.3 0.32 1"/>
            <body name="{side}_forearm_roll_link" gravcomp="1">
              {joint("forearm_roll", "1 0 0")}
              <geom class="robot" type="capsule" fromto="0.06 0 0 0.26 0 0" size="0.043"/>
              <body name="{side}_wrist_flex_link" pos="{FOREARM_LENGTH} 0 0" gravcomp="1">
                {joint("wrist_flex", "0 1 0")}
                <geom class="robot" type="sphere" size="0.032" rgba="0.3 0.3 0.32 1"/>
                <body name="{side}_gripper_palm_link" gravcomp="1">
                  <geom name="{side}_gripper_palm" class="robot" type="box"
                        pos="0.082 0 0" size="0.05 0.04 0.022"/>
                  <site name="{side}_tcp" pos="{TCP_X} 0 0" size="0.005" rgba="1 0 0 0.5"/>
                  {fingers}
                </body>
              </body>
            </body>
          </body>
        </body>
      </body>
    </body>"""


def _gear() -> str:
    g = GEAR
    r_feet = 0.03
    feet = []
    for k, a in enumerate(np.deg2rad([90.0, 210.0, 330.0])):
        pos = (r_feet * np.cos(a), r_feet * np.sin(a), 0.002)
        feet.append(f'<geom name="gear_foot_{k}" class="gear_foot" pos="{_f(pos)}" size="0.003"/>')
    feet_xml = "\n".join(feet)
    return f"""
    <body name="gear" pos="0.6 0.25 {TABLE_TOP_Z}">
      <freejoint name="gear_free"/>
      {_ring("gear_large", g.bore_apothem, g.large_radius, 0.0, g.large_thickness, g.segments,
             "gear_rim")}
      {_ring("gear_small", g.bore_apothem, g.small_radius, g.large_thickness,
             g.small_thickness, g.segments, "gear_rim_small")}
      {feet_xml}
      <site name="gear_bottom" pos="0 0 0" size="0.003"/>
    </body>"""


def scene_xml(objects: bool = True) -> str:
    """The MJCF of the scene.

    Args:
        objects: include the table, gear and human. ``False`` gives the robot alone
            (same kinematics), used for inverse kinematics.
    """
    table = ""
    gear = ""
    human = ""
    if objects:
        cx, cy = TABLE_CENTER_XY
        hx, hy = TABLE_HALF_XY
        legs = "\n".join(
            f'<geom class="visual" type="box" pos="{cx + sx * (hx - 0.04)} {cy + sy * (hy - 0.04)}'
            f' {(TABLE_TOP_Z - 0.03) / 2}" size="0.025 0.025 {(TABLE_TOP_Z - 0.03) / 2}" '
            f'rgba="0.45 0.33 0.22 1"/>'
            for sx in (-1, 1) for sy in (-1, 1)
        )
        table = f"""
    <geom name="table" class="table" type="box" pos="{cx} {cy} {TABLE_TOP_Z - 0.02}"
          size="{hx} {hy} 0.02"/>
    {legs}"""
        gear = _gear()
        hx_, hy_, hz_ = HUMAN_HAND_HALF
        human = f"""
    <body name="human" mocap="true" pos="1.25 0.45 0.95">
      <geom name="human_hand" class="human" type="box" size="{hx_} {hy_} {hz_}"/>
      <geom name="human_forearm" class="human" type="capsule" size="{HUMAN_FOREARM_RADIUS}"
            fromto="{hx_ + 0.01} 0 0 {hx_ + 0.01 + HUMAN_FOREARM_LENGTH} 0 0"/>
    </body>"""
    # Robot-human contacts, counted inside MuJoCo on every physics step (the human
    # collides with nothing but the robot).
    sensors = ('<sensor><contact name="human_contact" body1="human" data="found"/></sensor>'
               if objects else "")
    return f"""
<mujoco model="dynoplan_gear_assembly">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{TIMESTEP}" integrator="implicitfast" cone="elliptic" impratio="10"/>
  <size memory="8M"/>
  <visual>
    <global offwidth="1280" offheight="960"/>
    <quality shadowsize="0"/>
  </visual>
  <default>
    <default class="robot">
      <geom contype="2" conaffinity="15" friction="0.8 0.005 0.0001" density="1000"
            rgba="0.82 0.82 0.85 1"/>
    </default>
    <default class="arm">
      <joint damping="1.0" armature="0.05" frictionloss="0.05"/>
    </default>
    <default class="finger">
      <joint type="slide" range="0 {FINGER_TRAVEL}" damping="60" armature="0.05"
             solreflimit="0.004 1"/>
    </default>
    <default class="pad">
      <geom type="box" contype="2" conaffinity="15" condim="4" friction="1.5 0.02 0.0005"
            solref="0.004 1" solimp="0.95 0.99 0.001" rgba="0.15 0.15 0.15 1"/>
    </default>
    <default class="gear_rim">
      <geom contype="4" conaffinity="3" condim="4" friction="1.0 0.02 0.0005"
            density="{GEAR.density}" rgba="0.85 0.6 0.1 1"/>
    </default>
    <default class="gear_rim_small">
      <geom contype="4" conaffinity="3" condim="4" friction="1.0 0.02 0.0005"
            density="{GEAR.density}" rgba="0.95 0.75 0.2 1"/>
    </default>
    <default class="gear_foot">
      <geom type="sphere" contype="16" conaffinity="1" condim="4" friction="0.8 0.01 0.0005"
            density="{GEAR.density}" rgba="0.85 0.6 0.1 1"/>
    </default>
    <default class="table">
      <geom contype="1" conaffinity="22" friction="0.8 0.005 0.0001" rgba="0.62 0.47 0.32 1"/>
    </default>
    <default class="human">
      <geom contype="8" conaffinity="2" rgba="0.93 0.72 0.6 1"/>
    </default>
    <default class="visual">
      <geom contype="0" conaffinity="0" group="1"/>
    </default>
  </default>
  <asset>
    <texture name="grid" type="2d" builtin="checker" rgb1="0.75 0.77 0.8" rgb2="0.68 0.7 0.73"
             width="256" height="256"/>
    <material name="floor" texture="grid" texrepeat="8 8"/>
  </asset>
  <worldbody>
    <light pos="0.6 -0.6 2.6" dir="-0.1 0.3 -1" diffuse="0.75 0.75 0.75"/>
    <light pos="-0.5 0.8 2.4" dir="0.4 -0.3 -1" diffuse="0.35 0.35 0.35"/>
    <geom name="floor" type="plane" size="3 3 0.1" material="floor" contype="1"
          conaffinity="20"/>
    <camera name="overview" pos="1.55 -0.85 1.55" xyaxes="0.633 0.774 0 -0.342 0.280 0.897"/>
    <camera name="closeup" pos="1.0 -0.5 1.2" xyaxes="0.809 0.588 0 -0.224 0.308 0.925"/>
    <body name="torso">
      <geom name="base" class="robot" type="box" pos="-0.12 0 0.17" size="0.33 0.33 0.17"
            rgba="0.3 0.3 0.32 1"/>
      <geom name="torso_column" class="robot" type="box" pos="-0.17 0 0.72" size="0.12 0.14 0.38"
            rgba="0.85 0.85 0.88 1"/>
      <geom name="head" class="robot" type="sphere" pos="-0.12 0 1.28" size="0.11"
            rgba="0.3 0.3 0.32 1"/>
      {_arm("l")}
      {_arm("r")}
    </body>
    {table}
    {gear}
    {human}
  </worldbody>
  <contact>
    <exclude body1="torso" body2="l_shoulder_pan_link"/>
    <exclude body1="torso" body2="r_shoulder_pan_link"/>
    <exclude body1="torso" body2="l_shoulder_lift_link"/>
    <exclude body1="torso" body2="r_shoulder_lift_link"/>
    <exclude body1="l_shoulder_pan_link" body2="l_upper_arm_roll_link"/>
    <exclude body1="r_shoulder_pan_link" body2="r_upper_arm_roll_link"/>
    <exclude body1="l_upper_arm_roll_link" body2="l_forearm_roll_link"/>
    <exclude body1="r_upper_arm_roll_link" body2="r_forearm_roll_link"/>
    <exclude body1="l_forearm_roll_link" body2="l_gripper_palm_link"/>
    <exclude body1="r_forearm_roll_link" body2="r_gripper_palm_link"/>
    <exclude body1="r_gripper_palm_link" body2="peg_module"/>
    <exclude body1="l_gripper_palm_link" body2="l_gripper_l_finger"/>
    <exclude body1="l_gripper_palm_link" body2="l_gripper_r_finger"/>
    <exclude body1="l_gripper_l_finger" body2="l_gripper_r_finger"/>
  </contact>
  <actuator>
    {_actuators()}
  </actuator>
  {sensors}
</mujoco>"""


def _actuators() -> str:
    lines = []
    for side in ("l", "r"):
        for suffix in ARM_JOINT_SUFFIXES:
            lo, hi = joint_limits(side)[suffix]
            lines.append(
                f'<position name="{side}_{suffix}" joint="{side}_{suffix}_joint" '
                f'kp="{_KP[suffix]}" dampratio="1" ctrlrange="{lo:.6g} {hi:.6g}" '
                f'forcerange="{-_FORCE[suffix]} {_FORCE[suffix]}"/>'
            )
    # Gripper command u in [0, 1] (0 open, 1 closed) -> finger target
    # FINGER_TRAVEL + u * (GRIP_CLOSED_TARGET - FINGER_TRAVEL); force = kp (target - q) - kv qdot.
    span = GRIP_CLOSED_TARGET - FINGER_TRAVEL
    for name, joint in zip(GRIPPER_ACTUATORS, FINGER_JOINTS, strict=True):
        lines.append(
            f'<general name="{name}" joint="{joint}" ctrlrange="0 1" '
            f'forcerange="{-GRIP_FORCE} {GRIP_FORCE}" biastype="affine" '
            f'gainprm="{GRIP_KP * span:.6g}" '
            f'biasprm="{GRIP_KP * FINGER_TRAVEL:.6g} {-GRIP_KP:.6g} 0"/>'
        )
    return "\n    ".join(lines)


def build_model(objects: bool = True) -> mujoco.MjModel:
    """Compile the scene (see :func:`scene_xml`)."""
    return mujoco.MjModel.from_xml_string(scene_xml(objects))
