"""Safety regions of options from demonstrations (the paper's Eq. 5).

A Gaussian mixture ``F_M = {N(mu_i, Sigma_i)}`` is fitted on demonstration states. The
components that carry option ``k``'s samples form ``J_k``; the likelihood that option
``k`` works in state ``s`` is

    L(s | k) = max_{i in J_k} p(s | mu_i, Sigma_i).

A state is inside option ``k``'s region when ``log L(s | k)`` is at least a threshold
calibrated on the demonstrations: the ``1 - coverage`` quantile of ``log L`` over option
``k``'s own demonstration states, minus ``slack`` nats. With ``coverage=0.99`` and
``slack=0`` (defaults), 99% of the option's training states are inside by construction;
held-out coverage is what the evaluation measures.
"""

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from sklearn.mixture import GaussianMixture

from dynoplan.errors import DynoplanError
from dynoplan.models.storage import as_states, load_arrays, require, require_finite, save_arrays
from dynoplan.types import BoolArray, FloatArray, IntArray

_KIND = "safety_regions"


@dataclass
class SafetyRegions:
    """Per-option regions from one Gaussian mixture.

    Attributes:
        option_names: ``(options,)`` names; labels index into this list.
        means: ``(components, state_dim)``.
        precisions_cholesky: ``(components, state_dim, state_dim)``, as in scikit-learn
            (``precision = L @ L.T``).
        members: ``(options, components)`` booleans, row ``k`` is ``J_k``.
        log_thresholds: ``(options,)`` membership thresholds on ``log L(s | k)``.
    """

    option_names: list[str]
    means: FloatArray
    precisions_cholesky: FloatArray
    members: BoolArray
    log_thresholds: FloatArray

    @property
    def state_dim(self) -> int:
        return int(self.means.shape[1])

    @property
    def n_components(self) -> int:
        return int(self.means.shape[0])

    def option_index(self, option: str | int) -> int:
        if isinstance(option, int | np.integer):
            if not 0 <= int(option) < len(self.option_names):
                raise DynoplanError(f"option index {option} out of range")
            return int(option)
        try:
            return self.option_names.index(option)
        except ValueError:
            known = ", ".join(self.option_names)
            raise DynoplanError(f"unknown option '{option}' (known: {known})") from None

    # --- Eq. 5 -----------------------------------------------------------------------
    def component_log_density(self, states: FloatArray) -> FloatArray:
        """``log p(s | mu_i, Sigma_i)`` for every state and component: ``(batch, components)``."""
        x = as_states(states, self.state_dim)
        d = self.state_dim
        # (batch, components, d): whitened residuals (x - mu_i) @ L_i
        diff = x[:, None, :] - self.means[None, :, :]
        z = np.einsum("bmd,mde->bme", diff, self.precisions_cholesky)
        log_det = np.log(np.diagonal(self.precisions_cholesky, axis1=1, axis2=2)).sum(axis=1)
        return -0.5 * (d * np.log(2 * np.pi) + np.sum(z * z, axis=2)) + log_det[None, :]

    def log_likelihood(self, states: FloatArray, option: str | int) -> FloatArray:
        """``log L(s | k) = max_{i in J_k} log p(s | mu_i, Sigma_i)``, shape ``(batch,)``."""
        k = self.option_index(option)
        return self.component_log_density(states)[:, self.members[k]].max(axis=1)

    def likelihood(self, states: FloatArray, option: str | int) -> FloatArray:
        """``L(s | k)`` of Eq. 5, shape ``(batch,)``."""
        return np.exp(self.log_likelihood(states, option))

    def contains(self, states: FloatArray, option: str | int) -> BoolArray:
        """Whether each state lies in option ``k``'s region, shape ``(batch,)``."""
        k = self.option_index(option)
        return self.log_likelihood(states, k) >= self.log_thresholds[k]

    def contains_all(self, states: FloatArray) -> BoolArray:
        """Membership for every option at once: ``(batch, options)``."""
        log_p = self.component_log_density(states)
        masked = np.where(self.members[None, :, :], log_p[:, None, :], -np.inf)
        return masked.max(axis=2) >= self.log_thresholds[None, :]

    # --- fitting ---------------------------------------------------------------------
    @classmethod
    def fit(
        cls,
        states: FloatArray,
        labels: IntArray,
        option_names: Sequence[str],
        n_components: int | None = None,
        max_components: int = 12,
        coverage: float = 0.99,
        slack: float = 0.0,
        min_share: float = 0.1,
        reg_covar: float = 1e-6,
        seed: int = 0,
    ) -> "SafetyRegions":
        """Fit the mixture and the per-option regions.

        Args:
            states: ``(N, state_dim)`` demonstration states.
            labels: ``(N,)`` option index of each state.
            n_components: fixed ``M``; ``None`` picks ``M`` in ``1..max_components`` by BIC.
            coverage: fraction of an option's own states that its threshold admits.
            slack: nats subtracted from each threshold (widens every region).
            min_share: component ``i`` joins ``J_k`` when at least this fraction of the
                states assigned to ``i`` carry label ``k``; each option always keeps the
                component holding most of its states.
            seed: seeds scikit-learn's initialisation.
        """
        x = np.asarray(states, dtype=np.float64)
        y = np.asarray(labels, dtype=np.int64)
        names = list(option_names)
        if x.ndim != 2 or y.shape != (x.shape[0],):
            raise DynoplanError(
                f"states must be (N, d) and labels (N,), got {x.shape} and {y.shape}")
        if not np.isfinite(x).all():
            raise DynoplanError("demonstration states contain NaN or infinite values")
        if y.size and (y.min() < 0 or y.max() >= len(names)):
            raise DynoplanError(f"labels must lie in 0..{len(names) - 1}")
        missing = [names[k] for k in range(len(names)) if not np.any(y == k)]
        if missing:
            raise DynoplanError(f"no demonstration states for option(s): {', '.join(missing)}")
        if not 0.0 < coverage <= 1.0:
            raise DynoplanError(f"coverage must be in (0, 1], got {coverage}")

        gmm = _fit_mixture(x, n_components, max_components, reg_covar, seed)
        assigned = gmm.predict(x)
        m = gmm.n_components
        counts = np.zeros((len(names), m))
        np.add.at(counts, (y, assigned), 1.0)
        share = counts / np.maximum(counts.sum(axis=0, keepdims=True), 1.0)
        members = share >= min_share
        members &= counts > 0
        members[np.arange(len(names)), counts.argmax(axis=1)] = True

        regions = cls(
            option_names=names,
            means=np.asarray(gmm.means_, dtype=np.float64),
            precisions_cholesky=np.asarray(gmm.precisions_cholesky_, dtype=np.float64),
            members=members,
            log_thresholds=np.zeros(len(names)),
        )
        for k in range(len(names)):
            own = regions.log_likelihood(x[y == k], k)
            regions.log_thresholds[k] = np.quantile(own, 1.0 - coverage) - slack
        return regions

    # --- storage ---------------------------------------------------------------------
    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write a ``.safetensors`` file (no pickle) with the option names in its metadata."""
        return save_arrays(
            path,
            _KIND,
            {
                "means": self.means,
                "precisions_cholesky": self.precisions_cholesky,
                "members": self.members.astype(np.uint8),
                "log_thresholds": self.log_thresholds,
            },
            {"option_names": self.option_names, "state_dim": self.state_dim},
        )

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> "SafetyRegions":
        arrays, meta = load_arrays(path, _KIND)
        names = meta.get("option_names")
        d = meta.get("state_dim")
        if not isinstance(names, list) or not isinstance(d, int):
            raise DynoplanError(f"{path}: metadata lacks option_names or state_dim")
        means = require_finite(arrays, "means", (None, d), None, path)
        m, o = means.shape[0], len(names)
        return cls(
            option_names=[str(n) for n in names],
            means=means.astype(np.float64),
            precisions_cholesky=require_finite(arrays, "precisions_cholesky", (m, d, d), None,
                                               path),
            members=require(arrays, "members", (o, m), path).astype(bool),
            log_thresholds=require_finite(arrays, "log_thresholds", (o,), None,
                                          path).astype(np.float64),
        )



def _fit_mixture(x: FloatArray, n_components: int | None, max_components: int,
                 reg_covar: float, seed: int) -> GaussianMixture:
    if n_components is not None:
        candidates = [n_components]
    else:
        candidates = list(range(1, max(1, min(max_components, len(x) // 2)) + 1))
    best: GaussianMixture | None = None
    best_bic = np.inf
    for m in candidates:
        gmm = GaussianMixture(n_components=m, covariance_type="full", reg_covar=reg_covar,
                              random_state=seed, n_init=1)
        gmm.fit(x)
        bic = float(gmm.bic(x))
        if bic < best_bic:
            best, best_bic = gmm, bic
    assert best is not None
    return best
