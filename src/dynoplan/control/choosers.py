"""Policies over options: the planner (Eq. 1) and the baselines it is compared with.

An ``OptionChooser`` returns a :class:`~dynoplan.planning.Plan` for a state. The
baselines fill only ``admissible`` and ``chosen``; their scores are NaN. Every chooser
judges a running option (``running``: the index of an option the controller interrupted
to plan again) by its continuation set, the others by their initiation sets
(:func:`~dynoplan.options.option.admissible`).
"""

from collections.abc import Sequence
from dataclasses import replace
from typing import Protocol

import numpy as np

from dynoplan.errors import DynoplanError
from dynoplan.options.option import Option, admissible
from dynoplan.planning.option_planner import Plan
from dynoplan.types import BoolArray, FloatArray, Generator


class OptionChooser(Protocol):
    """``choose(state (state_dim,), rng, running) -> Plan``; ``option_names`` fixes the
    order; ``running`` is the index of the option that is running (``None``: none)."""

    @property
    def option_names(self) -> tuple[str, ...]: ...

    def choose(self, state: FloatArray, rng: Generator,
               running: int | None = None) -> Plan: ...


class _Baseline:
    def __init__(self, options: Sequence[Option]) -> None:
        self.options = list(options)

    @property
    def option_names(self) -> tuple[str, ...]:
        return tuple(o.name for o in self.options)

    def index(self, name: str) -> int:
        try:
            return self.option_names.index(name)
        except ValueError:
            known = ", ".join(self.option_names)
            raise DynoplanError(f"unknown option '{name}' (known: {known})") from None

    def _plan(self, state: FloatArray, admissible: BoolArray, chosen: int | None) -> Plan:
        n, d = len(self.options), np.asarray(state).reshape(-1).shape[0]
        return Plan(self.option_names, admissible, np.full(n, np.nan), np.full(n, np.nan),
                    np.full((n, 0, d), np.nan), np.zeros((n, 0), dtype=np.int64), chosen)

    def _admissible(self, state: FloatArray, running: int | None) -> BoolArray:
        return admissible(self.options, state, running)


class FixedChoice(_Baseline):
    """Always the same option ("each option run alone"), wherever the state is."""

    def __init__(self, options: Sequence[Option], name: str) -> None:
        super().__init__(options)
        self.chosen = self.index(name)

    def choose(self, state: FloatArray, rng: Generator, running: int | None = None) -> Plan:
        return self._plan(state, self._admissible(state, running), self.chosen)


class RandomChoice(_Baseline):
    """A uniformly random option among the admissible ones."""

    def choose(self, state: FloatArray, rng: Generator, running: int | None = None) -> Plan:
        may_run = self._admissible(state, running)
        idx = np.flatnonzero(may_run)
        chosen = int(rng.choice(idx)) if idx.size else None
        return self._plan(state, may_run, chosen)


class ScriptedSequence(_Baseline):
    """A fixed script: the named options in order, ignoring regions; repeats the last.

    The step in the script advances each time ``choose`` is called; ``reset`` restarts.
    """

    def __init__(self, options: Sequence[Option], sequence: Sequence[str]) -> None:
        super().__init__(options)
        if not sequence:
            raise DynoplanError("a scripted sequence needs at least one option")
        self.sequence = [self.index(name) for name in sequence]
        self._step = 0

    def reset(self) -> None:
        self._step = 0

    def choose(self, state: FloatArray, rng: Generator, running: int | None = None) -> Plan:
        chosen = self.sequence[min(self._step, len(self.sequence) - 1)]
        self._step += 1
        return self._plan(state, self._admissible(state, running), chosen)


class Exploring:
    """Another chooser's choice, except that at each decision, with probability
    ``epsilon``, a uniformly random admissible option is chosen instead (epsilon-greedy
    over options): the improvement rounds' own episodes
    (:mod:`~dynoplan.pipeline.improve`) then also hold runs of the options the chooser
    would not try where its models misjudge them. The draw is made only where an option
    is admissible and ``epsilon`` is above 0, from the decision's ``rng``, after the
    chooser's own draws (with ``epsilon`` 0 the choices and the stream are the chooser's).

    Args:
        chooser: the chooser explored around.
        epsilon: the probability, in ``[0, 1]``.
    """

    def __init__(self, chooser: OptionChooser, epsilon: float) -> None:
        if not 0.0 <= epsilon <= 1.0:
            raise DynoplanError(f"the exploration probability must be in [0, 1], got {epsilon}")
        self.chooser = chooser
        self.epsilon = float(epsilon)

    @property
    def option_names(self) -> tuple[str, ...]:
        return tuple(self.chooser.option_names)

    def reset(self) -> None:
        """Resets the chooser explored around, where it has a per-episode state."""
        reset = getattr(self.chooser, "reset", None)
        if callable(reset):
            reset()

    def choose(self, state: FloatArray, rng: Generator, running: int | None = None) -> Plan:
        plan = self.chooser.choose(state, rng, running)
        idx = np.flatnonzero(plan.admissible)
        if idx.size and self.epsilon > 0.0 and rng.random() < self.epsilon:
            return replace(plan, chosen=int(rng.choice(idx)), explored=True)
        return plan
