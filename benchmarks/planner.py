"""Decision latency of the option planner (Eq. 1) over neural ensemble dynamics.

Setup (the library defaults): 4 options, each with an untrained, seeded
``MLPEnsembleDynamics`` of the default size on a 12-dimensional state, constant
termination ``beta = 0`` (every rollout runs the full horizon, so every decision does the
same work), a fixed linear-sigmoid goal heuristic, and
``OptionPlanner(options, goal, horizon=20, samples=64)``.

Measured in one run, interleaved in rounds so that all numbers see the same (noisy,
shared) machine:

- ``planner.plan(state, rng)`` latency: p50 / p99 over ``--repeats`` decisions, after a
  warm-up;
- the same decision done naively (for every option, every sample, every step: the model
  on a batch of one row, a termination draw, then the goal on the end state), on
  ``--loop-repeats`` decisions: ``batched_vs_loop = loop median / batched p50``;
- the FLOP/s of a 2048 x 2048 float32 ``torch.mm`` with the same torch thread count
  (median), and the planner's achieved FLOP/s: MLP forward FLOPs per decision
  (``2 * in * out`` per layer per computed row, every row the ensembles compute) over the
  p50 decision time. ``gemm_fraction = achieved / GEMM``.

``--depth 2`` times :class:`~dynoplan.planning.SequencePlanner` instead: every option,
then every option again from each rollout's end (16 sequences of the 4 options), with
``--samples`` (default 32 at depth 2) rollouts per sequence and ``--horizon`` (default 10
at depth 2) steps per option; the naive loop is timed at depth 1 only.

Run ``python benchmarks/planner.py`` for a table, ``--json`` for one JSON object.
"""

import argparse
import json
import os
import platform
import sys
import time
from collections.abc import Callable, Sequence

import numpy as np
import torch

from dynoplan.models.neural_dynamics import DEFAULT_HIDDEN, DEFAULT_MEMBERS, MLPEnsembleDynamics
from dynoplan.options import ConstantTermination, FunctionPolicy, Option
from dynoplan.planning import OptionPlanner, SequencePlanner
from dynoplan.types import FloatArray, Generator

STATE_DIM = 12
OPTIONS = 4
SAMPLES = 64
HORIZON = 20
BETA = 0.0
GEMM_SIZE = 2048


class LinearSigmoidGoal:
    """``G(s) = sigmoid(w . s + b + noise * z)``, ``z ~ N(0, 1)``: a fixed goal heuristic."""

    def __init__(self, weights: FloatArray, bias: float = 0.0, noise: float = 0.1) -> None:
        self.weights = np.asarray(weights, dtype=np.float64)
        self.bias = float(bias)
        self.noise = float(noise)
        # Gauss-Hermite nodes for E[sigmoid(a + noise z)]
        self._nodes, w = np.polynomial.hermite_e.hermegauss(21)
        self._node_weights = w / w.sum()

    def sample(self, states: FloatArray, rng: Generator) -> FloatArray:
        """``(batch, d)`` -> ``(batch,)`` draws in ``[0, 1]``."""
        a = states @ self.weights + self.bias
        return _sigmoid(a + self.noise * rng.standard_normal(a.shape))

    def mean_std(self, states: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Mean and standard deviation per state, ``(batch,)`` each (quadrature)."""
        a = states @ self.weights + self.bias
        g = _sigmoid(a[:, None] + self.noise * self._nodes[None, :])
        mean = g @ self._node_weights
        var = (g * g) @ self._node_weights - mean * mean
        return mean, np.sqrt(np.maximum(var, 0.0))


def _sigmoid(x: FloatArray) -> FloatArray:
    return 0.5 * (1.0 + np.tanh(0.5 * x))


def build(hidden: Sequence[int], members: int, seed: int, depth: int = 1,
          samples: int = SAMPLES, horizon: int = HORIZON
          ) -> tuple[OptionPlanner, list[Option], LinearSigmoidGoal]:
    """The benchmark's planner: 4 options with untrained ensembles, seeded (depth 1:
    :class:`OptionPlanner`; more: :class:`SequencePlanner`)."""
    options = [
        Option(f"option_{k}", FunctionPolicy(lambda obs, rng: None),
               MLPEnsembleDynamics(STATE_DIM, hidden, members, option=f"option_{k}",
                                   seed=seed + k),
               ConstantTermination(BETA))
        for k in range(OPTIONS)
    ]
    goal = LinearSigmoidGoal(np.random.default_rng(seed).normal(size=STATE_DIM)
                             / np.sqrt(STATE_DIM))
    if depth == 1:
        return OptionPlanner(options, goal, horizon=horizon, samples=samples), options, goal
    return (SequencePlanner(options, goal, horizon=horizon, samples=samples, depth=depth),
            options, goal)


def naive_decision(options: Sequence[Option], goal: LinearSigmoidGoal, state: FloatArray,
                   rng: Generator) -> int:
    """The planner's decision with a Python loop per option, sample and step (batch of 1)."""
    scores = np.empty(len(options))
    for k, option in enumerate(options):
        total = 0.0
        for _ in range(SAMPLES):
            x = state[None].copy()
            for _ in range(HORIZON):
                nxt = option.dynamics.sample(x, rng)
                if not np.isfinite(nxt).all():
                    break
                x = nxt
                if rng.random() < option.termination.probability(x)[0]:
                    break
            total += float(goal.sample(x, rng)[0])
        scores[k] = total / SAMPLES
    return int(np.argmax(scores))


def _time(fn: Callable[[], object], repeats: int) -> list[float]:
    out = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        out.append(time.perf_counter() - start)
    return out


def gemm_seconds(n: int, repeats: int) -> list[float]:
    """Times of ``repeats`` float32 ``n x n`` matrix products (after one warm-up)."""
    gen = torch.Generator().manual_seed(0)
    a, b = torch.randn(n, n, generator=gen), torch.randn(n, n, generator=gen)
    c = torch.empty(n, n)
    with torch.inference_mode():
        torch.mm(a, b, out=c)
        return _time(lambda: torch.mm(a, b, out=c), repeats)


def profile_breakdown(planner: OptionPlanner, state: FloatArray, rng: Generator,
                      decisions: int = 50) -> dict[str, float]:
    """Where a decision's time goes (ms per decision), from ``torch.profiler``.

    ``matmul`` is the ensembles' ``bmm`` and ``baddbmm`` calls (the counted FLOPs),
    ``silu`` the activations, ``other_torch`` every other torch op (log-variance bounds,
    noise scaling, bias copies), ``numpy_python`` the rest of the wall time (random
    draws, gathers, the planner's bookkeeping, the goal heuristic, interpreter overhead).
    """
    from torch.profiler import ProfilerActivity, profile

    with profile(activities=[ProfilerActivity.CPU]) as prof:
        start = time.perf_counter()
        for _ in range(decisions):
            planner.plan(state, rng)
        wall = (time.perf_counter() - start) * 1e3 / decisions
    self_ms: dict[str, float] = {}
    for event in prof.key_averages():
        self_ms[event.key] = event.self_cpu_time_total / 1e3 / decisions
    matmul = self_ms.get("aten::baddbmm", 0.0) + self_ms.get("aten::bmm", 0.0)
    silu = self_ms.get("aten::silu_", 0.0)
    torch_total = sum(self_ms.values())
    return {"profile_wall_ms": wall, "profile_matmul_ms": matmul, "profile_silu_ms": silu,
            "profile_other_torch_ms": torch_total - matmul - silu,
            "profile_numpy_python_ms": wall - torch_total}


def run(repeats: int, loop_repeats: int, rounds: int, threads: int, hidden: Sequence[int],
        members: int, seed: int, with_profile: bool = False, depth: int = 1,
        samples: int = SAMPLES, horizon: int = HORIZON) -> dict[str, object]:
    """Measure everything in one process; returns the results as a flat dict."""
    torch.set_num_threads(threads)
    planner, options, goal = build(hidden, members, seed, depth, samples, horizon)
    if depth > 1:
        loop_repeats = 0  # the naive loop is Eq. 1's (depth 1)
    state = np.zeros(STATE_DIM)
    rng = np.random.default_rng(seed)
    for _ in range(20):  # warm-up: buffers, allocator, thread pool
        plan = planner.plan(state, rng)
    if not (plan.steps == horizon).all():
        raise RuntimeError("rollouts stopped early; the FLOP count assumes full horizons")
    if loop_repeats:
        naive_decision(options, goal, state, rng)

    decisions: list[float] = []
    loops: list[float] = []
    gemms: list[float] = []
    per_round = max(1, repeats // rounds)
    loops_per_round = -(-loop_repeats // rounds) if loop_repeats else 0
    for r in range(rounds):
        gemms += gemm_seconds(GEMM_SIZE, 5)
        decisions += _time(lambda: planner.plan(state, rng), per_round)
        if loop_repeats and r * loops_per_round < loop_repeats:
            loops += _time(lambda: naive_decision(options, goal, state, rng), loops_per_round)
    gemms += gemm_seconds(GEMM_SIZE, 5)

    model = options[0].dynamics
    assert isinstance(model, MLPEnsembleDynamics)
    slots = -(-samples // members)
    branches = sum(OPTIONS ** k for k in range(1, depth + 1))  # every level's sequences
    rows_per_decision = branches * members * slots * horizon
    flops_per_decision = rows_per_decision * model.flops_per_row()
    breakdown = profile_breakdown(planner, state, rng) if with_profile else {}
    p50, p99 = float(np.percentile(decisions, 50)), float(np.percentile(decisions, 99))
    loop = float(np.median(loops)) if loops else None
    gemm_flops = 2.0 * GEMM_SIZE ** 3 / float(np.median(gemms))
    achieved = flops_per_decision / p50
    return {
        "decision_ms_p50": 1e3 * p50,
        "decision_ms_p99": 1e3 * p99,
        "decision_ms_mean": 1e3 * float(np.mean(decisions)),
        "loop_decision_ms_median": None if loop is None else 1e3 * loop,
        "batched_vs_loop": None if loop is None else loop / p50,
        "achieved_gflops": achieved / 1e9,
        "gemm_gflops": gemm_flops / 1e9,
        "gemm_fraction": achieved / gemm_flops,
        "mflop_per_decision": flops_per_decision / 1e6,
        "rows_per_decision": rows_per_decision,
        "options": OPTIONS,
        "depth": depth,
        "sequences": OPTIONS ** depth,
        "samples": samples,
        "horizon": horizon,
        "state_dim": STATE_DIM,
        "hidden_sizes": list(hidden),
        "members": members,
        "beta": BETA,
        "repeats": len(decisions),
        "loop_repeats": len(loops),
        "gemm_size": GEMM_SIZE,
        "gemm_repeats": len(gemms),
        "torch_threads": torch.get_num_threads(),
        "torch_version": torch.__version__,
        "cpu_count": os.cpu_count(),
        "machine": platform.machine(),
        "python": platform.python_version(),
        **breakdown,
    }


def digest(depth: int, samples: int, horizon: int, hidden: Sequence[int], members: int,
           seed: int, decisions: int = 20) -> str:
    """SHA-256 of the scores and end states of ``decisions`` seeded decisions from
    different states: equal digests mean an engine change kept the seeded results."""
    import hashlib

    torch.set_num_threads(1)
    planner, _, _ = build(hidden, members, seed, depth, samples, horizon)
    rng, h = np.random.default_rng(seed), hashlib.sha256()
    for k in range(decisions):
        plan = planner.plan(np.full(STATE_DIM, 0.1 * k), rng)
        h.update(plan.scores.tobytes())
        h.update(plan.end_states.tobytes())
    return h.hexdigest()


def _table(result: dict[str, object]) -> str:
    rows = [
        ("decision latency p50", f"{result['decision_ms_p50']:.2f} ms"),
        ("decision latency p99", f"{result['decision_ms_p99']:.2f} ms"),
        ("naive loop decision (median)", "-" if result["loop_decision_ms_median"] is None
         else f"{result['loop_decision_ms_median']:.0f} ms"),
        ("batched vs loop", "-" if result["batched_vs_loop"] is None
         else f"{result['batched_vs_loop']:.0f}x"),
        ("MLP work per decision", f"{result['mflop_per_decision']:.0f} MFLOP "
                                  f"({result['rows_per_decision']} member rows)"),
        ("achieved", f"{result['achieved_gflops']:.1f} GFLOP/s"),
        (f"GEMM {result['gemm_size']}x{result['gemm_size']} float32",
         f"{result['gemm_gflops']:.1f} GFLOP/s"),
        ("fraction of GEMM", f"{100 * float(result['gemm_fraction']):.0f}%"),  # type: ignore[arg-type]
        ("torch threads", str(result["torch_threads"])),
        ("setup", f"depth {result['depth']} ({result['sequences']} sequences), "
                  f"{result['options']} options x {result['samples']} samples x horizon "
                  f"{result['horizon']}, d={result['state_dim']}, MLP {result['hidden_sizes']}"
                  f" x {result['members']} members"),
        ("decisions timed", f"{result['repeats']} (+ {result['loop_repeats']} naive)"),
    ]
    if "profile_wall_ms" in result:
        rows.append(("profile (ms per decision)",
                     f"wall {result['profile_wall_ms']:.2f} = matmul "
                     f"{result['profile_matmul_ms']:.2f} + silu {result['profile_silu_ms']:.2f}"
                     f" + other torch {result['profile_other_torch_ms']:.2f} + numpy/Python "
                     f"{result['profile_numpy_python_ms']:.2f}"))
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--repeats", type=int, default=300, help="planner decisions timed")
    parser.add_argument("--loop-repeats", type=int, default=3, help="naive decisions timed")
    parser.add_argument("--rounds", type=int, default=5,
                        help="interleaving rounds of GEMM / planner / loop timing")
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads")
    parser.add_argument("--hidden", type=int, nargs="+", default=list(DEFAULT_HIDDEN),
                        help="hidden layer widths")
    parser.add_argument("--members", type=int, default=DEFAULT_MEMBERS, help="ensemble size")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--depth", type=int, default=1,
                        help="options per imagined sequence (2: SequencePlanner)")
    parser.add_argument("--samples", type=int, default=None,
                        help=f"rollouts per option sequence [{SAMPLES}; 32 at depth > 1]")
    parser.add_argument("--horizon", type=int, default=None,
                        help=f"steps per option [{HORIZON}; 10 at depth > 1]")
    parser.add_argument("--digest", action="store_true",
                        help="only print a SHA-256 of 20 seeded decisions (compare engines)")
    parser.add_argument("--profile", action="store_true",
                        help="also split a decision's time with torch.profiler (50 decisions)")
    args = parser.parse_args(argv)
    samples = args.samples or (SAMPLES if args.depth == 1 else 32)
    horizon = args.horizon or (HORIZON if args.depth == 1 else 10)
    if min(args.repeats, args.loop_repeats, args.rounds, args.threads, args.members,
           args.depth, samples, horizon) < 1:
        parser.error("--repeats, --loop-repeats, --rounds, --threads, --members, --depth, "
                     "--samples, --horizon must be >= 1")
    if args.digest:
        print(digest(args.depth, samples, horizon, args.hidden, args.members, args.seed))
        return 0
    result = run(args.repeats, args.loop_repeats, args.rounds, args.threads, args.hidden,
                 args.members, args.seed, args.profile, args.depth, samples, horizon)
    print(json.dumps(result) if args.json else _table(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
