"""The batched rollout engine of the ensemble dynamics: many options' ensembles, one program.

:class:`StackedMLPEnsemble` advances ``(options, samples, d)`` states of several
ensembles of one architecture by one step, each given as its :class:`EnsembleLayers`
(:meth:`~dynoplan.models.neural_dynamics.MLPEnsembleDynamics.sampling_layers`). Their
weights are stacked to ``(options * members, in, out)`` and every layer is one
``torch.baddbmm`` over ``(options * members, rows_per_member, in)``. Inside, everything
is float32 with the normalisation folded into the first and last layers; states come in
and go out as float64.

Sampling (``D_w``) has two modes. A rollout of the planner keeps one member for its whole
length (PETS's TS-infinity, :meth:`StackedMLPEnsemble.trajectory_sampler`): the spread of
the futures then shows the members' disagreement, not just their average. A single
``sample`` call propagates like mbrl-lib's ``random_model`` / PETS's TS1. In both, the
rows are split across the members by a random permutation (drawn once per batch of
rollouts, or at every ``sample`` call),
in groups of equal size (``ceil(batch / members)`` slots each; when ``members`` does not
divide ``batch`` a random rotation decides which members get the extra rows). Each row
therefore uses a member that is uniform over the ensemble, and each member runs on one
dense block of rows, so the whole ensemble is one batched matrix product per layer with
no wasted rows. (Unlike drawing the member of every row independently, the number of
rows per member is fixed; the per-row distribution is the same.) The next state is
``s + mu_k(s) + sigma_k(s) * eps`` with ``eps ~ N(0, I)`` drawn from the caller's
``numpy.random.Generator``; the torch global random state is never used.
"""

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch.nn import functional as F

from dynoplan.types import FloatArray, Generator

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
    """Several options' ensembles of one architecture as one float32 tensor program.

    ``sample(states, rng)`` maps ``(options, samples, d)`` float64 to the same shape;
    slice ``o`` follows option ``o``'s model, with the same distribution as calling
    ``models[o].sample(states[o], rng)``. Per call: a random permutation of every
    option's rows, the rows gathered into ``(options * members, ceil(samples / members),
    d)`` blocks (one block per member), one ``baddbmm`` per layer with the weights stacked
    to ``(options * members, in, out)``, Gaussian noise, and the rows put back in order.
    The object keeps the weights it was built with.

    Attributes:
        rows_computed: member-forward rows evaluated so far (including padding slots
            when ``members`` does not divide ``samples``); for FLOP counts.
    """

    def __init__(self, models: Sequence[EnsembleLayers]) -> None:
        if not models or len({m.architecture for m in models}) != 1:
            raise ValueError("stacked ensembles must be non-empty and share one architecture")
        self.options = len(models)
        self.members = models[0].members
        self.state_dim = models[0].state_dim
        self.groups = self.options * self.members
        self.rows_computed = 0
        e = self.members
        self._weights, self._biases = _folded_layers(models)

        def per_group(rows: list[np.ndarray]) -> np.ndarray:
            return np.repeat(np.stack(rows), e, axis=0)[:, None, :]  # (groups, 1, d)

        lo = per_group([m.min_logvar for m in models])
        hi = per_group([m.max_logvar for m in models])
        log_sd = per_group([m.log_std for m in models])
        # logvar = lo + softplus((hi - lo) - softplus(hi - raw)), and in state units
        # sigma = exp(0.5 * logvar + log(delta_std)) = exp(0.5 * softplus(.) + offset)
        self._max_logvar = torch.from_numpy(hi.astype(np.float32))
        self._logvar_span = torch.from_numpy((hi - lo).astype(np.float32))
        self._log_std_offset = torch.from_numpy((0.5 * lo + log_sd).astype(np.float32))
        self._layouts: dict[int, _Layout] = {}

    def sample(self, states: FloatArray, rng: Generator) -> FloatArray:
        """``(options, samples, d)`` float64 -> next states, same shape, float64."""
        states = np.asarray(states, dtype=np.float64)
        o, s, d = states.shape
        if o != self.options or d != self.state_dim:
            raise ValueError(f"states must be ({self.options}, samples, {self.state_dim}), "
                             f"got {states.shape}")
        lay = self._layout(s)
        return self._sample(states, lay, *lay.draw(rng), rng)

    def trajectory_sampler(self, samples: int, rng: Generator) -> Callable[[FloatArray],
                                                                              FloatArray]:
        """A step function for one batch of rollouts of ``samples`` rows per option that
        keeps every row on one ensemble member (drawn now, uniform over the members) for
        as many steps as it is called: ``(options, samples, d) -> same shape``. The
        Gaussian noise is fresh at every step."""
        lay = self._layout(samples)
        gather, scatter = lay.draw(rng)
        o, d = self.options, self.state_dim
        # the member of every rollout: slot p of the blocks belongs to member (p // m) % e
        member = np.empty(lay.result_rows, dtype=np.int64)
        member[scatter] = (np.arange(len(scatter)) // lay.slots) % self.members

        def step(states: FloatArray) -> FloatArray:
            x = np.asarray(states, dtype=np.float64)
            if x.shape != (o, samples, d):
                raise ValueError(f"states must be {(o, samples, d)}, got {x.shape}")
            return self._sample(x, lay, gather, scatter, rng)
        return MemberStep(step, member[:o * samples].reshape(o, samples))

    def _layout(self, samples: int) -> "_Layout":
        lay = self._layouts.get(samples)
        if lay is None:
            if len(self._layouts) >= _MAX_LAYOUTS:
                del self._layouts[next(iter(self._layouts))]
            widths = [w.shape[2] for w in self._weights]
            lay = self._layouts[samples] = _Layout(self.options, self.members, samples,
                                                   self.state_dim, widths)
        return lay

    def block_sampler(self, samples: int, rng: Generator) -> "BlockSampler":
        """:meth:`trajectory_sampler` in the engine's own row order: the caller keeps the
        rollouts' states as ``(options, slots, d)`` blocks (:class:`BlockSampler`), so a
        step neither gathers nor scatters rows. The same draws from ``rng`` as
        :meth:`trajectory_sampler` and the same next state of every rollout."""
        lay = self._layout(samples)
        gather, scatter = lay.draw(rng)
        return BlockSampler(self, lay, gather, scatter, rng)

    def _sample(self, states: FloatArray, lay: "_Layout", gather: np.ndarray,
                scatter: np.ndarray, rng: Generator) -> FloatArray:
        o, s, d = states.shape
        np.take(states.reshape(o * s, d), gather, axis=0, out=lay.x64)
        lay.x32_np[...] = lay.x64_blocks
        self._forward(lay, rng)
        result = np.empty((lay.result_rows, d))
        result[scatter] = lay.next_np
        return result[:o * s].reshape(o, s, d)

    def _forward(self, lay: "_Layout", rng: Generator) -> None:
        """``lay.next`` from ``lay.x32``: one draw of every block row's next state."""
        d = self.state_dim
        rng.standard_normal(dtype=np.float32, out=lay.noise_np)  # (groups, slots, d)
        with torch.inference_mode():
            x = lay.x32
            h = x
            for i in range(len(self._weights) - 1):
                h = torch.baddbmm(self._biases[i], h, self._weights[i], out=lay.hidden[i])
                F.silu(h, inplace=True)
            out = torch.baddbmm(self._biases[-1], h, self._weights[-1], out=lay.hidden[-1])
            t = F.softplus(torch.sub(self._max_logvar, out[..., d:], out=lay.tmp))
            t = F.softplus(torch.sub(self._logvar_span, t, out=lay.tmp))
            std = torch.add(self._log_std_offset, t, alpha=0.5, out=lay.tmp).exp_()
            nxt = torch.addcmul(x, std, lay.noise, out=lay.next)
            nxt.add_(out[..., :d])
        self.rows_computed += self.groups * lay.slots


class BlockSampler:
    """One batch of rollouts of a :class:`StackedMLPEnsemble`, each kept on one member,
    in the engine's block order.

    Option ``o``'s rollouts live in ``slots = members * ceil(samples / members)``
    places; place ``j`` holds sample row ``rows[o, j]`` and is run by member
    ``members[o, j]``. Where ``members`` does not divide ``samples``, the places with
    ``real[o, j]`` False are padding (they hold a copy of row 0; their results mean
    nothing). ``self(states)`` maps ``(options, slots, d)`` states (any float dtype) to
    the next states, a float32 ``(options, slots, d)`` array that the next call
    overwrites.

    Attributes:
        rows: ``(options, slots)`` the sample row of every place.
        real: ``(options, slots)`` False at padding places.
        members: ``(options, slots)`` the member of every place.
    """

    def __init__(self, engine: StackedMLPEnsemble, lay: "_Layout", gather: np.ndarray,
                 scatter: np.ndarray, rng: Generator) -> None:
        o, s = engine.options, lay.samples
        self._engine, self._lay, self._rng = engine, lay, rng
        self.slots = engine.members * lay.slots
        base = (np.arange(o) * s)[:, None]
        self.rows = gather.reshape(o, self.slots) - base
        self.real = scatter.reshape(o, self.slots) < o * s
        self.members = np.broadcast_to(
            (np.arange(self.slots) // lay.slots)[None, :], (o, self.slots))
        self._x32 = lay.x32_np.reshape(o, self.slots, engine.state_dim)
        self._next = lay.next_np.reshape(o, self.slots, engine.state_dim)

    def __call__(self, states: np.ndarray) -> np.ndarray:
        self._x32[...] = states
        self._engine._forward(self._lay, self._rng)
        return self._next


class _Layout:
    """Work buffers and the random row-to-member assignment for one ``samples`` size.

    Rows are taken in a random order (a permutation per option); position ``p`` of that
    order goes to member ``(p + c) % members`` (slot ``p // members``), where the
    rotation ``c`` is uniform (it only matters when ``members`` does not divide
    ``samples``): every row's member is uniform over the ensemble and every member gets
    ``ceil(samples / members)`` or one fewer rows. ``widths`` are the layers' output
    widths.
    """

    def __init__(self, options: int, members: int, samples: int, d: int,
                 widths: Sequence[int]) -> None:
        self.options, self.members, self.samples = options, members, samples
        e = members
        m = self.slots = -(-samples // members)
        self.padded = e * m != samples
        n_slots = options * e * m
        # a padded slot computes on a copy of a real row and writes to an extra result row
        self.result_rows = options * samples + int(self.padded)
        self._row_base = (np.arange(options) * samples)[:, None]
        if self.padded:
            rot = np.arange(e)[:, None, None]
            # [c, e * m + j] -> position read by member e's slot j, or ``samples`` (padding)
            pos = (np.arange(e)[None, :, None] - rot) % e + e * np.arange(m)[None, None, :]
            self._pos_of_slot = np.where(pos < samples, pos, samples).reshape(e, e * m)
            self._ext_base = (np.arange(options) * (samples + 1))[:, None]
            self._gather_ext = np.empty((options, samples + 1), dtype=np.intp)
            self._scatter_ext = np.empty((options, samples + 1), dtype=np.intp)
            self._gather_ext[:, samples] = self._row_base[:, 0]  # padding reads row 0
            self._scatter_ext[:, samples] = options * samples  # ... and writes the extra row
        self.x64 = np.empty((n_slots, d))
        self.x64_blocks = self.x64.reshape(options * e, m, d)
        self.x32_np = np.empty((options * e, m, d), dtype=np.float32)
        self.x32 = torch.from_numpy(self.x32_np)
        self.hidden = [torch.empty(options * e, m, w) for w in widths]
        self.tmp = torch.empty(options * e, m, d)
        self.next = torch.empty(options * e, m, d)
        self.noise_np = np.empty((options * e, m, d), dtype=np.float32)  # drawn in place
        self.noise = torch.from_numpy(self.noise_np)
        self.next_np = self.next.numpy().reshape(n_slots, d)

    def draw(self, rng: Generator) -> tuple[np.ndarray, np.ndarray]:
        """A fresh assignment: for every block slot, ``(options * members * slots,)``, the
        state row it reads and the result row it writes."""
        o, e, s = self.options, self.members, self.samples
        if not self.padded:
            rows = np.argsort(rng.random((o, s)), axis=1)
            rows += self._row_base
            flat = rows.reshape(-1)  # member k of option o takes positions k*m .. k*m+m-1
            return flat, flat
        u = rng.random((o, s + 1))
        rows = np.argsort(u[:, :s], axis=1)
        rows += self._row_base
        self._gather_ext[:, :s] = rows
        self._scatter_ext[:, :s] = rows
        c = (u[:, s] * e).astype(np.intp)  # rotation of every option
        idx = self._pos_of_slot[c] + self._ext_base
        return (np.take(self._gather_ext, idx).reshape(-1),
                np.take(self._scatter_ext, idx).reshape(-1))


def _folded_layers(models: Sequence[EnsembleLayers]) -> tuple[list[torch.Tensor],
                                                              list[torch.Tensor]]:
    """Stack the members of all models to ``(options * members, in, out)`` float32 (the
    float64 folded layers rounded once)."""
    return ([torch.from_numpy(np.concatenate(w).astype(np.float32))
             for w in zip(*(m.weights for m in models), strict=True)],
            [torch.from_numpy(np.concatenate(b).astype(np.float32))
             for b in zip(*(m.biases for m in models), strict=True)])


__all__ = ["BlockSampler", "EnsembleLayers", "MemberStep", "StackedMLPEnsemble"]
