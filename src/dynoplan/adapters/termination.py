"""Terminations ``beta_w`` from a number, a callable or a learned classifier."""

from collections.abc import Callable
from typing import Any

import numpy as np

from dynoplan.errors import DynoplanError
from dynoplan.options.termination import (
    ConstantTermination,
    Termination,
    TerminationFromCallable,
)
from dynoplan.types import FloatArray


class ClassifierTermination:
    """``beta(s)`` from a classifier's probability that the option is done in ``s``.

    Works with any scikit-learn classifier (``predict_proba(states) -> (B, classes)``;
    the column of ``stop_class`` is looked up in ``classes_``), or any callable
    returning ``(B,)`` stop probabilities or ``(B, classes)`` class probabilities.
    This is the paper's "neural recognition module that decides termination".

    Args:
        classifier: an object with ``predict_proba``, or a callable with its signature.
        stop_class: the label meaning "stop" (``1`` by default; for a classifier without
            ``classes_`` it is the column index).
        threshold: ``None``: ``beta`` is the probability itself (a stochastic stop);
            a number: ``beta = 1`` where the probability is at least ``threshold``,
            else ``0`` (a deterministic stop).
    """

    def __init__(self, classifier: Any, stop_class: Any = 1,
                 threshold: float | None = None) -> None:
        proba = getattr(classifier, "predict_proba", None)
        if proba is None and callable(classifier):
            proba = classifier
        if not callable(proba):
            raise DynoplanError(
                f"{type(classifier).__name__} has no predict_proba(states) and is not callable")
        if threshold is not None and not 0.0 <= threshold <= 1.0:
            raise DynoplanError(f"threshold must be in [0, 1], got {threshold}")
        self.classifier = classifier
        self._proba: Callable[[FloatArray], Any] = proba
        classes = getattr(classifier, "classes_", None)
        if classes is not None:
            known = list(np.asarray(classes).tolist())
            if stop_class not in known:
                raise DynoplanError(
                    f"stop_class {stop_class!r} is not one of the classifier's classes {known}")
            self.column = known.index(stop_class)
        else:
            self.column = int(stop_class)
        self.threshold = threshold

    def probability(self, states: FloatArray) -> FloatArray:
        """``(batch, state_dim)`` -> ``(batch,)`` stop probabilities in ``[0, 1]``."""
        x = np.asarray(states, dtype=np.float64)
        p = np.asarray(self._proba(x), dtype=np.float64)
        if p.ndim == 2:
            p = p[:, self.column]
        if p.shape != x.shape[:1]:
            raise DynoplanError(
                f"the termination classifier returned shape {p.shape} for {x.shape[0]} states; "
                f"expected ({x.shape[0]},) or ({x.shape[0]}, classes)")
        p = np.clip(np.nan_to_num(p, nan=1.0), 0.0, 1.0)  # a broken prediction stops
        if self.threshold is None:
            return p
        return (p >= self.threshold).astype(np.float64)


def termination_from(termination: Any) -> Termination:
    """Turn what the user has into a :class:`~dynoplan.options.Termination`.

    - a number ``beta`` in ``[0, 1]``: :class:`~dynoplan.options.ConstantTermination`;
    - a ``Termination`` (has ``probability``): used as it is;
    - a classifier with ``predict_proba``: :class:`ClassifierTermination`;
    - a callable ``fn(states (B, d)) -> (B,)`` probabilities or booleans:
      :class:`~dynoplan.options.TerminationFromCallable`;
    - ``None``: never stops by itself (``beta = 0``; the controller's replanning
      period or step cap ends it).

    Raises:
        DynoplanError: anything else, or a number outside ``[0, 1]``.
    """
    if termination is None:
        return ConstantTermination(0.0)
    if isinstance(termination, bool):
        raise DynoplanError("a termination must be a probability, not a bool")
    if isinstance(termination, int | float | np.integer | np.floating):
        if not 0.0 <= float(termination) <= 1.0:
            raise DynoplanError(f"a constant termination must be in [0, 1], got {termination}")
        return ConstantTermination(float(termination))
    if isinstance(termination, Termination):
        return termination
    if callable(getattr(termination, "predict_proba", None)):
        return ClassifierTermination(termination)
    if callable(termination):
        return TerminationFromCallable(termination)
    raise DynoplanError(
        f"cannot make a termination from {type(termination).__name__}: expected a number, "
        "a Termination, a classifier with predict_proba, or fn(states) -> probabilities")
