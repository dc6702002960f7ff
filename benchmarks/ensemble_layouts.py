"""Where one step of the ensemble engine spends its time, and how the matrix products'
layout changes their speed.

One thread. All timings of a run are interleaved in ``--rounds`` rounds (each item a
batch of calls per round; the median of its rounds is reported), with a float32
2048 x 2048 ``torch.mm`` as the GEMM reference of the same run.

- ``layer``: each layer of the default MLP (12 -> 160 -> 160 -> 24) on one planner step
  of the benchmark's depth-1 decision (4 options x 4 members = 16 blocks of 16 rows), as
  ``baddbmm`` (bias added inside the product, from a ``(blocks, 1, out)`` bias), ``bmm``
  without a bias (a bound), ``bmm`` on inputs with a column of ones and the bias as one
  more weight row (``folded``; for the hidden layer also with its output written into
  a view of a buffer that has the next layer's column of ones), and a loop of ``addmm``
  over the 16 blocks.
- ``level2``: the three layers and their SiLU on one step of the depth-2 benchmark's
  second level (16 sequences x 32 samples, 4 members): a block per branch and member
  (64 blocks of 8 rows, each option's weights copied per branch) against a block per
  option and member (16 blocks of 32 rows).
- ``step``: one step of :class:`~dynoplan.models.ensemble_rollouts.StackedMLPEnsemble`
  at depth 1, and its parts: the SiLU calls, the float32 noise draw of ``numpy`` (the
  engine's, 3072 values; and the 20 steps' values in one call) and, for comparison,
  torch's ``normal_`` on the same buffer.

Run ``python benchmarks/ensemble_layouts.py`` (``--json`` for one JSON object).
"""

import argparse
import json
import sys
import time
from collections.abc import Callable, Sequence
from functools import partial

import numpy as np
import torch
from torch.nn import functional as F

from dynoplan.models.neural_dynamics import MLPEnsembleDynamics

D, H, E = 12, 160, 4
GEMM_SIZE = 2048
HORIZON_DRAW = "step: numpy float32 normal, 20 steps in one call, per step"


def _blocks(groups: int, rows: int, fan_in: int, fan_out: int,
            gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Inputs ``(groups, rows, in)``, weights ``(groups, in, out)``, biases
    ``(groups, 1, out)``, at the scale of the default initialisation."""
    x = torch.randn(groups, rows, fan_in, generator=gen)
    w = torch.randn(groups, fan_in, fan_out, generator=gen) / (2 * fan_in ** 0.5)
    return x, w, torch.randn(groups, 1, fan_out, generator=gen)


def _addmm_loop(blocks: Sequence[tuple[torch.Tensor, ...]]) -> None:
    for bias, x, w, out in blocks:
        torch.addmm(bias, x, w, out=out)


def layer_items(gen: torch.Generator) -> tuple[dict[str, Callable[[], object]], dict[str, float]]:
    """The per-layer variants at depth-1 blocks, and their FLOPs."""
    items: dict[str, Callable[[], object]] = {}
    flops: dict[str, float] = {}
    for fan_in, fan_out in [(D, H), (H, H), (H, 2 * D)]:
        x, w, b = _blocks(16, 16, fan_in, fan_out, gen)
        out = torch.empty(16, 16, fan_out)
        ones = torch.cat([x, torch.ones(16, 16, 1)], dim=2)
        wb = torch.cat([w, b], dim=1)
        per = [(b[g], x[g], w[g], out[g]) for g in range(16)]
        name = f"layer {fan_in}->{fan_out}"
        variants: dict[str, Callable[[], object]] = {
            "baddbmm": partial(torch.baddbmm, b, x, w, out=out),
            "bmm": partial(torch.bmm, x, w, out=out),
            "folded": partial(torch.bmm, ones, wb, out=out),
            "addmm loop": partial(_addmm_loop, per),
        }
        if fan_in == fan_out == H:  # a hidden output would need its own column of ones
            with_ones = torch.ones(16, 16, fan_out + 1)
            variants["folded, output into a view"] = partial(torch.bmm, ones, wb,
                                                             out=with_ones[..., :fan_out])
        for kind, fn in variants.items():
            items[f"{name} {kind}"] = fn
            flops[f"{name} {kind}"] = 2.0 * 16 * 16 * fan_in * fan_out
    return items, flops


def level2_items(gen: torch.Generator) -> tuple[dict[str, Callable[[], object]], float]:
    """One step's MLP (products and SiLU) of the depth-2 level, in the two layouts."""
    sizes = [(D, H), (H, H), (H, 2 * D)]
    layers = [_blocks(E * 4, 8, a, b, gen)[1:] for a, b in sizes]  # 4 options' members
    per_branch = [(w.repeat(4, 1, 1), b.repeat(4, 1, 1)) for w, b in layers]
    x = torch.randn(64, 8, D, generator=gen)
    grouped = x.reshape(4, 16, 8, D).transpose(0, 1).reshape(16, 32, D).contiguous()

    def mlp(h: torch.Tensor, params: Sequence[tuple[torch.Tensor, torch.Tensor]]) -> None:
        for i, (w, b) in enumerate(params):
            h = torch.baddbmm(b, h, w)
            if i < len(params) - 1:
                F.silu(h, inplace=True)

    flops = 2.0 * 512 * sum(a * b for a, b in sizes)
    return ({"level2 block per branch (64 x 8)": lambda: mlp(x, per_branch),
             "level2 block per option (16 x 32)": lambda: mlp(grouped, layers)}, flops)


def step_items(gen: torch.Generator) -> dict[str, Callable[[], object]]:
    """One engine step at depth 1 and the parts outside its matrix products."""
    models = [MLPEnsembleDynamics(D, (H, H), E, seed=k) for k in range(4)]
    engine = MLPEnsembleDynamics.stack(models)
    sampler = engine.block_sampler(64, np.random.default_rng(0))  # type: ignore[attr-defined]
    start = np.random.default_rng(1).normal(size=(4, 64, D))
    rng = np.random.default_rng(2)
    noise = np.empty((16, 16, D), dtype=np.float32)
    horizon = np.empty((20, 16, 16, D), dtype=np.float32)
    noise_t = torch.empty(16, 16, D)
    torch_gen = torch.Generator().manual_seed(0)
    hidden, src = torch.empty(16, 16, H), torch.randn(16, 16, H, generator=gen)

    def engine_step() -> None:
        sampler.start(start)  # from the same states every time
        sampler.advance()

    return {"step: engine (start + advance)": engine_step,
            "step: start alone": lambda: sampler.start(start),
            "step: copy + SiLU": lambda: F.silu(hidden.copy_(src), inplace=True),
            "step: copy": lambda: hidden.copy_(src),
            "step: numpy float32 normal (3072)": lambda: rng.standard_normal(
                dtype=np.float32, out=noise),
            HORIZON_DRAW: lambda: rng.standard_normal(
                dtype=np.float32, out=horizon),
            "step: torch normal_ (3072)": lambda: noise_t.normal_(generator=torch_gen)}


def measure(items: dict[str, Callable[[], object]], rounds: int,
            seconds: float) -> dict[str, float]:
    """Median over ``rounds`` of each item's time per call (s), items interleaved."""
    calls = {}
    for name, fn in items.items():  # warm up, and size each batch to about ``seconds``
        start = time.perf_counter()
        for _ in range(5):
            fn()
        calls[name] = max(1, int(seconds / max((time.perf_counter() - start) / 5, 1e-7)))
    times: dict[str, list[float]] = {name: [] for name in items}
    for _ in range(rounds):
        for name, fn in items.items():
            start = time.perf_counter()
            for _ in range(calls[name]):
                fn()
            times[name].append((time.perf_counter() - start) / calls[name])
    return {name: float(np.median(v)) for name, v in times.items()}


def run(rounds: int, seconds: float) -> dict[str, object]:
    torch.set_num_threads(1)
    gen = torch.Generator().manual_seed(0)
    a, b = torch.randn(GEMM_SIZE, GEMM_SIZE, generator=gen), torch.randn(GEMM_SIZE, GEMM_SIZE,
                                                                       generator=gen)
    c = torch.empty(GEMM_SIZE, GEMM_SIZE)
    layers, flops = layer_items(gen)
    level2, level2_flops = level2_items(gen)
    items = {"gemm": lambda: torch.mm(a, b, out=c), **layers, **level2, **step_items(gen)}
    flops.update({k: level2_flops for k in level2}, gemm=2.0 * GEMM_SIZE ** 3)
    with torch.inference_mode():
        times = measure(items, rounds, seconds)
    times[HORIZON_DRAW] /= 20
    gemm = flops["gemm"] / times["gemm"]
    return {"gemm_gflops": gemm / 1e9, "torch_threads": torch.get_num_threads(),
            "us": {k: 1e6 * v for k, v in times.items() if k != "gemm"},
            "gemm_fraction": {k: flops[k] / times[k] / gemm for k in flops if k != "gemm"}}


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--seconds", type=float, default=0.05,
                        help="time per item per round (about)")
    args = parser.parse_args(argv)
    result = run(args.rounds, args.seconds)
    if args.json:
        print(json.dumps(result))
        return 0
    print(f"GEMM {GEMM_SIZE} float32: {result['gemm_gflops']:.1f} GFLOP/s, "
          f"{result['torch_threads']} thread")
    fractions: dict[str, float] = result["gemm_fraction"]  # type: ignore[assignment]
    times: dict[str, float] = result["us"]  # type: ignore[assignment]
    width = max(len(name) for name in times)
    for name, us in times.items():
        share = f"  {fractions[name]:.2f} of GEMM" if name in fractions else ""
        print(f"{name:<{width}} {us:8.1f} us{share}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
