"""Neural grasp recognition: does the left gripper hold the gear, judged from one observation?

The pick option (:mod:`~dynoplan.envs.gear.options.pick`) ends when this recogniser says
"grasped". It is a small torch MLP classifier over :data:`FEATURE_NAMES`, features of
the observation a real robot has:

==================  =====================================================================
feature             meaning
==================  =====================================================================
finger_left/right   the two left finger openings (m), from the finger joint encoders
gear_in_tool_x/y/z  the perceived gear bottom centre in the tool frame (m): forward
                    kinematics of the left arm joints, and the gear pose as perceived
tool_height         left tool point above the table top (m)
gear_height         perceived gear bottom above the table top (m)
gear_axis_z         ``z`` component of the gear's axis (cosine of its tilt)
==================  =====================================================================

(The gear pose "as perceived" is the observation's gear pose.) Output:
``P(grasped | observation)``.

**Label** (ground truth from the simulator, :func:`grasp_label`): both finger pads touch
the gear (``info["pads_on_gear"] >= 2``) and its bottom is off the table (more than
:data:`OFF_TABLE_HEIGHT` above the table top).

**Data** (:func:`generate_grasp_data`): seeded pick starts
(:func:`~dynoplan.envs.gear.options.starts.drive_to_start`) and the
pick option's own scripted grasp (:class:`PickPolicy` without a recogniser), with
perturbations that make both classes and the cases near the boundary common: a nominal
grasp, a grasp aimed off the gear by 0.5-4 cm (missed, one-pad and tilted grasps), the
gripper opened at a random moment of the close/lift/hold (the gear slips and drops), and
the gripper never closed (the tool lifts without the gear). The held-out set is a
random subset of whole episodes, never single steps of a training episode. Episode ``e``
depends on ``(seed, e)`` alone (:func:`grasp_episode`), so episodes can be generated in
any order, in any process, and give the same data.

**Files**: one safetensors file (float32 weights, float64 feature normalisation) with
JSON metadata (kind ``grasp_recognizer``, format version, feature names, hidden sizes,
the training report); see :mod:`dynoplan.models.storage`. No pickle.
"""

import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
import torch
from torch import nn

from dynoplan.envs.gear.env import GRIPPER_OPEN, OBS_DIM, OBS_SLICES, GearAssemblyEnv
from dynoplan.envs.gear.kinematics import ArmKinematics
from dynoplan.envs.gear.options.motion import reseed_ompl
from dynoplan.envs.gear.options.pick import PICK_NAME, PICK_START, PickPolicy
from dynoplan.envs.gear.options.starts import DATA_EPISODE_STEPS, drive_to_start
from dynoplan.envs.gear.scene import TABLE_TOP_Z
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
from dynoplan.models.trainer import deterministic_training, shuffled, train
from dynoplan.timing import without_wall_clock
from dynoplan.types import BoolArray, FloatArray, Generator, IntArray

MODEL_KIND = "grasp_recognizer"
FEATURE_NAMES: tuple[str, ...] = (
    "finger_left", "finger_right", "gear_in_tool_x", "gear_in_tool_y", "gear_in_tool_z",
    "tool_height", "gear_height", "gear_axis_z")
FEATURE_DIM = len(FEATURE_NAMES)
OFF_TABLE_HEIGHT = 0.005
"""A gear counts as grasped only with its bottom more than this (m) above the table."""
DEFAULT_HIDDEN = (32, 32)
DEFAULT_EPISODES = 80  # about 20 s of simulation on the 2-core development machine
DEFAULT_EPOCHS = 150
PERTURBATIONS = ("nominal", "offset", "release", "no_close")
PERTURBATION_WEIGHTS = (0.35, 0.35, 0.2, 0.1)


def grasp_features(observations: FloatArray, kin: ArmKinematics | None = None) -> FloatArray:
    """Observations (50,) or (N, 50) -> features (N, 8) in :data:`FEATURE_NAMES` order."""
    obs = np.atleast_2d(np.asarray(observations, dtype=np.float64))
    if obs.ndim != 2 or obs.shape[1] != OBS_DIM:
        raise DynoplanError(f"gear observations have {OBS_DIM} values, got shape {obs.shape}")
    kin = kin or ArmKinematics()
    out = np.empty((len(obs), FEATURE_DIM))
    out[:, 0:2] = obs[:, OBS_SLICES["fingers"]]
    gear = obs[:, OBS_SLICES["gear_pos"]]
    for i, row in enumerate(obs):
        tcp, rot = kin.tool_pose(row[OBS_SLICES["arm_qpos"]])
        out[i, 2:5] = rot.T @ (gear[i] - tcp)
        out[i, 5] = tcp[2] - TABLE_TOP_Z
    out[:, 6] = gear[:, 2] - TABLE_TOP_Z
    quat = obs[:, OBS_SLICES["gear_quat"]]
    out[:, 7] = 1.0 - 2.0 * (quat[:, 1] ** 2 + quat[:, 2] ** 2)
    return out


def grasp_label(observation: FloatArray, info: dict[str, Any]) -> bool:
    """Ground truth: both pads on the gear and the gear's bottom off the table."""
    gear_z = float(np.asarray(observation)[OBS_SLICES["gear_pos"]][2])
    return int(info["pads_on_gear"]) >= 2 and gear_z > TABLE_TOP_Z + OFF_TABLE_HEIGHT


class GraspRecognizer:
    """``P(grasped | observation)``: an MLP with SiLU over standardised features.

    Args:
        hidden_sizes: widths of the hidden layers.
        seed: seeds the weight initialisation (a local ``torch.Generator``).

    Attributes:
        network: the :class:`~dynoplan.models.mlp.MLP` (float32), standardised features
            -> one logit.
        feature_mean, feature_std: (8,) float64 standardisation.
        report: what :func:`fit_recognizer` measured (held-out accuracy, sizes, ...),
            stored in and read back from the file.
    """

    def __init__(self, hidden_sizes: Sequence[int] = DEFAULT_HIDDEN, seed: int = 0) -> None:
        if not hidden_sizes or min(hidden_sizes) < 1:
            raise DynoplanError(f"the recogniser needs hidden layers of width >= 1, got "
                                f"{tuple(hidden_sizes)}")
        self.hidden_sizes = tuple(int(h) for h in hidden_sizes)
        self.network = MLP([FEATURE_DIM, *self.hidden_sizes, 1], uniform_weight_init,
                           torch.Generator().manual_seed(int(seed)))
        self.feature_mean = np.zeros(FEATURE_DIM)
        self.feature_std = np.ones(FEATURE_DIM)
        self.report: dict[str, Any] = {}
        self._kin = ArmKinematics()

    @property
    def linears(self) -> list[nn.Linear]:
        return cast(list[nn.Linear], list(self.network.linears))

    # ------------------------------------------------------------------ inference
    def logits(self, features: FloatArray) -> FloatArray:
        """Features (N, 8) -> logits (N,) float64."""
        x = (np.asarray(features, dtype=np.float64) - self.feature_mean) / self.feature_std
        with torch.no_grad():
            out = self.network(torch.from_numpy(x.astype(np.float32)))[:, 0]
        return out.numpy().astype(np.float64)

    def probability(self, observations: FloatArray) -> FloatArray | float:
        """``P(grasped)``: an observation (50,) -> float; observations (N, 50) -> (N,)."""
        obs = np.asarray(observations, dtype=np.float64)
        logits = self.logits(grasp_features(obs, self._kin))
        with np.errstate(over="ignore"):  # a logit below -709: exp overflows, P is 0.0
            p: FloatArray = 1.0 / (1.0 + np.exp(-logits))
        return float(p[0]) if obs.ndim == 1 else p

    def accuracy(self, features: FloatArray, labels: BoolArray) -> float:
        """Fraction of rows whose decision ``P > 0.5`` equals the label."""
        if len(labels) == 0:
            return float("nan")
        return float(np.mean((self.logits(features) > 0.0) == np.asarray(labels, dtype=bool)))

    # ------------------------------------------------------------------ training
    def fit(self, features: FloatArray, labels: BoolArray, epochs: int = DEFAULT_EPOCHS,
            batch_size: int = 256, learning_rate: float = 3e-3, seed: int = 0) -> list[float]:
        """Minimise the binary cross-entropy with Adam (minibatches in an order drawn from a
        ``torch.Generator`` seeded with ``seed``); returns the mean loss per epoch. Sets the
        feature standardisation from ``features`` (N, 8)."""
        x = np.asarray(features, dtype=np.float64)
        y = np.asarray(labels, dtype=bool)
        if x.ndim != 2 or x.shape[1] != FEATURE_DIM or len(x) != len(y) or len(x) == 0:
            raise DynoplanError(f"training needs features (N, {FEATURE_DIM}) and N labels, "
                                f"got {x.shape} and {y.shape}")
        self.feature_mean = x.mean(axis=0)
        self.feature_std = np.maximum(x.std(axis=0), 1e-6)
        xt = torch.from_numpy(((x - self.feature_mean) / self.feature_std).astype(np.float32))
        yt = torch.from_numpy(y.astype(np.float32))
        optimiser = torch.optim.Adam(self.network.parameters(), lr=learning_rate)
        loss_fn = nn.BCEWithLogitsLoss()

        def loss(inputs: torch.Tensor, targets: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            bce = loss_fn(self.network(inputs)[:, 0], targets)
            return bce, bce

        rows = shuffled(len(xt), torch.Generator().manual_seed(int(seed)))
        report = train(self.network, loss, xt, yt, optimiser, rows, epochs=epochs,
                       batch_size=batch_size)
        return list(report.train_loss)

    # ------------------------------------------------------------------ files
    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the recogniser to ``path`` (safetensors + JSON metadata, atomically)."""
        arrays = linear_arrays(self.network)
        arrays["feature_mean"] = self.feature_mean
        arrays["feature_std"] = self.feature_std
        meta = {"feature_names": list(FEATURE_NAMES), "hidden_sizes": list(self.hidden_sizes),
                "activation": "silu", "output": "logit_grasped",
                "label": f"pads_on_gear >= 2 and gear bottom > table + {OFF_TABLE_HEIGHT} m",
                "report": self.report}
        return save_arrays(path, MODEL_KIND, arrays, meta)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> "GraspRecognizer":
        """Read a recogniser written by :meth:`save`.

        Raises:
            DynoplanError: missing, truncated or corrupt file, another kind of model,
                other features, or arrays that do not match the metadata.
        """
        arrays, meta = load_arrays(path, MODEL_KIND)
        if meta.get("feature_names") != list(FEATURE_NAMES):
            raise DynoplanError(f"{path}: recogniser features {meta.get('feature_names')!r} "
                                f"do not match this dynoplan's {list(FEATURE_NAMES)}")
        hidden = hidden_sizes(meta, path)
        check_parameter_count(path, arrays, [FEATURE_DIM, *hidden, 1])
        model = cls(hidden)
        expected = {"feature_mean", "feature_std"}
        expected |= load_linears(model.network, arrays, path)
        extra = set(arrays) - expected
        if extra:
            raise DynoplanError(f"{path}: unexpected arrays {sorted(extra)} (the metadata "
                                f"describes {len(hidden)} hidden layers)")
        model.feature_mean = require_finite(arrays, "feature_mean", (FEATURE_DIM,),
                                            np.float64, path)
        std = require_finite(arrays, "feature_std", (FEATURE_DIM,), np.float64, path)
        if np.any(std <= 0.0):
            raise DynoplanError(f"{path}: array 'feature_std' must be positive")
        model.feature_std = std
        report = meta.get("report", {})
        model.report = report if isinstance(report, dict) else {}
        return model


# ---------------------------------------------------------------------- data
@dataclass
class GraspData:
    """Labelled observations: ``observations`` (N, 50), ``labels`` (N,) bool,
    ``episodes`` (N,) episode index of each row, ``perturbations`` (E,) the kind of each
    episode (:data:`PERTURBATIONS`)."""

    observations: FloatArray
    labels: BoolArray
    episodes: IntArray
    perturbations: list[str]


@dataclass(frozen=True)
class DataConfig:
    """How :func:`generate_grasp_data` perturbs the scripted grasps."""

    offset_range: tuple[float, float] = (0.005, 0.04)  # m, grasp aimed this far off
    hold_steps: tuple[int, int] = (5, 25)  # env steps recorded after the pick finished
    max_steps: int = 400  # env steps per episode at most


@dataclass
class GraspEpisode:
    """One perturbed scripted pick: ``observations`` (T, 50), ``labels`` (T,) bool and
    its ``perturbation`` (:data:`PERTURBATIONS`)."""

    observations: FloatArray
    labels: BoolArray
    perturbation: str


def grasp_episode(env: GearAssemblyEnv, policy: PickPolicy, seed: int, episode: int,
                  config: DataConfig | None = None) -> GraspEpisode:
    """Episode ``episode`` of :func:`generate_grasp_data` for ``seed``, run in ``env`` with
    ``policy`` (a :class:`PickPolicy` without a recogniser on ``env``). Every random
    choice comes from ``default_rng([seed, 0, episode])`` and OMPL is reseeded from the
    same key, so the episode is the same in any process, after any other."""
    cfg = config or DataConfig()
    key = [int(seed), 0, int(episode)]
    reseed_ompl(int(np.random.SeedSequence(key).generate_state(1)[0]))
    rng = np.random.default_rng(key)
    kind = str(rng.choice(PERTURBATIONS, p=PERTURBATION_WEIGHTS))
    start = drive_to_start(env, PICK_START, rng, "away", option=PICK_NAME)
    obs, info = start.observation, start.info
    offset = np.zeros(3)
    if kind == "offset":
        angle = rng.uniform(-np.pi, np.pi)
        offset[:2] = rng.uniform(*cfg.offset_range) * np.array([np.cos(angle), np.sin(angle)])
    release_after = int(rng.integers(0, 60))  # steps after the closing starts
    hold = int(rng.integers(*cfg.hold_steps))
    perceived = obs.copy()
    perceived[OBS_SLICES["gear_pos"]] += offset
    policy.reset(perceived, rng)
    observations: list[FloatArray] = []
    labels: list[bool] = []
    closing_steps = 0
    extra = 0
    for _ in range(cfg.max_steps):
        observations.append(obs)
        labels.append(grasp_label(obs, info))
        perceived = obs.copy()
        perceived[OBS_SLICES["gear_pos"]] += offset
        action = policy.act(perceived)
        if policy.phase in ("close", "lift", "verify") or policy.finished():
            closing_steps += 1
        if kind == "no_close" or (kind == "release" and closing_steps > release_after):
            action[12] = GRIPPER_OPEN
        obs, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            break
        if policy.finished():
            extra += 1
            if extra > hold:
                break
    return GraspEpisode(np.array(observations).reshape(-1, OBS_DIM),
                        np.array(labels, dtype=bool), kind)


def grasp_data(episodes: Sequence[GraspEpisode]) -> GraspData:
    """The episodes as one :class:`GraspData` (rows of episode ``e`` labelled ``e``)."""
    return GraspData(
        observations=np.concatenate([e.observations for e in episodes]),
        labels=np.concatenate([e.labels for e in episodes]),
        episodes=np.concatenate([np.full(len(e.labels), i, dtype=np.int64)
                                 for i, e in enumerate(episodes)]),
        perturbations=[e.perturbation for e in episodes])


def generate_grasp_data(env: GearAssemblyEnv, episodes: int, seed: int,
                        config: DataConfig | None = None) -> GraspData:
    """Run ``episodes`` perturbed scripted picks from seeded starts and label every
    observation with :func:`grasp_label` (see the module docstring); episode ``e`` is
    :func:`grasp_episode` ``(seed, e)``, whatever ran before it."""
    if episodes < 1:
        raise DynoplanError(f"episodes must be >= 1, got {episodes}")
    policy = PickPolicy(env, recognizer=None)
    return grasp_data([grasp_episode(env, policy, seed, e, config) for e in range(episodes)])


def split_by_episode(data: GraspData, held_out_fraction: float,
                     rng: Generator) -> tuple[BoolArray, BoolArray]:
    """Row masks (train, held-out): a random ``held_out_fraction`` of whole episodes is
    held out (at least one episode each side when there are two or more)."""
    if not 0.0 < held_out_fraction < 1.0:
        raise DynoplanError(f"held_out_fraction must be in (0, 1), got {held_out_fraction}")
    ids = np.unique(data.episodes)
    n_out = round(held_out_fraction * len(ids))
    if len(ids) >= 2:
        n_out = min(max(n_out, 1), len(ids) - 1)
    out_ids = rng.permutation(ids)[:n_out]
    held = np.isin(data.episodes, out_ids)
    return ~held, held


def fit_recognizer(data: GraspData, seed: int = 0, held_out_fraction: float = 0.25,
                   hidden_sizes: Sequence[int] = DEFAULT_HIDDEN,
                   epochs: int = DEFAULT_EPOCHS) -> tuple[GraspRecognizer, dict[str, Any]]:
    """Train on the training episodes of ``data`` and measure on the held-out ones.

    Returns the recogniser (its ``report`` filled) and the report: ``held_out_accuracy``,
    ``train_accuracy``, sizes in rows and episodes, positive fractions, ``epochs``,
    ``final_loss``, ``train_seconds``. The same ``data`` and ``seed`` give the same
    weights to the bit on one machine (trained and measured inside
    :func:`~dynoplan.models.trainer.deterministic_training`).
    """
    rng = np.random.default_rng([int(seed), 1])
    train, held = split_by_episode(data, held_out_fraction, rng)
    kin = ArmKinematics()
    features = grasp_features(data.observations, kin)
    model = GraspRecognizer(hidden_sizes, seed=seed)
    with deterministic_training():
        t0 = time.perf_counter()
        losses = model.fit(features[train], data.labels[train], epochs=epochs, seed=seed)
        seconds = time.perf_counter() - t0
        held_out_accuracy = model.accuracy(features[held], data.labels[held])
        train_accuracy = model.accuracy(features[train], data.labels[train])
    report: dict[str, Any] = {
        "held_out_accuracy": held_out_accuracy,
        "train_accuracy": train_accuracy,
        "train_size": int(train.sum()),
        "held_out_size": int(held.sum()),
        "train_episodes": len(np.unique(data.episodes[train])),
        "held_out_episodes": len(np.unique(data.episodes[held])),
        "train_positive_fraction": float(data.labels[train].mean()),
        "held_out_positive_fraction": (float(data.labels[held].mean()) if held.any()
                                       else float("nan")),
        "epochs": int(epochs),
        "final_loss": float(losses[-1]),
        "train_seconds": float(seconds),
        "seed": int(seed),
    }
    model.report = dict(report)
    return model, report


def train_recognizer(out_path: str | os.PathLike[str] | None,
                     episodes: int | GraspData = DEFAULT_EPISODES, seed: int = 0,
                     held_out_fraction: float = 0.25, epochs: int = DEFAULT_EPOCHS,
                     hidden_sizes: Sequence[int] = DEFAULT_HIDDEN) -> dict[str, Any]:
    """Generate ``episodes`` of labelled grasp data in a fresh env (or take the given
    :class:`GraspData`), train, measure on the held-out episodes and save to ``out_path``
    (skipped when ``None``).

    Returns the report of :func:`fit_recognizer` plus ``episodes``, ``data_seconds``,
    ``seconds`` (total wall time) and ``path``.
    """
    t0 = time.perf_counter()
    if isinstance(episodes, GraspData):
        data = episodes
    else:
        env = GearAssemblyEnv(max_episode_steps=DATA_EPISODE_STEPS)
        try:
            data = generate_grasp_data(env, episodes, seed)
        finally:
            env.close()
    data_seconds = time.perf_counter() - t0
    model, report = fit_recognizer(data, seed=seed, held_out_fraction=held_out_fraction,
                                   hidden_sizes=hidden_sizes, epochs=epochs)
    report["episodes"] = len(data.perturbations)
    report["data_seconds"] = float(data_seconds)
    report["seconds"] = float(time.perf_counter() - t0)
    model.report = without_wall_clock(report)  # the file: the same bytes for the same fit
    if out_path is not None:
        model.save(out_path)
    report["path"] = None if out_path is None else str(out_path)
    return report


__all__ = ["FEATURE_NAMES", "MODEL_KIND", "OFF_TABLE_HEIGHT", "PERTURBATIONS", "DataConfig",
           "GraspData", "GraspEpisode", "GraspRecognizer", "fit_recognizer",
           "generate_grasp_data", "grasp_data", "grasp_episode", "grasp_features",
           "grasp_label", "split_by_episode", "train_recognizer"]
