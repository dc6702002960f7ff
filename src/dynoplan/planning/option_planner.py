"""The policy over options as n-step model-predictive control (the paper's Eq. 1).

    pi_Omega(s_t) = argmax_w E[ 1_{I_w}(s_t) * G(D_w^n(s_t)) ]

For every option admissible at ``s_t`` the planner draws ``samples`` rollouts of the
option's dynamics model, each running until the option's termination ``beta_w`` fires
(drawn per step, as in the real run), the rollout leaves the option's continuation set
(its initiation set unless it has another), or ``horizon`` steps pass; ensemble models
keep one member per rollout (PETS's TS-infinity). The goal heuristic scores each end
state; an option's score is the mean over its rollouts minus ``risk`` times their
standard deviation (``risk=0`` is the paper's expectation), minus ``epistemic`` times
the ensemble's disagreement about it: the standard deviation over the dynamics
ensemble's members of the mean ``G`` of each member's rollouts (PETS's and MOPO's idea:
where the members disagree the model has not seen the data, and a rollout that promises
progress there is not to be trusted).

All admissible options x samples advance together, one stacked array computation per
horizon step; the only Python loop is over the horizon.
"""

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from dynoplan.errors import DynoplanError
from dynoplan.models.dynamics import StackedDynamics, stack_dynamics, trajectory_sampler
from dynoplan.models.goal import GoalHeuristic
from dynoplan.options.initiation import Everywhere, Initiation
from dynoplan.options.option import Option, admissible
from dynoplan.options.termination import StackedTermination, stack_terminations
from dynoplan.safety.constraint import SafetyConstraint
from dynoplan.types import BoolArray, FloatArray, Generator, IntArray


@dataclass(frozen=True)
class Rollouts:
    """Imagined futures of a set of options from one state.

    Attributes:
        end_states: ``(options, samples, state_dim)``, state where each rollout stopped.
        steps: ``(options, samples)``, steps taken before stopping.
        valid: ``(options, samples)``, False where the model produced a non-finite state
            (the rollout is stopped at its last finite state and scored 0).
        members: ``(options, samples)``, the ensemble member each rollout followed, or
            ``None`` when the dynamics are not ensembles that say so.
        unsafe: ``(options, samples)``, True where the safety constraint found an unsafe
            step of the rollout (``None`` without a constraint).
        survival: ``(options, samples)``, ``1 - P(fail | s)`` of each rollout's option at
            its start state (:attr:`~dynoplan.options.option.Option.failure`; 1 for a
            rollout that does not run), or ``None`` when no option has a failure model.
    """

    end_states: FloatArray
    steps: IntArray
    valid: BoolArray
    members: IntArray | None = None
    unsafe: BoolArray | None = None
    survival: FloatArray | None = None


@dataclass(frozen=True)
class Plan:
    """One decision of the planner, with everything a figure or trace needs.

    Arrays are over all options (in the order given to the planner); entries of
    options that were not admissible are NaN (scores, spreads, end states) or 0 (steps).

    Attributes:
        option_names: ``(options,)``.
        admissible: ``(options,)``, ``1_{I_w}(s_t)``.
        scores: ``(options,)``, ``E[G] - risk * std[G] - epistemic * disagreement``,
            where a rollout's ``G`` is weighed by its option's chance not to fail
            (:attr:`Rollouts.survival`).
        spreads: ``(options,)``, ``std[G]`` over rollouts.
        disagreements: ``(options,)``, std over ensemble members of each member's mean
            ``G`` (0 without member information).
        end_states: ``(options, samples, state_dim)``.
        steps: ``(options, samples)``.
        chosen: index of the argmax, or ``None`` when no option is admissible.
        unsafe_shares: ``(options,)``, the share of an option's rollouts with an unsafe
            step (``None`` without a safety constraint). An option above the planner's
            risk level is not admissible now: its score is ``-inf``.
        sequences: ``(options,)`` the best option sequence each option starts, by name
            (:class:`SequencePlanner`; an empty tuple for an option not admissible;
            ``None`` from a planner that looks one option ahead).
        gain_floor: where the best option was a fallback that did not score the goal
            heuristic at the present state (``fallback_must_gain``), that value ``G(s)``,
            and ``chosen`` is ``None``; else ``None``.
        widened: ``(options,)``, the options admitted under their fallback sets because
            no option admissible under its own sets scored the goal heuristic at the
            present state (``widen_without_gain``; they are in ``admissible`` too);
            ``None`` where the planner did not widen.
        explored: ``chosen`` was drawn at random by an exploring chooser
            (:class:`~dynoplan.control.choosers.Exploring`), not the chooser's own choice.
    """

    option_names: tuple[str, ...]
    admissible: BoolArray
    scores: FloatArray
    spreads: FloatArray
    end_states: FloatArray
    steps: IntArray
    chosen: int | None
    disagreements: FloatArray | None = None
    unsafe_shares: FloatArray | None = None
    sequences: tuple[tuple[str, ...], ...] | None = None
    gain_floor: float | None = None
    widened: BoolArray | None = None
    explored: bool = False

    @property
    def chosen_name(self) -> str | None:
        return None if self.chosen is None else self.option_names[self.chosen]


def member_disagreement(g: FloatArray, members: IntArray | None) -> FloatArray:
    """Std over ensemble members of the mean of each member's rollout scores.

    Args:
        g: ``(options, samples)`` goal values of the rollouts' end states.
        members: ``(options, samples)`` member index of each rollout, or ``None``.

    Returns:
        ``(options,)``; 0 where there is no member information or one member.
    """
    if members is None:
        return np.zeros(g.shape[0])
    out = np.zeros(g.shape[0])
    for o in range(g.shape[0]):
        ids = np.unique(members[o])
        if len(ids) > 1:
            out[o] = float(np.std([g[o][members[o] == k].mean() for k in ids]))
    return out


def member_disagreements(g: FloatArray, members: IntArray | None) -> FloatArray:
    """:func:`member_disagreement` with no loop over branches (its sums in another
    order: equal up to rounding): the std over the ensemble members present in each
    branch of the mean ``G`` of that member's rollouts.

    Args:
        g: ``(branches, samples)`` goal values of the rollouts' end states.
        members: ``(branches, samples)`` member index of each rollout, or ``None``.

    Returns:
        ``(branches,)``; 0 where there is no member information or one member.
    """
    b = g.shape[0]
    if members is None:
        return np.zeros(b)
    e = int(members.max()) + 1
    cell = (np.arange(b)[:, None] * e + members).reshape(-1)
    counts = np.bincount(cell, minlength=b * e).reshape(b, e)
    sums = np.bincount(cell, weights=g.reshape(-1), minlength=b * e).reshape(b, e)
    present = counts > 0
    means = sums / np.maximum(counts, 1)
    n = present.sum(axis=1)
    mu = (means * present).sum(axis=1) / n
    var = (((means - mu[:, None]) ** 2) * present).sum(axis=1) / n
    out: FloatArray = np.where(n > 1, np.sqrt(var), 0.0)
    return out


class BlockOrder:
    """The map between rollouts in row order, ``(branches, samples, ...)``, and in an
    engine's block order, ``(slices, places, ...)``: place ``j`` of slice ``k`` holds
    sample ``rows[k, j]`` of branch ``branches[k, j]``; places with ``real`` False are
    padding (no sample). ``shape`` is ``(branches, samples)``."""

    def __init__(self, branches: IntArray, rows: IntArray, real: BoolArray,
                 shape: tuple[int, int]) -> None:
        self.branches, self.rows, self.real, self.shape = branches, rows, real, shape
        self._all_real = bool(real.all())

    def to_blocks(self, a: np.ndarray, axis: int = 0) -> np.ndarray:
        """``a`` with axes ``axis, axis + 1`` = ``(branches, samples)`` in block order."""
        index: tuple[Any, ...] = (*(slice(None),) * axis, self.branches, self.rows)
        return a[index]

    def to_rows(self, a: np.ndarray) -> np.ndarray:
        """``(slices, places, ...)`` back to ``(branches, samples, ...)``."""
        out = np.empty((*self.shape, *a.shape[2:]), dtype=a.dtype)
        if self._all_real:
            out[self.branches, self.rows] = a
        else:
            out[self.branches[self.real], self.rows[self.real]] = a[self.real]
        return out


@dataclass(frozen=True)
class _ScoreTable:
    """One decision's per-option results as the planner fills them (NaN / 0 for an
    option not scored): ``scores``, ``spreads``, ``disagreements`` ``(options,)``,
    ``end_states`` ``(options, samples, state_dim)``, ``steps`` ``(options, samples)``,
    ``shares`` ``(options,)`` (``None`` without a safety constraint)."""

    scores: FloatArray
    spreads: FloatArray
    disagreements: FloatArray
    end_states: FloatArray
    steps: IntArray
    shares: FloatArray | None

    @classmethod
    def empty(cls, options: int, samples: int, state_dim: int,
              constrained: bool) -> "_ScoreTable":
        return cls(np.full(options, np.nan), np.full(options, np.nan),
                   np.full(options, np.nan), np.full((options, samples, state_dim), np.nan),
                   np.zeros((options, samples), dtype=np.int64),
                   np.full(options, np.nan) if constrained else None)


class OptionPlanner:
    """Chooses the option whose imagined future the goal heuristic likes best (Eq. 1).

    Args:
        options: the candidate options; their dynamics and terminations must accept
            states of the same dimension.
        goal: the goal heuristic ``G``.
        horizon: ``n``, the most steps a rollout may take.
        samples: ``S``, Monte-Carlo rollouts per option.
        risk: ``k`` in ``mean - k * std``; 0 reproduces the paper.
        epistemic: weight of the ensemble disagreement subtracted from the score (0
            reproduces the paper).
        respect_regions: stop a rollout when it leaves the option's continuation set
            (its initiation set unless given; the controller would stop the real option
            there too).
        constraint: the chance constraint of the safe Eq. 1
            (:class:`~dynoplan.safety.constraint.SafetyConstraint`; ``None``: the paper's
            Eq. 1).
        risk_level: ``epsilon``: an option whose share of rollouts with an unsafe step
            exceeds it is not admissible now (score ``-inf``); with none left, no option
            is chosen and the controller holds.
        end_inside: a rollout that leaves the continuation set ends at its last state
            inside it, not at the first state beyond it: the goal heuristic then scores
            only states where the option's dynamics had data (a model that carries an
            insertion on past the seat, or a move on past its end, into states no
            demonstration showed, cannot win or lose a decision there).
        fallback_must_gain: where no option may start under its own sets and the options
            fall back (:func:`admissible`), an option is chosen only if its score is at
            least the goal heuristic's mean at the present state; else none is (the
            controller holds): a fallback is a way on, not a way back.
        widen_without_gain: where options may start under their own sets but the best
            of them scores below the goal heuristic's mean at the present state (none
            is predicted to gain), the demonstrated options (``Option.demonstrated``)
            whose fallback set holds there are scored too, and the best of them is
            chosen if it scores at least that mean and more than the best admissible
            one: the learned sets say where each option ran in the demonstrations, and
            a disturbance can leave the state where only another demonstrated option
            gains.
        regions_without_gain: where no admissible option is predicted to gain (as
            above, after ``widen_without_gain``), the admissible option whose region
            gives the state the highest likelihood (``Option.likelihood``: the
            demonstrations' choice there) is chosen instead of the best-scoring one;
            options without a region are left to the scores (with fewer than two
            regions among the admissible options, nothing changes).
        compact: advance only the rollouts still running, as rows, where the stacked
            dynamics and terminations can (``sample_rows`` and ``probability_rows``, see
            :meth:`rollout`): the same distribution of rollouts for a fraction of the
            work when most stop early, but another use of the generator than the full
            arrays (so other seeded draws).
    """

    def __init__(self, options: Sequence[Option], goal: GoalHeuristic, horizon: int = 20,
                 samples: int = 64, risk: float = 0.0, respect_regions: bool = True,
                 epistemic: float = 0.0, constraint: SafetyConstraint | None = None,
                 risk_level: float = 0.05, end_inside: bool = False,
                 fallback_must_gain: bool = False, compact: bool = False,
                 widen_without_gain: bool = False, regions_without_gain: bool = False) -> None:
        if not options:
            raise DynoplanError("the planner needs at least one option")
        names = [o.name for o in options]
        if len(set(names)) != len(names):
            raise DynoplanError(f"option names must be unique, got {names}")
        if horizon < 1 or samples < 1:
            raise DynoplanError(f"horizon and samples must be >= 1, got {horizon}, {samples}")
        self.options = list(options)
        self.goal = goal
        self.horizon = int(horizon)
        self.samples = int(samples)
        self.risk = float(risk)
        self.epistemic = float(epistemic)
        self.respect_regions = respect_regions
        if not 0.0 <= risk_level <= 1.0:
            raise DynoplanError(f"risk_level must be in [0, 1], got {risk_level}")
        self.constraint = constraint
        self.risk_level = float(risk_level)
        self.end_inside = bool(end_inside)
        self.fallback_must_gain = bool(fallback_must_gain)
        self.compact = bool(compact)
        self.widen_without_gain = bool(widen_without_gain)
        self.regions_without_gain = bool(regions_without_gain)
        self._stacks: dict[tuple[int, ...], tuple[StackedDynamics, StackedTermination]] = {}
        self._terminations: dict[tuple[int, ...], StackedTermination] = {}

    @property
    def option_names(self) -> tuple[str, ...]:
        return tuple(o.name for o in self.options)

    def admissible(self, state: FloatArray, running: int | None = None) -> BoolArray:
        """``1_{I_w}(s)`` for every option, shape ``(options,)``; the running option's
        continuation set stands for its initiation set (:func:`admissible`)."""
        return admissible(self.options, state, running)

    def choose(self, state: FloatArray, rng: Generator, running: int | None = None) -> Plan:
        """Alias of :meth:`plan`, so the planner is an ``OptionChooser``."""
        return self.plan(state, rng, running)

    def plan(self, state: FloatArray, rng: Generator, running: int | None = None) -> Plan:
        """Score every admissible option from ``state`` (shape ``(state_dim,)``).

        ``running``: the index of an option that is running (the controller interrupted
        it to plan again); it is admissible where it may go on, not only where it may
        start.
        """
        s = np.asarray(state, dtype=np.float64).reshape(-1)
        n_opt, d = len(self.options), s.shape[0]
        may_run = self.admissible(s, running)
        table = _ScoreTable.empty(n_opt, self.samples, d, self.constraint is not None)
        idx = tuple(int(i) for i in np.flatnonzero(may_run))
        chosen: int | None = None
        floor: float | None = None
        widened: BoolArray | None = None
        scores = table.scores
        if idx:
            if self.constraint is not None:
                self.constraint.prepare(s)
            self._score(idx, s, rng, table)
            best = int(np.argmax(scores[list(idx)]))
            unsafe_everywhere = table.shares is not None and scores[idx[best]] == -np.inf
            chosen = None if unsafe_everywhere else idx[best]
            gain_rules = chosen is not None and (self.fallback_must_gain
                                                 or self.widen_without_gain
                                                 or self.regions_without_gain)
            if gain_rules and self._falls_back(s, running):  # asked only where a rule needs it
                if self.fallback_must_gain:
                    here = float(self.goal.mean_std(s[None])[0][0])
                    if scores[chosen] < here:
                        chosen, floor = None, here
            elif gain_rules and (self.widen_without_gain or self.regions_without_gain):
                assert chosen is not None
                here = float(self.goal.mean_std(s[None])[0][0])
                widened = self._widen(s, may_run) \
                    if self.widen_without_gain and scores[chosen] < here else None
                if widened is not None:
                    extra = tuple(int(i) for i in np.flatnonzero(widened))
                    self._score(extra, s, rng, table)
                    may_run = may_run | widened
                    best_extra = extra[int(np.argmax(scores[list(extra)]))]
                    if scores[best_extra] >= here and scores[best_extra] > scores[chosen]:
                        chosen = best_extra
                if self.regions_without_gain and scores[chosen] < here:  # still no gain
                    chosen = self._most_likely(s, idx, chosen, scores)
        return Plan(self.option_names, may_run, scores, table.spreads, table.end_states,
                    table.steps, chosen, table.disagreements, table.shares, gain_floor=floor,
                    widened=widened)

    def _score(self, idx: tuple[int, ...], state: FloatArray, rng: Generator,
               table: "_ScoreTable") -> None:
        """Roll the options ``idx`` forward from ``state`` (``(state_dim,)``) and write
        their scores, spreads, disagreements, end states, steps and (with a constraint)
        unsafe shares into their rows of ``table``."""
        roll = self.rollout(idx, state, rng)
        g = self.goal.sample(roll.end_states.reshape(-1, state.shape[0]), rng).reshape(
            len(idx), -1)
        g = np.where(roll.valid, g, 0.0)
        if roll.survival is not None:  # a run that fails leaves no progress
            g = g * roll.survival
        mean, std = g.mean(axis=1), g.std(axis=1)
        split = member_disagreements(g, roll.members)
        rows = list(idx)
        table.scores[rows] = mean - self.risk * std - self.epistemic * split
        table.spreads[rows] = std
        table.disagreements[rows] = split
        table.end_states[rows] = roll.end_states
        table.steps[rows] = roll.steps
        if table.shares is not None and roll.unsafe is not None:
            table.shares[rows] = roll.unsafe.mean(axis=1)
            table.scores[rows] = np.where(table.shares[rows] > self.risk_level, -np.inf,
                                          table.scores[rows])

    def _most_likely(self, state: FloatArray, idx: tuple[int, ...], chosen: int,
                     scores: FloatArray) -> int:
        """Of the options ``idx`` (admissible at ``state``, ``(state_dim,)``) that the
        safety constraint allows (``scores``, ``(options,)``, above ``-inf``), the one
        whose region gives ``state`` the highest likelihood (``Option.likelihood``);
        ``chosen`` where fewer than two of them have a region."""
        known = [(k, f) for k in idx
                 if (f := self.options[k].likelihood) is not None and scores[k] > -np.inf]
        if len(known) < 2:
            return chosen
        log_l = [float(f(state[None])[0]) for _, f in known]
        return known[int(np.argmax(log_l))][0]

    def _widen(self, state: FloatArray, may_run: BoolArray) -> BoolArray | None:
        """``(options,)``: the demonstrated options not admissible at ``state``
        (``may_run``) whose fallback set holds there; ``None`` where no such option is
        left."""
        extra = np.array([not may_run[k] and o.demonstrated and o.may_fall_back(state)
                          for k, o in enumerate(self.options)], dtype=bool)
        return extra if extra.any() else None

    def _falls_back(self, state: FloatArray, running: int | None) -> bool:
        """Whether no option may run at ``state`` under its own sets (the admissible ones
        are fallbacks)."""
        return not any(o.may_run(state, k == running) for k, o in enumerate(self.options))

    def rollout(self, option_indices: Sequence[int], state: FloatArray, rng: Generator,
                start_alive: BoolArray | None = None, step_offset: int = 0) -> Rollouts:
        """Roll the given options forward: one batched step per horizon step.

        Args:
            option_indices: ``(branches,)`` the option each branch follows; an option may
                appear more than once (a level of :class:`SequencePlanner`).
            state: ``(state_dim,)``, one start state for every branch and sample, or
                ``(branches, samples, state_dim)``, a start state per rollout.
            start_alive: ``(branches, samples)``, False where a rollout does not run at
                all (its option may not start there): it stays at its start state with
                0 steps. Default: every rollout runs.
            step_offset: model steps already taken before these rollouts (the safety
                constraint judges step ``step_offset + t``).

        Returns arrays over ``(branches, samples, ...)``.

        With ``compact`` on, and stacked dynamics and terminations that offer
        ``sample_rows(states (rows, d), branches (rows,), rng)`` and
        ``probability_rows(states (rows, d), branches (rows,))`` (row ``i`` follows the
        stack's slice ``branches[i]``), each step advances only the rollouts still
        running (:meth:`_rollout_rows`).
        """
        idx = tuple(option_indices)
        x = np.broadcast_to(state, (len(idx), self.samples, state.shape[-1])).copy()
        alive = np.ones(x.shape[:2], dtype=bool) if start_alive is None \
            else np.array(start_alive, dtype=bool)
        survival = self._survival(idx, np.asarray(state), x, alive)
        if self.compact:  # rows name their option: a stack of the distinct options
            kinds = tuple(dict.fromkeys(idx))
            dynamics, termination = self._stack(kinds)
            if callable(getattr(dynamics, "sample_rows", None)) \
                    and callable(getattr(termination, "probability_rows", None)):
                where = np.zeros(max(kinds) + 1, dtype=np.int64)
                where[list(kinds)] = np.arange(len(kinds))
                return replace(self._rollout_rows(kinds, where[np.asarray(idx)], dynamics,
                                                  termination, x, alive, rng, step_offset),
                               survival=survival)
        dynamics, termination = self._stack(idx)
        stop_draws = rng.random((self.horizon, *alive.shape))  # beta draws, one per step
        blocks = getattr(dynamics, "block_sampler", None)
        slices = self._engine_options(idx, dynamics) if callable(blocks) else None
        order: BlockOrder | None = None
        if callable(blocks) and slices is not None:  # the ensembles' own order, no reordering
            sampler = blocks(self.samples, rng)  # a member per rollout, as trajectory_sampler
            members = sampler.members
            order = BlockOrder(sampler.branches, sampler.rows, sampler.real, alive.shape)
            termination = self._termination(slices)  # slice k of the blocks runs slices[k]
            x, alive, stop_draws = order.to_blocks(x), order.to_blocks(alive) & sampler.real, \
                order.to_blocks(stop_draws, axis=1)
            sampler.start(x)
            advance = sampler.advance
        else:
            slices = idx
            step = trajectory_sampler(dynamics, self.samples, rng)  # a member per rollout
            members = getattr(step, "members", None)

            def advance() -> np.ndarray:
                return step(x)
        regions = self._region_groups(slices) if self.respect_regions else []
        steps, valid, unsafe = self._advance(advance, x, alive, stop_draws, termination,
                                             regions, step_offset)
        if order is not None:
            x, steps, valid = order.to_rows(x), order.to_rows(steps), order.to_rows(valid)
            unsafe = None if unsafe is None else order.to_rows(unsafe)
            members = None if members is None else order.to_rows(np.asarray(members))
        return Rollouts(x, steps, valid, None if members is None else np.asarray(members),
                        unsafe, survival)

    def _advance(self, advance: Callable[[], np.ndarray], x: FloatArray,
                 alive: BoolArray, stop_draws: FloatArray, termination: StackedTermination,
                 regions: list[tuple[IntArray, Initiation]],
                 step_offset: int) -> tuple[IntArray, BoolArray, BoolArray | None]:
        """Run rollouts for up to ``horizon`` steps: ``x`` ``(slices, places, d)`` their
        start states (changed in place to where they stop), ``advance()`` the next state
        of every place from ``x`` (at places whose rollouts run), ``alive`` ``(slices,
        places)`` which run, ``stop_draws`` ``(horizon, slices, places)`` the uniform
        draws of the terminations, ``termination`` and ``regions`` over the slices.

        Returns ``(steps, valid, unsafe)``, each ``(slices, places)`` (``unsafe`` is
        ``None`` without a safety constraint).
        """
        valid = np.ones(x.shape[:2], dtype=bool)
        steps = np.zeros(x.shape[:2], dtype=np.int64)
        unsafe = None if self.constraint is None else np.zeros_like(alive)
        places = alive.size
        for t in range(self.horizon):
            if not np.count_nonzero(alive):  # count_nonzero: less overhead than any()
                break
            nxt = advance()
            moved = alive
            if not np.isfinite(nxt).all():  # rare: stop diverged rollouts where they are
                finite = np.isfinite(nxt).all(axis=-1)
                valid &= finite | ~alive
                moved = alive & finite
            if unsafe is not None and self.constraint is not None:
                unsafe |= moved & self.constraint.unsafe(x, np.where(moved[..., None], nxt, x),
                                                         step_offset + t + 1)
            before = x.copy() if self.end_inside and regions else None
            if np.count_nonzero(moved) == places:  # the common case: a plain copy is faster
                x[...] = nxt
            else:
                np.copyto(x, nxt, where=moved[..., None])
            steps += moved
            alive = moved & (stop_draws[t] >= termination.probability(x))
            for rows, initiation in regions:  # one call per option, over all its slices
                inside = initiation.contains(x[rows].reshape(-1, x.shape[-1])).reshape(
                    len(rows), -1)
                alive[rows] &= inside
                if before is not None:  # back to the last state inside the set
                    left = moved[rows] & ~inside
                    x[rows] = np.where(left[..., None], before[rows], x[rows])
                    steps[rows] -= left
        return steps, valid, unsafe

    def _engine_options(self, idx: tuple[int, ...], dynamics: Any) -> tuple[int, ...] | None:
        """The option of every slice of an engine's block order (the engine stacks each
        distinct model once, ``dynamics.branches`` ``(branches,)`` names the model of
        every branch), or ``None`` where one model serves two options of ``idx`` (their
        terminations and sets may differ: the rollouts stay in row order)."""
        models = np.asarray(dynamics.branches)
        options = np.asarray(idx)
        of = np.empty(int(models.max()) + 1, dtype=np.int64)
        of[models] = options
        return tuple(of.tolist()) if (of[models] == options).all() else None

    def _survival(self, idx: tuple[int, ...], state: FloatArray, x: FloatArray,
                  alive: BoolArray) -> FloatArray | None:
        """``(branches, samples)`` ``1 - P(fail | s)`` of each rollout's option at its start
        state ``x`` (``state`` ``(d,)`` when every rollout starts there), 1 where a rollout
        does not run; ``None`` when no option of ``idx`` has a failure model."""
        if all(self.options[i].failure is None for i in idx):
            return None
        branches = np.asarray(idx, dtype=np.int64)
        out = np.ones(x.shape[:2])
        for i in dict.fromkeys(idx):
            model = self.options[i].failure
            if model is None:
                continue
            rows = np.flatnonzero(branches == i)
            if state.ndim == 1:  # one start state for all: one query
                p = np.asarray(model.probability(state[None]), dtype=np.float64).reshape(1, 1)
            else:
                p = np.asarray(model.probability(x[rows].reshape(-1, x.shape[-1])),
                               dtype=np.float64).reshape(len(rows), -1)
            out[rows] = 1.0 - np.clip(p, 0.0, 1.0)
        return np.where(alive, out, 1.0)

    def _rollout_rows(self, kinds: tuple[int, ...], kind: IntArray, dynamics: Any,
                      termination: Any, x: FloatArray, alive: BoolArray, rng: Generator,
                      step_offset: int) -> Rollouts:
        """:meth:`rollout` on the running rollouts only: ``x`` ``(branches, samples, d)``
        start states (changed in place), ``alive`` ``(branches, samples)`` which run;
        ``dynamics`` and ``termination`` stack the options ``kinds`` (distinct), and
        branch ``b`` follows ``kinds[kind[b]]`` (``kind`` ``(branches,)``).

        The running rollouts are carried as compact rows (their states, their slice of
        the stack and their indices into ``x``); a rollout's end state and step count
        are written once, when it stops.
        """
        b, n, d = x.shape
        flat = x.reshape(-1, d)
        steps = np.zeros(b * n, dtype=np.int64)
        valid = np.ones(b * n, dtype=bool)
        unsafe = None if self.constraint is None else np.zeros(b * n, dtype=bool)
        regions = [(k, self.options[i].continuation_set) for k, i in enumerate(kinds)
                   if self.respect_regions
                   and not isinstance(self.options[i].continuation_set, Everywhere)]
        live = np.flatnonzero(alive.reshape(-1))  # (rows,) indices into flat
        now = flat.take(live, axis=0)  # (rows, d) their states
        branch = kind.take(live // n)  # (rows,) their slices of the stack
        for t in range(self.horizon):
            if live.size == 0:
                break
            nxt = dynamics.sample_rows(now, branch, rng)
            finite = np.isfinite(nxt).all(axis=-1)
            if not finite.all():  # rare: stop diverged rollouts where they are
                gone = live[~finite]
                valid[gone], steps[gone] = False, t
                flat[gone] = now[~finite]
                live, now, nxt, branch = live[finite], now[finite], nxt[finite], branch[finite]
            if unsafe is not None and self.constraint is not None:
                unsafe[live] |= self.constraint.unsafe(now, nxt, step_offset + t + 1)
            go_on = rng.random(live.size) >= termination.probability_rows(nxt, branch)
            took = None  # the rows that left their set and end where they were
            for k, initiation in regions:
                mine = np.flatnonzero(branch == k)
                out = mine[~np.asarray(initiation.contains(nxt[mine]), dtype=bool)]
                go_on[out] = False
                if self.end_inside:  # back to the last state inside the set
                    took = out if took is None else np.concatenate([took, out])
            if took is not None and took.size:
                nxt = nxt.copy()  # the model's array stays as it gave it
                nxt[took] = now[took]
            stop = np.flatnonzero(~go_on)
            ended = live.take(stop)
            flat[ended] = nxt.take(stop, axis=0)
            steps[ended] = t + 1
            if took is not None and took.size:
                steps[live.take(took)] = t
            keep = np.flatnonzero(go_on)
            live, now, branch = live.take(keep), nxt.take(keep, axis=0), branch.take(keep)
        flat[live] = now  # the horizon ran out
        steps[live] = self.horizon
        return Rollouts(flat.reshape(b, n, d), steps.reshape(b, n), valid.reshape(b, n), None,
                        None if unsafe is None else unsafe.reshape(b, n))

    def _region_groups(self, idx: tuple[int, ...]) -> list[tuple[IntArray, Initiation]]:
        """``(branch rows, continuation set)`` of every option in ``idx`` with a set that
        is not everywhere: the rows of all branches that follow it."""
        branches = np.asarray(idx, dtype=np.int64)
        groups = []
        for i in dict.fromkeys(idx):
            region = self.options[i].continuation_set
            if not isinstance(region, Everywhere):
                groups.append((np.flatnonzero(branches == i), region))
        return groups

    def _stack(self, idx: tuple[int, ...]) -> tuple[StackedDynamics, StackedTermination]:
        """The dynamics and terminations of the options ``idx``, stacked (cached)."""
        if idx not in self._stacks:
            chosen = [self.options[i] for i in idx]
            self._remember(self._stacks, idx,
                           (stack_dynamics([o.planner_dynamics for o in chosen]),
                            stack_terminations([o.termination for o in chosen])))
        return self._stacks[idx]

    def _termination(self, idx: tuple[int, ...]) -> StackedTermination:
        """The terminations of the options ``idx``, stacked (cached)."""
        if idx not in self._terminations:
            self._remember(self._terminations, idx,
                           stack_terminations([self.options[i].termination for i in idx]))
        return self._terminations[idx]

    @staticmethod
    def _remember(cache: dict[tuple[int, ...], Any], key: tuple[int, ...], value: Any) -> None:
        if len(cache) >= 256:  # batches over many states: each key is new
            cache.clear()
        cache[key] = value
