"""Reading small torch MLPs back from model files (:mod:`dynoplan.models.storage`).

A file holds ``weight_i`` ``(fan_out, fan_in)`` and ``bias_i`` ``(fan_out,)`` float32
arrays per linear layer, and its metadata lists ``hidden_sizes`` and the activation.
Every check failure is one :class:`~dynoplan.errors.DynoplanError` line.
"""

import os
from collections.abc import Sequence
from itertools import pairwise
from typing import Any

import numpy as np

from dynoplan.errors import DynoplanError
from dynoplan.models.storage import require


def require_finite(arrays: dict[str, np.ndarray], name: str, shape: tuple[int | None, ...],
                   dtype: type, path: str | os.PathLike[str]) -> np.ndarray:
    """A copy of ``arrays[name]`` after checking its shape, its dtype and that every value
    is finite."""
    a = require(arrays, name, shape, path)
    if a.dtype != dtype:
        raise DynoplanError(f"{path}: array '{name}' has dtype {a.dtype}, expected "
                            f"{np.dtype(dtype)}")
    if not np.all(np.isfinite(a)):
        raise DynoplanError(f"{path}: array '{name}' holds NaN or infinity")
    return a.copy()


def hidden_sizes(meta: dict[str, Any], path: str | os.PathLike[str]) -> list[int]:
    """The metadata's ``hidden_sizes`` (a non-empty list of positive integers), after
    checking that the activation is SiLU."""
    hidden = meta.get("hidden_sizes")
    if (not isinstance(hidden, list) or not hidden
            or not all(isinstance(h, int) and not isinstance(h, bool) and h >= 1
                       for h in hidden)):
        raise DynoplanError(f"{path}: metadata field 'hidden_sizes' must be a non-empty "
                            f"list of positive integers, got {hidden!r}")
    if meta.get("activation") != "silu":
        raise DynoplanError(f"{path}: activation {meta.get('activation')!r} is not "
                            "supported (expected 'silu')")
    return hidden


def load_linears(linears: Sequence[Any], sizes: Sequence[int], arrays: dict[str, np.ndarray],
                 path: str | os.PathLike[str]) -> set[str]:
    """Copy ``weight_i`` and ``bias_i`` into ``linears`` (torch ``nn.Linear`` layers of
    ``sizes[i] -> sizes[i + 1]``); return the names of the arrays read."""
    import torch

    read: set[str] = set()
    with torch.no_grad():
        for i, (layer, (fan_in, fan_out)) in enumerate(zip(linears, pairwise(sizes),
                                                           strict=True)):
            w = require_finite(arrays, f"weight_{i}", (fan_out, fan_in), np.float32, path)
            b = require_finite(arrays, f"bias_{i}", (fan_out,), np.float32, path)
            layer.weight.copy_(torch.from_numpy(w))
            layer.bias.copy_(torch.from_numpy(b))
            read |= {f"weight_{i}", f"bias_{i}"}
    return read


__all__ = ["hidden_sizes", "load_linears", "require_finite"]
