"""Evaluation of learned ensemble dynamics against held-out transitions.

The functions work on any model with a ``predict`` method returning the per-member
Gaussian of the next state (:class:`GaussianEnsemblePredictor`), so that a learned model
can be compared with the "state stays the same" baseline (:func:`one_step_error`, and
``n`` steps ahead along held-out trajectories, :func:`n_step_report`) and its
uncertainty checked against held-out transitions (:func:`calibration`).
"""

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from scipy.special import ndtr

from dynoplan.types import FloatArray, Generator


class GaussianEnsemblePredictor(Protocol):
    """A dynamics model that exposes its per-member Gaussian next-state prediction.

    ``predict(states (batch, d))`` returns ``(means, variances)``, each
    ``(members, batch, d)`` float64, in state units; the predictive distribution is the
    equal-weight mixture over members.
    """

    def predict(self, states: FloatArray) -> tuple[FloatArray, FloatArray]: ...


class EnsembleModel(GaussianEnsemblePredictor, Protocol):
    """A :class:`GaussianEnsemblePredictor` that says how many members it has."""

    @property
    def members(self) -> int: ...


@dataclass(frozen=True)
class OneStepError:
    """Root-mean-square one-step error of the model against "the state stays the same".

    Attributes:
        model_rmse: ``(state_dim,)``, RMSE of the mixture mean per dimension.
        baseline_rmse: ``(state_dim,)``, RMSE of predicting ``s_{t+1} = s_t``.
        model_rmse_total: RMSE over all dimensions.
        baseline_rmse_total: the baseline's RMSE over all dimensions.
    """

    model_rmse: FloatArray
    baseline_rmse: FloatArray
    model_rmse_total: float
    baseline_rmse_total: float

    @property
    def ratio(self) -> float:
        """``model / baseline`` over all dimensions; below 1 means the model helps."""
        return self.model_rmse_total / max(self.baseline_rmse_total, 1e-300)


@dataclass(frozen=True)
class Calibration:
    """How often true next states fall inside the predicted central interval.

    The predictive distribution is the equal-weight mixture of the members' Gaussians;
    per dimension its central ``level`` interval runs from the ``(1 - level) / 2`` to the
    ``(1 + level) / 2`` quantile of the mixture's marginal. A calibrated model has
    ``coverage`` close to ``level``; much higher means over-wide intervals, much lower
    over-confident ones.

    Attributes:
        level: nominal coverage, for example 0.9.
        coverage: fraction of (row, dimension) pairs inside their interval.
        per_dimension: ``(state_dim,)`` coverage of each dimension.
        mean_width: ``(state_dim,)`` mean interval width, in state units.
    """

    level: float
    coverage: float
    per_dimension: FloatArray
    mean_width: FloatArray


def one_step_error(model: GaussianEnsemblePredictor, states: FloatArray,
                   next_states: FloatArray) -> OneStepError:
    """One-step RMSE of the model's mixture mean vs the "no change" baseline.

    Args:
        states: ``(batch, d)`` current states; ``next_states``: ``(batch, d)`` true next states.
    """
    s, nxt = _pair(states, next_states)
    means, _ = model.predict(s)
    pred = means.mean(axis=0)
    model_sq = (pred - nxt) ** 2
    base_sq = (s - nxt) ** 2
    return OneStepError(np.sqrt(model_sq.mean(axis=0)), np.sqrt(base_sq.mean(axis=0)),
                        float(np.sqrt(model_sq.mean())), float(np.sqrt(base_sq.mean())))


def calibration(model: GaussianEnsemblePredictor, states: FloatArray, next_states: FloatArray,
                level: float = 0.9) -> Calibration:
    """Coverage of the per-dimension central ``level`` interval of the member mixture.

    Args:
        states: ``(batch, d)``; ``next_states``: ``(batch, d)``.
        level: nominal coverage in ``(0, 1)``.
    """
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level}")
    s, nxt = _pair(states, next_states)
    means, variances = model.predict(s)
    std = np.sqrt(variances)
    lo = mixture_quantile(means, std, (1.0 - level) / 2.0)
    hi = mixture_quantile(means, std, (1.0 + level) / 2.0)
    inside = (nxt >= lo) & (nxt <= hi)
    return Calibration(float(level), float(inside.mean()), inside.mean(axis=0),
                       (hi - lo).mean(axis=0))


def mixture_quantile(means: FloatArray, stds: FloatArray, q: float,
                     iterations: int = 60) -> FloatArray:
    """Quantile ``q`` of an equal-weight Gaussian mixture per element, by bisection.

    Args:
        means, stds: ``(members, ...)``; the mixture is over the first axis.
    Returns:
        ``(...)``, the value ``x`` with ``mean_k Phi((x - mu_k) / sigma_k) = q``.
    """
    stds = np.maximum(stds, 1e-300)
    lo = (means - 10.0 * stds).min(axis=0)
    hi = (means + 10.0 * stds).max(axis=0)
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        below = ndtr((mid[None] - means) / stds).mean(axis=0) < q
        lo = np.where(below, mid, lo)
        hi = np.where(below, hi, mid)
    return 0.5 * (lo + hi)


def _pair(states: FloatArray, next_states: FloatArray) -> tuple[FloatArray, FloatArray]:
    s = np.asarray(states, dtype=np.float64)
    nxt = np.asarray(next_states, dtype=np.float64)
    if s.ndim != 2 or s.shape != nxt.shape:
        raise ValueError(f"states and next_states must both be (batch, d), got {s.shape} "
                         f"and {nxt.shape}")
    return s, nxt


def n_step_report(model: EnsembleModel, trajectories: Sequence[FloatArray], n: int,
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
    b = len(x0)
    paths = _rollouts(model, x0, n, rollouts, rng)  # a diverged one stays out of the mean
    pred = np.nanmean(paths, axis=1)
    lo, hi = np.nanpercentile(paths, [5.0, 95.0], axis=1)
    model_rmse = float(np.sqrt(np.nanmean((pred - truth) ** 2)))
    base_rmse = float(np.sqrt(np.mean((x0 - truth) ** 2)))
    return {"n": n, "starts": b, "rmse": model_rmse, "no_change_rmse": base_rmse,
            "ratio": model_rmse / max(base_rmse, 1e-300),
            "coverage_90": float(np.mean((truth >= lo) & (truth <= hi)))}


def _rollouts(model: EnsembleModel, x: FloatArray, steps: int, rollouts: int,
              rng: Generator) -> FloatArray:
    """``rollouts`` samples of ``steps`` steps from each row of ``x`` ``(b, d)``, one ensemble
    member per rollout; ``(b, rollouts, d)`` (NaN rows where a rollout diverged)."""
    b, d = x.shape
    x = np.repeat(x, rollouts, axis=0)
    member = rng.integers(model.members, size=len(x))
    rows = np.arange(len(x))
    for _ in range(steps):
        means, variances = model.predict(x)
        x = means[member, rows] + np.sqrt(variances[member, rows]) * rng.standard_normal(x.shape)
        x[~np.isfinite(x).all(axis=1)] = np.nan
    return x.reshape(b, rollouts, d)


def option_end_gap(model: EnsembleModel, starts: FloatArray, ends: FloatArray,
                   steps: Sequence[int], goal: Callable[[FloatArray], FloatArray],
                   rollouts: int, rng: Generator) -> dict[str, Any] | None:
    """How far the goal's score of an option's imagined end is from that of its real end.

    Eq. 1 asks exactly this: from the state where an option starts, the model rolls it
    to its end and the goal heuristic scores that. For each run ``r`` (an option started
    at ``starts[r]``, ``(R, d)``, and after ``steps[r]`` model steps was at ``ends[r]``),
    ``rollouts`` samples of the model are rolled ``steps[r]`` steps from its start, one
    ensemble member per rollout; the report holds the mean over runs of
    ``|mean_r G(rollout_r) - G(ends[r])|`` (``gap``) and the means of both scores
    (``imagined``, ``real``). ``goal`` maps states ``(N, d)`` to values ``(N,)``. A goal
    that reads features the dynamics predict badly shows a large gap. Runs of 0 steps
    are skipped; ``None`` when none is left.
    """
    imagined, real = [], []
    for start, end, m in zip(starts, ends, steps, strict=True):
        if m < 1:
            continue
        imagined_ends = _rollouts(model, start[None], int(m), rollouts, rng)[0]
        finite = np.isfinite(imagined_ends).all(axis=1)
        if finite.any():
            imagined.append(float(np.mean(goal(imagined_ends[finite]))))
            real.append(float(goal(end[None])[0]))
    if not imagined:
        return None
    im, re = np.asarray(imagined), np.asarray(real)
    return {"runs": len(im), "gap": float(np.mean(np.abs(im - re))),
            "imagined": float(im.mean()), "real": float(re.mean())}
