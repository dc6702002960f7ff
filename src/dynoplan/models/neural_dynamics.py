"""Probabilistic MLP ensemble dynamics ``s_{t+1} ~ D_w(s_t)`` (PETS, Chua et al. 2018).

Each of ``members`` MLPs maps the normalised state to a Gaussian (mean and log-variance)
over the normalised state *change* ``s_{t+1} - s_t``. The log-variance is soft-bounded
between learned ``min_logvar`` and ``max_logvar`` as in PETS and mbrl-lib's
``GaussianMLP``. Input and output normalisation live in the model and in its file.

Training (:meth:`MLPEnsembleDynamics.fit`) fits each member on its own bootstrap of the
training rows by minimising the Gaussian negative log-likelihood, with Adam and weight
decay, as mbrl-lib's ``ModelTrainer`` does for its ``GaussianMLP``
(:func:`~dynoplan.models.trainer.train`). Sampling, alone or for several options' models
at once, runs on the batched engine of :mod:`dynoplan.models.ensemble_rollouts`.
"""

import os
from collections.abc import Sequence
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from dynoplan.errors import DynoplanError
from dynoplan.models.dynamics import LoopStackedDynamics, StackedDynamics
from dynoplan.models.ensemble_rollouts import EnsembleLayers, StackedMLPEnsemble
from dynoplan.models.evaluation import mixture_quantile
from dynoplan.models.mlp import MLP, truncated_normal_init
from dynoplan.models.mlp_file import (
    check_parameter_count,
    hidden_sizes,
    linear_arrays,
    load_linears,
    require_finite,
)
from dynoplan.models.storage import load_arrays, save_arrays
from dynoplan.models.trainer import HoldOut, KeepBest, TrainingReport, bootstrapped, train
from dynoplan.types import FloatArray, Generator

MODEL_KIND = "mlp_ensemble_dynamics"
# Two hidden layers of 160 keep a default planner decision (4 options x 64 samples x
# horizon 20, d = 12) under 10 ms on one core of the 2-core development machine; 200
# (mbrl-lib's default) takes about 12 ms there (docs/benchmarks.md).
DEFAULT_HIDDEN = (160, 160)
# 4 members divide the planner's default 64 samples into full blocks of 16 rows, which
# the batched matrix products run at a higher fraction of peak than blocks of 13
DEFAULT_MEMBERS = 4
_LOG_2PI = float(np.log(2.0 * np.pi))


class GaussianEnsembleMLP(nn.Module):
    """``members`` independent MLPs with SiLU, evaluated as one batched program.

    ``forward(x)`` maps ``(members, batch, in_size)`` to ``(mean, logvar)``, each
    ``(members, batch, out_size)``; member ``k`` only sees ``x[k]``. The log-variance is
    soft-bounded: ``max - softplus(max - raw)`` then ``min + softplus(. - min)``.

    Weights are ``(members, in, out)`` and biases ``(members, 1, out)`` (an ensemble
    :class:`~dynoplan.models.mlp.MLP`, bias fused into the product), initialised from a
    truncated normal with std ``1 / (2 sqrt(in))`` (as mbrl-lib) drawn from ``generator``.
    """

    def __init__(self, in_size: int, out_size: int, hidden_sizes: Sequence[int], members: int,
                 generator: torch.Generator) -> None:
        super().__init__()
        self.in_size = int(in_size)
        self.out_size = int(out_size)
        self.hidden_sizes = tuple(int(h) for h in hidden_sizes)
        self.members = int(members)
        self.mlp = MLP([self.in_size, *self.hidden_sizes, 2 * self.out_size],
                       truncated_normal_init, generator, members=self.members)
        self.min_logvar = nn.Parameter(torch.full((1, self.out_size), -10.0))
        self.max_logvar = nn.Parameter(torch.full((1, self.out_size), 0.5))

    @property
    def weights(self) -> list[torch.Tensor]:
        """The layers' weights, ``(members, in, out)`` each."""
        return self.mlp.weights

    @property
    def biases(self) -> list[torch.Tensor]:
        """The layers' biases, ``(members, 1, out)`` each."""
        return self.mlp.biases

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        mean, raw = self.mlp(x).split(self.out_size, dim=-1)
        return mean, bound_logvar(raw, self.min_logvar, self.max_logvar)

    def loss(self, x: torch.Tensor, y: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """A minibatch's loss (:data:`~dynoplan.models.trainer.BatchLoss`): inputs ``x``
        ``(members, batch, in)``, targets ``y`` ``(members, batch, out)`` -> the sum over
        members of each member's mean NLL (as mbrl-lib) plus :meth:`logvar_bound_penalty`,
        and the mean NLL per target element."""
        mean, logvar = self(x)
        nll = gaussian_nll(mean, logvar, y)
        return nll.mean(dim=(1, 2)).sum() + self.logvar_bound_penalty(), nll.detach().mean()

    def holdout_nll(self, x: torch.Tensor, y: torch.Tensor) -> float:
        """Mean NLL per target element of every member on every row: ``x`` ``(batch, in)``,
        ``y`` ``(batch, out)``."""
        mean, logvar = self(x.expand(self.members, *x.shape))
        return float(gaussian_nll(mean, logvar, y.expand(self.members, *y.shape)).mean())

    def logvar_bound_penalty(self) -> torch.Tensor:
        """PETS's ``0.01 * (sum(max_logvar) - sum(min_logvar))``."""
        return 0.01 * (self.max_logvar.sum() - self.min_logvar.sum())


def gaussian_nll(mean: torch.Tensor, logvar: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Elementwise Gaussian negative log-likelihood ``0.5 (log 2pi + logvar + r^2 / var)``."""
    return 0.5 * (_LOG_2PI + logvar + (target - mean) ** 2 * torch.exp(-logvar))


def bound_logvar(raw: torch.Tensor, min_logvar: torch.Tensor,
                 max_logvar: torch.Tensor) -> torch.Tensor:
    """PETS's soft bounds: ``max - softplus(max - raw)``, then ``min + softplus(. - min)``."""
    lv = max_logvar - F.softplus(max_logvar - raw)
    return min_logvar + F.softplus(lv - min_logvar)


class MLPEnsembleDynamics:
    """An option's forward model ``D_w``: a probabilistic MLP ensemble (PETS).

    Implements :class:`~dynoplan.models.dynamics.DynamicsModel`.

    Args:
        state_dim: ``d``.
        hidden_sizes: widths of the hidden layers (default two of 160).
        members: ensemble size ``E`` (default 4; PETS used 5).
        option: name of the option this model belongs to (stored in the file).
        seed: seeds the weight initialisation (a local ``torch.Generator``).

    Attributes:
        network: the :class:`GaussianEnsembleMLP` on normalised inputs and targets.
        input_mean, input_std: ``(d,)`` float64, state normalisation.
        delta_mean, delta_std: ``(d,)`` float64, normalisation of ``s_{t+1} - s_t``.
        std_scale: ``(d,)`` float64, every member's predicted standard deviation is
            multiplied by it (ones until :meth:`calibrate`).

    Sampling uses a float32 snapshot of the weights, made on first use and renewed by
    :meth:`fit`; call :meth:`refresh` after changing ``network`` or the normalisers by
    hand. Objects from :meth:`stack` keep the snapshot they were built with. Sampling
    reuses work buffers, so one model (or stack) must not be sampled from two threads at
    once.
    """

    def __init__(self, state_dim: int, hidden_sizes: Sequence[int] = DEFAULT_HIDDEN,
                 members: int = DEFAULT_MEMBERS, option: str = "", seed: int = 0) -> None:
        if state_dim < 1 or members < 1 or not hidden_sizes or min(hidden_sizes) < 1:
            raise DynoplanError(
                f"an MLP ensemble needs state_dim >= 1, members >= 1 and at least one hidden "
                f"layer of width >= 1; got {state_dim}, {members}, {tuple(hidden_sizes)}")
        d = int(state_dim)
        self.option = str(option)
        self.network = GaussianEnsembleMLP(d, d, hidden_sizes, members,
                                           torch.Generator().manual_seed(int(seed)))
        self.input_mean = np.zeros(d)
        self.input_std = np.ones(d)
        self.delta_mean = np.zeros(d)
        self.delta_std = np.ones(d)
        self.std_scale = np.ones(d)
        self._single: StackedMLPEnsemble | None = None

    # --- description ------------------------------------------------------------------
    @property
    def state_dim(self) -> int:
        return self.network.in_size

    @property
    def hidden_sizes(self) -> tuple[int, ...]:
        return self.network.hidden_sizes

    @property
    def members(self) -> int:
        return self.network.members

    @property
    def architecture(self) -> tuple[int, tuple[int, ...], int]:
        """``(state_dim, hidden_sizes, members)``: models that stack together share it."""
        return self.state_dim, self.hidden_sizes, self.members

    def flops_per_row(self) -> int:
        """Floating-point operations of one member's forward pass on one row.

        ``2 * in * out`` per layer (multiply-adds of the matrix products), the count used
        by the benchmark; biases, activations and sampling are not counted.
        """
        sizes = [self.state_dim, *self.hidden_sizes, 2 * self.state_dim]
        return int(sum(2 * a * b for a, b in pairwise(sizes)))

    # --- DynamicsModel ----------------------------------------------------------------
    def sample(self, states: FloatArray, rng: Generator) -> FloatArray:
        """One draw of the next state per row: ``(batch, d)`` float64 -> ``(batch, d)``.

        Rows are split across members by a random permutation (see the module
        docstring); the member choice and the Gaussian noise come from ``rng`` only.
        """
        x = np.asarray(states, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != self.state_dim:
            raise ValueError(f"states must be (batch, {self.state_dim}), got {x.shape}")
        if self._single is None:
            self._single = StackedMLPEnsemble([self.sampling_layers()])
        return self._single.sample(x[None], rng)[0]

    def predict(self, states: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Every member's Gaussian over the next state, in state units.

        Args:
            states: ``(batch, d)``.
        Returns:
            ``(means, variances)``, each ``(members, batch, d)`` float64; the predictive
            distribution is their equal-weight mixture.
        """
        x = np.asarray(states, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != self.state_dim:
            raise ValueError(f"states must be (batch, {self.state_dim}), got {x.shape}")
        xn = torch.from_numpy(((x - self.input_mean) / self.input_std).astype(np.float32))
        with torch.inference_mode():
            mean, logvar = self.network(xn.expand(self.members, *xn.shape))
        mean64 = mean.numpy().astype(np.float64)
        var64 = np.exp(logvar.numpy().astype(np.float64))
        return (x + mean64 * self.delta_std + self.delta_mean,
                var64 * (self.delta_std * self.std_scale) ** 2)

    def calibrate(self, states: FloatArray, next_states: FloatArray,
                  level: float = 0.9, min_scale: float = 1.0) -> FloatArray:
        """Rescale the predicted spread so that, on these transitions, a fraction ``level``
        of true next states falls inside the central ``level`` interval, per dimension.

        Post-hoc recalibration (Kuleshov et al. 2018, with one scale per dimension): the
        members' standard deviations are multiplied by ``std_scale`` (``(d,)``), found by
        bisection on ``log(scale)`` in ``[log(min_scale), 5]``. Use transitions the model
        was not fitted on (whole held-out runs, not rows of the training runs). The default
        ``min_scale = 1`` only ever widens: a few calibration runs that happen to be easy
        must not make the model over-confident elsewhere. Returns ``std_scale``.

        Args:
            states, next_states: ``(N, d)``.
        """
        s, nxt = self._check_pairs(states, next_states)
        if not 0.0 < level < 1.0 or not 0.0 < min_scale <= np.exp(5.0):
            raise DynoplanError(f"level must be in (0, 1) and min_scale in (0, e^5], got "
                                f"{level}, {min_scale}")
        self.std_scale = np.ones(self.state_dim)
        means, variances = self.predict(s)
        std = np.sqrt(variances)

        def coverage(log_scale: FloatArray) -> FloatArray:
            scaled = std * np.exp(log_scale)
            low = mixture_quantile(means, scaled, (1.0 - level) / 2.0)
            high = mixture_quantile(means, scaled, (1.0 + level) / 2.0)
            out: FloatArray = ((nxt >= low) & (nxt <= high)).mean(axis=0)
            return out

        lo = np.full(self.state_dim, np.log(min_scale))
        hi = np.full(self.state_dim, 5.0)
        enough = coverage(lo) >= level  # these dimensions keep min_scale exactly
        for _ in range(30):
            mid = 0.5 * (lo + hi)
            short = coverage(mid) < level
            lo, hi = np.where(short, mid, lo), np.where(short, hi, mid)
        self.std_scale = np.where(enough, min_scale, np.exp(hi))
        self.refresh()
        return self.std_scale.copy()

    @classmethod
    def stack(cls, items: Sequence["MLPEnsembleDynamics"]) -> StackedDynamics:
        """Several options' ensembles as one ``(options, samples, d)`` sampler.

        Ensembles of one architecture become a :class:`StackedMLPEnsemble` (one batched
        tensor program; a model that appears more than once, as the options of a level of
        the sequence planner do, is computed once per member for all its slices); mixed
        architectures fall back to a loop over options.
        """
        if len({m.architecture for m in items}) == 1:
            index = {m: k for k, m in enumerate(dict.fromkeys(items))}  # by identity
            return StackedMLPEnsemble([m.sampling_layers() for m in index],
                                      [index[m] for m in items])
        return LoopStackedDynamics(items)

    def sampling_layers(self) -> EnsembleLayers:
        """The parameters sampling runs on (float64, normalisation folded in), for the
        batched engine (:class:`~dynoplan.models.ensemble_rollouts.StackedMLPEnsemble`)."""
        with torch.no_grad():
            ws = [w.numpy().astype(np.float64) for w in self.network.weights]
            bs = [b.numpy().astype(np.float64) for b in self.network.biases]
            lo = self.network.min_logvar.numpy()[0].astype(np.float64)
            hi = self.network.max_logvar.numpy()[0].astype(np.float64)
        d = self.state_dim
        # layer 0 on (x - mu) / sd  ==  x @ (W / sd[:, None]) + (b - (mu / sd) @ W)
        inv = 1.0 / self.input_std
        bs[0] = bs[0] - np.einsum("i,eio->eo", self.input_mean * inv, ws[0])[:, None, :]
        ws[0] = ws[0] * inv[None, :, None]
        # mean outputs: delta = mean_n * delta_std + delta_mean
        ws[-1][:, :, :d] *= self.delta_std
        bs[-1][:, :, :d] = bs[-1][:, :, :d] * self.delta_std + self.delta_mean
        return EnsembleLayers(tuple(ws), tuple(bs), lo, hi, np.log(self.delta_std * self.std_scale))

    def refresh(self) -> None:
        """Rebuild the float32 sampling snapshot after a change of weights or normalisers."""
        self._single = None

    # --- training ---------------------------------------------------------------------
    def fit(self, states: FloatArray, next_states: FloatArray, *, epochs: int = 50,
            batch_size: int = 256, lr: float = 1e-3, weight_decay: float = 5e-5,
            seed: int = 0, holdout_fraction: float = 0.1,
            keep_best: bool = True, keep_still: bool = True) -> TrainingReport:
        """Fit the ensemble on transitions ``(s_t, s_{t+1})`` by Gaussian NLL.

        A random ``holdout_fraction`` of the rows (chosen with ``seed``) is held out; the
        normalisers are computed from the remaining rows; each member trains on its own
        bootstrap of them (Adam with ``weight_decay``, ``batch_size`` rows per member and
        step; the bootstrap and the shuffling come from a ``torch.Generator`` seeded with
        ``seed``). With ``keep_best`` the weights of the first epoch with the lowest
        held-out loss are kept. With ``keep_still`` a dimension whose change never varies
        in the data keeps that change in every prediction (:data:`STILL_SPREAD`); without
        it, the network's error moves such a dimension off the data.

        The report's losses are the Gaussian negative log-likelihood per target element
        (with the ``0.5 * log(2 pi)`` constant), in the model's normalised target units,
        averaged over members: the training loss is the mean over the epoch's minibatches,
        the held-out loss is every member's on every held-out row. A model that predicts
        the training targets' mean and variance scores about 1.42; lower is better.

        Args:
            states: ``(N, d)``; ``next_states``: ``(N, d)``.
        Raises:
            DynoplanError: shapes do not match the model, non-finite values, too few rows,
                or a holdout fraction outside ``[0, 1)``.
        """
        s, nxt = self._check_pairs(states, next_states)
        if not 0.0 <= holdout_fraction < 1.0:
            raise DynoplanError(f"holdout_fraction must be in [0, 1), got {holdout_fraction}")
        if epochs < 1 or batch_size < 1 or lr <= 0.0:
            raise DynoplanError(f"epochs, batch_size and lr must be positive, got {epochs}, "
                                f"{batch_size}, {lr}")
        n = s.shape[0]
        n_holdout = round(n * holdout_fraction)
        if holdout_fraction > 0.0:
            n_holdout = min(max(n_holdout, 1), n - 2)
        self.std_scale = np.ones(self.state_dim)  # a new fit needs a new calibration
        perm = np.random.default_rng(seed).permutation(n)
        fit_rows, hold_rows = perm[n_holdout:], perm[:n_holdout]
        delta = nxt - s
        self.input_mean, self.input_std = _mean_std(s[fit_rows])
        self.delta_mean, self.delta_std = (_delta_mean_std if keep_still else _mean_std)(
            delta[fit_rows])
        xn = torch.from_numpy(((s - self.input_mean) / self.input_std).astype(np.float32))
        yn = torch.from_numpy(((delta - self.delta_mean) / self.delta_std).astype(np.float32))
        tr, ho = torch.from_numpy(fit_rows), torch.from_numpy(hold_rows)
        net = self.network
        rows = bootstrapped(self.members, len(fit_rows), torch.Generator().manual_seed(int(seed)))
        optimiser = torch.optim.Adam(net.parameters(), lr=lr, weight_decay=weight_decay)
        report = train(net, net.loss, xn[tr], yn[tr], optimiser, rows, epochs=epochs,
                       batch_size=batch_size, average="batches",
                       holdout=HoldOut(xn[ho], yn[ho], net.holdout_nll) if n_holdout else None,
                       keep_best=KeepBest() if keep_best else None)
        self.refresh()
        return report

    def _check_pairs(self, states: FloatArray,
                     next_states: FloatArray) -> tuple[FloatArray, FloatArray]:
        s = np.asarray(states, dtype=np.float64)
        nxt = np.asarray(next_states, dtype=np.float64)
        d = self.state_dim
        if s.ndim != 2 or s.shape[1] != d or s.shape != nxt.shape:
            raise DynoplanError(f"states and next_states must both be (N, {d}), got "
                                f"{s.shape} and {nxt.shape}")
        if s.shape[0] < 3:
            raise DynoplanError(f"need at least 3 transitions to fit, got {s.shape[0]}")
        if not (np.isfinite(s).all() and np.isfinite(nxt).all()):
            raise DynoplanError("states and next_states must be finite")
        return s, nxt

    # --- storage ----------------------------------------------------------------------
    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the model to ``path`` (safetensors + JSON metadata, atomically)."""
        arrays = linear_arrays(self.network.mlp)
        arrays["min_logvar"] = self.network.min_logvar.detach().numpy()
        arrays["max_logvar"] = self.network.max_logvar.detach().numpy()
        arrays["input_mean"] = self.input_mean
        arrays["input_std"] = self.input_std
        arrays["delta_mean"] = self.delta_mean
        arrays["delta_std"] = self.delta_std
        arrays["std_scale"] = self.std_scale
        meta = {"state_dim": self.state_dim, "hidden_sizes": list(self.hidden_sizes),
                "members": self.members, "option": self.option, "activation": "silu",
                "output": "gaussian_delta"}
        return save_arrays(path, MODEL_KIND, arrays, meta)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> "MLPEnsembleDynamics":
        """Read a model written by :meth:`save`.

        Raises:
            DynoplanError: unreadable or corrupt file, another kind of model, missing or
                mis-shaped arrays, or metadata that does not describe this model.
        """
        arrays, meta = load_arrays(path, MODEL_KIND)
        d = _meta_int(meta, "state_dim", path)
        members = _meta_int(meta, "members", path)
        hidden = hidden_sizes(meta, path)
        check_parameter_count(path, arrays, [d, *hidden, 2 * d], members)
        model = cls(d, hidden, members, option=str(meta.get("option", "")))
        net = model.network
        expected = load_linears(net.mlp, arrays, path)
        with torch.no_grad():
            for name in ("min_logvar", "max_logvar"):
                a = require_finite(arrays, name, (1, d), np.float32, path)
                getattr(net, name).copy_(torch.from_numpy(a))
        normalisers = ("input_mean", "input_std", "delta_mean", "delta_std", "std_scale")
        extra = set(arrays) - expected - {"min_logvar", "max_logvar", *normalisers}
        if extra:
            raise DynoplanError(f"{path}: unexpected arrays {sorted(extra)} (the metadata "
                                f"describes {len(hidden)} hidden layers)")
        for name in normalisers:
            setattr(model, name, require_finite(arrays, name, (d,), np.float64, path))
        if (model.input_std <= 0).any() or (model.delta_std <= 0).any() \
                or (model.std_scale <= 0).any():
            raise DynoplanError(f"{path}: normalisation standard deviations must be positive")
        return model


STILL_SPREAD = 1e-9
"""The normalising spread of a state change that the training data never shows varying:
the model keeps such a dimension where the data kept it (its constant change, to within
this), however far a rollout's input lies from the data."""


def _mean_std(a: FloatArray) -> tuple[FloatArray, FloatArray]:
    mean = a.mean(axis=0)
    std = a.std(axis=0)
    return mean, np.where(std > 1e-8, std, 1.0)


def _delta_mean_std(a: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The normalisation of the changes ``(N, d)``: a constant change keeps a spread of
    :data:`STILL_SPREAD`, so the network's error in it is scaled down to nothing."""
    mean = a.mean(axis=0)
    return mean, np.maximum(a.std(axis=0), STILL_SPREAD)


def _meta_int(meta: dict[str, Any], name: str, path: str | os.PathLike[str]) -> int:
    value = meta.get(name)
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        raise DynoplanError(f"{path}: metadata field '{name}' must be a positive integer, "
                            f"got {value!r}")
    return value

