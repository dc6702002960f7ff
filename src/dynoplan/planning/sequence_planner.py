"""Look-ahead over option sequences: Eq. 1 as a batched tree search.

Eq. 1 is one-step hill climbing: it runs the option whose own imagined future scores
best. :class:`SequencePlanner` looks ``depth`` options ahead:

    pi_Omega(s_t) = argmax_{w_1} max_{w_2 .. w_d} E[ G(D_{w_d}^n( ... D_{w_1}^n(s_t))) ]

Level 1 rolls every admissible option forward from ``s_t`` (``samples`` rollouts each,
exactly as :class:`~dynoplan.planning.OptionPlanner` does); level ``k + 1`` continues
every rollout of every kept level-``k`` branch with every option: rollout ``j`` of the
child starts where rollout ``j`` of its parent ended, so a branch is one option sequence
with ``samples`` imagined futures. A child option that may not start at a parent's end
state (its initiation set, :func:`~dynoplan.options.option.admissible_batch`) leaves
that rollout where it is: the sequence ends there. The goal heuristic scores the
leaves; a leaf's value is Eq. 1's score of its sequence (the mean over its samples,
minus ``risk`` times their spread and ``epistemic`` times the ensemble's disagreement;
``-inf`` where the share of its rollouts with an unsafe step, along the whole sequence,
exceeds ``risk_level``). Values are backed up by the max over children, and the planner
runs the first option of the best sequence. The values are open-loop (one sequence
for every sample), so they do not assume that the second option is chosen knowing
where the first one ended: a lower bound of what replanning after the first option
achieves under the models.

All branches of one level advance together: one stacked model call per horizon step
for the whole level (branches x samples rows), no Python loop over branches or
samples. :meth:`SequencePlanner.plan_many` plans for many states at once (all their
branches in the same calls), for example every episode of a batch at one decision.

``beam`` bounds the branches expanded per start state: before a level is expanded, its
branches are scored with the goal heuristic and only the best ``beam`` of each start
state get children (the others are not chosen).
"""

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from dynoplan.errors import DynoplanError
from dynoplan.models.goal import GoalHeuristic
from dynoplan.options.option import Option, admissible_batch
from dynoplan.planning.option_planner import OptionPlanner, Plan, member_disagreements
from dynoplan.safety.constraint import SafetyConstraint
from dynoplan.types import BoolArray, FloatArray, Generator, IntArray


@dataclass(frozen=True)
class Level:
    """One level of the search tree, ``branches`` option sequences of equal length.

    Attributes:
        options: ``(branches,)`` the last option of each sequence.
        parents: ``(branches,)`` the branch of the level above it extends (level 1: the
            index of the start state).
        roots: ``(branches,)`` the index of the start state of each branch.
        end_states: ``(branches, samples, state_dim)`` where each imagined future ended.
        steps: ``(branches, samples)`` model steps of this level's option.
        total_steps: ``(branches, samples)`` model steps of the whole sequence.
        valid: ``(branches, samples)`` False where a model produced a non-finite state
            somewhere along the sequence.
        unsafe: ``(branches, samples)`` an unsafe step somewhere along the sequence
            (``None`` without a safety constraint).
        members: ``(branches, samples)`` ensemble member of this level's rollouts, or
            ``None``.
        survival: ``(branches, samples)`` the chance that no option of the sequence
            failed (the product of each option's ``1 - P(fail | s)`` at its start), or
            ``None`` when no option has a failure model.
    """

    options: IntArray
    parents: IntArray
    roots: IntArray
    end_states: FloatArray
    steps: IntArray
    total_steps: IntArray
    valid: BoolArray
    unsafe: BoolArray | None
    members: IntArray | None
    survival: FloatArray | None = None


@dataclass(frozen=True)
class LeafScores:
    """Eq. 1's score of each branch of a level, ``(branches,)`` each: ``values`` is
    ``mean - risk * std - epistemic * disagreement`` (``-inf`` where unsafe)."""

    values: FloatArray
    spreads: FloatArray
    disagreements: FloatArray
    unsafe_shares: FloatArray | None


@dataclass(frozen=True)
class Tree:
    """A searched tree: its ``levels``, the leaves' scores, the backed-up ``values`` of
    level 1 ``(branches,)``, and per level above the leaves the ``best`` child of each
    branch (``-1`` where it was not expanded)."""

    levels: list[Level]
    leaf: LeafScores
    values: FloatArray
    best: list[IntArray]


class SequencePlanner(OptionPlanner):
    """Chooses the first option of the option sequence whose imagined future scores best.

    Args:
        options, goal, horizon, samples, risk, respect_regions, epistemic, constraint,
            risk_level, end_inside, fallback_must_gain, compact: as
            :class:`~dynoplan.planning.OptionPlanner`; ``horizon`` bounds each option of
            a sequence, ``samples`` are the imagined futures of every branch.
        depth: options per sequence; 1 is :class:`~dynoplan.planning.OptionPlanner`'s
            Eq. 1 (the same choices and scores from the same generator).
        beam: branches per start state expanded at each level (``None``: all).
    """

    def __init__(self, options: Sequence[Option], goal: GoalHeuristic, horizon: int = 20,
                 samples: int = 64, risk: float = 0.0, respect_regions: bool = True,
                 epistemic: float = 0.0, constraint: SafetyConstraint | None = None,
                 risk_level: float = 0.05, end_inside: bool = False,
                 fallback_must_gain: bool = False, depth: int = 2,
                 beam: int | None = None, compact: bool = False) -> None:
        super().__init__(options, goal, horizon=horizon, samples=samples, risk=risk,
                         respect_regions=respect_regions, epistemic=epistemic,
                         constraint=constraint, risk_level=risk_level, end_inside=end_inside,
                         fallback_must_gain=fallback_must_gain, compact=compact)
        if depth < 1:
            raise DynoplanError(f"depth must be >= 1, got {depth}")
        if beam is not None and beam < 1:
            raise DynoplanError(f"beam must be >= 1 or None, got {beam}")
        self.depth = int(depth)
        self.beam = None if beam is None else int(beam)

    def plan(self, state: FloatArray, rng: Generator, running: int | None = None) -> Plan:
        """Score every admissible first option from ``state`` (``(state_dim,)``) by the
        best sequence it starts; ``running`` as :meth:`OptionPlanner.plan`."""
        s = np.asarray(state, dtype=np.float64).reshape(1, -1)
        return self.plan_many(s, rng, [running])[0]

    def plan_many(self, states: FloatArray, rng: Generator,
                  running: Sequence[int | None] | None = None) -> list[Plan]:
        """One :class:`Plan` per row of ``states`` (``(roots, state_dim)``), all searched
        together: every level of every tree advances in one stacked call per step.

        ``running``: per state, the option the controller interrupted there (or
        ``None``). With a safety constraint (prepared for one state at a time) the
        states are planned one after another.
        """
        x = np.asarray(states, dtype=np.float64)
        x = x.reshape(x.shape[0], -1)
        run: list[int | None] = [None] * len(x) if running is None else list(running)
        if len(run) != len(x):
            raise DynoplanError(f"running has {len(run)} entries for {len(x)} states")
        if self.constraint is not None and len(x) > 1:
            return [self.plan_many(x[r:r + 1], rng, run[r:r + 1])[0] for r in range(len(x))]
        may_run = admissible_batch(self.options, x,
                                   np.array([-1 if k is None else k for k in run]))
        roots, firsts = np.nonzero(may_run.T)  # root-major, options in order
        if len(firsts) == 0:
            return self._plans(x, may_run, run, None)
        if self.constraint is not None:
            self.constraint.prepare(x[0])
        start = x[0] if len(x) == 1 else x[roots][:, None, :]
        roll = self.rollout(tuple(firsts.tolist()), start, rng)
        levels = [Level(firsts, roots, roots, roll.end_states, roll.steps, roll.steps, roll.valid,
                        roll.unsafe, roll.members, roll.survival)]
        kept: list[IntArray] = []
        for _ in range(1, self.depth):
            parents = self._expand(levels[-1], len(x), rng)
            kept.append(parents)
            levels.append(self._children(levels[-1], parents, rng))
        leaf = self.score(levels[-1], rng)
        values, best_child = self._back_up(levels, kept, leaf.values)
        tree = Tree(levels, leaf, values, best_child)
        return self._plans(x, may_run, run, tree)

    def score(self, level: Level, rng: Generator) -> LeafScores:
        """Eq. 1's score of every branch of ``level`` from one goal draw per rollout."""
        b, s, d = level.end_states.shape
        g = self.goal.sample(level.end_states.reshape(-1, d), rng).reshape(b, s)
        g = np.where(level.valid, g, 0.0)
        if level.survival is not None:  # a sequence that fails leaves no progress
            g = g * level.survival
        mean, std = g.mean(axis=1), g.std(axis=1)
        split = member_disagreements(g, level.members)
        values = mean - self.risk * std - self.epistemic * split
        shares = None
        if level.unsafe is not None:
            shares = level.unsafe.mean(axis=1)
            values = np.where(shares > self.risk_level, -np.inf, values)
        return LeafScores(values, std, split, shares)

    def _expand(self, level: Level, roots: int, rng: Generator) -> IntArray:
        """The branches of ``level`` that get children: all, or the best ``beam`` of each
        start state by their own score."""
        n = len(level.options)
        root = level.roots
        if self.beam is None or np.bincount(root, minlength=roots).max() <= self.beam:
            return np.arange(n)
        values = self.score(level, rng).values
        order = np.lexsort((-values, root))  # by start state, best first
        rank = np.empty(n, dtype=np.int64)
        starts = np.searchsorted(root[order], root[order])
        rank[order] = np.arange(n) - starts
        return np.flatnonzero(rank < self.beam)

    def _children(self, level: Level, parents: IntArray, rng: Generator) -> Level:
        """Every option after every rollout of the branches ``parents`` of ``level``:
        ``(parents * options)`` branches, parent-major."""
        n_opt, p = len(self.options), len(parents)
        ends = level.end_states[parents]  # (p, samples, d)
        d = ends.shape[-1]
        may = admissible_batch(self.options, ends.reshape(-1, d))  # (options, p * samples)
        may = may.reshape(n_opt, p, self.samples).transpose(1, 0, 2).reshape(p * n_opt, -1)
        options = np.tile(np.arange(n_opt), p)
        before = np.repeat(level.total_steps[parents], n_opt, axis=0)
        roll = self.rollout(tuple(options.tolist()), np.repeat(ends, n_opt, axis=0), rng,
                            start_alive=may, step_offset=int(before.min()))
        unsafe = None
        if roll.unsafe is not None and level.unsafe is not None:
            unsafe = roll.unsafe | np.repeat(level.unsafe[parents], n_opt, axis=0)
        survival = roll.survival
        if level.survival is not None:
            above = np.repeat(level.survival[parents], n_opt, axis=0)
            survival = above if survival is None else survival * above
        return Level(options, np.repeat(parents, n_opt),
                     np.repeat(level.roots[parents], n_opt), roll.end_states, roll.steps,
                     before + roll.steps,
                     roll.valid & np.repeat(level.valid[parents], n_opt, axis=0), unsafe,
                     roll.members, survival)

    def _back_up(self, levels: list[Level], kept: list[IntArray],
                 leaf_values: FloatArray) -> tuple[FloatArray, list[IntArray]]:
        """The max over children, level by level up to level 1: ``(branches of level
        1,)`` values, and per level above the leaves the best child of each branch
        (``-1`` where a branch was not expanded)."""
        values = leaf_values
        best: list[IntArray] = []
        n_opt = len(self.options)
        for k in range(len(levels) - 2, -1, -1):
            by_parent = values.reshape(len(kept[k]), n_opt)
            up = np.full(len(levels[k].options), -np.inf)
            up[kept[k]] = by_parent.max(axis=1)
            child = np.full(len(levels[k].options), -1, dtype=np.int64)
            child[kept[k]] = np.argmax(by_parent, axis=1) + np.arange(len(kept[k])) * n_opt
            best.insert(0, child)
            values = up
        return values, best

    def _plans(self, states: FloatArray, may_run: BoolArray, running: list[int | None],
               tree: Tree | None) -> list[Plan]:
        """One :class:`Plan` per start state: the first options' backed-up values as
        ``scores``; the spreads, disagreements and unsafe shares of each first option's
        best sequence; its level-1 rollouts; the best sequences' names. Arrays are
        filled for all start states at once, ``(roots, options, ...)``."""
        (n_root, d), n_opt = states.shape, len(self.options)
        scores = np.full((n_root, n_opt), np.nan)
        spreads = np.full((n_root, n_opt), np.nan)
        disagreements = np.full((n_root, n_opt), np.nan)
        end_states = np.full((n_root, n_opt, self.samples, d), np.nan)
        steps = np.zeros((n_root, n_opt, self.samples), dtype=np.int64)
        shares = None if self.constraint is None else np.full((n_root, n_opt), np.nan)
        names = np.empty((n_root, n_opt), dtype=object)  # the best sequences, by name
        names.fill(())  # an option not admissible: no sequence
        if tree is not None:
            first = tree.levels[0]
            at = (first.parents, first.options)
            scores[at] = tree.values
            end_states[at] = first.end_states
            steps[at] = first.steps
            # follow every level-1 branch down its best children to its best leaf
            branch = np.arange(len(first.options))
            path = [first.options]
            for k, child in enumerate(tree.best):
                branch = np.where(branch >= 0, child[np.maximum(branch, 0)], -1)
                path.append(np.where(branch >= 0, tree.levels[k + 1].options[branch], -1))
            done = branch >= 0
            leaf_at = (first.parents[done], first.options[done])
            spreads[leaf_at] = tree.leaf.spreads[branch[done]]
            disagreements[leaf_at] = tree.leaf.disagreements[branch[done]]
            if shares is not None and tree.leaf.unsafe_shares is not None:
                shares[leaf_at] = tree.leaf.unsafe_shares[branch[done]]
            # name each distinct sequence once, then place the names by fancy indexing
            # a sequence as one integer: option + 1 per level in base options + 1
            code = np.zeros(len(first.options), dtype=np.int64)
            for level_options in reversed(path):
                code = code * (n_opt + 1) + level_options + 1
            sequences, which = np.unique(code, return_inverse=True)
            option_names = self.option_names
            named = np.empty(len(sequences), dtype=object)
            for k, c in enumerate(sequences.tolist()):  # element by element: a tuple
                seq = []  # is one object
                while c:
                    c, digit = divmod(c, n_opt + 1)
                    if digit:
                        seq.append(option_names[digit - 1])
                named[k] = tuple(seq)
            names[first.parents, first.options] = named[which.reshape(-1)]
        best = np.argmax(np.where(may_run.T, np.nan_to_num(scores, nan=-np.inf), -np.inf),
                         axis=1)
        option_names = self.option_names
        plans = []
        for r in range(n_root):
            chosen: int | None = int(best[r])
            floor: float | None = None
            if not may_run[:, r].any() or scores[r, best[r]] == -np.inf:
                chosen = None
            elif self.fallback_must_gain and self._falls_back(states[r], running[r]):
                # a fallback is a way on, not a way back (OptionPlanner's rule)
                here = float(self.goal.mean_std(states[r][None])[0][0])
                if scores[r, best[r]] < here:
                    chosen, floor = None, here
            plans.append(Plan(option_names, may_run[:, r], scores[r], spreads[r],
                              end_states[r], steps[r], chosen, disagreements[r],
                              None if shares is None else shares[r], tuple(names[r].tolist()),
                              gain_floor=floor))
        return plans
