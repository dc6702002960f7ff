"""The learned goal heuristic ``g ~ G(s)``: a network that reads task progress off a state.

Training targets come from the demonstrations: each demonstration state is labelled with
its normalised progress along that demonstration (``infos["progress"]``, or
``t / (T - 1)`` from :func:`progress_from_episode`), which is monotone by construction.
The network outputs a **Beta distribution** over ``[0, 1]`` for each state,

    mu = sigmoid(a(s)),   kappa = softplus(b(s)) + kappa_floor,
    G(s) = Beta(alpha = mu * kappa, beta = (1 - mu) * kappa),

trained by the Beta negative log-likelihood of the targets (clipped to
``[eps, 1 - eps]`` so that the first and last states of a demonstration have finite
density), plus, with ``ranking > 0``, a pairwise ranking loss along each demonstration:
for states ``s_i`` before ``s_j`` of one demonstration, ``softplus(a(s_i) - a(s_j))``
on the logit of the mean (RankNet's logistic loss), so that later states score higher
even where the likelihood alone lets two phases blur (the last phase, where a half-done
insertion must score above the pose it started from).

Why a Beta and not a Gaussian on the logit: the Beta's support is exactly ``[0, 1]``, its
mean ``mu`` and variance ``mu (1 - mu) / (kappa + 1)`` are closed-form (the planner's
``E[G]`` and the figures' bands need no quadrature, a logit-normal's mean has no closed
form), ``numpy.random.Generator.beta`` draws from it directly, and ``scipy.stats.beta``
gives exact quantiles for calibration checks.

With ``members > 1`` the model is a small deep ensemble (members differ only in their
initialisation, are trained on the same batches and evaluated as one batched tensor
program) and ``G(s)`` is the uniform mixture of the members' Betas, so the spread also
grows where the members disagree (away from the demonstrations).
"""

import math
import os
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from scipy import stats
from torch import nn

from dynoplan.data.episodes import Episode, StateFn
from dynoplan.errors import DynoplanError
from dynoplan.models.goal import GoalHeuristic
from dynoplan.models.mlp import MLP, uniform_init
from dynoplan.models.mlp_file import (
    check_parameter_count,
    linear_arrays,
    load_linears,
    require_finite,
)
from dynoplan.models.storage import as_states, load_arrays, save_arrays
from dynoplan.models.trainer import BatchLoss, HoldOut, KeepBest, shuffled, train
from dynoplan.types import FloatArray, Generator, IntArray

_KIND = "goal_network"
_ARCHITECTURE = "beta-mlp-silu-2"
_TARGET_EPS = 1e-3
"""Targets are clipped to ``[eps, 1 - eps]`` before the Beta log-likelihood."""
_KAPPA_FLOOR = 1e-2
"""Lower bound of the Beta concentration ``alpha + beta`` (keeps both parameters > 0)."""
_LOGIT_CLAMP = 15.0
"""``|a(s)|`` is clamped so that ``alpha`` and ``beta`` stay positive in float32."""


@dataclass
class GoalTrainingReport:
    """What :meth:`GoalNetwork.fit` did.

    Attributes:
        train_loss: ``(epochs,)`` mean Beta negative log-likelihood per training state,
            averaged over the epoch's minibatches (and over ensemble members).
        holdout_loss: ``(epochs,)`` the same on the held-out states after each epoch;
            empty when ``holdout_fraction == 0``.
        n_train: number of training states.
        n_holdout: number of held-out states.
        holdout_index: ``(n_holdout,)`` row indices (into the ``states`` given to ``fit``)
            of the held-out states.
        best_epoch: index of the epoch whose weights were returned (the last one unless
            ``keep_best`` chose an earlier one).
    """

    train_loss: list[float] = field(default_factory=list)
    holdout_loss: list[float] = field(default_factory=list)
    n_train: int = 0
    n_holdout: int = 0
    holdout_index: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    best_epoch: int = -1


class _BetaEnsemble(nn.Module):
    """``members`` MLPs ``d -> hidden -> hidden -> 2`` (SiLU), evaluated as one batch.

    ``forward`` maps raw states ``(batch, d)`` to ``(members, batch, 2)``: the logit of
    the mean and the pre-softplus concentration. Input normalisation is part of the model.
    The weights (an ensemble :class:`~dynoplan.models.mlp.MLP`, bias added after the
    product) get PyTorch's ``nn.Linear`` default init, drawn from ``generator`` only.
    """

    in_mean: torch.Tensor
    in_std: torch.Tensor

    def __init__(self, state_dim: int, hidden: int, members: int,
                 generator: torch.Generator) -> None:
        super().__init__()
        self.members = members
        self.mlp = MLP([state_dim, hidden, hidden, 2], uniform_init, generator, members=members,
                       fused_bias=False)
        self.register_buffer("in_mean", torch.zeros(state_dim))
        self.register_buffer("in_std", torch.ones(state_dim))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.mlp(((x - self.in_mean) / self.in_std).unsqueeze(0))

    def loss(self, x: torch.Tensor, y: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """A minibatch's loss (:data:`~dynoplan.models.trainer.BatchLoss`): states ``x``
        ``(batch, d)``, clipped progress ``y`` ``(batch,)`` -> :func:`_beta_nll`, twice."""
        nll = _beta_nll(self(x), y)
        return nll, nll

    def ranked_loss(self, ranking: float) -> BatchLoss:
        """The loss with a pairwise ranking term of weight ``ranking``: targets
        ``(batch, 2)`` hold the clipped progress and the demonstration id of each state;
        returns ``(nll + ranking * rank, nll)``."""

        def loss(x: torch.Tensor, y: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            raw = self(x)
            nll = _beta_nll(raw, y[:, 0])
            return nll + ranking * _ranking_loss(raw, y[:, 0], y[:, 1]), nll

        return loss

    def holdout_nll(self, x: torch.Tensor, y: torch.Tensor) -> float:
        """:func:`_beta_nll` per member (the mean over members of their mean NLL); ``y``
        ``(batch,)`` or ``(batch, 2)`` (progress first)."""
        return float(_beta_nll(self(x), y if y.ndim == 1 else y[:, 0])) / self.members


def _beta_params(raw: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(..., 2)`` network outputs to Beta ``alpha``, ``beta``, each ``(...)``."""
    a = raw[..., 0].clamp(-_LOGIT_CLAMP, _LOGIT_CLAMP)
    kappa = nn.functional.softplus(raw[..., 1]) + _KAPPA_FLOOR
    # sigmoid(-a) rather than 1 - sigmoid(a): keeps beta > 0 when mu rounds to 1
    return torch.sigmoid(a) * kappa, torch.sigmoid(-a) * kappa


def _ranking_loss(raw: torch.Tensor, progress: torch.Tensor,
                  group: torch.Tensor) -> torch.Tensor:
    """Sum over members of the mean ``softplus(a_i - a_j)`` over the minibatch's pairs
    ``(i, j)`` of one demonstration with ``progress_j > progress_i`` (0 without pairs);
    ``raw`` ``(members, batch, 2)``, ``progress`` and ``group`` ``(batch,)``."""
    a = raw[..., 0].clamp(-_LOGIT_CLAMP, _LOGIT_CLAMP)  # (members, batch)
    later = (group[:, None] == group[None, :]) & (progress[None, :] > progress[:, None])
    if not bool(later.any()):
        return raw.sum() * 0.0
    diff = a[:, :, None] - a[:, None, :]  # (members, i, j): a_i - a_j
    return nn.functional.softplus(diff[:, later]).mean(dim=1).sum()


def _beta_nll(raw: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Mean over states (summed over members) of ``-log Beta(y | alpha, beta)``.

    ``raw`` is ``(members, batch, 2)``, ``y`` ``(batch,)`` already clipped to ``(0, 1)``.
    """
    alpha, beta = _beta_params(raw)
    log_b = torch.lgamma(alpha) + torch.lgamma(beta) - torch.lgamma(alpha + beta)
    log_p = (alpha - 1.0) * torch.log(y) + (beta - 1.0) * torch.log1p(-y) - log_b
    return -log_p.mean(dim=1).sum()


class GoalNetwork:
    """Learned goal heuristic ``G(s)``: a Beta over progress in ``[0, 1]`` per state.

    Satisfies :class:`~dynoplan.models.goal.GoalHeuristic`. Build one with :meth:`fit`
    or :meth:`load`. Inference runs in float32 under ``torch.inference_mode()``; the
    Beta parameters are then computed in float64 and every output is ``float64``.
    """

    def __init__(self, net: _BetaEnsemble, state_dim: int, hidden: int, members: int) -> None:
        self._net = net.eval()
        self._state_dim = state_dim
        self._hidden = hidden
        self._members = members

    @property
    def state_dim(self) -> int:
        return self._state_dim

    @property
    def hidden(self) -> int:
        return self._hidden

    @property
    def members(self) -> int:
        return self._members

    # --- the distribution ------------------------------------------------------------
    def beta_params(self, states: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Each member's Beta ``alpha`` and ``beta``, each ``(batch, members)`` float64."""
        x = as_states(states, self._state_dim)
        with torch.inference_mode():
            raw = self._net(torch.as_tensor(x, dtype=torch.float32)).to(torch.float64)
            alpha, beta = _beta_params(raw)
        return alpha.numpy().T.copy(), beta.numpy().T.copy()

    def sample(self, states: FloatArray, rng: Generator) -> FloatArray:
        """One draw of ``g ~ G(s)`` per state: ``(batch, state_dim)`` -> ``(batch,)`` in [0, 1].

        Uses ``rng`` only (a member index per state when ``members > 1``, then
        ``rng.beta``), so the same generator state gives the same draws. A non-finite
        state (a diverged rollout) gives ``nan`` rather than an error, for the caller
        to mask.
        """
        alpha, beta = self.beta_params(states)
        if self._members == 1:
            return rng.beta(alpha[:, 0], beta[:, 0])
        rows = np.arange(alpha.shape[0])
        pick = rng.integers(self._members, size=alpha.shape[0])
        return rng.beta(alpha[rows, pick], beta[rows, pick])

    def mean_std(self, states: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Mean and standard deviation of ``G(s)``, each ``(batch,)`` float64.

        For an ensemble, of the uniform mixture of the members' Betas.
        """
        alpha, beta = self.beta_params(states)
        kappa = alpha + beta
        mu = alpha / kappa
        var = mu * (1.0 - mu) / (kappa + 1.0)
        mean = mu.mean(axis=1)
        second = (var + mu * mu).mean(axis=1)
        return mean, np.sqrt(np.maximum(second - mean * mean, 0.0))

    def cdf(self, states: FloatArray, values: FloatArray) -> FloatArray:
        """``P(G(s) <= value)`` for each state and its value, both ``(batch,)`` -> ``(batch,)``."""
        alpha, beta = self.beta_params(states)
        v = np.asarray(values, dtype=np.float64)
        if v.shape != (alpha.shape[0],):
            raise DynoplanError(f"values must have shape ({alpha.shape[0]},), got {v.shape}")
        return np.asarray(stats.beta.cdf(v[:, None], alpha, beta).mean(axis=1), np.float64)

    def interval(self, states: FloatArray, level: float = 0.9) -> tuple[FloatArray, FloatArray]:
        """Central ``level`` interval of ``G(s)``: lower and upper bounds, each ``(batch,)``.

        Exact ``scipy.stats.beta.ppf`` for one member; for an ensemble, the mixture's
        quantiles found by bisection on its CDF (to ~1e-12).
        """
        if not 0.0 < level < 1.0:
            raise DynoplanError(f"level must be in (0, 1), got {level}")
        alpha, beta = self.beta_params(states)
        tail = (1.0 - level) / 2.0
        if self._members == 1:
            lo = stats.beta.ppf(tail, alpha[:, 0], beta[:, 0])
            hi = stats.beta.ppf(1.0 - tail, alpha[:, 0], beta[:, 0])
            return np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        return _mixture_quantile(alpha, beta, tail), _mixture_quantile(alpha, beta, 1.0 - tail)

    # --- fitting ---------------------------------------------------------------------
    @classmethod
    def fit(
        cls,
        states: FloatArray,
        progress: FloatArray,
        *,
        hidden: int = 128,
        members: int = 1,
        epochs: int = 100,
        batch_size: int = 256,
        lr: float = 3e-3,
        weight_decay: float = 1e-2,
        seed: int = 0,
        holdout_fraction: float = 0.0,
        groups: IntArray | None = None,
        keep_best: bool = True,
        ranking: float = 0.0,
    ) -> tuple["GoalNetwork", GoalTrainingReport]:
        """Fit ``G`` to demonstration states and their progress by Beta maximum likelihood.

        Args:
            states: ``(N, state_dim)`` demonstration states.
            progress: ``(N,)`` progress of each state in ``[0, 1]``.
            hidden: width of both hidden layers.
            members: ensemble size (1: a single network).
            epochs: passes over the training states (AdamW, cosine-decayed learning rate).
            batch_size: minibatch size.
            lr: initial learning rate.
            weight_decay: AdamW decoupled weight decay.
            seed: seeds the initialisation, the minibatch order and the held-out split
                (through a private ``torch.Generator`` and ``numpy`` generator; no global
                random state is read or changed).
            holdout_fraction: fraction of states (or of ``groups``) held out to report
                a held-out loss per epoch; they are not trained on.
            groups: ``(N,)`` optional demonstration id of each state, so that whole
                demonstrations are held out rather than scattered states.
            keep_best: with a hold-out, return the weights of the epoch with the lowest
                held-out loss (the concentration overfits first when trained long).
            ranking: weight of the pairwise ranking loss along demonstrations (module
                docstring; 0: likelihood alone); pairs come from one group of ``groups``
                (all states are one group without them).

        Returns:
            The fitted network and a :class:`GoalTrainingReport`.

        Raises:
            DynoplanError: wrong shapes, non-finite values, progress outside ``[0, 1]``,
                or a bad setting.
        """
        x, y = _check_training_data(states, progress)
        for name, value in (("hidden", hidden), ("members", members), ("epochs", epochs),
                            ("batch_size", batch_size)):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise DynoplanError(f"{name} must be a positive integer, got {value!r}")
        if not (math.isfinite(lr) and lr > 0.0):
            raise DynoplanError(f"lr must be positive, got {lr}")
        if not (math.isfinite(weight_decay) and weight_decay >= 0.0):
            raise DynoplanError(f"weight_decay must be >= 0, got {weight_decay}")
        if not (math.isfinite(ranking) and ranking >= 0.0):
            raise DynoplanError(f"ranking must be >= 0, got {ranking}")
        if not 0.0 <= holdout_fraction < 1.0:
            raise DynoplanError(f"holdout_fraction must be in [0, 1), got {holdout_fraction}")
        train_idx, held_idx = _split(len(x), holdout_fraction, groups, seed)

        generator = torch.Generator().manual_seed(seed)
        net = _BetaEnsemble(x.shape[1], hidden, members, generator)
        xt = torch.as_tensor(x, dtype=torch.float32)
        yt = torch.as_tensor(np.clip(y, _TARGET_EPS, 1.0 - _TARGET_EPS), dtype=torch.float32)
        if ranking > 0.0:  # targets carry the demonstration id for the pairs
            ids = np.zeros(len(y)) if groups is None else np.asarray(groups, np.float64)
            yt = torch.stack([yt, torch.as_tensor(ids, dtype=torch.float32)], dim=1)
        x_train, y_train = xt[train_idx], yt[train_idx]
        with torch.no_grad():
            net.in_mean.copy_(x_train.mean(dim=0))
            # constant features would divide by zero; leave them unscaled
            std = x_train.std(dim=0, correction=0)
            net.in_std.copy_(torch.where(std > 1e-8, std, torch.ones_like(std)))

        optimiser = torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=weight_decay)
        schedule = torch.optim.lr_scheduler.LambdaLR(
            optimiser, lambda epoch: 0.5 * (1.0 + math.cos(math.pi * epoch / epochs)))
        holdout = HoldOut(xt[held_idx], yt[held_idx], net.holdout_nll) if len(held_idx) else None
        rows = shuffled(len(train_idx), generator)
        loss = net.ranked_loss(ranking) if ranking > 0.0 else net.loss
        result = train(net, loss, x_train, y_train, optimiser, rows, epochs=epochs,
                       batch_size=batch_size, schedule=schedule, holdout=holdout,
                       keep_best=KeepBest(ties="last") if keep_best else None)
        report = GoalTrainingReport(
            train_loss=[loss / members for loss in result.train_loss],
            holdout_loss=list(result.holdout_loss), n_train=result.n_train,
            n_holdout=result.n_holdout, holdout_index=held_idx, best_epoch=result.best_epoch)
        return cls(net, x.shape[1], hidden, members), report

    # --- storage ---------------------------------------------------------------------
    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write a ``.safetensors`` file (no pickle); :meth:`load` restores it bit-exactly."""
        arrays = linear_arrays(self._net.mlp, "w{}", "b{}", first=1)
        arrays["in_mean"] = self._net.in_mean.numpy().copy()
        arrays["in_std"] = self._net.in_std.numpy().copy()
        meta = {
            "architecture": _ARCHITECTURE,
            "state_dim": self._state_dim,
            "hidden": self._hidden,
            "members": self._members,
            "kappa_floor": _KAPPA_FLOOR,
            "logit_clamp": _LOGIT_CLAMP,
        }
        return save_arrays(path, _KIND, arrays, meta)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> "GoalNetwork":
        """Read a file written by :meth:`save`.

        Raises:
            DynoplanError: missing, corrupt or truncated file, another kind of model,
                another architecture, or arrays of the wrong shape or type.
        """
        arrays, meta = load_arrays(path, _KIND)
        d, h, m = meta.get("state_dim"), meta.get("hidden"), meta.get("members")
        if not all(isinstance(v, int) and not isinstance(v, bool) and v >= 1
                   for v in (d, h, m)):
            raise DynoplanError(f"{path}: metadata lacks valid state_dim, hidden or members")
        assert isinstance(d, int) and isinstance(h, int) and isinstance(m, int)
        if (meta.get("architecture") != _ARCHITECTURE or meta.get("kappa_floor") != _KAPPA_FLOOR
                or meta.get("logit_clamp") != _LOGIT_CLAMP):
            raise DynoplanError(
                f"{path}: architecture {meta.get('architecture')!r} (kappa_floor "
                f"{meta.get('kappa_floor')!r}, logit_clamp {meta.get('logit_clamp')!r}) is not "
                f"this version's {_ARCHITECTURE!r} ({_KAPPA_FLOOR}, {_LOGIT_CLAMP})")
        check_parameter_count(path, arrays, [d, h, h, 2], m)
        net = _BetaEnsemble(d, h, m, torch.Generator())
        load_linears(net.mlp, arrays, path, "w{}", "b{}", first=1)
        for name in ("in_mean", "in_std"):
            getattr(net, name).copy_(torch.from_numpy(
                require_finite(arrays, name, (d,), np.float32, path)))
        return cls(net, d, h, m)



# --- targets from demonstrations -------------------------------------------------------
def progress_from_episode(length: int) -> FloatArray:
    """Normalised progress ``t / (length - 1)`` of ``length`` consecutive states: ``(length,)``.

    The first state has progress 0 and the last 1 (a single state counts as finished).
    """
    if isinstance(length, bool) or not isinstance(length, int | np.integer) or length < 1:
        raise DynoplanError(f"length must be a positive integer, got {length!r}")
    if length == 1:
        return np.ones(1)
    return np.arange(length, dtype=np.float64) / (length - 1)


def goal_training_set(
    episodes: Iterable[Episode], state_fn: StateFn | None = None
) -> tuple[FloatArray, FloatArray, IntArray]:
    """States of every demonstration with progress targets from their position in time.

    All ``T + 1`` observations of each episode are used, labelled ``t / T`` by
    :func:`progress_from_episode` (no ``infos["progress"]`` needed), so each
    demonstration runs from progress 0 at its reset to 1 at its final state.

    Args:
        episodes: a :class:`~dynoplan.data.Dataset` or any iterable of episodes.
        state_fn: observations ``(T+1, *obs_shape)`` to states ``(T+1, state_dim)``;
            default: observations flattened per row.

    Returns:
        ``states`` ``(N, state_dim)``, ``progress`` ``(N,)`` and ``groups`` ``(N,)`` (the
        episode index of each row, for :meth:`GoalNetwork.fit`'s ``groups``).
    """
    states: list[np.ndarray] = []
    targets: list[np.ndarray] = []
    groups: list[np.ndarray] = []
    for index, episode in enumerate(episodes):
        obs = episode.observations
        rows = obs.reshape(obs.shape[0], -1) if state_fn is None else np.asarray(state_fn(obs))
        if rows.ndim != 2 or rows.shape[0] != obs.shape[0]:
            raise DynoplanError(
                f"episode {index}: state_fn must map observations {obs.shape} to "
                f"({obs.shape[0]}, state_dim), got {rows.shape}")
        states.append(rows.astype(np.float64))
        targets.append(progress_from_episode(rows.shape[0]))
        groups.append(np.full(rows.shape[0], index, dtype=np.int64))
    if not states:
        raise DynoplanError("no episodes to build goal targets from")
    if len({s.shape[1] for s in states}) > 1:
        raise DynoplanError(
            f"episodes disagree on state_dim: {sorted({s.shape[1] for s in states})}")
    return np.concatenate(states), np.concatenate(targets), np.concatenate(groups)


# --- evaluation ------------------------------------------------------------------------
def evaluate_goal(
    goal: GoalHeuristic, states: FloatArray, progress: FloatArray
) -> dict[str, float]:
    """How well a goal heuristic tracks ground-truth progress on (held-out) states.

    Args:
        goal: a :class:`~dynoplan.models.goal.GoalHeuristic`. For a :class:`GoalNetwork`
            the 90% interval is its own; for any other heuristic it is that of the Beta
            with the same mean and standard deviation.
        states: ``(N, state_dim)``.
        progress: ``(N,)`` ground truth in ``[0, 1]``.

    Returns:
        ``spearman``: rank correlation of the mean with the truth
        (``scipy.stats.spearmanr``); ``mae``: mean ``|mean - truth|``; ``coverage_90``:
        fraction of truths inside the central 90% interval (``scipy.stats.beta.ppf``).
    """
    if not isinstance(goal, GoalHeuristic):
        raise DynoplanError(f"{type(goal).__name__} is not a GoalHeuristic")
    x, y = _check_training_data(states, progress)
    mean, std = goal.mean_std(x)
    if isinstance(goal, GoalNetwork):
        lo, hi = goal.interval(x, 0.9)
    else:
        lo, hi = _moment_matched_interval(mean, std, 0.9)
    rho = stats.spearmanr(mean, y).statistic
    return {
        "spearman": float(rho),
        "mae": float(np.mean(np.abs(mean - y))),
        "coverage_90": float(np.mean((y >= lo) & (y <= hi))),
    }


def _moment_matched_interval(mean: FloatArray, std: FloatArray,
                             level: float) -> tuple[FloatArray, FloatArray]:
    """Central interval of the Beta with the given mean and std (a point mass if std ~ 0)."""
    m = np.clip(mean, 1e-9, 1.0 - 1e-9)
    var = np.clip(std * std, 1e-18, m * (1.0 - m) * (1.0 - 1e-9))
    kappa = m * (1.0 - m) / var - 1.0
    tail = (1.0 - level) / 2.0
    lo = stats.beta.ppf(tail, m * kappa, (1.0 - m) * kappa)
    hi = stats.beta.ppf(1.0 - tail, m * kappa, (1.0 - m) * kappa)
    return np.asarray(lo, np.float64), np.asarray(hi, np.float64)


def _mixture_quantile(alpha: FloatArray, beta: FloatArray, q: float) -> FloatArray:
    """``q``-quantile of the uniform mixture of Betas per row; ``alpha``, ``beta`` ``(B, M)``."""
    lo = np.zeros(alpha.shape[0])
    hi = np.ones(alpha.shape[0])
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        below = stats.beta.cdf(mid[:, None], alpha, beta).mean(axis=1) < q
        lo = np.where(below, mid, lo)
        hi = np.where(below, hi, mid)
    return 0.5 * (lo + hi)


def _check_training_data(states: FloatArray, progress: FloatArray) -> tuple[FloatArray,
                                                                            FloatArray]:
    x = np.asarray(states, dtype=np.float64)
    y = np.asarray(progress, dtype=np.float64)
    if x.ndim != 2 or x.shape[0] < 1 or x.shape[1] < 1:
        raise DynoplanError(f"states must have shape (N, state_dim), got {x.shape}")
    if y.shape != (x.shape[0],):
        raise DynoplanError(
            f"progress must have shape ({x.shape[0]},) to match states {x.shape}, got {y.shape}")
    if not np.isfinite(x).all():
        raise DynoplanError("states contain NaN or infinite values")
    if not np.isfinite(y).all():
        raise DynoplanError("progress contains NaN or infinite values")
    if y.min() < 0.0 or y.max() > 1.0:
        raise DynoplanError(
            f"progress must lie in [0, 1], got values in [{y.min():.4g}, {y.max():.4g}]")
    return x, y


def _split(n: int, fraction: float, groups: IntArray | None,
           seed: int) -> tuple[IntArray, IntArray]:
    """Training and held-out row indices; whole groups are held out when given."""
    rng = np.random.default_rng(seed)
    everything = np.arange(n, dtype=np.int64)
    if fraction == 0.0:
        return everything, np.zeros(0, dtype=np.int64)
    if groups is None:
        held = np.sort(rng.permutation(n)[:round(fraction * n)])
    else:
        g = np.asarray(groups)
        if g.shape != (n,):
            raise DynoplanError(f"groups must have shape ({n},), got {g.shape}")
        ids = rng.permutation(np.unique(g))
        chosen = ids[:round(fraction * len(ids))]
        held = everything[np.isin(g, chosen)]
    if len(held) == 0 or len(held) == n:
        raise DynoplanError(
            f"holdout_fraction {fraction} leaves {n - len(held)} training and {len(held)} "
            "held-out states; both must be non-empty")
    return everything[~np.isin(everything, held)], held.astype(np.int64)
