"""The one trainer of every learned network (as mbrl-lib's ``ModelTrainer``).

:func:`train` runs minibatch epochs of a given loss with a given optimiser: every epoch
visits the training rows in the order its :data:`RowOrder` draws, steps the optimiser
once per minibatch, steps the learning-rate schedule, then scores the hold-out rows.
It can return the weights of the epoch with the lowest hold-out loss (:class:`KeepBest`).
What differs between networks (the loss, Adam or AdamW, weight decay, the schedule, the
batch order, the hold-out, which epoch is kept) is a parameter, so each network trains
exactly as it always has. Every random choice comes from the generator inside the row
order; the global torch random state is not used.

:func:`deterministic_training` is what makes a fit repeat to the bit on one machine
whoever calls it: a fixed thread count (the sums inside a matrix product are split
over the threads, and float addition does not associate) and torch's deterministic
algorithms, both restored afterwards.
"""

import math
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Literal

import torch
from threadpoolctl import threadpool_limits
from torch import nn

TRAINING_THREADS = 1
"""Threads every fit of :func:`deterministic_training` runs on unless told otherwise."""


@contextmanager
def deterministic_training(threads: int = TRAINING_THREADS) -> Iterator[None]:
    """Run the ``with`` block on ``threads`` threads with deterministic algorithms.

    Inside the block torch uses ``threads`` intra-op threads
    (``torch.set_num_threads``) and only deterministic algorithms
    (``torch.use_deterministic_algorithms(True)``: an operation without one raises), and
    the BLAS and OpenMP pools of numpy, scipy and scikit-learn are limited to ``threads``
    (``threadpoolctl``). A fit seeded the same then gives the same bits on one machine
    however many threads the caller ran on (the reductions inside a matrix product are
    split over the threads, so their rounding depends on how many there are). Every
    setting is restored on leaving, also when the block raises. Random draws are not
    touched: each fit seeds its own generators.
    """
    if threads < 1:
        raise ValueError(f"threads must be >= 1, got {threads}")
    previous_threads = torch.get_num_threads()
    previous_deterministic = torch.are_deterministic_algorithms_enabled()
    previous_warn_only = torch.is_deterministic_algorithms_warn_only_enabled()
    try:
        with threadpool_limits(limits=threads):
            torch.set_num_threads(threads)
            torch.use_deterministic_algorithms(True)
            yield
    finally:
        torch.use_deterministic_algorithms(previous_deterministic, warn_only=previous_warn_only)
        torch.set_num_threads(previous_threads)

BatchLoss = Callable[[torch.Tensor, torch.Tensor], tuple[torch.Tensor, torch.Tensor]]
"""``loss(inputs, targets)`` of one minibatch -> ``(objective, value)``: the scalar the
optimiser minimises and the scalar the report records (often the same tensor)."""

RowOrder = Callable[[], torch.Tensor]
"""Called once per epoch: the training rows in the order the epoch visits them, ``(n,)``,
or ``(members, n)`` for one order per ensemble member. Minibatches are consecutive
slices of ``batch_size`` along the last axis."""


def shuffled(n: int, generator: torch.Generator) -> RowOrder:
    """A new random permutation of the ``n`` rows every epoch (``torch.randperm``)."""
    return lambda: torch.randperm(n, generator=generator)


def bootstrapped(members: int, n: int, generator: torch.Generator) -> RowOrder:
    """Each ensemble member's own bootstrap sample of the ``n`` rows (``n`` draws with
    replacement, made now), shuffled anew every epoch: ``(members, n)``."""
    boot = torch.randint(n, (members, n), generator=generator)

    def order() -> torch.Tensor:
        return torch.gather(boot, 1, torch.argsort(torch.rand(members, n, generator=generator),
                                                   dim=1))
    return order


@dataclass(frozen=True)
class HoldOut:
    """Rows kept out of training, scored after every epoch (without gradients).

    Attributes:
        inputs, targets: the held-out rows, indexed like the training rows.
        loss: ``loss(inputs, targets) -> float``, lower is better.
    """

    inputs: torch.Tensor
    targets: torch.Tensor
    loss: Callable[[torch.Tensor, torch.Tensor], float]


@dataclass(frozen=True)
class KeepBest:
    """Return the weights of the epoch with the lowest hold-out loss.

    An epoch whose hold-out loss is NaN is never kept. When no epoch is kept the
    weights of the last one are returned, unless ``start``.

    Attributes:
        ties: which of several epochs with the same lowest loss is kept, ``"first"`` or
            ``"last"`` (the latter compares with the minimum of all losses so far,
            Python's ``min``).
        start: the weights before the first epoch are a candidate of loss ``+inf``,
            reported as epoch 0: returned when no epoch's loss is below ``+inf``.
    """

    ties: Literal["first", "last"] = "first"
    start: bool = False


@dataclass(frozen=True)
class TrainingReport:
    """What :func:`train` did.

    Attributes:
        train_loss: ``(epochs,)``, mean of the minibatches' loss values over each epoch.
        holdout_loss: ``(epochs,)``, the hold-out loss after each epoch; empty without
            a hold-out.
        best_epoch: index of the epoch whose weights the model keeps (the last one
            unless :class:`KeepBest` chose another).
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


def train(
    model: nn.Module,
    loss: BatchLoss,
    inputs: torch.Tensor,
    targets: torch.Tensor,
    optimiser: torch.optim.Optimizer,
    order: RowOrder,
    *,
    epochs: int,
    batch_size: int,
    schedule: torch.optim.lr_scheduler.LRScheduler | None = None,
    holdout: HoldOut | None = None,
    keep_best: KeepBest | None = None,
    average: Literal["rows", "batches"] = "rows",
) -> TrainingReport:
    """Fit ``model``'s parameters (those ``optimiser`` holds) by minibatch epochs of ``loss``.

    Per epoch: ``model.train()``; for each slice ``rows`` of ``order()``, the
    minibatch ``loss(inputs[rows], targets[rows])``, a gradient step of its objective;
    ``schedule.step()``; ``model.eval()``; the hold-out loss. The model is left in
    evaluation mode.

    Args:
        model: the network; ``loss`` and ``holdout`` evaluate it.
        inputs, targets: ``(n_train, ...)`` training rows.
        optimiser: holds the parameters to fit and their settings (lr, weight decay).
        order: the row order of each epoch (:func:`shuffled`, :func:`bootstrapped`).
        epochs: passes over the rows.
        batch_size: rows per minibatch (per member for a ``(members, n)`` order).
        schedule: a learning-rate schedule of ``optimiser``, stepped after every epoch.
        holdout: rows to score after every epoch.
        keep_best: with a ``holdout``, which epoch's weights to return.
        average: the epoch's training loss is the mean of its minibatches' values
            weighted by their rows (``"rows"``) or one weight per minibatch
            (``"batches"``, mbrl-lib's).
    """
    started = time.perf_counter()
    train_loss: list[float] = []
    holdout_loss: list[float] = []
    best_epoch = epochs - 1
    best_score = math.inf
    best_state = _snapshot(model) if keep_best is not None and keep_best.start else None
    if best_state is not None:
        best_epoch = 0
    for epoch in range(epochs):
        model.train()
        rows_in_order = order()
        total, count = 0.0, 0
        for start in range(0, rows_in_order.shape[-1], batch_size):
            rows = rows_in_order[..., start:start + batch_size]
            objective, value = loss(inputs[rows], targets[rows])
            optimiser.zero_grad(set_to_none=True)
            objective.backward()
            optimiser.step()
            weight = rows.shape[-1] if average == "rows" else 1
            total += float(value.detach()) * weight
            count += weight
        train_loss.append(total / count)
        if schedule is not None:
            schedule.step()
        model.eval()
        if holdout is None:
            continue
        with torch.no_grad():
            score = holdout.loss(holdout.inputs, holdout.targets)
        holdout_loss.append(score)
        if keep_best is None:
            continue
        better = score <= min(holdout_loss) if keep_best.ties == "last" else score < best_score
        if better:
            best_score, best_epoch, best_state = score, epoch, _snapshot(model)
    if best_state is not None:
        model.load_state_dict(best_state)
    model.eval()
    return TrainingReport(tuple(train_loss), tuple(holdout_loss), best_epoch,
                          int(inputs.shape[0]),
                          0 if holdout is None else int(holdout.inputs.shape[0]),
                          time.perf_counter() - started)


def _snapshot(model: nn.Module) -> dict[str, torch.Tensor]:
    return {k: v.detach().clone() for k, v in model.state_dict().items()}


__all__ = ["TRAINING_THREADS", "BatchLoss", "HoldOut", "KeepBest", "RowOrder", "TrainingReport",
           "bootstrapped", "deterministic_training", "shuffled", "train"]
