"""Held-out measurements of the gear models (the numbers of ``metrics.json``).

- :func:`fit_regions_cross_validated`: safety regions whose thresholds are widened by
  what leaving demonstrations out shows (states ``(N, d)``, labels and demonstration
  ids ``(N,)``);
- :func:`far_states`: planner states ``(n_far, 22)`` far from every demonstration, for
  ``region_far_outside_rate``;
- :func:`n_step_report`: ``n``-step rollout error and coverage of a dynamics ensemble
  along held-out trajectories (each ``(T+1, 22)``).
"""

from collections.abc import Sequence
from typing import Any

import numpy as np
from sklearn.neighbors import NearestNeighbors

from dynoplan.envs.gear.features import TASK, FeatureMap
from dynoplan.envs.gear.kinematics import ArmKinematics
from dynoplan.envs.gear.scene import ARM_JOINTS
from dynoplan.envs.gear.state import STATE_SLICES
from dynoplan.models.neural_dynamics import MLPEnsembleDynamics
from dynoplan.models.regions import SafetyRegions
from dynoplan.types import FloatArray, Generator, IntArray


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

