"""A downstream gear task: the peg module held at a different pose each episode.

The same scene, the same options, another goal (the paper: "The dynamics can be learned
independently of the task, and can be used to solve a downstream task"). In the first
task (``dynoplan/GearAssembly-v0``) the right hand always holds the peg module at
:data:`~dynoplan.envs.gear.env.RIGHT_HOLD`, so the peg's tip is always at
``(0.615, -0.089, 0.911)``. Here (``dynoplan/GearPegPose-v0``,
:class:`GearPegPoseEnv`) the right hand holds it elsewhere in every episode:

- the peg tip's offset from the first task's is drawn uniformly from
  :data:`PEG_WORKSPACE` (``x`` and ``y`` in [-5, 5] cm, ``z`` in [-3, 3] cm), from the
  episode's generator, after the gear's pose and before the human's schedule (whose
  ``block`` events aim at the peg);
- the peg's axis stays vertical (within IK tolerance, 5 mrad); its yaw about that axis
  is whatever the right arm's inverse kinematics from ``RIGHT_HOLD`` gives (the arm is
  near its joint limits at ``RIGHT_HOLD``: a fixed yaw does not reach the whole box);
- the right arm is set there at reset (joints and their position targets) and holds
  still, as in the first task.

Success is the environment's own (``info["is_success"]``: the gear seated on the peg,
wherever it is), the demonstrator the first task's operator
(:class:`~dynoplan.envs.gear.operator.OptionOperator`: the options read the peg's pose
from the observation, so they already go to wherever it is). What the new task needs of
the learned parts is its own goal heuristic, on the features ``peg_objects``
(:data:`~dynoplan.envs.gear.features.PEG_OBJECTS`: where the gear is relative to the
peg, which the first task's ``objects`` features, with the gear's absolute position, do
not say when the peg moves). ``benchmarks/transfer/gear_peg_task.py`` fits and measures
it on a first task's options folder (``docs/transfer.md``).
"""

from dataclasses import dataclass
from typing import Any

import numpy as np

from dynoplan.envs.gear.env import HOME_Q, GearAssemblyEnv
from dynoplan.envs.gear.state import STATE_DIM, STATE_SLICES
from dynoplan.errors import DynoplanError
from dynoplan.models.features import FeatureMap
from dynoplan.models.outcome_initiation import OutcomeInitiation, OutcomeInitiationOnFeatures
from dynoplan.types import FloatArray

PEG_TASK_NAME = "gear_peg_pose"
"""The downstream task's name (its models' manifest, its summaries)."""

IK_TOLERANCE = 1e-3
"""m: the peg tip is placed at least this close to its drawn position, else the reset
fails (never within :data:`PEG_WORKSPACE`: ``tests/test_gear_peg_task.py`` checks its
corners)."""


@dataclass(frozen=True)
class PegWorkspace:
    """Where the peg tip may be, as offsets (m) from the first task's tip, per axis
    ``(low, high)`` of a uniform draw."""

    x: tuple[float, float] = (-0.05, 0.05)
    y: tuple[float, float] = (-0.05, 0.05)
    z: tuple[float, float] = (-0.03, 0.03)

    def __post_init__(self) -> None:
        for name, (low, high) in (("x", self.x), ("y", self.y), ("z", self.z)):
            if not low <= high:
                raise DynoplanError(f"peg workspace: {name} range ({low}, {high}) needs "
                                    "low <= high")

    @property
    def low(self) -> FloatArray:
        return np.array([self.x[0], self.y[0], self.z[0]])

    @property
    def high(self) -> FloatArray:
        return np.array([self.x[1], self.y[1], self.z[1]])

    def sample(self, rng: np.random.Generator) -> FloatArray:
        """(3,) an offset drawn uniformly from the box (three draws from ``rng``)."""
        out: FloatArray = rng.uniform(self.low, self.high)
        return out


PEG_WORKSPACE = PegWorkspace()
"""The downstream task's workspace: the peg tip within +-5 cm in ``x`` and ``y`` and
+-3 cm in ``z`` of the first task's."""


class RightHold:
    """Right-arm joints (6,) that hold the peg tip at a given offset from the first
    task's, axis vertical (IK of the robot-only model, seeded at ``RIGHT_HOLD``, yaw about
    the peg's axis free; deterministic)."""

    def __init__(self) -> None:
        from dynoplan.envs.gear.kinematics import ArmKinematics

        self.kin = ArmKinematics()
        model, data = self.kin.model, self.kin.data
        self.kin.tool_pose(HOME_Q, "r")  # forward kinematics at HOME_Q
        site = model.site("peg_tip").id
        self.tip0 = data.site_xpos[site].copy()
        self.rot0 = data.site_xmat[site].reshape(3, 3).copy()

    def __call__(self, offset: FloatArray) -> FloatArray:
        target = self.tip0 + np.asarray(offset, dtype=np.float64)
        result = self.kin.solve(HOME_Q, target, self.rot0, side="r", free_axis=2,
                                site="peg_tip", iterations=1000)
        if result.position_error > IK_TOLERANCE:
            raise DynoplanError(f"the right arm cannot hold the peg tip at offset "
                                f"{np.round(offset, 4).tolist()} (IK error "
                                f"{result.position_error * 1000:.1f} mm)")
        out: FloatArray = result.q[6:]
        return out


class GearPegPoseEnv(GearAssemblyEnv):
    """``dynoplan/GearPegPose-v0``: :class:`~dynoplan.envs.gear.env.GearAssemblyEnv` with
    the peg module held at a pose drawn from ``workspace`` at every reset (module
    docstring). ``reset(options={"peg_offset": (dx, dy, dz)})`` places it at that offset
    instead (no draw); ``peg_offset`` is the episode's offset (m)."""

    reset_options = ("peg_offset",)

    def __init__(self, workspace: PegWorkspace = PEG_WORKSPACE, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.workspace = workspace
        self.peg_offset = np.zeros(3)
        self._hold: RightHold | None = None

    def _place_peg(self, rng: np.random.Generator, options: dict[str, Any]) -> None:
        if "peg_offset" in options:
            offset = np.asarray(options["peg_offset"], dtype=np.float64).reshape(3)
        else:
            offset = self.workspace.sample(rng)
        if self._hold is None:
            self._hold = RightHold()
        q_right = self._hold(offset)
        ids = self.arm_qpos_ids[6:]
        self.data.qpos[ids] = q_right
        self.data.ctrl[self.arm_actuator_ids[6:]] = q_right
        self.peg_offset = offset


FIRST_TASK_RIGHT_ARM = np.array([-0.6790968, 0.23777644, -1.87470343, -1.6522002,
                                 1.30020109, -0.26837573])
"""(6,) rad: the first task's right arm as measured once it has settled under gravity at
:data:`~dynoplan.envs.gear.env.RIGHT_HOLD` (a few mrad below its targets; what the first
task's states hold, ``tests/test_gear_peg_task.py`` checks it)."""


class PegFrame:
    """The gear options' state in the first task's frame: a
    :class:`~dynoplan.options.state_map.StateMap` from this task's planner state (22,)
    to the state the first task's option dynamics were learned on (22,).

    The first task always held the peg at one pose; here it is elsewhere, by the offset
    ``d`` of its tip (forward kinematics of the state's right-arm joints,
    :class:`~dynoplan.envs.gear.features.PegTip`). ``to_option`` moves the scene by
    ``-d`` (the tool, the gear and the human hand: positions 13:22) and puts the right arm
    at :data:`FIRST_TASK_RIGHT_ARM`, so an option's dynamics see the peg where they
    always saw it; ``to_planner`` moves the option's predicted positions back by the
    planner state's ``d`` and keeps its right arm (which holds still). The left arm's
    joints are passed as they are (no map of them: the same tool pose relative to the
    peg needs other joints here; the dynamics see joints that reach a place offset by
    ``d``). Round trip: ``to_planner(s, to_option(s)) == s``.
    """

    planner_dim = STATE_DIM
    option_dim = STATE_DIM

    def __init__(self) -> None:
        from dynoplan.envs.gear.features import PegTip

        self._tip = PegTip()
        self._tip0 = self._tip(FIRST_TASK_RIGHT_ARM[None])[0]

    def offset(self, states: FloatArray) -> FloatArray:
        """``(..., 22)`` -> ``(..., 3)``: the peg tip's offset from the first task's."""
        s = np.asarray(states, dtype=np.float64)
        flat = s.reshape(-1, STATE_DIM)
        out: FloatArray = (self._tip(flat[:, 6:12]) - self._tip0).reshape(*s.shape[:-1], 3)
        return out

    def to_option(self, states: FloatArray) -> FloatArray:
        z = np.array(states, dtype=np.float64)
        d = self.offset(z)
        for part in _MOVED:
            z[..., part] -= d
        z[..., 6:12] = FIRST_TASK_RIGHT_ARM
        return z

    def to_planner(self, planner_states: FloatArray, option_states: FloatArray
                   ) -> FloatArray:
        s = np.asarray(planner_states, dtype=np.float64)
        out = np.array(option_states, dtype=np.float64)
        d = self.offset(s)
        for part in _MOVED:
            out[..., part] += d
        out[..., 6:12] = s[..., 6:12]
        return out


_MOVED = (STATE_SLICES["tool_pos"], STATE_SLICES["gear_pos"], STATE_SLICES["human_pos"])


def initiation_in_frame(learned: OutcomeInitiation | OutcomeInitiationOnFeatures,
                        frame: PegFrame) -> OutcomeInitiationOnFeatures:
    """The first task's initiation learned from the options' outcome runs, read in the
    first task's frame: at this task's planner states ``s`` ``(batch, 22)`` it answers
    what ``learned`` answers at ``frame.to_option(s)`` (on the same feature map, when it
    reads one). An option's outcome runs say where it reaches its own end, relative to
    a peg that never moved; the frame puts the scene back where they saw it, as it does
    for the option's dynamics."""
    if isinstance(learned, OutcomeInitiationOnFeatures):
        inner, features = learned.initiation, learned.features
    else:
        inner = learned
        features = FeatureMap("planner state", tuple(f"s{i}" for i in range(STATE_DIM)),
                              lambda states: np.asarray(states, dtype=np.float64), STATE_DIM)
    return OutcomeInitiationOnFeatures(inner, FeatureMap(
        f"{features.name} in the first task's frame", features.names,
        lambda states: features(frame.to_option(states)), STATE_DIM))


__all__ = ["FIRST_TASK_RIGHT_ARM", "IK_TOLERANCE", "PEG_TASK_NAME", "PEG_WORKSPACE",
           "GearPegPoseEnv", "PegFrame", "PegWorkspace", "RightHold", "initiation_in_frame"]
