"""Training data and behaviour cloning of the ``insert`` option's network.

Demonstrations: a scripted insertion teacher (:class:`ScriptedInserter`) reproduces the
expert's insertion (:class:`~dynoplan.envs.gear.expert.GearExpert`'s ``insert`` step: put
the gear on the peg axis with its axis aligned, by IK, lower it along the axis, wait above
the tip until centred) as a stateless function of the observation, from seeded noisy
pre-insertion poses (:func:`~dynoplan.envs.gear.options.starts.drive_to_start` with
``"insert"``, the human away). The expert itself keeps an internal commanded height and a
jam timer that the observation does not show; cloned directly, the learner hovered above
the tip (20% success in a first try), so the teacher has none.

Noise injection (DART, Laskey et al. 2017): the env executes the teacher's left-arm joint
targets plus Gaussian noise (std ``sigma`` rad per joint and step, ``sigma`` drawn per
episode uniformly from ``[0, noise_std]``), while the recorded label is the teacher's
clean step; so the data covers the states a slightly wrong learner drifts into, each with
the teacher's correction. A row is ``(insertion_features(obs), q_teacher[:6] - q[:6])``
for every step until the gear is seated, slips out of the hand, or ``max_steps``.

Training: mean squared error on standardised steps, Adam with a cosine-decayed learning
rate, whole episodes held out; the weights of the epoch with the lowest held-out loss are
kept.
"""

import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from dynoplan.envs.gear.env import GRIPPER_CLOSED, OBS_SLICES, GearAssemblyEnv
from dynoplan.envs.gear.grasp import quat_to_mat, rotation_between
from dynoplan.envs.gear.kinematics import ArmKinematics
from dynoplan.envs.gear.options.base import start_joints
from dynoplan.envs.gear.options.insert import (
    DEFAULT_HIDDEN,
    FEATURE_DIM,
    INSERT_NAME,
    INSERT_START,
    OUTPUT_DIM,
    OUTPUT_MEANING,
    InsertionNetwork,
    insertion_features,
)
from dynoplan.envs.gear.options.starts import DATA_EPISODE_STEPS, drive_to_start
from dynoplan.envs.gear.task import STAGE_INDEX, relation
from dynoplan.errors import DynoplanError
from dynoplan.models.trainer import (
    HoldOut,
    KeepBest,
    deterministic_training,
    shuffled,
    train,
)
from dynoplan.timing import without_wall_clock
from dynoplan.types import BoolArray, FloatArray, IntArray

DEFAULT_EPISODES = 80
DEFAULT_NOISE_STD = 0.01  # rad
DEFAULT_EPOCHS = 150


@dataclass
class InsertionDemos:
    """Behaviour-cloning rows from noisy-executed scripted insertions.

    Attributes:
        features: (N, 20) :func:`~dynoplan.envs.gear.options.insert.insertion_features`.
        steps: (N, 6) the teacher's clean left-arm joint step (rad).
        episodes: (N,) episode index of every row.
        n_episodes: episodes run (including ones that produced no row).
        seated: episodes that ended with the gear seated.
        noise_std: largest per-episode noise std (rad).
        seed: the seed the start states and noise came from.
    """

    features: FloatArray
    steps: FloatArray
    episodes: IntArray
    n_episodes: int
    seated: int
    noise_std: float
    seed: int

    def __len__(self) -> int:
        return len(self.features)


def ik_gear_on_axis(kin: ArmKinematics, q: FloatArray, gear: FloatArray,
                    gear_rot: FloatArray, tip: FloatArray, peg_rot: FloatArray,
                    height: float) -> FloatArray:
    """Arm joints (12,) that put the gear held at arm joints ``q`` (12,) with its bottom
    centre ``height`` (m) above the peg ``tip`` on the peg axis, the gear's axis on the
    peg's axis (the expert's pre-insertion IK; the roll about the approach axis is free)."""
    axis = peg_rot[:, 2]
    tcp, tool_rot = kin.tool_pose(q)
    offset = tool_rot.T @ (gear - tcp)  # gear bottom in the tool frame
    target_rot = rotation_between(gear_rot[:, 2], axis) @ tool_rot
    q1 = kin.solve(q, tip + axis * height - target_rot @ offset, target_rot, free_roll=True,
                   iterations=100).q
    _, rot1 = kin.tool_pose(q1)  # a second pass puts the bottom right for the roll found
    return kin.solve(q1, tip + axis * height - rot1 @ offset, rot1, free_roll=True,
                     iterations=100).q


@dataclass(frozen=True)
class TeacherConfig:
    """Gains of the scripted insertion teacher (m)."""

    lead_fast: float = 0.006  # commanded height below the current height, well above the tip
    lead_slow: float = 0.0025  # ... near the tip and in the bore
    slow_band: float = 0.01  # the lead blends from slow to fast over this height above the tip
    wait_height: float = 0.004  # hold here above the tip while not centred
    centred: tuple[float, float] = (0.001, 0.002)  # radial error: descend fully / not at all
    final_depth: float = 0.043  # deepest commanded depth (the shoulder is at 0.045)


class ScriptedInserter:
    """A scripted insertion teacher whose action depends on the observation only.

    Every step it commands the gear onto the peg axis with its axis aligned (the expert's
    insertion IK, :func:`ik_gear_on_axis`) at height ``h_cmd`` above the tip, where ``h``
    is the gear bottom's current height::

        h_cmd = max(h - lead(h), floor)
        floor = g * (-final_depth) + (1 - g) * wait_height   (above the tip)
        floor = -final_depth                                 (in the bore)

    ``lead`` blends from ``lead_slow`` at the tip to ``lead_fast`` ``slow_band`` above it,
    and the gate ``g`` falls from 1 to 0 as the radial error grows over ``centred``: a
    gear that is not centred waits (or rises to) ``wait_height`` above the tip. Unlike the
    expert's insert step it keeps no internal state (no commanded height, no jam timer),
    so its action is a continuous function of the observation that an MLP can clone.
    Privileged only in that it reads the exact gear and peg poses, which the observation
    holds as well.
    """

    def __init__(self, config: TeacherConfig | None = None) -> None:
        self.cfg = config or TeacherConfig()
        self.kin = ArmKinematics()

    def commanded_height(self, height: float, radial: float) -> float:
        """``h_cmd`` (m) for the gear bottom ``height`` above the tip and ``radial`` error."""
        c = self.cfg
        blend = float(np.clip(height / c.slow_band, 0.0, 1.0))
        lead = c.lead_slow + (c.lead_fast - c.lead_slow) * blend
        if height > 0.0:
            lo, hi = c.centred
            gate = float(np.clip((hi - radial) / (hi - lo), 0.0, 1.0))
            floor = -gate * c.final_depth + (1.0 - gate) * c.wait_height
        else:
            floor = -c.final_depth
        return max(height - lead, floor)

    def act(self, observation: FloatArray) -> FloatArray:
        """Observation (50,) -> action (13,): both arms' joint targets (the right arm
        where it is), gripper closed."""
        obs = np.asarray(observation, dtype=np.float64)
        q = obs[OBS_SLICES["arm_qpos"]]
        gear = obs[OBS_SLICES["gear_pos"]]
        tip = obs[OBS_SLICES["peg_pos"]]
        gear_rot = quat_to_mat(obs[None, OBS_SLICES["gear_quat"]])[0]
        peg_rot = quat_to_mat(obs[None, OBS_SLICES["peg_quat"]])[0]
        rel = relation(gear, gear_rot, tip, peg_rot)
        h_cmd = self.commanded_height(-rel.depth, rel.radial)
        q_cmd = ik_gear_on_axis(self.kin, q, gear, gear_rot, tip, peg_rot, h_cmd)
        return np.concatenate([q_cmd[:6], q[6:12], [GRIPPER_CLOSED]])


@dataclass
class InsertionEpisode:
    """One noisy-executed teacher insertion: ``features`` (T, 20), ``steps`` (T, 6) and
    whether it ended ``seated``."""

    features: FloatArray
    steps: FloatArray
    seated: bool


def insertion_episode(env: GearAssemblyEnv, teacher: ScriptedInserter, seed: int, episode: int,
                      noise_std: float = DEFAULT_NOISE_STD,
                      max_steps: int = 300) -> InsertionEpisode:
    """Episode ``episode`` of :func:`collect_demonstrations` for ``seed``: its start and
    noise come from ``default_rng([seed, episode])`` alone (no OMPL), so it is the same in
    any process, after any other."""
    rng = np.random.default_rng([int(seed), int(episode)])
    start = drive_to_start(env, INSERT_START, rng, "away", option=INSERT_NAME)
    sigma = noise_std * rng.uniform()
    obs, info = start.observation, start.info
    q_right = start_joints(env, obs)[6:12]  # held where commanded (measured angles sag)
    lim = env.joint_limits
    feats: list[FloatArray] = []
    steps: list[FloatArray] = []
    for _ in range(max_steps):
        action = teacher.act(obs)
        feats.append(insertion_features(obs)[0])
        steps.append(action[:6] - obs[:6])
        noisy = action.copy()
        noisy[:6] += rng.normal(0.0, sigma, size=6)
        noisy[6:12] = q_right
        noisy[:12] = np.clip(noisy[:12], lim[:, 0], lim[:, 1])
        obs, _, terminated, truncated, info = env.step(noisy)
        if terminated or truncated or (int(info["pads_on_gear"]) < 2
                                        and info["stage"] != STAGE_INDEX["on_peg"]):
            break  # seated, or the gear slipped out of the hand
    return InsertionEpisode(np.array(feats).reshape(-1, FEATURE_DIM),
                            np.array(steps).reshape(-1, OUTPUT_DIM),
                            bool(info["is_success"]))


def insertion_demos(episodes: Sequence[InsertionEpisode], seed: int,
                    noise_std: float) -> InsertionDemos:
    """The episodes (of ``seed`` and ``noise_std``) as one :class:`InsertionDemos`."""
    return InsertionDemos(
        features=np.concatenate([e.features for e in episodes]).reshape(-1, FEATURE_DIM),
        steps=np.concatenate([e.steps for e in episodes]).reshape(-1, OUTPUT_DIM),
        episodes=np.concatenate([np.full(len(e.features), i, dtype=np.int64)
                                 for i, e in enumerate(episodes)]),
        n_episodes=len(episodes), seated=sum(e.seated for e in episodes),
        noise_std=float(noise_std), seed=int(seed))


def check_demo_settings(episodes: int, noise_std: float, max_steps: int) -> None:
    """Raise :class:`DynoplanError` unless ``episodes, max_steps >= 1`` and
    ``noise_std >= 0``."""
    if episodes < 1 or max_steps < 1:
        raise DynoplanError(f"episodes and max_steps must be >= 1, got {episodes}, "
                            f"{max_steps}")
    if noise_std < 0.0:
        raise DynoplanError(f"noise_std must be >= 0, got {noise_std}")


def collect_demonstrations(env: GearAssemblyEnv, episodes: int, seed: int,
                           noise_std: float = DEFAULT_NOISE_STD, max_steps: int = 300,
                           teacher_config: TeacherConfig | None = None) -> InsertionDemos:
    """Run ``episodes`` noisy-executed teacher insertions (see the module docstring).

    Episode ``e`` is :func:`insertion_episode` ``(seed, e)``: it draws its start and noise
    from ``default_rng([seed, e])``.
    """
    check_demo_settings(episodes, noise_std, max_steps)
    teacher = ScriptedInserter(teacher_config)
    return insertion_demos([insertion_episode(env, teacher, seed, e, noise_std, max_steps)
                            for e in range(episodes)], seed, noise_std)


def split_episodes(episodes: IntArray, held_out_fraction: float,
                   seed: int) -> tuple[BoolArray, BoolArray]:
    """Row masks (train, held-out): a random ``held_out_fraction`` of whole episodes is
    held out (at least one episode each side when there are two or more)."""
    if not 0.0 < held_out_fraction < 1.0:
        raise DynoplanError(f"held_out_fraction must be in (0, 1), got {held_out_fraction}")
    ids = np.unique(episodes)
    n_out = round(held_out_fraction * len(ids))
    if len(ids) >= 2:
        n_out = min(max(n_out, 1), len(ids) - 1)
    out_ids = np.random.default_rng([int(seed), 2]).permutation(ids)[:n_out]
    held = np.isin(episodes, out_ids)
    return ~held, held


def fit_insertion(network: InsertionNetwork, demos: InsertionDemos, *,
                  epochs: int = DEFAULT_EPOCHS, batch_size: int = 256, lr: float = 2e-3,
                  weight_decay: float = 1e-5, held_out_fraction: float = 0.2,
                  seed: int = 0) -> dict[str, Any]:
    """Behaviour cloning: fit ``network`` to the demos' steps by mean squared error on
    standardised targets (Adam, cosine-decayed learning rate, shuffling from a seeded
    ``torch.Generator``), keeping the epoch with the lowest held-out loss. The same demos
    and ``seed`` give the same weights to the bit on one machine (trained inside
    :func:`~dynoplan.models.trainer.deterministic_training`).

    Returns the report: ``train_loss``/``held_out_loss`` per epoch (standardised MSE; 1.0
    is "predict the mean"), their values at the kept epoch, ``best_epoch``, sizes and
    ``train_seconds``. Raises :class:`DynoplanError` for too little data.
    """
    if len(demos) < 4 or len(np.unique(demos.episodes)) < 2:
        raise DynoplanError(f"behaviour cloning needs at least 4 rows from 2 episodes, got "
                            f"{len(demos)} rows from {len(np.unique(demos.episodes))}")
    if epochs < 1 or batch_size < 1 or lr <= 0.0:
        raise DynoplanError(f"epochs, batch_size and lr must be positive, got {epochs}, "
                            f"{batch_size}, {lr}")
    fit_rows, held = split_episodes(demos.episodes, held_out_fraction, seed)
    network.set_normalisation(demos.features[fit_rows], demos.steps[fit_rows])
    x, y = network.normalise(demos.features, demos.steps)
    assert y is not None
    tr, ho = torch.from_numpy(np.flatnonzero(fit_rows)), torch.from_numpy(np.flatnonzero(held))
    x_tr, y_tr, x_ho, y_ho = x[tr], y[tr], x[ho], y[ho]
    net = network.network

    def mse(inputs: torch.Tensor, targets: torch.Tensor) -> torch.Tensor:
        return torch.mean((net(inputs) - targets) ** 2)

    def loss(inputs: torch.Tensor, targets: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        batch_mse = mse(inputs, targets)
        return batch_mse, batch_mse

    optimiser = torch.optim.Adam(net.parameters(), lr=lr, weight_decay=weight_decay)
    with deterministic_training():
        report = train(net, loss, x_tr, y_tr, optimiser,
                       shuffled(len(x_tr), torch.Generator().manual_seed(int(seed))),
                       epochs=epochs, batch_size=batch_size,
                       schedule=torch.optim.lr_scheduler.CosineAnnealingLR(optimiser,
                                                                           T_max=epochs),
                       holdout=HoldOut(x_ho, y_ho,
                                       lambda inputs, targets: float(mse(inputs, targets))),
                       keep_best=KeepBest(start=True))
        with torch.no_grad():
            final_train = float(mse(x_tr, y_tr))
    # the kept epoch's held-out loss; +inf when none was finite (the starting weights)
    final_held_out = min((h for h in report.holdout_loss if not math.isnan(h)), default=math.inf)
    return {
        "epochs": int(epochs),
        "best_epoch": int(report.best_epoch),
        "train_seconds": float(report.seconds),
        "train_samples": int(fit_rows.sum()),
        "held_out_samples": int(held.sum()),
        "train_episodes": len(np.unique(demos.episodes[fit_rows])),
        "held_out_episodes": len(np.unique(demos.episodes[held])),
        "final_train_loss": final_train,
        "final_held_out_loss": float(final_held_out),
        "train_loss": list(report.train_loss),
        "held_out_loss": list(report.holdout_loss),
        "loss": "mean squared error of the standardised joint step",
        "batch_size": int(batch_size),
        "lr": float(lr),
        "weight_decay": float(weight_decay),
    }


def train_insertion(out_path: str | os.PathLike[str] | None,
                    demos: int | InsertionDemos = DEFAULT_EPISODES, seed: int = 0, *,
                    noise_std: float = DEFAULT_NOISE_STD, epochs: int = DEFAULT_EPOCHS,
                    hidden_sizes: Sequence[int] = DEFAULT_HIDDEN,
                    held_out_fraction: float = 0.2, max_steps: int = 300,
                    batch_size: int = 256, lr: float = 2e-3) -> dict[str, Any]:
    """Collect demonstrations (``demos`` episodes in a fresh env, or the given
    :class:`InsertionDemos`), train an :class:`InsertionNetwork` and save it to
    ``out_path`` (skipped when ``None``).

    Returns the report, also stored in the file's metadata: what the network was trained
    on (``episodes``, ``seated_demos``, ``samples``, ``noise_std``, ``demo_seed``) and for
    how long (``epochs``, ``data_seconds``, ``train_seconds``, ``seconds``), the final
    ``final_train_loss`` and ``final_held_out_loss`` (per-epoch curves are returned but
    not stored), and ``path``.
    """
    t0 = time.perf_counter()
    if isinstance(demos, InsertionDemos):
        data = demos
    else:
        env = GearAssemblyEnv(max_episode_steps=DATA_EPISODE_STEPS)
        try:
            data = collect_demonstrations(env, int(demos), seed, noise_std, max_steps)
        finally:
            env.close()
    data_seconds = time.perf_counter() - t0
    network = InsertionNetwork(hidden_sizes, seed=seed)
    fit = fit_insertion(network, data, epochs=epochs, batch_size=batch_size, lr=lr,
                        held_out_fraction=held_out_fraction, seed=seed)
    curves = {k: fit.pop(k) for k in ("train_loss", "held_out_loss")}
    report: dict[str, Any] = {
        "teacher": "ScriptedInserter (the expert's insertion, stateless)",
        "starts": f"reach_start(env, {INSERT_NAME!r}, default_rng([demo_seed, episode]))",
        "episodes": data.n_episodes,
        "seated_demos": data.seated,
        "samples": len(data),
        "noise_std": data.noise_std,
        "noise": "DART: executed left-arm targets + N(0, sigma^2), sigma ~ U(0, noise_std) "
                 "per episode; labels are the teacher's clean steps",
        "demo_seed": data.seed,
        "seed": int(seed),
        "hidden_sizes": list(network.hidden_sizes),
        "output": OUTPUT_MEANING,
        **fit,
        "data_seconds": float(data_seconds),
        "seconds": float(time.perf_counter() - t0),
    }
    network.report = without_wall_clock(report)  # the file: the same bytes for the same fit
    if out_path is not None:
        network.save(out_path)
    report["path"] = None if out_path is None else str(out_path)
    report.update(curves)
    return report


__all__ = ["DEFAULT_EPISODES", "DEFAULT_EPOCHS", "DEFAULT_NOISE_STD", "InsertionDemos",
           "InsertionEpisode", "ScriptedInserter", "TeacherConfig", "check_demo_settings",
           "collect_demonstrations", "fit_insertion", "ik_gear_on_axis", "insertion_demos",
           "insertion_episode", "split_episodes", "train_insertion"]
