"""The batched rollout engine of the ensemble dynamics: many options' ensembles, one program.

:class:`StackedMLPEnsemble` advances ``(branches, samples, d)`` states by one step, where
branch ``b`` follows one of several ensembles of one architecture (given as
:class:`EnsembleLayers`, :meth:`~dynoplan.models.neural_dynamics.MLPEnsembleDynamics.
sampling_layers`); several branches may follow the same ensemble (a level of the
sequence planner continues every rollout with every option). Each distinct ensemble's
weights are stacked once, to ``(models * members, in, out)``, and every layer is one
batched matrix product over ``(models * members, rows, in)``: the rows of a member are
the slots of that member in every branch that follows its ensemble. Inside, everything
is float32 with the normalisation folded into the first and last layers (and the first
layer's bias into its weights, against a column of ones); states come in and go out as
float64.

Sampling (``D_w``) has two modes. A rollout of the planner keeps one member for its whole
length (PETS's TS-infinity, :meth:`StackedMLPEnsemble.trajectory_sampler`): the spread of
the futures then shows the members' disagreement, not just their average. A single
``sample`` call propagates like mbrl-lib's ``random_model`` / PETS's TS1. In both, the
rows of each branch are split across the members by a random permutation (drawn once per
batch of rollouts, or at every ``sample`` call), in groups of equal size
(``ceil(samples / members)`` slots each; when ``members`` does not divide ``samples`` a
random rotation decides which members get the extra rows). Each row therefore uses a
member that is uniform over the ensemble, and each member runs on one dense block of
rows, so the whole stack is one batched matrix product per layer. (Unlike drawing the
member of every row independently, the number of rows per member is fixed; the per-row
distribution is the same.) The next state is ``s + mu_k(s) + sigma_k(s) * eps`` with
``eps ~ N(0, I)`` drawn from the caller's ``numpy.random.Generator`` (float32, one
``(branches, members, slots, d)`` array per step, in that order); the torch global
random state is never used.
"""

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch.nn import functional as F

from dynoplan.types import FloatArray, Generator, IntArray

_MAX_LAYOUTS = 8  # work-buffer sets kept per stack (one per batch size seen, newest kept)


@dataclass(frozen=True)
class EnsembleLayers:
    """One ensemble's sampling parameters, float64, on states in state units.

    Attributes:
        weights: per layer, ``(members, in, out)``; the input normalisation is folded
            into the first layer and the mean part of the output denormalisation into
            the last (outputs: ``d`` state changes, then ``d`` raw log-variances).
        biases: per layer, ``(members, 1, out)``, folded as the weights.
        min_logvar, max_logvar: ``(d,)``, the soft bounds of the normalised log-variance.
        log_std: ``(d,)``, log of the factor from normalised to state-unit standard
            deviations (the target normalisation times any calibration).
    """

    weights: tuple[FloatArray, ...]
    biases: tuple[FloatArray, ...]
    min_logvar: FloatArray
    max_logvar: FloatArray
    log_std: FloatArray

    @property
    def members(self) -> int:
        return int(self.weights[0].shape[0])

    @property
    def state_dim(self) -> int:
        return int(self.weights[0].shape[1])

    @property
    def architecture(self) -> tuple[int, tuple[int, ...], int]:
        """``(state_dim, hidden_sizes, members)``: layers that stack together share it."""
        return (self.state_dim, tuple(int(w.shape[2]) for w in self.weights[:-1]),
                self.members)


class MemberStep:
    """A rollout step function ``(options, samples, d) -> same shape`` that keeps every
    rollout on one ensemble member, and says which: ``members`` ``(options, samples)``,
    the member index of each rollout (for the planner's epistemic term)."""

    def __init__(self, step: Callable[[FloatArray], FloatArray], members: np.ndarray) -> None:
        self._step = step
        self.members = members

    def __call__(self, states: FloatArray) -> FloatArray:
        return self._step(states)


class StackedMLPEnsemble:
    """Several branches' ensembles of one architecture as one float32 tensor program.

    ``sample(states, rng)`` maps ``(branches, samples, d)`` float64 to the same shape;
    slice ``b`` follows ``models[branches[b]]``, with the same distribution as calling
    ``models[branches[b]].sample(states[b], rng)``. Per call: a random permutation of
    every branch's rows, the rows gathered into one block per member of every model
    (``(models * members, rows, d)``, ``rows = ceil(samples / members)`` times the most
    branches any model has), one matrix product per layer, Gaussian noise, and the rows
    put back in order. The object keeps the weights it was built with.

    Args:
        models: the distinct ensembles, of one architecture.
        branches: ``(branches,)`` the model each stacked slice follows (default: slice
            ``k`` follows ``models[k]``).

    Attributes:
        models: the number of distinct ensembles.
        branches: ``(branches,)`` as given; ``options`` is their number (the stacked
            slices).
        rows_computed: member-forward rows evaluated so far (including padding rows);
            for FLOP counts.
    """

    def __init__(self, models: Sequence[EnsembleLayers],
                 branches: Sequence[int] | None = None) -> None:
        if not models or len({m.architecture for m in models}) != 1:
            raise ValueError("stacked ensembles must be non-empty and share one architecture")
        self.models = len(models)
        self.branches: IntArray = np.arange(self.models) if branches is None \
            else np.asarray(branches, dtype=np.int64).reshape(-1)
        if len(self.branches) == 0 or self.branches.min() < 0 \
                or self.branches.max() >= self.models:
            raise ValueError(f"branches must name models 0 .. {self.models - 1}")
        self.options = len(self.branches)
        self.members = models[0].members
        self.state_dim = models[0].state_dim
        self.rows_computed = 0
        self._first, self._weights, self._biases = _folded_layers(models)
        e = self.members

        def per_group(rows: list[np.ndarray]) -> torch.Tensor:  # (models * members, 1, d)
            return torch.from_numpy(np.repeat(np.stack(rows), e, axis=0)[:, None, :]
                                    .astype(np.float32))

        lo = [m.min_logvar for m in models]
        hi = [m.max_logvar for m in models]
        # logvar = lo + softplus((hi - lo) - softplus(hi - raw)), and in state units
        # sigma = exp(0.5 * logvar + log(delta_std)) = exp(0.5 * softplus(.) + offset)
        self._max_logvar = per_group(hi)
        self._logvar_span = per_group([h - low for h, low in zip(hi, lo, strict=True)])
        self._log_std_offset = per_group([0.5 * low + m.log_std
                                          for low, m in zip(lo, models, strict=True)])
        self._layouts: dict[int, _Layout] = {}

    def sample(self, states: FloatArray, rng: Generator) -> FloatArray:
        """``(branches, samples, d)`` float64 -> next states, same shape, float64."""
        states = np.asarray(states, dtype=np.float64)
        o, s, d = states.shape
        if o != self.options or d != self.state_dim:
            raise ValueError(f"states must be ({self.options}, samples, {self.state_dim}), "
                             f"got {states.shape}")
        lay = self._layout(s)
        return self._sample(states, lay, *lay.draw(rng), rng)

    def trajectory_sampler(self, samples: int, rng: Generator) -> Callable[[FloatArray],
                                                                              FloatArray]:
        """A step function for one batch of rollouts of ``samples`` rows per branch that
        keeps every row on one ensemble member (drawn now, uniform over the members) for
        as many steps as it is called: ``(branches, samples, d) -> same shape``. The
        Gaussian noise is fresh at every step."""
        lay = self._layout(samples)
        gather, scatter = lay.draw(rng)
        o, d = self.options, self.state_dim
        member = np.empty(lay.result_rows, dtype=np.int64)
        member[scatter] = lay.member_of_row

        def step(states: FloatArray) -> FloatArray:
            x = np.asarray(states, dtype=np.float64)
            if x.shape != (o, samples, d):
                raise ValueError(f"states must be {(o, samples, d)}, got {x.shape}")
            return self._sample(x, lay, gather, scatter, rng)
        return MemberStep(step, member[:o * samples].reshape(o, samples))

    def block_sampler(self, samples: int, rng: Generator) -> "BlockSampler":
        """:meth:`trajectory_sampler` in the engine's own row order: the caller keeps the
        rollouts' states as ``(models, places, d)`` blocks (:class:`BlockSampler`), so a
        step neither gathers nor scatters rows. The same draws from ``rng`` as
        :meth:`trajectory_sampler` and the same next state of every rollout."""
        lay = self._layout(samples)
        return BlockSampler(self, lay, *lay.draw(rng), rng)

    def _layout(self, samples: int) -> "_Layout":
        lay = self._layouts.get(samples)
        if lay is None:
            if len(self._layouts) >= _MAX_LAYOUTS:
                del self._layouts[next(iter(self._layouts))]
            widths = [self._first.shape[2], *(w.shape[2] for w in self._weights)]
            lay = self._layouts[samples] = _Layout(self.branches, self.models, self.members,
                                                   samples, self.state_dim, widths)
        return lay

    def _sample(self, states: FloatArray, lay: "_Layout", gather: np.ndarray,
                scatter: np.ndarray, rng: Generator) -> FloatArray:
        o, s, d = states.shape
        own = lay.states
        own.array[...] = np.take(states.reshape(o * s, d), gather, axis=0).reshape(
            own.array.shape)
        self._forward(lay, own, rng)
        result = np.empty((lay.result_rows, d))
        result[scatter] = own.array.reshape(-1, d)
        return result[:o * s].reshape(o, s, d)

    def _forward(self, lay: "_Layout", states: "_States", rng: Generator) -> None:
        """One draw of every block row's next state, in place of ``states``."""
        with torch.inference_mode():
            h = torch.bmm(states.x, self._first, out=lay.hidden[0])  # the bias: x's ones
            F.silu(h, inplace=True)
            for i in range(len(self._weights) - 1):
                h = torch.baddbmm(self._biases[i], h, self._weights[i], out=lay.hidden[i + 1])
                F.silu(h, inplace=True)
            torch.baddbmm(self._biases[-1], h, self._weights[-1], out=lay.hidden[-1])
            # the noise now, not first: its buffer is still in cache for the tail
            rng.standard_normal(dtype=np.float32, out=lay.noise_drawn)  # in the draw order
            lay.gather_noise()
            std = lay.tmp  # the bounded log-variance, then sigma, in place; softplus
            # takes ``out`` (aten's softplus.out), which torch's stubs do not list
            F.softplus(torch.sub(self._max_logvar, lay.raw_logvar, out=std), out=std)  # type: ignore[call-arg]
            F.softplus(torch.sub(self._logvar_span, std, out=std), out=std)  # type: ignore[call-arg]
            torch.add(self._log_std_offset, std, alpha=0.5, out=std).exp_()
            torch.addcmul(states.state, std, lay.noise, out=states.state).add_(lay.mean_change)
        self.rows_computed += states.x.shape[0] * states.x.shape[1]


class BlockSampler:
    """One batch of rollouts of a :class:`StackedMLPEnsemble`, each kept on one member,
    in the engine's block order.

    The rollouts of every branch that follows model ``k`` live in slice ``k`` of
    ``(models, places, d)`` arrays, member by member (``places = members * rows``).
    Place ``j`` of slice ``k`` holds sample ``rows[k, j]`` of branch ``branches[k, j]``
    and is run by member ``members[k, j]``; places with ``real[k, j]`` False are
    padding (a member's slot left over when ``members`` does not divide ``samples``, or
    a model with fewer branches than another): their results mean nothing.

    The sampler keeps the states itself (its own float32 buffer): :meth:`start` sets
    them, and every call of :meth:`advance` moves every place one step on from where the
    last one left it (a caller that stops some rollouts simply ignores their further
    states, which therefore cost no copy).

    Attributes:
        branches, rows, members: ``(models, places)`` int64, see above.
        real: ``(models, places)`` bool, False at padding places.
    """

    def __init__(self, engine: StackedMLPEnsemble, lay: "_Layout", gather: np.ndarray,
                 scatter: np.ndarray, rng: Generator) -> None:
        self._engine, self._lay, self._rng = engine, lay, rng
        shape = (engine.models, -1)
        s = lay.samples
        self.branches = (gather // s).reshape(shape)
        self.rows = (gather % s).reshape(shape)
        self.real = (scatter < engine.options * s).reshape(shape)
        self.members = np.broadcast_to(lay.member_of_row.reshape(shape), self.real.shape)
        self._states = _States(lay.groups, lay.rows, engine.state_dim)  # its own
        self._state = self._states.array.reshape(engine.models, -1, engine.state_dim)

    def start(self, states: np.ndarray) -> None:
        """Set the states of every place, ``(models, places, d)`` (any float dtype)."""
        self._state[...] = states

    def advance(self) -> np.ndarray:
        """One step of every place: the new states, a float32 ``(models, places, d)``
        view of the sampler's own states (the next call changes it)."""
        self._engine._forward(self._lay, self._states, self._rng)
        return self._state


class _States:
    """Rollout states in block order, float32: ``x`` ``(groups, rows, d + 1)`` with a
    last column of ones (the first layer's bias is its last weight row), ``state`` its
    first ``d`` columns (a view) and ``array`` the same as a numpy view."""

    def __init__(self, groups: int, rows: int, d: int) -> None:
        self.x = torch.ones(groups, rows, d + 1)
        self.state = self.x[..., :d]
        self.array = self.x.numpy()[..., :d]


class _Layout:
    """Work buffers and the random row-to-member assignment for one ``samples`` size.

    Draw order: the rows of branch ``b`` are taken in a random order (a permutation per
    branch); position ``p`` of that order goes to member ``(p + c) % members`` (slot
    ``p // members``), where the rotation ``c`` is uniform (it only matters when
    ``members`` does not divide ``samples``): every row's member is uniform over the
    ensemble and every member gets ``slots = ceil(samples / members)`` or one fewer
    rows. A place of the draw order is ``(branch, member, slot)``.

    Block order (the matrix products'): ``(models * members, depth * slots)``, where
    ``depth`` is the most branches that follow one model: group ``k * members + e``
    holds member ``e``'s slots of every branch of model ``k``, branch by branch in the
    branches' order; a model with fewer branches leaves padding rows at the end.
    ``widths`` are the layers' output widths.
    """

    def __init__(self, branches: IntArray, models: int, members: int, samples: int, d: int,
                 widths: Sequence[int]) -> None:
        o, e = len(branches), members
        self.options, self.members, self.samples = o, e, samples
        m = self.slots = -(-samples // members)
        self.padded = e * m != samples
        self.result_rows = o * samples + 1  # padding writes to the extra last row
        self._row_base = (np.arange(o) * samples)[:, None]
        if self.padded:
            self._init_rotations()
        self.order = _block_order(branches, models, e, m)  # block row -> draw place, or -1
        groups = self.groups = models * e
        rows = self.rows = len(self.order) // groups
        self.member_of_row = (np.arange(len(self.order)) // rows) % e
        self.states = _States(groups, rows, d)  # for ``sample`` and ``trajectory_sampler``
        self.hidden = [torch.empty(groups, rows, w) for w in widths]
        self.mean_change, self.raw_logvar = self.hidden[-1][..., :d], self.hidden[-1][..., d:]
        self.tmp = torch.empty(groups, rows, d)
        self._init_noise(d)

    def _init_rotations(self) -> None:
        """The tables of :meth:`_draw_places` where ``members`` does not divide
        ``samples``."""
        o, e, m, s = self.options, self.members, self.slots, self.samples
        rot = np.arange(e)[:, None, None]
        # [c, e * m + j] -> position read by member e's slot j, or ``samples`` (padding)
        pos = (np.arange(e)[None, :, None] - rot) % e + e * np.arange(m)[None, None, :]
        self._pos_of_slot = np.where(pos < s, pos, s).reshape(e, e * m)
        self._ext_base = (np.arange(o) * (s + 1))[:, None]
        self._gather_ext = np.empty((o, s + 1), dtype=np.intp)
        self._scatter_ext = np.empty((o, s + 1), dtype=np.intp)
        self._gather_ext[:, s] = self._row_base[:, 0]  # padding reads row 0
        self._scatter_ext[:, s] = o * s  # ... and writes the extra row

    def _init_noise(self, d: int) -> None:
        """``noise_drawn`` ``(branches * members, slots, d)`` float32, filled in the draw
        order, and ``noise``, the same values in the block order (the same memory where
        the two orders agree)."""
        self.noise_drawn = np.empty((self.options * self.members, self.slots, d),
                                    dtype=np.float32)
        n = len(self.order)
        self._in_order = n == self.noise_drawn.size // d and bool(
            (self.order == np.arange(n)).all())
        self.noise = torch.from_numpy(self.noise_drawn).view(self.groups, self.rows, d) \
            if self._in_order else torch.empty(self.groups, self.rows, d)
        self._noise_rows = self.noise.numpy().reshape(-1, d)
        self._noise_index = np.maximum(self.order, 0)

    def gather_noise(self) -> None:
        """``noise`` (block order) from ``noise_drawn`` (draw order)."""
        if not self._in_order:
            np.take(self.noise_drawn.reshape(-1, self.noise_drawn.shape[-1]),
                    self._noise_index, axis=0, out=self._noise_rows)

    def draw(self, rng: Generator) -> tuple[np.ndarray, np.ndarray]:
        """A fresh assignment: for every block row, ``(models * members * rows,)``, the
        state row it reads and the result row it writes."""
        gather, scatter = self._draw_places(rng)
        if self._in_order:
            return gather, scatter
        index = np.maximum(self.order, 0)
        pad = self.order < 0  # padding rows read row 0 and write the extra row
        return (np.where(pad, 0, gather[index]),
                np.where(pad, self.result_rows - 1, scatter[index]))

    def _draw_places(self, rng: Generator) -> tuple[np.ndarray, np.ndarray]:
        """The assignment in the draw order, ``(branches * members * slots,)``."""
        o, e, s = self.options, self.members, self.samples
        if not self.padded:
            rows = np.argsort(rng.random((o, s)), axis=1)
            rows += self._row_base
            flat = rows.reshape(-1)  # member k of branch b takes positions k*m .. k*m+m-1
            return flat, flat
        u = rng.random((o, s + 1))
        rows = np.argsort(u[:, :s], axis=1)
        rows += self._row_base
        self._gather_ext[:, :s] = rows
        self._scatter_ext[:, :s] = rows
        c = (u[:, s] * e).astype(np.intp)  # rotation of every branch
        idx = self._pos_of_slot[c] + self._ext_base
        return (np.take(self._gather_ext, idx).reshape(-1),
                np.take(self._scatter_ext, idx).reshape(-1))


def _block_order(branches: IntArray, models: int, members: int, slots: int) -> IntArray:
    """``(models * members * depth * slots,)``: the draw place (``(branch * members +
    member) * slots + slot``) of every block row, ``-1`` at padding rows; ``depth`` is
    the most branches of one model (see :class:`_Layout`)."""
    order = np.argsort(branches, kind="stable")  # branches grouped by model, in order
    counts = np.bincount(branches, minlength=models)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    depth = int(counts.max())
    of = np.full((models, depth), -1, dtype=np.int64)  # [model, p]: its p-th branch
    of[branches[order], np.arange(len(order)) - starts[branches[order]]] = order
    b = of[:, None, :, None]
    place = (b * members + np.arange(members)[None, :, None, None]) * slots \
        + np.arange(slots)[None, None, None, :]
    out: IntArray = np.where(b >= 0, place, -1).reshape(-1)
    return out


def _folded_layers(models: Sequence[EnsembleLayers]) -> tuple[torch.Tensor, list[torch.Tensor],
                                                              list[torch.Tensor]]:
    """Stack the members of all models to ``(models * members, in, out)`` float32 (the
    float64 folded layers rounded once): the first layer with its bias as one more input
    row ``(models * members, in + 1, out)``, then the other layers' weights and biases."""
    weights = [np.concatenate(w).astype(np.float32)
               for w in zip(*(m.weights for m in models), strict=True)]
    biases = [np.concatenate(b).astype(np.float32)
              for b in zip(*(m.biases for m in models), strict=True)]
    first = torch.from_numpy(np.concatenate([weights[0], biases[0]], axis=1))
    return (first, [torch.from_numpy(w) for w in weights[1:]],
            [torch.from_numpy(b) for b in biases[1:]])


__all__ = ["BlockSampler", "EnsembleLayers", "MemberStep", "StackedMLPEnsemble"]
