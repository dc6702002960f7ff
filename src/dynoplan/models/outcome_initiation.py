"""Initiation sets learned from the options' own outcomes (Bagaria et al., "Effectively
Learning Initiation Sets in Hierarchical RL", NeurIPS 2023).

The Eq. 5 regions say where the *demonstrations* ran an option; they cannot say where an
option, started, would do its job. Here each option gets a classifier of its start
states: ``P(ok | s)``, where ``ok`` is the outcome of a run of the option started at
``s`` (the caller decides what counts: for example "reached its own end without
failing, and did not finish at once"). A state is in the option's learned initiation set
when ``P(ok | s) >= threshold``; :class:`~dynoplan.options.initiation.InRegion` turns it
into an initiation set, and ``AllOf(region, outcome)`` combines it with Eq. 5.

Per option the classifier is an MLP ``d -> hidden -> hidden -> 1`` (SiLU) on normalised
states, trained by class-balanced binary cross-entropy (the positive and negative runs
weigh the same in total, so a rare outcome is not ignored). An option whose runs all
ended well is admissible wherever it was tried and beyond (``always``); one whose runs all
failed is admissible nowhere (``never``); an option without runs has no classifier and
:meth:`OutcomeInitiation.option_index` refuses it (the caller decides, and should say,
what such an option gets).

Files: one ``.safetensors`` (no pickle) through :mod:`dynoplan.models.storage`.
"""

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from dynoplan.errors import DynoplanError
from dynoplan.models.features import FeatureMap
from dynoplan.models.mlp import MLP, uniform_init
from dynoplan.models.mlp_file import linear_arrays, load_linears, require_finite
from dynoplan.models.storage import as_states, load_arrays, save_arrays
from dynoplan.models.trainer import train
from dynoplan.types import BoolArray, FloatArray

_KIND = "outcome_initiation"
_KINDS = ("network", "always", "never")


@dataclass
class OutcomeFitReport:
    """What :meth:`OutcomeInitiation.fit` saw and reached, per option name.

    Attributes:
        runs: number of runs (start states).
        positives: runs whose outcome was good.
        kind: ``network``, ``always`` (every run good) or ``never`` (none).
        train_accuracy: class-balanced accuracy of ``P >= threshold`` on the runs
            (``None`` for ``always`` / ``never``).
    """

    runs: dict[str, int] = field(default_factory=dict)
    positives: dict[str, int] = field(default_factory=dict)
    kind: dict[str, str] = field(default_factory=dict)
    train_accuracy: dict[str, float | None] = field(default_factory=dict)


class _Classifier(nn.Module):
    """One option's ``logit P(ok | s)``: states ``(batch, d)`` -> ``(batch,)``."""

    in_mean: torch.Tensor
    in_std: torch.Tensor

    def __init__(self, state_dim: int, hidden: int, generator: torch.Generator) -> None:
        super().__init__()
        self.mlp = MLP([state_dim, hidden, hidden, 1], uniform_init, generator, members=1)
        self.register_buffer("in_mean", torch.zeros(state_dim))
        self.register_buffer("in_std", torch.ones(state_dim))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        z = ((x - self.in_mean) / self.in_std).unsqueeze(0)
        return self.mlp(z)[0, :, 0]


class OutcomeInitiation:
    """Per option, ``P(ok | s)`` from its runs' outcomes, and the set where it is high.

    Offers what :class:`~dynoplan.options.initiation.InRegion` needs (``option_names``,
    ``option_index``, ``contains``). Build one with :meth:`fit` or :meth:`load`.

    Args:
        option_names: the options that have a classifier.
        kinds: per option ``network``, ``always`` or ``never``.
        classifiers: per option with kind ``network`` its trained module.
        state_dim: size of the states the classifiers read.
        hidden: hidden width of every classifier.
        threshold: ``P(ok | s)`` at and above which a state is in the set.
    """

    def __init__(self, option_names: list[str], kinds: dict[str, str],
                 classifiers: dict[str, _Classifier], state_dim: int, hidden: int,
                 threshold: float) -> None:
        self.option_names = list(option_names)
        self.kinds = dict(kinds)
        self._classifiers = {k: v.eval() for k, v in classifiers.items()}
        self.state_dim = int(state_dim)
        self.hidden = int(hidden)
        self.threshold = float(threshold)

    def option_index(self, option: str | int) -> int:
        """The index of ``option`` (a name or an index) among :attr:`option_names`."""
        if isinstance(option, int) and not isinstance(option, bool):
            if 0 <= option < len(self.option_names):
                return option
        elif option in self.option_names:
            return self.option_names.index(option)
        raise DynoplanError(f"no learned initiation for option {option!r}; options with "
                            f"one: {', '.join(self.option_names) or 'none'}")

    def probability(self, states: FloatArray, option: str | int) -> FloatArray:
        """``P(ok | s)`` of option ``option`` started at each state: ``(batch, d)`` ->
        ``(batch,)`` float64 (1 or 0 for ``always`` / ``never``)."""
        name = self.option_names[self.option_index(option)]
        x = as_states(states, self.state_dim)
        kind = self.kinds[name]
        if kind != "network":
            return np.full(len(x), 1.0 if kind == "always" else 0.0)
        with torch.inference_mode():
            logit = self._classifiers[name](torch.as_tensor(x, dtype=torch.float32))
        return torch.sigmoid(logit.to(torch.float64)).numpy().copy()

    def contains(self, states: FloatArray, option: str | int) -> BoolArray:
        """Whether option ``option`` may start at each state (``P >= threshold``),
        ``(batch,)``."""
        out: BoolArray = self.probability(states, option) >= self.threshold
        return out

    # --- fitting ---------------------------------------------------------------------
    @classmethod
    def fit(cls, starts: Mapping[str, FloatArray], outcomes: Mapping[str, BoolArray], *,
            hidden: int = 32, epochs: int = 400, lr: float = 1e-2,
            weight_decay: float = 1e-3, threshold: float = 0.5,
            seed: int = 0, balanced: bool = True) -> tuple["OutcomeInitiation", OutcomeFitReport]:
        """Fit one classifier per option on its runs.

        Args:
            starts: per option name, the start states of its runs ``(N_k, d)``.
            outcomes: per option name, ``(N_k,)`` booleans, True where the run ended
                well.
            hidden: width of both hidden layers.
            epochs: full-batch AdamW steps (cosine-decayed learning rate).
            lr: initial learning rate.
            weight_decay: AdamW decoupled weight decay.
            threshold: ``P(ok | s)`` from which a state is in the set.
            seed: seeds every classifier's initialisation (a private generator).
            balanced: weigh both outcomes the same in total (a rare outcome is not
                ignored, and ``P`` is not a calibrated chance); ``False``: every run
                weighs the same (``P`` estimates the chance of ``ok``).

        Raises:
            DynoplanError: no options, mismatched names or shapes, non-finite states.
        """
        if not starts or sorted(starts) != sorted(outcomes):
            raise DynoplanError("starts and outcomes must name the same, non-empty options")
        if not 0.0 < threshold < 1.0:
            raise DynoplanError(f"threshold must be in (0, 1), got {threshold}")
        if hidden < 1 or epochs < 1:
            raise DynoplanError("hidden and epochs must be >= 1")
        dims = {np.asarray(s).shape[-1] for s in starts.values()}
        if len(dims) != 1:
            raise DynoplanError(f"start states of the options disagree on their size: "
                                f"{sorted(dims)}")
        d = dims.pop()
        names = [n for n in starts if len(np.asarray(starts[n]))]
        kinds: dict[str, str] = {}
        classifiers: dict[str, _Classifier] = {}
        report = OutcomeFitReport()
        for k, name in enumerate(names):
            x = as_states(starts[name], d)
            y = np.asarray(outcomes[name], dtype=bool)
            if y.shape != (len(x),):
                raise DynoplanError(f"option '{name}': outcomes must have shape "
                                    f"({len(x)},), got {y.shape}")
            if not np.isfinite(x).all():
                raise DynoplanError(f"option '{name}': start states hold NaN or infinity")
            report.runs[name], report.positives[name] = len(y), int(y.sum())
            if y.all() or not y.any():
                kinds[name] = "always" if y.all() else "never"
                report.kind[name], report.train_accuracy[name] = kinds[name], None
                continue
            net = _fit_classifier(x, y, hidden, epochs, lr, weight_decay, seed + k,
                                  balanced)
            kinds[name] = "network"
            classifiers[name] = net
            with torch.inference_mode():
                p = torch.sigmoid(net(torch.as_tensor(x, dtype=torch.float32))).numpy()
            hit = (p >= threshold) == y
            report.kind[name] = "network"
            report.train_accuracy[name] = float(0.5 * (hit[y].mean() + hit[~y].mean()))
        return cls(names, kinds, classifiers, d, hidden, threshold), report

    # --- storage ---------------------------------------------------------------------
    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write a ``.safetensors`` file (no pickle); :meth:`load` restores it exactly."""
        arrays: dict[str, np.ndarray] = {}
        for k, name in enumerate(self.option_names):
            net = self._classifiers.get(name)
            if net is None:
                continue
            arrays.update(linear_arrays(net.mlp, f"o{k}_w{{}}", f"o{k}_b{{}}"))
            arrays[f"o{k}_in_mean"] = net.in_mean.numpy().copy()
            arrays[f"o{k}_in_std"] = net.in_std.numpy().copy()
        meta = {"option_names": self.option_names, "kinds": [self.kinds[n] for n in
                                                             self.option_names],
                "state_dim": self.state_dim, "hidden": self.hidden,
                "threshold": self.threshold}
        return save_arrays(path, _KIND, arrays, meta)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> "OutcomeInitiation":
        """Read a file written by :meth:`save`.

        Raises:
            DynoplanError: missing, corrupt or truncated file, another kind of model, or
                malformed metadata or arrays.
        """
        arrays, meta = load_arrays(path, _KIND)
        names, kinds = meta.get("option_names"), meta.get("kinds")
        d, h, threshold = meta.get("state_dim"), meta.get("hidden"), meta.get("threshold")
        if (not isinstance(names, list) or not isinstance(kinds, list)
                or len(names) != len(kinds) or not all(isinstance(n, str) for n in names)
                or not all(k in _KINDS for k in kinds)):
            raise DynoplanError(f"{path}: metadata must list option_names and their kinds "
                                f"({', '.join(_KINDS)})")
        if not (isinstance(d, int) and isinstance(h, int) and d >= 1 and h >= 1
                and isinstance(threshold, float) and 0.0 < threshold < 1.0):
            raise DynoplanError(f"{path}: metadata lacks a valid state_dim, hidden or "
                                "threshold")
        classifiers: dict[str, _Classifier] = {}
        for k, (name, kind) in enumerate(zip(names, kinds, strict=True)):
            if kind != "network":
                continue
            net = _Classifier(d, h, torch.Generator())
            load_linears(net.mlp, arrays, path, f"o{k}_w{{}}", f"o{k}_b{{}}")
            with torch.no_grad():
                for part in ("in_mean", "in_std"):
                    getattr(net, part).copy_(torch.from_numpy(
                        require_finite(arrays, f"o{k}_{part}", (d,), np.float32, path)))
            classifiers[name] = net
        return cls(names, dict(zip(names, kinds, strict=True)), classifiers, d, h, threshold)


class OutcomeInitiationOnFeatures:
    """An :class:`OutcomeInitiation` of full planner states ``(batch, state_dim)`` that
    reads ``features(states)`` (as :class:`~dynoplan.models.features.RegionsOnFeatures`)."""

    def __init__(self, initiation: OutcomeInitiation, features: FeatureMap) -> None:
        self.initiation = initiation
        self.features = features

    @property
    def option_names(self) -> list[str]:
        return self.initiation.option_names

    @property
    def state_dim(self) -> int:
        return self.features.state_dim

    def option_index(self, option: str | int) -> int:
        return self.initiation.option_index(option)

    def probability(self, states: FloatArray, option: str | int) -> FloatArray:
        """``P(ok | s)``, ``(batch,)``."""
        return self.initiation.probability(self.features(states), option)

    def contains(self, states: FloatArray, option: str | int) -> BoolArray:
        """Whether the option may start at each state, ``(batch,)``."""
        return self.initiation.contains(self.features(states), option)


def _fit_classifier(x: FloatArray, y: BoolArray, hidden: int, epochs: int, lr: float,
                    weight_decay: float, seed: int, balanced: bool = True) -> _Classifier:
    generator = torch.Generator().manual_seed(seed)
    net = _Classifier(x.shape[1], hidden, generator)
    xt = torch.as_tensor(x, dtype=torch.float32)
    yt = torch.as_tensor(y, dtype=torch.float32)
    with torch.no_grad():
        net.in_mean.copy_(xt.mean(dim=0))
        std = xt.std(dim=0, correction=0)
        net.in_std.copy_(torch.where(std > 1e-8, std, torch.ones_like(std)))
    # class-balanced: each class weighs half of the loss
    positive, negative = 0.5 / yt.mean(), 0.5 / (1.0 - yt.mean())

    def loss(inputs: torch.Tensor, targets: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        weight = torch.where(targets > 0.5, positive, negative) if balanced else None
        value = nn.functional.binary_cross_entropy_with_logits(net(inputs), targets,
                                                               weight=weight)
        return value, value

    optimiser = torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=weight_decay)
    schedule = torch.optim.lr_scheduler.LambdaLR(
        optimiser, lambda epoch: 0.5 * (1.0 + math.cos(math.pi * epoch / epochs)))
    every_row = torch.arange(len(xt))  # full-batch gradient steps, one per epoch
    train(net, loss, xt, yt, optimiser, lambda: every_row, epochs=epochs,
          batch_size=len(xt), schedule=schedule)
    return net


class RunFailure:
    """One option's ``P(fail | s) = 1 - P(ok | s)`` from an :class:`OutcomeInitiation`
    fitted on whether its runs did *not* end their episode in failure (``balanced``
    off, so that it is a chance): the option's
    :class:`~dynoplan.options.option.FailureModel`."""

    def __init__(self, model: OutcomeInitiation, option: str) -> None:
        model.option_index(option)  # refuses an option without a classifier
        self.model = model
        self.option = option

    def probability(self, states: FloatArray) -> FloatArray:
        """``(batch, d)`` -> ``(batch,)`` the chance that a run started there fails."""
        out: FloatArray = 1.0 - self.model.probability(states, self.option)
        return out


def fit_report_dict(report: OutcomeFitReport) -> dict[str, Any]:
    """The report as a JSON-ready dict, per option name."""
    return {name: {"runs": report.runs[name], "positives": report.positives[name],
                   "kind": report.kind[name], "train_accuracy": report.train_accuracy[name]}
            for name in report.runs}


__all__ = ["OutcomeFitReport", "OutcomeInitiation", "OutcomeInitiationOnFeatures",
           "RunFailure", "fit_report_dict"]
