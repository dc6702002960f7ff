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

:meth:`SafetyRegions.fit_heldout` is the fit that works by default on a new task: the
states are standardised per dimension, the covariances are regularised relative to
each dimension's spread, the number of components is the one with the best held-out
log-likelihood (folds of whole demonstrations), and each threshold is the
``1 - coverage`` quantile of ``log L`` of *held-out* states, so ``coverage`` is the
rate at which unseen demonstration states fall inside (not the rate on the states the
mixture was fitted on, which BIC with few demonstrations makes needle-thin).
"""

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from sklearn.mixture import GaussianMixture

from dynoplan.errors import DynoplanError
from dynoplan.models.storage import as_states, load_arrays, require, require_finite, save_arrays
from dynoplan.types import BoolArray, FloatArray, IntArray

_KIND = "safety_regions"
CONSTANT_SPREAD = 1e-9
"""A dimension whose standard deviation over the data is at most this (times one plus
its magnitude) never changes: :meth:`SafetyRegions.fit_heldout` does not test it."""
def constant_mask(states: FloatArray) -> BoolArray:
    """``(d,)`` which dimensions of ``states`` ``(N, d)`` never change: a spread of at most
    :data:`CONSTANT_SPREAD` times one plus their magnitude."""
    x = np.asarray(states, dtype=np.float64)
    return np.asarray(x.std(axis=0) <= CONSTANT_SPREAD * (1.0 + np.abs(x.mean(axis=0))))


REMEMBERED_STATES = 8
"""How many states :meth:`SafetyRegions.component_log_density` remembers its answer for."""

UNTESTED_SCALE = 1e6
"""The scale of an untested dimension, in units of the largest spread of the data."""


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
        log_offsets: ``(components,)`` added to each component's log density: zero for a
            fitted mixture (``None`` stands for zeros); a component that joined an option
            from another region (:meth:`joined`) carries the difference of the two
            thresholds, so that the option's one threshold tests both.
    """

    option_names: list[str]
    means: FloatArray
    precisions_cholesky: FloatArray
    members: BoolArray
    log_thresholds: FloatArray
    log_offsets: FloatArray | None = None
    _last: tuple[bytes, FloatArray] | None = field(default=None, init=False, repr=False,
                                                   compare=False)
    """The last few states asked about and their densities: a controller asks about one
    state for every option in turn."""

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
        """``log p(s | mu_i, Sigma_i)`` for every state and component: ``(batch, components)``
        (read-only; the same states asked again in a row, up to :data:`REMEMBERED_STATES`
        of them, are answered from memory)."""
        x = as_states(states, self.state_dim)
        key = x.tobytes() if len(x) <= REMEMBERED_STATES else None
        if key is not None and self._last is not None and self._last[0] == key:
            return self._last[1]
        log_p = self._component_log_density(x)
        log_p.flags.writeable = False
        if key is not None:
            self._last = (key, log_p)
        return log_p

    def _component_log_density(self, x: FloatArray) -> FloatArray:
        d = self.state_dim
        # (batch, components, d): whitened residuals (x - mu_i) @ L_i
        diff = x[:, None, :] - self.means[None, :, :]
        z = np.einsum("bmd,mde->bme", diff, self.precisions_cholesky)
        log_det = np.log(np.diagonal(self.precisions_cholesky, axis1=1, axis2=2)).sum(axis=1)
        if self.log_offsets is not None:
            log_det = log_det + self.log_offsets
        return -0.5 * (d * np.log(2 * np.pi) + np.sum(z * z, axis=2)) + log_det[None, :]

    def log_likelihood(self, states: FloatArray, option: str | int) -> FloatArray:
        """``log L(s | k) = max_{i in J_k} log p(s | mu_i, Sigma_i)``, shape ``(batch,)``."""
        k = self.option_index(option)
        log_p = self.component_log_density(states)
        if not self.members[k].any():  # an option with no components is admissible nowhere
            return np.full(log_p.shape[0], -np.inf)
        return log_p[:, self.members[k]].max(axis=1)

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
        if masked.shape[2] == 0:
            return np.zeros(masked.shape[:2], dtype=bool)
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
        x, y, names = _checked(states, labels, option_names, coverage)
        gmm = _fit_mixture(x, n_components, max_components, reg_covar, seed)
        regions = cls._from_mixture(gmm, x, y, names, min_share)
        for k in range(len(names)):
            own = regions.log_likelihood(x[y == k], k)
            regions.log_thresholds[k] = np.quantile(own, 1.0 - coverage) - slack
        return regions

    @classmethod
    def _from_mixture(cls, gmm: GaussianMixture, x: FloatArray, y: IntArray,
                      names: list[str], min_share: float) -> "SafetyRegions":
        """Regions with ``J_k`` from ``gmm``'s assignment of ``x`` (thresholds 0).

        An option with no state in ``x`` gets no component (it is admissible nowhere).
        """
        assigned = gmm.predict(x)
        m = gmm.n_components
        counts = np.zeros((len(names), m))
        np.add.at(counts, (y, assigned), 1.0)
        share = counts / np.maximum(counts.sum(axis=0, keepdims=True), 1.0)
        members = share >= min_share
        members &= counts > 0
        present = counts.sum(axis=1) > 0
        members[np.flatnonzero(present), counts[present].argmax(axis=1)] = True
        return cls(
            option_names=names,
            means=np.asarray(gmm.means_, dtype=np.float64),
            precisions_cholesky=np.asarray(gmm.precisions_cholesky_, dtype=np.float64),
            members=members,
            log_thresholds=np.zeros(len(names)),
        )

    @classmethod
    def fit_heldout(
        cls,
        states: FloatArray,
        labels: IntArray,
        option_names: Sequence[str],
        groups: IntArray | None = None,
        coverage: float = 0.95,
        folds: int = 5,
        n_components: int | None = None,
        max_components: int = 6,
        reg_covar: float = 1e-2,
        slack: float = 0.0,
        seed: int = 0,
        test_constant: bool = False,
    ) -> tuple["SafetyRegions", dict[str, Any]]:
        """Regions whose held-out coverage is ``coverage``, chosen without BIC.

        1. Every dimension is standardised by its spread over ``states`` (floored at
           ``1e-3`` of the largest spread); a dimension that never changes (a spread of
           at most ``CONSTANT_SPREAD`` times one plus its magnitude: padding, a fixed
           goal) is scaled by ``UNTESTED_SCALE`` times the largest spread, so that no
           move in it changes the likelihood: it is not tested (``test_constant``: it is
           floored as the others, and a move of a thousandth of the largest spread in it
           leaves the region);
           ``reg_covar`` is added to every covariance's diagonal in those units (``1e-2``:
           no component is narrower than a tenth of the data's spread in any direction).
        2. Each option gets its own mixture on its own states, so ``J_k`` is that
           mixture's components (one mixture shared by all options lets a component
           span several options' states, and their regions become the same).
        3. Option ``k``'s states are dealt into at most ``folds`` folds of whole
           demonstrations (``groups``). Its ``M`` (when ``n_components`` is ``None``) is
           the size in ``1..max_components`` with the best mean log-likelihood of the
           held-out folds; sizes with fewer than ``2 (d + 1)`` training states per
           component are not tried.
        4. Mixtures of that ``M`` fitted without each fold give ``log L(s | k)`` of the
           fold's states. The threshold is the ``1 - coverage`` quantile of these
           held-out values (no higher than the same quantile over the training states),
           minus ``slack`` nats. The final mixture is fitted on all of ``k``'s states;
           only the threshold comes from the folds.

        Args:
            states: ``(N, state_dim)`` states; labels: ``(N,)`` option indices.
            groups: ``(N,)`` id of the demonstration (episode) of every state. Where an
                option's states come from one group (or ``groups`` is ``None``), its folds
                are contiguous blocks of its states.
            coverage: the target share of held-out states of each option inside its region.
            seed: seeds the fold assignment and scikit-learn.

        Returns:
            The regions and a report: ``{"method": "heldout", "folds", "components":
            total, "per_option": {name: {"components", "heldout_coverage",
            "heldout_states", "heldout_loglik"}}}``; ``heldout_coverage`` is the share of
            the option's held-out states inside its final threshold (``None`` without
            held-out states).

        Raises:
            DynoplanError: malformed input, an option without states, ``folds < 2``.
        """
        x, y, names = _checked(states, labels, option_names, coverage)
        if folds < 2:
            raise DynoplanError(f"folds must be >= 2, got {folds}")
        if reg_covar <= 0.0:
            raise DynoplanError(f"reg_covar must be > 0, got {reg_covar}")
        if n_components is not None and n_components < 1:
            raise DynoplanError(f"n_components must be >= 1, got {n_components}")
        center = x.mean(axis=0)
        spread = x.std(axis=0)
        scale = np.maximum(spread, 1e-3 * float(spread.max()) + 1e-12)
        # a dimension with no spread at all is not tested: at this scale no move matters
        if not test_constant:
            scale[constant_mask(x)] = UNTESTED_SCALE * (1.0 + float(spread.max()))
        z = (x - center) / scale
        g = None if groups is None else np.asarray(groups)
        if g is not None and g.shape != y.shape:
            raise DynoplanError(f"groups must be {y.shape}, got {g.shape}")
        merged: SafetyRegions | None = None
        per_option: dict[str, Any] = {}
        for k, name in enumerate(names):
            own = y == k
            one, info = _heldout_option(z[own], None if g is None else g[own], name, coverage,
                                        folds, n_components, max_components, reg_covar, seed)
            one.log_thresholds = one.log_thresholds - slack
            per_option[name] = info
            merged = one if merged is None else cls.merge(merged, one)
        assert merged is not None
        # back to the original units: z = (x - center) / scale
        merged.means = center + merged.means * scale
        merged.precisions_cholesky = merged.precisions_cholesky / scale[None, :, None]
        merged.log_thresholds = merged.log_thresholds - float(np.log(scale).sum())
        return merged, {"method": "heldout", "components": merged.n_components,
                        "per_option": per_option}

    @classmethod
    def merge(cls, first: "SafetyRegions", second: "SafetyRegions") -> "SafetyRegions":
        """One model holding both models' options (their names must not overlap).

        Exact: ``L(s | k)`` is a maximum over ``J_k``, so the mixtures' components are
        concatenated and each option keeps its own components and threshold.
        """
        if first.state_dim != second.state_dim:
            raise DynoplanError(f"cannot merge regions on {first.state_dim} and "
                                f"{second.state_dim} values")
        common = set(first.option_names) & set(second.option_names)
        if common:
            raise DynoplanError(f"both regions hold option(s) {sorted(common)}")
        m1, m2 = first.n_components, second.n_components
        members = np.zeros((len(first.option_names) + len(second.option_names), m1 + m2),
                           dtype=bool)
        members[:len(first.option_names), :m1] = first.members
        members[len(first.option_names):, m1:] = second.members
        offsets = (None if first.log_offsets is None and second.log_offsets is None else
                   np.concatenate([first.offsets, second.offsets]))
        return cls(option_names=[*first.option_names, *second.option_names],
                   means=np.concatenate([first.means, second.means]),
                   precisions_cholesky=np.concatenate([first.precisions_cholesky,
                                                       second.precisions_cholesky]),
                   members=members,
                   log_thresholds=np.concatenate([first.log_thresholds,
                                                  second.log_thresholds]),
                   log_offsets=offsets)

    @property
    def offsets(self) -> FloatArray:
        """:attr:`log_offsets`, zeros when ``None``: ``(components,)``."""
        return (np.zeros(self.n_components) if self.log_offsets is None
                else self.log_offsets)

    def joined(self, into: dict[str, str]) -> "SafetyRegions":
        """Each option ``a`` of ``into``'s keys joins option ``into[a]``: ``b``'s region
        becomes the union of both regions, and ``a`` is dropped.

        Exact: ``L(s | b)`` is a maximum over ``J_b``, so ``a``'s components join ``J_b``
        with the log offset ``threshold_b - threshold_a``; a state passes ``b``'s
        threshold through them exactly when it passed ``a``'s. (A component shared by
        both options keeps ``b``'s own density: it is inside ``b``'s region already.)

        Raises:
            DynoplanError: an unknown name, or an option that would join itself.
        """
        offsets = self.offsets.copy()
        members = self.members.copy()
        for source, target in into.items():
            a, b = self.option_index(source), self.option_index(target)
            if a == b:
                raise DynoplanError(f"option '{source}' cannot join itself")
            moved = members[a] & ~members[b]
            offsets[moved] += self.log_thresholds[b] - self.log_thresholds[a]
            members[b] |= moved
        keep = [k for k, n in enumerate(self.option_names) if n not in into]
        return SafetyRegions([self.option_names[k] for k in keep], self.means,
                             self.precisions_cholesky, members[keep],
                             self.log_thresholds[keep], offsets)

    @classmethod
    def nowhere(cls, option_names: Sequence[str], state_dim: int) -> "SafetyRegions":
        """Regions of options that are admissible nowhere (no component: ``log L = -inf``,
        below any threshold; the stored threshold is 0, files hold finite numbers)."""
        names = list(option_names)
        return cls(option_names=names, means=np.zeros((0, state_dim)),
                   precisions_cholesky=np.zeros((0, state_dim, state_dim)),
                   members=np.zeros((len(names), 0), dtype=bool),
                   log_thresholds=np.zeros(len(names)))

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
                # written only when a region joined another (files of plain fits unchanged)
                **({} if not self.offsets.any() else {"log_offsets": self.offsets}),
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
            log_offsets=(require_finite(arrays, "log_offsets", (m,), None,
                                        path).astype(np.float64)
                         if "log_offsets" in arrays else None),
        )



def _checked(states: FloatArray, labels: IntArray, option_names: Sequence[str],
             coverage: float) -> tuple[FloatArray, IntArray, list[str]]:
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
    return x, y, names


def _heldout_option(z: FloatArray, groups: IntArray | None, name: str, coverage: float,
                    folds: int, n_components: int | None, max_components: int,
                    reg_covar: float, seed: int) -> tuple[SafetyRegions, dict[str, Any]]:
    """One option's region in standardised units (see :meth:`SafetyRegions.fit_heldout`)."""
    n, d = z.shape
    fold = _folds(n, groups, min(folds, n), seed) if n >= 2 else np.zeros(n, np.int64)
    # a fold can be held out only when at least two states are left to fit on
    fold_ids = np.array([f for f in np.unique(fold) if np.sum(fold != f) >= 2], np.int64)

    def mixture(m: int, rows: BoolArray) -> SafetyRegions:
        gmm = GaussianMixture(n_components=m, covariance_type="full", reg_covar=reg_covar,
                              random_state=seed, n_init=1).fit(z[rows])
        return SafetyRegions([name], np.asarray(gmm.means_, dtype=np.float64),
                             np.asarray(gmm.precisions_cholesky_, dtype=np.float64),
                             np.ones((1, m), dtype=bool), np.zeros(1))

    scores: dict[int, float] = {}
    if n_components is not None:
        m_best = min(n_components, n)
    elif len(fold_ids) < 2:
        m_best = 1
    else:
        smallest_train = min(int(np.sum(fold != f)) for f in fold_ids)
        cap = max(1, min(max_components, smallest_train // (2 * (d + 1))))
        worse = 0
        for m in range(1, cap + 1):
            total = 0.0
            for f in fold_ids:
                gmm = GaussianMixture(n_components=m, covariance_type="full",
                                      reg_covar=reg_covar, random_state=seed,
                                      n_init=1).fit(z[fold != f])
                total += float(gmm.score_samples(z[fold == f]).sum())
            scores[m] = total / n
            worse = worse + 1 if scores[m] < max(scores.values()) else 0
            if worse == 2:
                break
        m_best = max(scores, key=lambda m: scores[m])
    held: list[FloatArray] = []
    if len(fold_ids) >= 2:
        for f in fold_ids:
            held.append(mixture(m_best, fold != f).log_likelihood(z[fold == f], 0))
    final = mixture(m_best, np.ones(n, dtype=bool))
    q = 1.0 - coverage
    threshold = float(np.quantile(final.log_likelihood(z, 0), q))
    values = np.concatenate(held) if held else None
    if values is not None:
        threshold = min(threshold, float(np.quantile(values, q)))
    final.log_thresholds = np.array([threshold])
    return final, {
        "components": m_best,
        "heldout_loglik": {str(m): round(v, 4) for m, v in scores.items()},
        "heldout_coverage": None if values is None else float(np.mean(values >= threshold)),
        "heldout_states": 0 if values is None else len(values),
    }


def _folds(n: int, groups: IntArray | None, folds: int, seed: int) -> IntArray:
    """``(n,)`` fold index of every state: whole groups dealt at random into folds, or
    contiguous blocks when there is at most one group."""
    g = None if groups is None else np.asarray(groups)
    if g is not None and g.shape != (n,):
        raise DynoplanError(f"groups must be ({n},), got {g.shape}")
    if g is None or len(np.unique(g)) < 2:
        return np.minimum(np.arange(n) * folds // max(n, 1), folds - 1)
    ids, index = np.unique(g, return_inverse=True)
    order = np.random.default_rng(seed).permutation(len(ids))
    return (order % min(folds, len(ids)))[index]


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
