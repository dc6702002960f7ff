"""The ``insert`` option: a neural-network policy that wiggles the held gear onto the peg.

The policy ``pi_insert`` is a small torch MLP (:class:`InsertionNetwork`) trained by
behaviour cloning with noise injection from scripted insertion demonstrations
(:mod:`dynoplan.envs.gear.options.insert_training`). Every env step it maps features of
the observation (:func:`insertion_features`) to a small step of the left arm's joint
targets:

- input (20,): the gear's bottom centre relative to the peg tip and the gear's axis, both
  in the peg frame (``z`` = the peg axis, so ``-z`` of the first is the insertion depth),
  the left arm's joint angles and velocities, and the two finger openings;
- output (6,): ``delta q`` (rad), the next left-arm joint target minus the current left-arm
  joint angles; the action is ``q_left + clip(delta q, +-max_joint_step)``, clipped to the
  joint limits.

Inputs and outputs are standardised inside the network (statistics of the training rows,
stored in the file). The gripper stays closed (1.0); the right arm's targets are its joint
angles observed at ``reset`` (held fixed, so the peg does not drift while the option runs).

Termination of the running policy is judged from the observation: ``"done"`` as soon as
the observed gear pose is seated on the observed peg pose
(:func:`dynoplan.envs.gear.task.is_seated`), ``"failed"`` when the gear is more than
``fail_distance`` from the peg tip (dropped). For the planner, :meth:`InsertPolicy.termination`
gives ``beta_insert`` on planner states (see :func:`insert_termination`).

Model files: safetensors arrays plus JSON metadata (kind ``gear_insertion_policy``, format
version, feature and output names and sizes, hidden sizes, the training report), no
pickle (:mod:`dynoplan.models.storage`).
"""

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import mujoco
import numpy as np
import torch
from torch import nn

from dynoplan.envs.gear.env import GRIPPER_CLOSED, OBS_DIM, OBS_SLICES, RIGHT_HOLD, GearAssemblyEnv
from dynoplan.envs.gear.grasp import quat_to_mat
from dynoplan.envs.gear.options.base import GearOptionPolicy, start_joints
from dynoplan.envs.gear.options.motion import reseed_ompl
from dynoplan.envs.gear.options.moves import FastMovePolicy
from dynoplan.envs.gear.options.pick import PickPolicy
from dynoplan.envs.gear.options.starts import StartConfig, displace
from dynoplan.envs.gear.scene import RIGHT_ARM_JOINTS, build_model
from dynoplan.envs.gear.state import STATE_DIM, STATE_SLICES, proximity_beta
from dynoplan.envs.gear.task import RADIAL_TOLERANCE, SEAT_DEPTH, is_seated, relation
from dynoplan.errors import DynoplanError
from dynoplan.models.mlp import MLP, uniform_weight_init
from dynoplan.models.mlp_file import (
    check_parameter_count,
    hidden_sizes,
    linear_arrays,
    load_linears,
    require_finite,
)
from dynoplan.models.storage import load_arrays, save_arrays
from dynoplan.options.state_map import CoordinateMap
from dynoplan.options.termination import Termination, TerminationFromCallable
from dynoplan.types import FloatArray, Generator

INSERT_NAME = "insert"
"""The option's name (its registry record, datasets, model files, the command line)."""
INSERT_STATE = CoordinateMap(STATE_DIM, (
    *range(STATE_SLICES["arm_qpos"].start, STATE_SLICES["arm_qpos"].start + 6),
    *range(STATE_SLICES["gripper"].start, STATE_SLICES["human_pos"].stop)))
"""The insertion's own state (16 of the planner state's 22 values): what it moves, the
left arm's six joints, the gripper, the tool and the gear, and what acts on it, the
human's hand (which may block the way to the peg, and whose nearness ends the
insertion, :func:`insert_termination`). It leaves out the right
arm, which holds the peg still: in a rollout of the insertion on this state its joints
stay where they were (``gear run --own-states``). Without the hand (13 values) the
insertion's one-step errors on held-out runs are larger than on the planner state;
with it they are smaller (``docs/transfer.md``, "An option on its own state")."""


def after_the_moves(env: GearAssemblyEnv, rng: Generator, config: StartConfig) -> bool:
    """Start at a noisy pre-insertion pose reached as the task reaches it: the ``pick``
    option grasps and lifts the gear (its scripted form, without the recogniser: the
    grasp the recogniser then confirms), the ``fast_move`` option carries it to the
    pre-insertion pose, and the left arm is held at a random joint offset
    (``config.insert_noise``) for ``config.settle_steps`` steps with the gear held
    (:func:`~dynoplan.envs.gear.options.starts.displace`). OMPL is reseeded from ``rng``
    first, so the start depends on ``rng`` alone.

    The insertion network learns from these starts. Trained from the expert's grasps
    instead (:func:`~dynoplan.envs.gear.options.starts.before_insertion`), a network
    could insert every gear the expert grasped and still hover above the peg with gears
    the ``pick`` option grasped: the fixed script chaining the options succeeded in 41 %
    of the episodes with one such network, 94 % with another (``docs/gear-options.md``,
    "Where the insertion starts")."""
    reseed_ompl(int(rng.integers(2**31 - 1)))
    obs, info = env.set_human_schedule(env.schedule)
    for policy in (PickPolicy(env, recognizer=None), FastMovePolicy(env)):
        policy.reset(obs, rng)
        for _ in range(config.max_expert_steps):
            obs, _, terminated, truncated, info = env.step(policy.act(obs))
            if terminated or truncated:
                return False
            if policy.finished():
                break
        if not policy.succeeded(info):
            return False
    return displace(env, rng, config) is not None


INSERT_START = after_the_moves
"""Where the option starts (its registry record's ``start``): the gear grasped by the pick
option, carried above the peg by the fast move, the arm displaced."""

MODEL_KIND = "gear_insertion_policy"
FEATURE_NAMES: tuple[str, ...] = (
    "gear_in_peg_x", "gear_in_peg_y", "gear_in_peg_z",
    "gear_axis_in_peg_x", "gear_axis_in_peg_y", "gear_axis_in_peg_z",
    *(f"q_left_{i}" for i in range(6)), *(f"qvel_left_{i}" for i in range(6)),
    "finger_left", "finger_right")
FEATURE_DIM = len(FEATURE_NAMES)
OUTPUT_NAMES: tuple[str, ...] = tuple(f"dq_left_{i}" for i in range(6))
OUTPUT_DIM = len(OUTPUT_NAMES)
OUTPUT_MEANING = "left-arm joint target minus current left-arm joint angles (rad)"
DEFAULT_HIDDEN = (128, 128)


def _as_observations(observations: FloatArray) -> FloatArray:
    obs = np.atleast_2d(np.asarray(observations, dtype=np.float64))
    if obs.ndim != 2 or obs.shape[1] != OBS_DIM:
        raise DynoplanError(f"gear observations have {OBS_DIM} values, got shape "
                            f"{np.shape(observations)}")
    return obs


def insertion_features(observations: FloatArray) -> FloatArray:
    """Observations (50,) or (N, 50) -> features (N, 20) in :data:`FEATURE_NAMES` order."""
    obs = _as_observations(observations)
    gear = obs[:, OBS_SLICES["gear_pos"]]
    tip = obs[:, OBS_SLICES["peg_pos"]]
    gear_rot = quat_to_mat(obs[:, OBS_SLICES["gear_quat"]])
    peg_rot = quat_to_mat(obs[:, OBS_SLICES["peg_quat"]])
    out = np.empty((len(obs), FEATURE_DIM))
    out[:, 0:3] = np.einsum("nji,nj->ni", peg_rot, gear - tip)  # R_peg^T (gear - tip)
    out[:, 3:6] = np.einsum("nji,nj->ni", peg_rot, gear_rot[:, :, 2])
    out[:, 6:12] = obs[:, OBS_SLICES["arm_qpos"]][:, :6]
    out[:, 12:18] = obs[:, OBS_SLICES["arm_qvel"]][:, :6]
    out[:, 18:20] = obs[:, OBS_SLICES["fingers"]]
    return out


def observed_relation_seated(observation: FloatArray) -> tuple[bool, float]:
    """From one observation (50,): whether the observed gear is seated on the observed peg,
    and the distance (m) from the gear's bottom centre to the peg tip."""
    obs = _as_observations(observation)
    gear_rot = quat_to_mat(obs[:, OBS_SLICES["gear_quat"]])[0]
    peg_rot = quat_to_mat(obs[:, OBS_SLICES["peg_quat"]])[0]
    rel = relation(obs[0, OBS_SLICES["gear_pos"]], gear_rot, obs[0, OBS_SLICES["peg_pos"]],
                   peg_rot)
    return is_seated(rel), rel.distance


class InsertionNetwork:
    """``pi_insert``'s network: standardised features (20,) -> standardised joint step (6,).

    An MLP with SiLU activations, float32 inside; :meth:`predict` takes and returns
    float64 in physical units (features as :func:`insertion_features`, steps in rad).

    Args:
        hidden_sizes: widths of the hidden layers.
        seed: seeds the weight initialisation (a local ``torch.Generator``).

    Attributes:
        network: the :class:`~dynoplan.models.mlp.MLP` (float32).
        input_mean, input_std: (20,) float64 feature standardisation.
        output_mean, output_std: (6,) float64 standardisation of the joint step.
        report: what the training measured (data, time, losses); stored in the file.
    """

    def __init__(self, hidden_sizes: Sequence[int] = DEFAULT_HIDDEN, seed: int = 0) -> None:
        if not hidden_sizes or min(hidden_sizes) < 1:
            raise DynoplanError(f"the insertion network needs hidden layers of width >= 1, "
                                f"got {tuple(hidden_sizes)}")
        self.hidden_sizes = tuple(int(h) for h in hidden_sizes)
        self.network = MLP([FEATURE_DIM, *self.hidden_sizes, OUTPUT_DIM], uniform_weight_init,
                           torch.Generator().manual_seed(int(seed)))
        self.input_mean = np.zeros(FEATURE_DIM)
        self.input_std = np.ones(FEATURE_DIM)
        self.output_mean = np.zeros(OUTPUT_DIM)
        self.output_std = np.ones(OUTPUT_DIM)
        self.report: dict[str, Any] = {}

    @property
    def linears(self) -> list[nn.Linear]:
        return cast(list[nn.Linear], list(self.network.linears))

    def set_normalisation(self, features: FloatArray, steps: FloatArray) -> None:
        """Standardise with the mean and standard deviation of ``features`` (N, 20) and
        ``steps`` (N, 6) (a floor of 1e-6 on the deviations)."""
        x = np.asarray(features, dtype=np.float64)
        y = np.asarray(steps, dtype=np.float64)
        self.input_mean = x.mean(axis=0)
        self.input_std = np.maximum(x.std(axis=0), 1e-6)
        self.output_mean = y.mean(axis=0)
        self.output_std = np.maximum(y.std(axis=0), 1e-6)

    def normalise(self, features: FloatArray,
                  steps: FloatArray | None = None) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Float32 tensors of standardised features (N, 20) and, if given, steps (N, 6)."""
        x = (np.asarray(features, dtype=np.float64) - self.input_mean) / self.input_std
        xt = torch.from_numpy(x.astype(np.float32))
        if steps is None:
            return xt, None
        y = (np.asarray(steps, dtype=np.float64) - self.output_mean) / self.output_std
        return xt, torch.from_numpy(y.astype(np.float32))

    def predict(self, features: FloatArray) -> FloatArray:
        """Features (N, 20) -> joint steps (N, 6) float64, rad."""
        x = np.asarray(features, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != FEATURE_DIM:
            raise DynoplanError(f"insertion features must have shape (N, {FEATURE_DIM}), "
                                f"got {x.shape}")
        xt, _ = self.normalise(x)
        with torch.no_grad():
            out = self.network(xt).numpy().astype(np.float64)
        result: FloatArray = out * self.output_std + self.output_mean
        return result

    # ------------------------------------------------------------------ files
    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the network to ``path`` (safetensors + JSON metadata, atomically)."""
        arrays = linear_arrays(self.network)
        arrays["input_mean"] = self.input_mean
        arrays["input_std"] = self.input_std
        arrays["output_mean"] = self.output_mean
        arrays["output_std"] = self.output_std
        meta = {"input_dim": FEATURE_DIM, "output_dim": OUTPUT_DIM,
                "feature_names": list(FEATURE_NAMES), "output_names": list(OUTPUT_NAMES),
                "output": OUTPUT_MEANING, "hidden_sizes": list(self.hidden_sizes),
                "activation": "silu", "report": self.report}
        return save_arrays(path, MODEL_KIND, arrays, meta)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> "InsertionNetwork":
        """Read a network written by :meth:`save`.

        Raises:
            DynoplanError: missing, truncated or corrupt file, another kind of model,
                other inputs or outputs, or arrays that do not match the metadata.
        """
        arrays, meta = load_arrays(path, MODEL_KIND)
        for key, want in (("input_dim", FEATURE_DIM), ("output_dim", OUTPUT_DIM),
                          ("feature_names", list(FEATURE_NAMES)),
                          ("output_names", list(OUTPUT_NAMES))):
            if meta.get(key) != want:
                raise DynoplanError(f"{path}: metadata '{key}' is {meta.get(key)!r}, this "
                                    f"dynoplan's insertion policy needs {want!r}")
        hidden = hidden_sizes(meta, path)
        check_parameter_count(path, arrays, [FEATURE_DIM, *hidden, OUTPUT_DIM])
        model = cls(hidden)
        expected = {"input_mean", "input_std", "output_mean", "output_std"}
        expected |= load_linears(model.network, arrays, path)
        extra = set(arrays) - expected
        if extra:
            raise DynoplanError(f"{path}: unexpected arrays {sorted(extra)} (the metadata "
                                f"describes {len(hidden)} hidden layers)")
        for name, dim in (("input_mean", FEATURE_DIM), ("input_std", FEATURE_DIM),
                          ("output_mean", OUTPUT_DIM), ("output_std", OUTPUT_DIM)):
            a = require_finite(arrays, name, (dim,), np.float64, path)
            if name.endswith("_std") and np.any(a <= 0.0):
                raise DynoplanError(f"{path}: array '{name}' must be positive")
            setattr(model, name, a.copy())
        report = meta.get("report", {})
        model.report = report if isinstance(report, dict) else {}
        return model


# ---------------------------------------------------------------------- termination
class PegTipModel:
    """The peg tip (3,) and axis (3,) as functions of the right arm's joints (6,).

    The peg module is part of the right hand, so its pose follows from the right arm's
    joints by forward kinematics of the robot-only model (as in
    :class:`~dynoplan.envs.gear.kinematics.ArmKinematics`). For batches of
    planner states it is linearised once about ``q_right0`` (central differences): the
    right arm does not move during the task, so its joints stay within a few mrad of it.
    """

    def __init__(self, q_right0: FloatArray = RIGHT_HOLD, eps: float = 1e-4) -> None:
        model = build_model(objects=False)
        data = mujoco.MjData(model)
        qadr = np.array([model.joint(j).qposadr[0] for j in RIGHT_ARM_JOINTS])
        site = model.site("peg_tip").id

        def tip_and_axis(q: FloatArray) -> tuple[FloatArray, FloatArray]:
            data.qpos[qadr] = q
            mujoco.mj_kinematics(model, data)
            return (data.site_xpos[site].copy(),
                    data.site_xmat[site].reshape(3, 3)[:, 2].copy())

        self.q_right0 = np.asarray(q_right0, dtype=np.float64).copy()
        self.tip0, self.axis0 = tip_and_axis(self.q_right0)
        self.jacobian = np.empty((3, 6))
        for j in range(6):
            dq = np.zeros(6)
            dq[j] = eps
            hi, _ = tip_and_axis(self.q_right0 + dq)
            lo, _ = tip_and_axis(self.q_right0 - dq)
            self.jacobian[:, j] = (hi - lo) / (2 * eps)

    def tip(self, q_right: FloatArray) -> FloatArray:
        """Right-arm joints (N, 6) -> peg tips (N, 3)."""
        out: FloatArray = self.tip0 + (np.atleast_2d(q_right) - self.q_right0) @ self.jacobian.T
        return out


def insert_termination(peg: PegTipModel | None = None, base: float = 0.02,
                       seat_ramp: float = 0.005) -> TerminationFromCallable:
    """``beta_insert`` on planner states (N, 22) -> (N,):
    ``max(seated, min(1, base + proximity_beta))``.

    - ``seated`` rises linearly from 0 at ``SEAT_DEPTH - seat_ramp`` to 1 at
      :data:`~dynoplan.envs.gear.task.SEAT_DEPTH` of the gear bottom (state 16:19) below
      the peg tip along the peg axis, and is 0 when the gear bottom is more than
      :data:`~dynoplan.envs.gear.task.RADIAL_TOLERANCE` off the axis. The peg tip comes
      from the state's right-arm joints (6:12) through ``peg`` (linearised forward
      kinematics); the planner state has no tilt, so tilt is not judged here.
    - ``base`` (per planner step) plus :func:`~dynoplan.envs.gear.state.proximity_beta`
      (rising as the human's hand comes close to the left tool).
    """
    model = peg or PegTipModel()

    def beta(states: FloatArray) -> FloatArray:
        s = np.atleast_2d(np.asarray(states, dtype=np.float64))
        tip = model.tip(s[:, STATE_SLICES["arm_qpos"]][:, 6:12])
        rel = s[:, STATE_SLICES["gear_pos"]] - tip
        along = rel @ model.axis0
        radial = np.linalg.norm(rel - along[:, None] * model.axis0, axis=1)
        depth = -along
        seated = np.clip((depth - (SEAT_DEPTH - seat_ramp)) / seat_ramp, 0.0, 1.0)
        seated = np.where(radial <= RADIAL_TOLERANCE, seated, 0.0)
        out: FloatArray = np.maximum(seated, np.minimum(1.0, base + proximity_beta(s)))
        return out

    return TerminationFromCallable(beta)


# ---------------------------------------------------------------------- the policy
@dataclass(frozen=True)
class InsertConfig:
    """Limits of the insertion policy."""

    max_joint_step: float = 0.08  # rad, largest change of a left-arm target per env step
    fail_distance: float = 0.12  # m, gear bottom this far from the peg tip -> "failed"
    termination_base: float = 0.02  # beta_insert away from the seat and the human
    settle_speed: float = 0.05  # rad/s: the network starts once every left joint is slower
    settle_steps: int = 20  # env steps the start pose is held at most before the network


class InsertPolicy(GearOptionPolicy):
    """``pi_insert``: the trained :class:`InsertionNetwork` in closed loop.

    ``reset(observation, rng)`` records the right arm's joints (its targets while the
    option runs) and judges the start; ``act(observation)`` returns the action (13,):
    left-arm joints plus the network's clipped step, right arm held, gripper closed
    (1.0). ``status`` becomes ``"done"`` when the observed gear is seated on the observed
    peg and ``"failed"`` when the gear is farther than ``fail_distance`` from the peg
    tip; once finished, the left arm holds its current joints. No motion planning
    (``plan_ms`` stays empty). Deterministic: ``rng`` is not used.

    The network learned from starts at rest. Started while the left arm still moves (a
    controller that switches as soon as the pre-insertion pose is reached), the policy
    first holds the start pose until every left joint is slower than
    ``config.settle_speed`` (at most ``config.settle_steps`` steps).
    """

    name = INSERT_NAME

    def __init__(self, env: GearAssemblyEnv, network: InsertionNetwork,
                 config: InsertConfig | None = None) -> None:
        super().__init__(env)
        self.network = network
        self.cfg = config or InsertConfig()
        self.limits = env.joint_limits.copy()
        self.steps = 0
        self._q_right = RIGHT_HOLD.copy()
        self._q_start = np.zeros(6)
        self._settled = True
        self._peg: PegTipModel | None = None

    @classmethod
    def from_file(cls, env: GearAssemblyEnv, path: str | os.PathLike[str],
                  config: InsertConfig | None = None) -> "InsertPolicy":
        """A policy around the network saved at ``path`` (see :meth:`InsertionNetwork.load`)."""
        return cls(env, InsertionNetwork.load(path), config)

    def reset(self, observation: FloatArray, rng: Generator) -> None:
        obs = _as_observations(observation)[0]
        self._q_right = start_joints(self.env, obs)[6:12]  # held, not the sagging measurement
        self.plan_ms = []
        self.steps = 0
        self.status = "running"
        self._q_start = obs[OBS_SLICES["arm_qpos"]][:6].copy()
        self._settled = False
        self._judge(obs)

    def act(self, observation: FloatArray) -> FloatArray:
        if self.status == "idle":
            raise RuntimeError("InsertPolicy.act called before reset")
        obs = _as_observations(observation)[0]
        self._judge(obs)
        q_left = obs[OBS_SLICES["arm_qpos"]][:6]
        if not self._settled:
            speed = float(np.abs(obs[OBS_SLICES["arm_qvel"]][:6]).max())
            self._settled = speed < self.cfg.settle_speed or self.steps >= self.cfg.settle_steps
        if self.status == "running" and not self._settled:
            q_left = self._q_start
        elif self.status == "running":
            step = self.network.predict(insertion_features(obs))[0]
            lim = self.cfg.max_joint_step
            q_left = q_left + np.clip(step, -lim, lim)
        target = np.clip(np.concatenate([q_left, self._q_right]), self.limits[:, 0],
                         self.limits[:, 1])
        self.steps += 1
        return np.concatenate([target, [GRIPPER_CLOSED]])

    def _judge(self, obs: FloatArray) -> None:
        if self.status != "running":
            return
        seated, distance = observed_relation_seated(obs)
        if seated:
            self.status = "done"
        elif distance > self.cfg.fail_distance:
            self.status = "failed"

    def succeeded(self, info: dict[str, Any]) -> bool:
        """The simulator says the gear is seated (``info["is_success"]``)."""
        return bool(info["is_success"])

    def termination(self) -> Termination:
        """``beta_insert`` (:func:`insert_termination`): 1 once the gear bottom is at the
        seated depth on the peg axis (the peg tip computed from the state's right-arm
        joints, linearised about those observed at the last ``reset``, or
        :data:`~dynoplan.envs.gear.env.RIGHT_HOLD` before any), else a small constant plus
        :func:`~dynoplan.envs.gear.state.proximity_beta`."""
        if self._peg is None or not np.array_equal(self._peg.q_right0, self._q_right):
            self._peg = PegTipModel(self._q_right)
        return insert_termination(self._peg, base=self.cfg.termination_base)


__all__ = ["DEFAULT_HIDDEN", "FEATURE_DIM", "FEATURE_NAMES", "INSERT_NAME", "INSERT_STATE",
           "MODEL_KIND", "OUTPUT_DIM", "OUTPUT_MEANING", "OUTPUT_NAMES", "InsertConfig",
           "InsertPolicy", "InsertionNetwork", "PegTipModel",
           "insert_termination", "insertion_features", "observed_relation_seated"]
