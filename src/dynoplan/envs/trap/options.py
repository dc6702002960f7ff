"""The trap walk's three options and their models (exact: the known answer is the
planner's, not a model's).

- ``forward``: step right until ``beta = 0.1`` fires (on the main lane it stops
  advancing at the wall);
- ``back``: step left until ``beta = 0.5`` fires;
- ``detour``: step left to the gate, then switch to the bypass; it ends on the bypass
  (``beta = 1`` there) and may start only on the main lane.

Their dynamics models are the environment's closed loops under the options' policies
(:class:`TrapDynamics`, the slip included); the goal heuristic is progress along the
corridor, ``G(s) = x / length``, with no noise (:class:`CorridorProgress`).
"""

from collections.abc import Sequence
from typing import Any

import numpy as np

from dynoplan.envs.trap.env import LEFT, RIGHT, SWITCH
from dynoplan.options.initiation import Everywhere, InitiationFromCallable
from dynoplan.options.option import FunctionPolicy, Option
from dynoplan.types import FloatArray, Generator, IntArray

FORWARD, BACK, DETOUR = 0, 1, 2
OPTION_NAMES = ("forward", "back", "detour")


class TrapDynamics:
    """``D_w`` of a trap-walk option: states ``(..., 2)`` = ``[position, lane]``.

    Args:
        kind: ``FORWARD``, ``BACK`` or ``DETOUR``.
        length, wall, gate, slip: the environment's (:class:`TrapWalkEnv`).
    """

    def __init__(self, kind: int, length: int = 20, wall: int = 8, gate: int = 4,
                 slip: float = 0.1) -> None:
        if kind not in (FORWARD, BACK, DETOUR):
            raise ValueError(f"unknown trap-walk option kind {kind}")
        self.kind = np.asarray(kind)
        self.length, self.wall, self.gate, self.slip = length, wall, gate, float(slip)

    @property
    def state_dim(self) -> int:
        return 2

    def sample(self, states: FloatArray, rng: Generator) -> FloatArray:
        """``(..., 2)`` -> ``(..., 2)``: one draw of the next state per row."""
        return self._step(states, self.kind, rng)

    @classmethod
    def stack(cls, items: Sequence["TrapDynamics"]) -> "TrapDynamics":
        """One model over ``(options, samples, 2)``: option ``o`` follows ``items[o]``."""
        first = items[0]
        stacked = cls(FORWARD, first.length, first.wall, first.gate, first.slip)
        if any((m.length, m.wall, m.gate, m.slip) != (first.length, first.wall, first.gate,
                                                       first.slip) for m in items):
            raise ValueError("stacked trap-walk models must share the corridor")
        stacked.kind = np.array([int(m.kind) for m in items])[:, None]  # (options, 1)
        return stacked

    def sample_rows(self, states: FloatArray, branches: IntArray,
                    rng: Generator) -> FloatArray:
        """``(rows, 2)`` -> ``(rows, 2)``; row ``i`` follows option ``branches[i]`` of a
        stack."""
        return self._step(states, self.kind.reshape(-1)[branches], rng)

    def _step(self, states: FloatArray, kind: np.ndarray, rng: Generator) -> FloatArray:
        x, lane = states[..., 0], states[..., 1]
        at_gate = x <= self.gate
        # the policy's action in every row (the detour: left to the gate, then across)
        action = np.where(kind == FORWARD, RIGHT,
                          np.where(kind == BACK, LEFT,
                                   np.where(at_gate & (lane == 0), SWITCH, LEFT)))
        action = np.broadcast_to(action, x.shape)
        moves = rng.random(x.shape) >= self.slip
        blocked = (lane == 0) & (x >= self.wall)
        nx = np.where(action == LEFT, np.maximum(x - 1, 0),
                      np.where((action == RIGHT) & moves & ~blocked, x + 1, x))
        nlane = np.where((action == SWITCH) & at_gate, 1 - lane, lane)
        out = np.stack([nx, nlane], axis=-1)
        np.copyto(out, states, where=(x >= self.length)[..., None])  # the goal is absorbing
        return out


BETAS = {FORWARD: 0.1, BACK: 0.5}


class TrapTermination:
    """``beta_w`` of a trap-walk option: 0.1 (``forward``), 0.5 (``back``), and for the
    ``detour`` 1 on the bypass lane, else 0; ``(..., 2)`` -> ``(...)``."""

    def __init__(self, kind: int) -> None:
        self.kind = np.asarray(kind)

    def probability(self, states: FloatArray) -> FloatArray:
        constant = np.where(self.kind == FORWARD, BETAS[FORWARD], BETAS[BACK])
        detour = (states[..., 1] == 1).astype(np.float64)
        out: FloatArray = np.where(self.kind == DETOUR, detour, constant)
        return np.broadcast_to(out, states.shape[:-1])

    def probability_rows(self, states: FloatArray, branches: IntArray) -> FloatArray:
        """``(rows, 2)`` -> ``(rows,)``; row ``i`` follows option ``branches[i]``."""
        rows = TrapTermination(FORWARD)
        rows.kind = self.kind.reshape(-1)[branches]
        return rows.probability(states)

    @classmethod
    def stack(cls, items: Sequence["TrapTermination"]) -> "TrapTermination":
        """One termination over ``(options, samples, 2)``."""
        stacked = cls(FORWARD)
        stacked.kind = np.array([int(t.kind) for t in items])[:, None]  # (options, 1)
        return stacked


class CorridorProgress:
    """``G(s) = x / length``: progress along the corridor, exact (a point mass)."""

    def __init__(self, length: int = 20) -> None:
        self.length = int(length)

    def sample(self, states: FloatArray, rng: Generator) -> FloatArray:
        """``(batch, 2)`` -> ``(batch,)`` in ``[0, 1]``."""
        return np.clip(states[..., 0] / self.length, 0.0, 1.0)

    def mean_std(self, states: FloatArray) -> tuple[FloatArray, FloatArray]:
        g = self.sample(states, np.random.default_rng(0))
        return g, np.zeros_like(g)


def _policy(kind: int, gate: int) -> FunctionPolicy:
    def act(obs: Any, _rng: Generator) -> int:
        x, lane = int(obs[0]), int(obs[1])
        if kind == FORWARD:
            return RIGHT
        if kind == BACK or x > gate or lane == 1:
            return LEFT
        return SWITCH

    return FunctionPolicy(act)


def make_trap_options(length: int = 20, wall: int = 8, gate: int = 4,
                      slip: float = 0.1) -> list[Option]:
    """``forward``, ``back`` and ``detour`` with exact models of the corridor."""
    def model(kind: int) -> TrapDynamics:
        return TrapDynamics(kind, length, wall, gate, slip)

    on_main_lane = InitiationFromCallable(lambda s: s[..., 1] == 0)
    return [
        Option("forward", _policy(FORWARD, gate), model(FORWARD), TrapTermination(FORWARD)),
        Option("back", _policy(BACK, gate), model(BACK), TrapTermination(BACK)),
        Option("detour", _policy(DETOUR, gate), model(DETOUR), TrapTermination(DETOUR),
               initiation=on_main_lane, continuation=Everywhere()),
    ]
