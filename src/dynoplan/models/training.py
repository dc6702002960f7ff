"""Training and evaluation of probabilistic ensemble dynamics (PETS-style).

Training (:func:`train_gaussian_ensemble`) fits each ensemble member on its own bootstrap
of the training rows by minimising the Gaussian negative log-likelihood, with Adam and
weight decay, as mbrl-lib's ``ModelTrainer`` does for its ``GaussianMLP``. Every random
choice (bootstrap, shuffling) comes from a seeded ``torch.Generator``; the global torch
random state is never used.

Evaluation (:func:`one_step_error`, :func:`calibration`) works on any model with a
``predict`` method returning the per-member Gaussian of the next state, so that a learned
model can be compared with the "state stays the same" baseline and its uncertainty
checked against held-out transitions.
"""

import copy
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import torch
from scipy.special import ndtr

from dynoplan.types import FloatArray

_LOG_2PI = float(np.log(2.0 * np.pi))


@dataclass(frozen=True)
class TrainingReport:
    """What happened during :func:`train_gaussian_ensemble`.

    Losses are the Gaussian negative log-likelihood per target element (with the
    ``0.5 * log(2 pi)`` constant), in the model's normalised target units, averaged over
    members. A model that predicts the training targets' mean and variance scores about
    1.42; lower is better.

    Attributes:
        train_loss: ``(epochs,)``, mean over the epoch's minibatches (each member on its
            own bootstrap sample).
        holdout_loss: ``(epochs,)``, on the held-out rows after each epoch (every member
            on every held-out row); empty when nothing was held out.
        best_epoch: index of the epoch whose weights the model keeps (lowest held-out
            loss when ``keep_best``, else the last).
        n_train: rows used for training.
        n_holdout: rows held out.
        seconds: wall-clock training time.
    """

    train_loss: tuple[float, ...]
    holdout_loss: tuple[float, ...]
    best_epoch: int
    n_train: int
    n_holdout: int
    seconds: float


def gaussian_nll(mean: torch.Tensor, logvar: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Elementwise Gaussian negative log-likelihood ``0.5 (log 2pi + logvar + r^2 / var)``."""
    return 0.5 * (_LOG_2PI + logvar + (target - mean) ** 2 * torch.exp(-logvar))


def train_gaussian_ensemble(
    net: torch.nn.Module,
    x_train: torch.Tensor,
    y_train: torch.Tensor,
    x_holdout: torch.Tensor,
    y_holdout: torch.Tensor,
    *,
    members: int,
    epochs: int,
    batch_size: int,
    lr: float,
    weight_decay: float,
    seed: int,
    keep_best: bool = True,
    penalty: Callable[[], torch.Tensor] | None = None,
) -> TrainingReport:
    """Fit an ensemble by Gaussian NLL, each member on its own bootstrap of the rows.

    Args:
        net: the ensemble, ``net(x (members, batch, in)) -> (mean, logvar)``, each
            ``(members, batch, out)``; its parameters are updated in place.
        x_train: ``(n_train, in)`` float32 normalised inputs; ``y_train``: ``(n_train, out)``.
        x_holdout: ``(n_holdout, in)``; ``y_holdout``: ``(n_holdout, out)``; may have 0 rows.
        members: the ensemble size (one bootstrap sample each).
        epochs: passes over each member's bootstrap sample.
        batch_size: rows per member per gradient step.
        lr: Adam learning rate.
        weight_decay: Adam's L2 weight decay.
        seed: seeds the bootstrap and the shuffling (a local ``torch.Generator``).
        keep_best: restore the weights of the epoch with the lowest held-out loss.
        penalty: a scalar added to the loss, for example PETS's
            ``0.01 * (sum(max_logvar) - sum(min_logvar))`` that keeps the learned
            log-variance bounds tight.
    """
    started = time.perf_counter()
    n_train, n_holdout = int(x_train.shape[0]), int(x_holdout.shape[0])
    gen = torch.Generator().manual_seed(int(seed))
    boot = torch.randint(n_train, (members, n_train), generator=gen)  # (members, n_train)
    optimiser = torch.optim.Adam(net.parameters(), lr=lr, weight_decay=weight_decay)
    train_loss: list[float] = []
    holdout_loss: list[float] = []
    best, best_epoch, best_state = np.inf, epochs - 1, None
    for epoch in range(epochs):
        net.train(True)
        order = torch.argsort(torch.rand(members, n_train, generator=gen), dim=1)
        rows = torch.gather(boot, 1, order)
        total, batches = 0.0, 0
        for start in range(0, n_train, batch_size):
            idx = rows[:, start:start + batch_size]  # (members, b)
            mean, logvar = net(x_train[idx])
            nll = gaussian_nll(mean, logvar, y_train[idx])
            # sum over members of each member's mean loss, as mbrl-lib does
            loss = nll.mean(dim=(1, 2)).sum()
            if penalty is not None:
                loss = loss + penalty()
            optimiser.zero_grad(set_to_none=True)
            loss.backward()
            optimiser.step()
            total += float(nll.detach().mean())
            batches += 1
        train_loss.append(total / batches)
        net.train(False)
        if n_holdout:
            score = _holdout_nll(net, x_holdout, y_holdout, members)
            holdout_loss.append(score)
            if keep_best and score < best:
                best, best_epoch = score, epoch
                best_state = copy.deepcopy(net.state_dict())
    if keep_best and best_state is not None:
        net.load_state_dict(best_state)
    if not (keep_best and n_holdout):
        best_epoch = epochs - 1
    return TrainingReport(tuple(train_loss), tuple(holdout_loss), best_epoch, n_train,
                          n_holdout, time.perf_counter() - started)


def _holdout_nll(net: torch.nn.Module, x: torch.Tensor, y: torch.Tensor,
                 members: int) -> float:
    with torch.inference_mode():
        mean, logvar = net(x.expand(members, *x.shape))
        return float(gaussian_nll(mean, logvar, y.expand(members, *y.shape)).mean())


# --- evaluation ---------------------------------------------------------------------------


class GaussianEnsemblePredictor(Protocol):
    """A dynamics model that exposes its per-member Gaussian next-state prediction.

    ``predict(states (batch, d))`` returns ``(means, variances)``, each
    ``(members, batch, d)`` float64, in state units; the predictive distribution is the
    equal-weight mixture over members.
    """

    def predict(self, states: FloatArray) -> tuple[FloatArray, FloatArray]: ...


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
