"""Learned models of the gear assembly (issue 5): goal heuristic, safety regions, dynamics.

:func:`train_gear_models` fits, from the project's own data, everything DynoPlan plans
with, and measures it on held-out data:

- the goal heuristic ``G`` (:class:`~dynoplan.models.goal_network.GoalNetwork`, a Beta
  over progress) on every demonstration state, target = the demonstration's normalised
  progress ``infos["progress"]`` (``0`` for the reset observation);
- the safety regions of Eq. 5 (:class:`~dynoplan.models.regions.SafetyRegions`): a
  Gaussian mixture with ``M`` chosen by BIC on the demonstration states, components
  assigned to options by their states' labels, and per-option thresholds calibrated on
  the demonstrations by leave-one-demonstration-out (:func:`fit_regions_cross_validated`);
- one dynamics model ``D_w`` per option (:class:`~dynoplan.models.neural_dynamics.
  MLPEnsembleDynamics`) on transitions at the decision rate (one step =
  :data:`~dynoplan.envs.gear.state.DECISION_STEPS` environment steps), from the option
  transitions collected by ``dynoplan gear collect`` or, without them, from the
  demonstrations subsampled (:func:`demonstration_transitions`).

The goal heuristic reads the planner state without the human's hand (the ``task``
feature map, columns 0:19): where the task stands does not depend on where the human is,
and with 10 demonstrations the hand's varied positions otherwise become spurious cues
(pooled held-out Spearman 0.85 with the hand, 0.90 without). The regions read a named
feature map (:mod:`dynoplan.envs.gear.features`; ``task`` by default, ``relative`` in
``dynoplan gear run``). The human enters planning through the dynamics models (which
predict all 22 columns), the terminations and, with ``relative``, the regions.

Everything is saved in one folder (:func:`load_gear_models` reads it back): one
safetensors file per model and ``models.json``, the manifest (format version, state
dimension, option names, decision rate, feature columns and each file's SHA-256), so a
missing, truncated, modified or mismatched file is rejected with one error line.
"""

import hashlib
import json
import os
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from scipy import stats
from sklearn.neighbors import NearestNeighbors

from dynoplan.data import (
    Dataset,
    DatasetMetadata,
    Episode,
    labelled_transitions,
    read_dataset,
    write_dataset,
)
from dynoplan.envs.gear.env import OBS_DIM
from dynoplan.envs.gear.features import FEATURE_MAPS, TASK, FeatureMap, feature_map
from dynoplan.envs.gear.kinematics import ArmKinematics
from dynoplan.envs.gear.scene import ARM_JOINTS
from dynoplan.envs.gear.state import (
    DECISION_STEPS,
    STATE_DIM,
    STATE_NAMES,
    STATE_SLICES,
    PlannerState,
)
from dynoplan.envs.gear.task import OPTION_NAMES
from dynoplan.errors import DynoplanError
from dynoplan.io import ensure_writable_dir, write_json
from dynoplan.models.dynamics import StackedDynamics
from dynoplan.models.goal_network import GoalNetwork, evaluate_goal
from dynoplan.models.neural_dynamics import DEFAULT_HIDDEN, DEFAULT_MEMBERS, MLPEnsembleDynamics
from dynoplan.models.regions import SafetyRegions
from dynoplan.models.training import calibration, one_step_error
from dynoplan.progress import track
from dynoplan.types import BoolArray, FloatArray, Generator, IntArray

MODELS_KIND = "gear_models"
MODELS_FORMAT_VERSION = 2
"""2: feature maps are named (``"features": "task"``); 1 listed state columns."""
MANIFEST_FILE = "models.json"
METRICS_FILE = "metrics.json"
GOAL_FILE = "goal.safetensors"
REGIONS_FILE = "regions.safetensors"
HELDOUT_DIR = "heldout-demos"
HELDOUT_SEED_OFFSET = 1000
"""Held-out trials are recorded from ``seed + HELDOUT_SEED_OFFSET`` (disjoint episodes)."""
GOAL_FEATURES = TASK
"""What the goal heuristic reads: arm joints, gripper, tool point and gear (no human)."""
CAUTIOUS = OPTION_NAMES.index("cautious_move")
TRANSITIONS_ID = "dynoplan/gear-assembly/demo-transitions-v0"
_BATCH = 256


def dynamics_file(option: str) -> str:
    """File name of option ``option``'s dynamics model inside a models folder."""
    return f"dynamics-{option}.safetensors"


@dataclass(frozen=True)
class GearTrainSettings:
    """How :func:`train_gear_models` learns and evaluates (recorded in ``metrics.json``).

    Attributes:
        goal_hidden, goal_members, goal_epochs: the goal network (width of both hidden
            layers, ensemble size, epochs).
        region_reg_covar: variance (rad^2 or m^2) added to every mixture covariance's
            diagonal: a floor of about 5 cm / 0.05 rad on the regions' width, so that
            directions the 10 demonstrations hardly vary in do not make regions
            needle-thin.
        region_max_components: BIC chooses ``M`` in ``1..region_max_components``.
        region_coverage: fraction of an option's own demonstration states its threshold
            admits before the cross-validated slack.
        region_cv_coverage: fraction of left-out demonstrations' states of option ``k``
            that the final threshold of ``k`` is widened to admit.
        dynamics_hidden, dynamics_members, dynamics_epochs: each option's ensemble.
        dynamics_max_updates: fewer epochs when an option has so many transitions that
            ``dynamics_epochs`` would take more gradient steps than this (bounds the
            training time on large collections).
        dynamics_heldout_fraction: share of each option's transition episodes (grouped by
            their ``seed``) held out for the dynamics report, when option transitions are
            given.
        dynamics_calibration_fraction: share of the remaining runs (grouped the same way)
            kept out of the fit to calibrate the predicted spread
            (:meth:`~dynoplan.models.neural_dynamics.MLPEnsembleDynamics.calibrate`);
            options with runs from fewer than 4 seeds are not calibrated.
        n_step: decision steps of the n-step report.
        rollouts: Monte-Carlo rollouts per start state in the n-step report.
        heldout_episodes: held-out expert trials recorded when none are given.
        far_states: candidate far-away states for ``region_far_outside_rate``.
        region_features: name of the feature map the regions read
            (:data:`~dynoplan.envs.gear.features.FEATURE_MAPS`).
    """

    goal_hidden: int = 64
    goal_members: int = 3
    goal_epochs: int = 150
    region_reg_covar: float = 3e-3
    region_max_components: int = 8
    region_coverage: float = 0.99
    region_cv_coverage: float = 0.97
    dynamics_hidden: tuple[int, ...] = DEFAULT_HIDDEN
    dynamics_members: int = DEFAULT_MEMBERS
    dynamics_epochs: int = 50
    dynamics_max_updates: int = 1500
    dynamics_heldout_fraction: float = 0.2
    dynamics_calibration_fraction: float = 0.15
    n_step: int = 3
    rollouts: int = 32
    heldout_episodes: int = 10
    far_states: int = 2000
    region_features: str = TASK.name


DEFAULT_SETTINGS = GearTrainSettings()
QUICK_SETTINGS = GearTrainSettings(
    goal_hidden=32, goal_epochs=40, region_max_components=4, dynamics_hidden=(64, 64),
    dynamics_epochs=15, rollouts=8, heldout_episodes=3, far_states=400)
"""Small settings for CI and smoke tests (well under 30 s of training)."""


# --- models on the task columns ---------------------------------------------------------
class _OnFeatures:
    """A model of full planner states ``(batch, 22)`` that reads ``features(states)``."""

    def __init__(self, features: FeatureMap) -> None:
        self.features = features

    @property
    def state_dim(self) -> int:
        return STATE_DIM

    def _columns(self, states: FloatArray) -> FloatArray:
        return self.features(states)


class GoalOnFeatures(_OnFeatures):
    """The goal heuristic ``G(s)`` of full planner states, read from some of their columns.

    Satisfies :class:`~dynoplan.models.goal.GoalHeuristic` for ``(batch, state_dim)``
    states; ``network`` sees ``features(states)``.
    """

    def __init__(self, network: GoalNetwork, features: FeatureMap) -> None:
        super().__init__(features)
        self.network = network

    def sample(self, states: FloatArray, rng: Generator) -> FloatArray:
        """One draw of ``g ~ G(s)`` per state: ``(batch, state_dim)`` -> ``(batch,)``."""
        return self.network.sample(self._columns(states), rng)

    def mean_std(self, states: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Mean and standard deviation of ``G(s)``, each ``(batch,)``."""
        return self.network.mean_std(self._columns(states))

    def interval(self, states: FloatArray, level: float = 0.9) -> tuple[FloatArray, FloatArray]:
        """Central ``level`` interval of ``G(s)``: lower and upper bounds, each ``(batch,)``."""
        return self.network.interval(self._columns(states), level)


class RegionsOnFeatures(_OnFeatures):
    """Safety regions (Eq. 5) of full planner states, read from some of their columns.

    Offers what :class:`~dynoplan.options.initiation.InRegion` and the planner use
    (``option_names``, ``option_index``, ``contains``, ``contains_all``, ``log_likelihood``)
    on ``(batch, state_dim)`` states; ``regions`` sees ``features(states)``.
    """

    def __init__(self, regions: SafetyRegions, features: FeatureMap) -> None:
        super().__init__(features)
        self.regions = regions

    @property
    def option_names(self) -> list[str]:
        return self.regions.option_names

    def option_index(self, option: str | int) -> int:
        return self.regions.option_index(option)

    def log_likelihood(self, states: FloatArray, option: str | int) -> FloatArray:
        """``log L(s | k)`` of Eq. 5, ``(batch,)``."""
        return self.regions.log_likelihood(self._columns(states), option)

    def contains(self, states: FloatArray, option: str | int) -> BoolArray:
        """Whether each state lies in option ``k``'s region, ``(batch,)``."""
        return self.regions.contains(self._columns(states), option)

    def contains_all(self, states: FloatArray) -> BoolArray:
        """Membership for every option at once, ``(batch, options)``."""
        return self.regions.contains_all(self._columns(states))


@dataclass
class GearModels:
    """What :func:`load_gear_models` returns.

    Attributes:
        goal: ``G(s)`` on planner states ``(batch, 22)``.
        regions: the options' safety regions on planner states.
        dynamics: ``D_w`` by option name (keys in :data:`OPTION_NAMES` order), each
            mapping planner states ``(batch, 22)`` one decision step ahead.
        manifest: the content of ``models.json``.
    """

    goal: GoalOnFeatures
    regions: RegionsOnFeatures
    dynamics: dict[str, MLPEnsembleDynamics]
    manifest: dict[str, Any] = field(default_factory=dict)

    @property
    def option_names(self) -> tuple[str, ...]:
        return tuple(self.dynamics)

    def stacked_dynamics(self) -> StackedDynamics:
        """All options' ensembles as one ``(options, samples, 22)`` sampler."""
        return MLPEnsembleDynamics.stack([self.dynamics[n] for n in self.option_names])


# --- data -------------------------------------------------------------------------------
def demonstration_transitions(demos: Iterable[Episode],
                              decision_steps: int = DECISION_STEPS) -> list[Episode]:
    """A stand-in for collected option transitions, cut from expert demonstrations.

    Every maximal run of one option label in a demonstration becomes ``decision_steps``
    episodes, one per offset ``o``: its observations ``o, o + k, o + 2k, ...`` (``k =
    decision_steps``) up to the run's last observation, so each step is one decision of
    that option. ``actions`` and ``infos["option"]`` are the option index; rewards are 0.
    Runs shorter than ``k`` steps give nothing.
    """
    out: list[Episode] = []
    for index, episode in enumerate(demos):
        labels = episode.options
        if labels is None:
            raise DynoplanError(f"demonstration {index} has no infos['option'] labels")
        starts = np.flatnonzero(np.r_[True, labels[1:] != labels[:-1]])
        ends = np.r_[starts[1:], len(labels)]
        for a, b in zip(starts, ends, strict=True):
            k = int(labels[a])
            for offset in range(decision_steps):
                idx = np.arange(a + offset, b + 1, decision_steps)
                if len(idx) < 2:
                    continue
                steps = len(idx) - 1
                out.append(Episode(
                    observations=episode.observations[idx],
                    actions=np.full(steps, k, dtype=np.int64),
                    rewards=np.zeros(steps),
                    terminations=np.zeros(steps, dtype=bool),
                    truncations=np.r_[np.zeros(steps - 1, dtype=bool), True],
                    infos={"option": np.full(steps, k, dtype=np.int64)},
                    seed=episode.seed,
                ))
    return out


def write_demonstration_transitions(demos: Path, out: Path,
                                    decision_steps: int = DECISION_STEPS) -> Path:
    """Write :func:`demonstration_transitions` of the dataset ``demos`` as a dataset."""
    source = read_dataset(demos)
    episodes = demonstration_transitions(source, decision_steps)
    if not episodes:
        raise DynoplanError(f"{demos}: no option run lasts {decision_steps} steps")
    meta = source.metadata
    metadata = DatasetMetadata(
        dataset_id=TRANSITIONS_ID, env_id=meta.env_id, env_spec=meta.env_spec,
        option_names=list(meta.option_names), seed=meta.seed,
        extra={"decision_steps": decision_steps, "source": str(demos),
               "note": "expert demonstrations subsampled every decision_steps steps, one "
                       "episode per option run and offset (stand-in for collected "
                       "option transitions)"},
        observation_space=meta.observation_space,
        action_space=gym.spaces.Discrete(len(meta.option_names)))
    return write_dataset(out, episodes, metadata)


def _read_labelled(path: Path, what: str) -> Dataset:
    dataset = read_dataset(path)
    names = list(dataset.metadata.option_names)
    if names != list(OPTION_NAMES):
        raise DynoplanError(f"{path}: {what} name options {names}, expected {list(OPTION_NAMES)}")
    for i, episode in enumerate(dataset):
        if episode.options is None:
            raise DynoplanError(f"{path}: {what} episode {i} has no infos['option'] labels")
        if episode.observations.shape[1:] != (OBS_DIM,):
            raise DynoplanError(f"{path}: {what} episode {i} has observations of shape "
                                f"{episode.observations.shape[1:]}, expected ({OBS_DIM},) "
                                "(the gear assembly's)")
    return dataset


def _read_demos(path: Path, what: str) -> Dataset:
    dataset = _read_labelled(path, what)
    for i, episode in enumerate(dataset):
        if "progress" not in episode.infos:
            raise DynoplanError(f"{path}: {what} episode {i} has no infos['progress']")
    return dataset


def _demo_arrays(dataset: Dataset, planner: PlannerState
                 ) -> list[tuple[FloatArray, FloatArray, IntArray]]:
    """Per episode: planner states ``(T+1, 22)``, progress ``(T+1,)`` (0 at the reset) and
    the option label of each step ``(T,)``."""
    out = []
    for episode in dataset:
        states = planner(episode.observations)
        truth = np.r_[0.0, episode.infos["progress"]]
        labels = episode.options
        assert labels is not None
        out.append((states, truth, labels))
    return out


def _record_heldout(n: int, seed: int, out: Path, progress: bool) -> Path:
    """``n`` expert trials from ``seed + HELDOUT_SEED_OFFSET`` in ``out`` (kept if there)."""
    from dynoplan.experiments.gear_demos import record_demos

    held_seed = seed + HELDOUT_SEED_OFFSET
    if (out / "data").is_dir():
        try:
            existing = read_dataset(out)
            if existing.metadata.seed == held_seed and len(existing) == n:
                return out
        except DynoplanError:
            pass  # unreadable: record again
    record_demos(n, held_seed, out, progress=progress)
    return out


def _check_disjoint(train: Dataset, held: Dataset, where: Path) -> None:
    shared = {e.seed for e in train if e.seed is not None} & {
        e.seed for e in held if e.seed is not None}
    if shared:
        raise DynoplanError(f"{where}: held-out trials share episode seeds {sorted(shared)} "
                            "with the training demonstrations; use disjoint seeds")


# --- regions ----------------------------------------------------------------------------
def fit_regions_cross_validated(
    states: FloatArray, labels: IntArray, groups: IntArray, option_names: Sequence[str], *,
    reg_covar: float, max_components: int, coverage: float, cv_coverage: float, seed: int,
    max_folds: int = 10,
) -> tuple[SafetyRegions, dict[str, Any]]:
    """Safety regions (Eq. 5) whose thresholds are calibrated by leaving demonstrations out.

    The mixture is fitted on all states (``M`` by BIC). Then the demonstrations
    (``groups``) are dealt into at most ``max_folds`` folds (one demonstration each when
    there are few); for each fold a mixture of the same ``M`` is fitted without it, and
    for each of the fold's states of option ``k`` the shortfall
    ``threshold_k - log L(s | k)`` under that mixture is recorded. Option ``k``'s final
    threshold is lowered by the ``cv_coverage`` quantile of its shortfalls (if positive):
    the region is as wide as it needs to be for a demonstration it has not seen,
    measured on the demonstrations alone.

    Args:
        states: ``(N, d)``; labels: ``(N,)`` option indices; groups: ``(N,)`` demonstration
            ids.
    Returns:
        The regions and ``{"components", "slack_nats", "folds"}``.
    """
    regions = SafetyRegions.fit(states, labels, option_names, max_components=max_components,
                                coverage=coverage, reg_covar=reg_covar, seed=seed)
    m = regions.n_components
    ids = np.unique(groups)
    fold_of = dict(zip(ids.tolist(), np.random.default_rng(seed).permutation(len(ids)) % max_folds,
                       strict=True))
    fold_index = np.array([fold_of[g] for g in groups.tolist()])
    shortfalls: list[list[FloatArray]] = [[] for _ in option_names]
    folds = 0
    for f in np.unique(fold_index):
        keep = fold_index != f
        if len(np.unique(labels[keep])) < len(option_names):
            continue  # the fold holds every demonstration of some option
        fold = SafetyRegions.fit(states[keep], labels[keep], option_names, n_components=m,
                                 coverage=coverage, reg_covar=reg_covar, seed=seed)
        folds += 1
        for k in range(len(option_names)):
            rows = (~keep) & (labels == k)
            if rows.any():
                shortfalls[k].append(fold.log_thresholds[k] - fold.log_likelihood(states[rows], k))
    slack = np.array([max(0.0, float(np.quantile(np.concatenate(s), cv_coverage))) if s else 0.0
                      for s in shortfalls])
    regions.log_thresholds = regions.log_thresholds - slack
    return regions, {"components": m, "slack_nats": [round(float(s), 3) for s in slack],
                     "folds": folds}


def far_states(train: FloatArray, heldout: FloatArray, rng: Generator, n: int,
               reg_covar: float, features: FeatureMap = TASK
               ) -> tuple[FloatArray, dict[str, Any]]:
    """Planner states far from every demonstration, for ``region_far_outside_rate``.

    Candidates (``n``, half each): (a) uniformly random left-arm joint angles within the
    joint limits; (b) held-out demonstration states with every left-arm joint moved by
    0.4-0.8 rad (random sign, clipped to the limits). The right arm, gripper, gear and
    human come from random held-out demonstration states; the tool point is recomputed
    by forward kinematics. A candidate counts as far when its distance to the nearest
    training demonstration state (in ``features``, each divided by its spread, floored at
    ``sqrt(reg_covar)``) exceeds that of every held-out demonstration state.

    Returns:
        The far states ``(n_far, 22)`` and ``{"candidates", "far", "distance_threshold"}``.
    """
    kin = ArmKinematics()
    limits = kin.model.jnt_range[[kin.model.joint(j).id for j in ARM_JOINTS]]
    left = slice(0, 6)
    base = heldout[rng.integers(len(heldout), size=n)].copy()
    half = n // 2
    base[:half, left] = rng.uniform(limits[left, 0], limits[left, 1], size=(half, 6))
    shift = rng.choice([-1.0, 1.0], size=(n - half, 6)) * rng.uniform(0.4, 0.8, (n - half, 6))
    base[half:, left] = np.clip(base[half:, left] + shift, limits[left, 0], limits[left, 1])
    tool = STATE_SLICES["tool_pos"]
    for row in base:
        row[tool] = kin.tool_pose(row[STATE_SLICES["arm_qpos"]])[0]
    f_train = features(train)
    scale = np.maximum(f_train.std(axis=0), np.sqrt(reg_covar))
    nn = NearestNeighbors(n_neighbors=1).fit(f_train / scale)
    threshold = float(nn.kneighbors(features(heldout) / scale)[0].max())
    dist = nn.kneighbors(features(base) / scale)[0][:, 0]
    far = base[dist > threshold]
    return far, {"candidates": n, "far": len(far), "distance_threshold": round(threshold, 3)}


# --- dynamics evaluation ----------------------------------------------------------------
def n_step_report(model: MLPEnsembleDynamics, trajectories: Sequence[FloatArray], n: int,
                  rollouts: int, rng: Generator) -> dict[str, Any] | None:
    """``n``-step prediction error of ``model`` along held-out trajectories.

    From every state ``s_t`` with ``t + n`` inside its trajectory, ``rollouts`` samples
    are rolled ``n`` steps, each with one ensemble member drawn for the whole rollout
    (PETS's TS-infinity), as one batch. Reported: RMSE of the rollouts' mean against
    ``s_{t+n}``, the "state stays the same" baseline's RMSE, and the fraction of
    ``(start, dimension)`` pairs whose truth lies between the rollouts' 5th and 95th
    percentiles. ``None`` when no trajectory has ``n + 1`` states.
    """
    starts = [traj[t] for traj in trajectories for t in range(len(traj) - n)]
    targets = [traj[t + n] for traj in trajectories for t in range(len(traj) - n)]
    if not starts:
        return None
    x0, truth = np.asarray(starts), np.asarray(targets)
    b, d = x0.shape
    x = np.repeat(x0, rollouts, axis=0)
    member = rng.integers(model.members, size=len(x))
    rows = np.arange(len(x))
    for _ in range(n):
        means, variances = model.predict(x)
        x = means[member, rows] + np.sqrt(variances[member, rows]) * rng.standard_normal(x.shape)
        x[~np.isfinite(x).all(axis=1)] = np.nan  # a diverged rollout stays out of the mean
    paths = x.reshape(b, rollouts, d)
    pred = np.nanmean(paths, axis=1)
    lo, hi = np.nanpercentile(paths, [5.0, 95.0], axis=1)
    model_rmse = float(np.sqrt(np.nanmean((pred - truth) ** 2)))
    base_rmse = float(np.sqrt(np.mean((x0 - truth) ** 2)))
    return {"n": n, "starts": b, "rmse": model_rmse, "no_change_rmse": base_rmse,
            "ratio": model_rmse / max(base_rmse, 1e-300),
            "coverage_90": float(np.mean((truth >= lo) & (truth <= hi)))}


def _split_episodes(episodes: Sequence[Episode], fraction: float,
                    rng: Generator) -> tuple[list[Episode], list[Episode]]:
    """Hold out ``fraction`` of each option's episodes (at least one when it has two).

    Episodes of one option that share an ``env`` seed (runs cut from one demonstration,
    or started from one reset) go to the same side, so that near-copies of a training
    run never count as held out.
    """
    train: list[Episode] = []
    held: list[Episode] = []
    groups: dict[int, dict[object, list[Episode]]] = {}
    for index, episode in enumerate(episodes):
        labels = episode.options
        assert labels is not None
        key = episode.seed if episode.seed is not None else ("episode", index)
        groups.setdefault(int(labels[0]), {}).setdefault(key, []).append(episode)
    for k in sorted(groups):
        runs = list(groups[k].values())
        order = rng.permutation(len(runs))
        n_held = min(max(1, round(fraction * len(runs))), len(runs) - 1)
        held += [e for i in order[:n_held] for e in runs[i]]
        train += [e for i in order[n_held:] for e in runs[i]]
    return train, held


def _trajectories(episodes: Sequence[Episode], planner: PlannerState, k: int) -> list[FloatArray]:
    """Planner states of the held-out episodes run by option ``k`` only."""
    out = []
    for episode in episodes:
        labels = episode.options
        if labels is not None and (labels == k).all():
            out.append(planner(episode.observations))
    return out


# --- training ---------------------------------------------------------------------------
def train_gear_models(demos: Path, transitions: Path | None, out: Path, seed: int,
                      heldout_demos: Path | None, quick: bool, progress: bool,
                      settings: GearTrainSettings | None = None) -> dict[str, Any]:
    """Fit the goal heuristic, the safety regions and one dynamics model per option.

    Args:
        demos: the demonstrations dataset (``dynoplan gear demos``): option labels and
            progress; trains the goal heuristic and the regions (and the dynamics
            without ``transitions``).
        transitions: option transitions at the decision rate (``dynoplan gear collect``);
            ``None``: the demonstrations subsampled (:func:`demonstration_transitions`).
        out: folder for the models, ``models.json`` and ``metrics.json``.
        seed: seeds every fit, split and evaluation draw.
        heldout_demos: expert trials not among ``demos`` for the goal and region
            metrics; ``None``: ``settings.heldout_episodes`` trials are recorded from
            ``seed + 1000`` into ``out/heldout-demos`` (or reused when already there).
        quick: :data:`QUICK_SETTINGS` instead of :data:`DEFAULT_SETTINGS`.
        progress: progress bars on stderr.
        settings: overrides ``quick``.

    Returns:
        The content of ``metrics.json``.

    Raises:
        DynoplanError: unreadable or mislabelled datasets, held-out trials that share
            seeds with the demonstrations, too little data for an option, or an
            unwritable ``out``.
    """
    cfg = settings or (QUICK_SETTINGS if quick else DEFAULT_SETTINGS)
    started = time.perf_counter()
    out = ensure_writable_dir(out)
    planner = PlannerState()
    train_set = _read_demos(demos, "demonstrations")
    seconds: dict[str, float] = {}

    t0 = time.perf_counter()
    if heldout_demos is None:
        heldout_demos = _record_heldout(cfg.heldout_episodes, seed, out / HELDOUT_DIR,
                                        progress)
        seconds["record_heldout"] = round(time.perf_counter() - t0, 2)
    held_set = _read_demos(heldout_demos, "held-out trials")
    _check_disjoint(train_set, held_set, heldout_demos)
    if transitions is None:
        dyn_train = demonstration_transitions(train_set)
        dyn_held = demonstration_transitions(held_set)
        dynamics_data = "demonstrations subsampled"
    else:
        collected = _read_labelled(transitions, "option transitions")
        steps = collected.metadata.extra.get("decision_steps", DECISION_STEPS)
        if steps != DECISION_STEPS:
            raise DynoplanError(f"{transitions}: recorded every {steps} environment steps, "
                                f"the models step every {DECISION_STEPS}")
        dyn_train, dyn_held = _split_episodes(list(collected), cfg.dynamics_heldout_fraction,
                                              np.random.default_rng([seed, 1]))
        dynamics_data = "option transitions"

    train = _demo_arrays(train_set, planner)
    held = _demo_arrays(held_set, planner)
    # a folder half-rewritten by a failed run must not load as a set of models
    for stale in (MANIFEST_FILE, METRICS_FILE):
        (out / stale).unlink(missing_ok=True)
    results: dict[str, Any] = {}
    stages: list[tuple[str, Callable[[], None]]] = [
        ("goal", lambda: results.update(goal=_train_goal(train, held, out, cfg, seed))),
        ("regions", lambda: results.update(
            regions=_train_regions(train, held, out, cfg, seed))),
    ]
    dyn_reports: dict[str, Any] = {}
    for k, name in enumerate(OPTION_NAMES):
        def fit_option(k: int = k, name: str = name) -> None:
            dyn_reports[name] = _train_dynamics(k, name, dyn_train, dyn_held, planner, out,
                                                cfg, seed)
        stages.append((f"dynamics {name}", fit_option))
    for name, run in track(stages, "gear models", total=len(stages), enabled=progress):
        t0 = time.perf_counter()
        run()
        seconds[name] = round(time.perf_counter() - t0, 2)

    manifest = _manifest(out, seed, cfg)
    write_json(out / MANIFEST_FILE, manifest)
    # coverage over all held-out transitions (options without any do not count)
    dyn_rows = [r for r in dyn_reports.values() if r["coverage_90"] is not None]
    held_rows = np.array([r["transitions_heldout"] for r in dyn_rows], dtype=np.float64)
    coverages = np.array([r["coverage_90"] for r in dyn_rows], dtype=np.float64)
    goal, regions = results["goal"], results["regions"]
    seconds["total"] = round(time.perf_counter() - started, 2)
    metrics: dict[str, Any] = {
        "goal_spearman": goal["spearman"],
        "goal_mae": goal["mae"],
        "region_inside_rate": regions["inside_rate"],
        "region_far_outside_rate": regions["far_outside_rate"],
        "dynamics_coverage_90": float(np.sum(coverages * held_rows) / held_rows.sum())
        if held_rows.sum() else None,
        "dynamics_data": dynamics_data,
        "goal": goal,
        "regions": regions,
        "dynamics": dyn_reports,
        "data": {"demos": str(demos), "demo_episodes": len(train_set),
                 "heldout_demos": str(heldout_demos), "heldout_episodes": len(held_set),
                 "transitions": None if transitions is None else str(transitions),
                 "transition_episodes_train": len(dyn_train),
                 "transition_episodes_heldout": len(dyn_held)},
        "state_dim": STATE_DIM,
        "option_names": list(OPTION_NAMES),
        "decision_steps": DECISION_STEPS,
        "task_features": list(GOAL_FEATURES.names),
        "region_features": list(feature_map(cfg.region_features).names),
        "seed": seed,
        "settings": {**asdict(cfg), "quick": settings is None and quick},
        "seconds": seconds,
    }
    write_json(out / METRICS_FILE, metrics)
    return metrics


def _train_goal(train: Sequence[tuple[FloatArray, FloatArray, IntArray]],
                held: Sequence[tuple[FloatArray, FloatArray, IntArray]], out: Path,
                cfg: GearTrainSettings, seed: int) -> dict[str, Any]:
    f = GOAL_FEATURES
    x = np.concatenate([f(s) for s, _, _ in train])
    y = np.concatenate([p for _, p, _ in train])
    network, report = GoalNetwork.fit(x, y, hidden=cfg.goal_hidden, members=cfg.goal_members,
                                      epochs=cfg.goal_epochs, seed=seed)
    network.save(out / GOAL_FILE)
    xh = np.concatenate([f(s) for s, _, _ in held])
    yh = np.concatenate([p for _, p, _ in held])
    pooled = evaluate_goal(network, xh, yh)
    interrupted = np.array([bool((lab == CAUTIOUS).any()) for _, _, lab in held])
    per_trial = [float(stats.spearmanr(network.mean_std(f(s))[0], p).statistic)
                 for s, p, _ in held]
    per_trial_mae = [float(np.mean(np.abs(network.mean_std(f(s))[0] - p)))
                     for s, p, _ in held]
    calm = [i for i in range(len(held)) if not interrupted[i]]
    calm_metrics = None
    if calm:
        calm_metrics = evaluate_goal(network, np.concatenate([f(held[i][0]) for i in calm]),
                                     np.concatenate([held[i][1] for i in calm]))
    return {
        "spearman": float(np.mean(per_trial)),
        "mae": float(np.mean(per_trial_mae)),
        "spearman_pooled": pooled["spearman"],
        "mae_pooled": pooled["mae"],
        "coverage_90": pooled["coverage_90"],
        "heldout_states": len(yh),
        "per_trial_spearman": per_trial,
        "per_trial_mae": per_trial_mae,
        "per_trial_interrupted": interrupted.tolist(),
        "uninterrupted": calm_metrics,
        "train_loss_first_last": [report.train_loss[0], report.train_loss[-1]],
        "train_states": len(y),
        "note": "truth = the trial's normalised time (infos['progress']); spearman and "
                "mae are means over held-out trials of each trial's rank correlation and "
                "error along that trial (Fig. 3a's view: the planner ranks futures of one "
                "episode); *_pooled pool the states of all trials, where the same state has "
                "different normalised times in trials of different lengths. Trials "
                "'interrupted' had cautious_move steps (the expert slowed, waited or "
                "backed away for the human), where time advances but the state does not",
    }


def _train_regions(train: Sequence[tuple[FloatArray, FloatArray, IntArray]],
                   held: Sequence[tuple[FloatArray, FloatArray, IntArray]], out: Path,
                   cfg: GearTrainSettings, seed: int) -> dict[str, Any]:
    features = feature_map(cfg.region_features)
    s = np.concatenate([st[:-1] for st, _, _ in train])
    y = np.concatenate([lab for _, _, lab in train])
    g = np.concatenate([np.full(len(lab), i) for i, (_, _, lab) in enumerate(train)])
    fitted, info = fit_regions_cross_validated(
        features(s), y, g, OPTION_NAMES, reg_covar=cfg.region_reg_covar,
        max_components=cfg.region_max_components, coverage=cfg.region_coverage,
        cv_coverage=cfg.region_cv_coverage, seed=seed)
    fitted.save(out / REGIONS_FILE)
    regions = RegionsOnFeatures(fitted, features)
    sh = np.concatenate([st[:-1] for st, _, _ in held])
    yh = np.concatenate([lab for _, _, lab in held])
    member = regions.contains_all(sh)
    own = member[np.arange(len(sh)), yh]
    by_option = {n: (float(own[yh == k].mean()) if (yh == k).any() else None)
                 for k, n in enumerate(OPTION_NAMES)}
    # how specific each region is: held-out states of the other options inside it
    others = {n: float(member[yh != k, k].mean()) if (yh != k).any() else None
              for k, n in enumerate(OPTION_NAMES)}
    train_own = regions.contains_all(s)[np.arange(len(s)), y]
    far, far_info = far_states(s, sh, np.random.default_rng([seed, 2]), cfg.far_states,
                               cfg.region_reg_covar, features)
    far_outside = float((~regions.contains_all(far).any(axis=1)).mean()) if len(far) else None
    return {
        "inside_rate": float(own.mean()),
        "inside_rate_by_option": by_option,
        "inside_any_rate": float(member.any(axis=1).mean()),
        "other_options_inside_rate": others,
        "train_inside_rate": float(train_own.mean()),
        "far_outside_rate": far_outside,
        "far_states": far_info,
        "heldout_states": len(yh),
        **info,
        "members": fitted.members.astype(int).tolist(),
    }


def _train_dynamics(k: int, name: str, train_eps: Sequence[Episode],
                    held_eps: Sequence[Episode], planner: PlannerState, out: Path,
                    cfg: GearTrainSettings, seed: int) -> dict[str, Any]:
    own = [e for e in train_eps if e.options is not None and int(e.options[0]) == k]
    fit_eps, cal_eps = (_split_episodes(own, cfg.dynamics_calibration_fraction,
                                        np.random.default_rng([seed, 4, k]))
                        if len({e.seed for e in own}) >= 4 else (own, []))
    s, labels, nxt = labelled_transitions(fit_eps, state_fn=planner)
    sh, labels_h, nxth = labelled_transitions(held_eps, state_fn=planner)
    s, nxt = s[labels == k], nxt[labels == k]
    sh, nxth = sh[labels_h == k], nxth[labels_h == k]
    if len(s) < 10:
        raise DynoplanError(f"option '{name}': only {len(s)} transitions to learn its "
                            "dynamics from (need >= 10); record more episodes")
    model = MLPEnsembleDynamics(STATE_DIM, cfg.dynamics_hidden, cfg.dynamics_members,
                                option=name, seed=seed + k)
    batches = -(-round(0.9 * len(s)) // _BATCH)  # fit holds out 10% of the rows
    epochs = max(5, min(cfg.dynamics_epochs, cfg.dynamics_max_updates // batches))
    report = model.fit(s, nxt, epochs=epochs, batch_size=_BATCH, seed=seed + k)
    std_scale = None
    if cal_eps:
        sc, labels_c, nxtc = labelled_transitions(cal_eps, state_fn=planner)
        if (labels_c == k).sum() >= 10:
            std_scale = model.calibrate(sc[labels_c == k], nxtc[labels_c == k], 0.9)
    model.save(out / dynamics_file(name))
    row: dict[str, Any] = {
        "transitions_train": len(s),
        "transitions_heldout": len(sh),
        "holdout_nll_first_best": [report.holdout_loss[0],
                                   report.holdout_loss[report.best_epoch]]
        if report.holdout_loss else None,
        "train_nll_first_last": [report.train_loss[0], report.train_loss[-1]],
        "epochs": epochs,
        "best_epoch": report.best_epoch,
        "calibration_episodes": len(cal_eps),
        "std_scale": None if std_scale is None else dict(zip(
            STATE_NAMES, np.round(std_scale, 3).tolist(), strict=True)),
    }
    if len(sh) == 0:  # nothing of this option among the held-out data: no report
        return {**row, "one_step_rmse": None, "one_step_no_change_rmse": None,
                "one_step_ratio": None, "n_step": None, "coverage_90": None}
    one = one_step_error(model, sh, nxth)
    cal = calibration(model, sh, nxth, 0.9)
    trajectories = _trajectories(held_eps, planner, k)
    multi = n_step_report(model, trajectories, cfg.n_step, cfg.rollouts,
                          np.random.default_rng([seed, 3, k]))
    return {
        **row,
        "one_step_rmse": one.model_rmse_total,
        "one_step_no_change_rmse": one.baseline_rmse_total,
        "one_step_ratio": one.ratio,
        "n_step": multi,
        "coverage_90": cal.coverage,
        "coverage_90_by_dimension": dict(zip(STATE_NAMES, cal.per_dimension.tolist(),
                                             strict=True)),
    }


# --- storage ----------------------------------------------------------------------------
def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _manifest(out: Path, seed: int, cfg: GearTrainSettings) -> dict[str, Any]:
    def entry(file: str) -> dict[str, Any]:
        return {"file": file, "sha256": _sha256(out / file)}

    return {
        "kind": MODELS_KIND,
        "format_version": MODELS_FORMAT_VERSION,
        "state_dim": STATE_DIM,
        "state_names": list(STATE_NAMES),
        "option_names": list(OPTION_NAMES),
        "decision_steps": DECISION_STEPS,
        "goal": {**entry(GOAL_FILE), "features": GOAL_FEATURES.name},
        "regions": {**entry(REGIONS_FILE), "features": cfg.region_features},
        "dynamics": {name: entry(dynamics_file(name)) for name in OPTION_NAMES},
        "seed": seed,
        "settings": asdict(cfg),
    }


def load_gear_models(folder: str | os.PathLike[str]) -> GearModels:
    """Read the models written by :func:`train_gear_models` from ``folder``.

    Raises:
        DynoplanError: (one line) no or unreadable ``models.json``, another kind or a
            newer format, a state dimension, option names or decision rate other than
            this version's gear assembly, a missing file, a file whose SHA-256 differs
            from the manifest (truncated, modified or from another run), or a model that
            does not fit the manifest.
    """
    root = Path(folder)
    path = root / MANIFEST_FILE
    if not path.is_file():
        raise DynoplanError(f"{path}: not found (train models with 'dynoplan gear train')")
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DynoplanError(f"{path}: not a readable manifest ({exc})") from None
    if not isinstance(manifest, dict) or manifest.get("kind") != MODELS_KIND:
        raise DynoplanError(f"{path}: not a gear models manifest")
    version = manifest.get("format_version")
    if not isinstance(version, int) or version != MODELS_FORMAT_VERSION:
        raise DynoplanError(f"{path}: format_version {version!r} is not supported (this "
                            f"dynoplan reads {MODELS_FORMAT_VERSION}; train the models again)")
    expected = {"state_dim": STATE_DIM, "option_names": list(OPTION_NAMES),
                "decision_steps": DECISION_STEPS}
    for key, value in expected.items():
        if manifest.get(key) != value:
            raise DynoplanError(f"{path}: {key} is {manifest.get(key)!r}, this version's gear "
                                f"assembly has {value!r}")

    def checked(entry: Any, what: str) -> Path:
        if not isinstance(entry, dict) or not isinstance(entry.get("file"), str):
            raise DynoplanError(f"{path}: no file given for {what}")
        file = root / entry["file"]
        if not file.is_file():
            raise DynoplanError(f"{file}: model file not found ({what})")
        if _sha256(file) != entry.get("sha256"):
            raise DynoplanError(f"{file}: does not match {MANIFEST_FILE} (truncated, modified "
                                "or from another training run)")
        return file

    def features(entry: Any, what: str) -> FeatureMap:
        name = entry.get("features") if isinstance(entry, dict) else None
        if not isinstance(name, str) or name not in FEATURE_MAPS:
            raise DynoplanError(f"{path}: {what} features must name a feature map "
                                f"({', '.join(FEATURE_MAPS)})")
        return FEATURE_MAPS[name]

    goal_features = features(manifest.get("goal"), "goal")
    network = GoalNetwork.load(checked(manifest.get("goal"), "goal heuristic"))
    if network.state_dim != goal_features.dim:
        raise DynoplanError(f"{root / GOAL_FILE}: reads {network.state_dim} features, the "
                            f"manifest's '{goal_features.name}' has {goal_features.dim}")
    region_features = features(manifest.get("regions"), "regions")
    fitted = SafetyRegions.load(checked(manifest.get("regions"), "safety regions"))
    if fitted.option_names != list(OPTION_NAMES) or fitted.state_dim != region_features.dim:
        raise DynoplanError(f"{root / REGIONS_FILE}: options {fitted.option_names} on "
                            f"{fitted.state_dim} features, expected {list(OPTION_NAMES)} on "
                            f"{region_features.dim} ('{region_features.name}')")
    entries = manifest.get("dynamics")
    if not isinstance(entries, dict) or sorted(entries) != sorted(OPTION_NAMES):
        raise DynoplanError(f"{path}: dynamics must list the options {list(OPTION_NAMES)}")
    dynamics: dict[str, MLPEnsembleDynamics] = {}
    for name in OPTION_NAMES:
        file = checked(entries[name], f"dynamics of {name}")
        model = MLPEnsembleDynamics.load(file)
        if model.state_dim != STATE_DIM or model.option != name:
            raise DynoplanError(f"{file}: a model of option '{model.option}' on "
                                f"{model.state_dim} values, expected '{name}' on {STATE_DIM}")
        dynamics[name] = model
    return GearModels(GoalOnFeatures(network, goal_features),
                      RegionsOnFeatures(fitted, region_features),
                      dynamics, manifest)

