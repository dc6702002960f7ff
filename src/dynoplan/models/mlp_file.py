"""Writing and reading the linear layers of an :class:`~dynoplan.models.mlp.MLP` in model
files (:mod:`dynoplan.models.storage`).

A file holds one weight and one bias float32 array per linear layer, named
``weight_i`` and ``bias_i`` (``i`` from 0) unless the model kind names them otherwise,
with the shapes of the layer's parameters: ``(fan_out, fan_in)`` and ``(fan_out,)`` for
a single network, ``(members, fan_in, fan_out)`` and ``(members, 1, fan_out)`` for an
ensemble. The metadata lists ``hidden_sizes`` and the activation. Every check failure is
one :class:`~dynoplan.errors.DynoplanError` line.
"""

import os
from collections.abc import Sequence
from itertools import pairwise
from typing import Any

import numpy as np
import torch

from dynoplan.errors import DynoplanError
from dynoplan.models.mlp import MLP
from dynoplan.models.storage import require_finite


def check_parameter_count(path: str | os.PathLike[str], arrays: dict[str, np.ndarray],
                          sizes: Sequence[int], members: int = 1) -> None:
    """Refuse metadata that describes a network larger than its file, before the network
    is built.

    Every parameter of an MLP with layer widths ``sizes`` (input, hidden..., output) and
    ``members`` ensemble members is read from the file, so a forged ``hidden_sizes`` (or
    state size, or member count) would otherwise allocate memory without bound. A network
    of more than twice the values the file holds is refused here, so a file never makes
    dynoplan allocate much more than its own size; a smaller mismatch is reported array by
    array when the weights are read (:func:`load_linears`).

    Raises:
        DynoplanError: one line naming the file, the widths and both counts.
    """
    needed = members * sum((a + 1) * b for a, b in pairwise(sizes))
    stored = sum(int(a.size) for a in arrays.values())
    if needed > 2 * stored:
        raise DynoplanError(f"{path}: metadata describes a network of {needed} parameters "
                            f"(layer widths {list(sizes)}, {members} member(s)) but the file "
                            f"holds only {stored} values")


def hidden_sizes(meta: dict[str, Any], path: str | os.PathLike[str]) -> list[int]:
    """The metadata's ``hidden_sizes`` (a non-empty list of positive integers), after
    checking that the activation is SiLU (the only one there is; absent means SiLU)."""
    hidden = meta.get("hidden_sizes")
    if (not isinstance(hidden, list) or not hidden
            or not all(isinstance(h, int) and not isinstance(h, bool) and h >= 1
                       for h in hidden)):
        raise DynoplanError(f"{path}: metadata field 'hidden_sizes' must be a non-empty "
                            f"list of positive integers, got {hidden!r}")
    if meta.get("activation", "silu") != "silu":
        raise DynoplanError(f"{path}: activation {meta.get('activation')!r} is not "
                            "supported (expected 'silu')")
    return hidden


def linear_arrays(mlp: MLP, weight: str = "weight_{}", bias: str = "bias_{}",
                  first: int = 0) -> dict[str, np.ndarray]:
    """Copies of the layers' weights and biases, named ``weight.format(i)`` and
    ``bias.format(i)`` for layer ``i - first``, in layer order (weight before bias)."""
    arrays: dict[str, np.ndarray] = {}
    for i, (w, b) in enumerate(zip(mlp.weights, mlp.biases, strict=True), start=first):
        arrays[weight.format(i)] = w.detach().numpy().copy()
        arrays[bias.format(i)] = b.detach().numpy().copy()
    return arrays


def load_linears(mlp: MLP, arrays: dict[str, np.ndarray], path: str | os.PathLike[str],
                 weight: str = "weight_{}", bias: str = "bias_{}", first: int = 0) -> set[str]:
    """Copy the arrays named as by :func:`linear_arrays` into ``mlp``'s layers after
    checking that each is finite float32 of the parameter's shape; return the names
    read."""
    read: set[str] = set()
    with torch.no_grad():
        for i, (w, b) in enumerate(zip(mlp.weights, mlp.biases, strict=True), start=first):
            for name, param in ((weight.format(i), w), (bias.format(i), b)):
                a = require_finite(arrays, name, tuple(param.shape), np.float32, path)
                param.copy_(torch.from_numpy(a))
                read.add(name)
    return read


__all__ = ["check_parameter_count", "hidden_sizes", "linear_arrays", "load_linears",
           "require_finite"]
