"""Held-out measurements of the gear models (the numbers of ``metrics.json``).

- :func:`far_states`: planner states ``(n_far, 22)`` far from every demonstration, for
  ``region_far_outside_rate``;
(the ``n``-step report of the dynamics is
:func:`~dynoplan.models.evaluation.n_step_report`).
"""

from typing import Any

import numpy as np
from sklearn.neighbors import NearestNeighbors

from dynoplan.envs.gear.features import TASK, FeatureMap
from dynoplan.envs.gear.kinematics import ArmKinematics
from dynoplan.envs.gear.scene import ARM_JOINTS
from dynoplan.envs.gear.state import STATE_SLICES
from dynoplan.types import FloatArray, Generator


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
