"""Model files that are safe to open: safetensors arrays plus JSON metadata, no pickle.

Every model file is one ``.safetensors`` file whose header metadata holds a JSON
document ``{"kind": ..., "format_version": ..., ...}``. Loading checks the kind and the
version and turns any unreadable, truncated or mismatched file into one
:class:`~dynoplan.errors.DynoplanError` line.
"""

import json
import os
from pathlib import Path
from typing import Any

import numpy as np
from safetensors import safe_open
from safetensors.numpy import save_file

from dynoplan.errors import DynoplanError
from dynoplan.io import atomic_path
from dynoplan.types import FloatArray

FORMAT_VERSION = 1
_META_KEY = "dynoplan"


def save_arrays(
    path: str | os.PathLike[str], kind: str, arrays: dict[str, np.ndarray], meta: dict[str, Any]
) -> Path:
    """Write ``arrays`` and ``meta`` (JSON-serialisable) to ``path`` atomically."""
    header = {"kind": kind, "format_version": FORMAT_VERSION, **meta}
    contiguous = {name: np.ascontiguousarray(a) for name, a in arrays.items()}
    with atomic_path(path) as tmp:
        save_file(contiguous, str(tmp), metadata={_META_KEY: json.dumps(header)})
    return Path(path)


def load_arrays(
    path: str | os.PathLike[str], kind: str
) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Read a file written by :func:`save_arrays` and check that it holds a ``kind`` model.

    Raises:
        DynoplanError: missing, truncated or corrupt file, another kind of model, or a
            newer format version.
    """
    file = Path(path)
    if not file.is_file():
        raise DynoplanError(f"{file}: model file not found")
    try:
        with safe_open(str(file), framework="numpy") as f:
            raw_meta = (f.metadata() or {}).get(_META_KEY)
            arrays = {name: f.get_tensor(name) for name in f.keys()}  # noqa: SIM118
    except Exception as exc:  # safetensors raises its own error types for corrupt files
        raise DynoplanError(f"{file}: not a readable model file ({exc})") from None
    if raw_meta is None:
        raise DynoplanError(f"{file}: no dynoplan metadata in the file header")
    try:
        meta = json.loads(raw_meta)
    except json.JSONDecodeError:
        raise DynoplanError(f"{file}: metadata is not valid JSON") from None
    if meta.get("kind") != kind:
        raise DynoplanError(f"{file}: holds a '{meta.get('kind')}' model, expected '{kind}'")
    version = meta.get("format_version")
    if not isinstance(version, int) or version > FORMAT_VERSION:
        raise DynoplanError(
            f"{file}: format_version {version!r} is not supported (this dynoplan reads "
            f"<= {FORMAT_VERSION})"
        )
    return arrays, meta


def as_states(states: FloatArray, state_dim: int) -> FloatArray:
    """``states`` as a float64 ``(batch, state_dim)`` array, or one clear error."""
    x = np.asarray(states, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != state_dim:
        raise DynoplanError(f"states must have shape (batch, {state_dim}), got {x.shape}")
    return x


def require(arrays: dict[str, np.ndarray], name: str, shape: tuple[int | None, ...],
            file: str | os.PathLike[str]) -> np.ndarray:
    """Return ``arrays[name]`` after checking its shape (``None`` matches any size)."""
    if name not in arrays:
        raise DynoplanError(f"{file}: array '{name}' is missing")
    a = arrays[name]
    if a.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, a.shape,
                                                                             strict=True)):
        raise DynoplanError(f"{file}: array '{name}' has shape {a.shape}, expected {shape}")
    return a


def require_finite(arrays: dict[str, np.ndarray], name: str, shape: tuple[int | None, ...],
                   dtype: type | None, path: str | os.PathLike[str]) -> np.ndarray:
    """A copy of ``arrays[name]`` after checking its shape, its dtype (``None``: any
    floating-point type) and that every value is finite: a NaN or infinite weight is
    refused at load, whatever checksum the manifest records."""
    a = require(arrays, name, shape, path)
    if (a.dtype != dtype) if dtype is not None else not np.issubdtype(a.dtype, np.floating):
        raise DynoplanError(f"{path}: array '{name}' has dtype {a.dtype}, expected "
                            f"{'a floating-point type' if dtype is None else np.dtype(dtype)}")
    if not np.all(np.isfinite(a)):
        raise DynoplanError(f"{path}: array '{name}' must be finite, it holds NaN or infinity")
    return a.copy()


__all__ = ["FORMAT_VERSION", "as_states", "load_arrays", "require", "require_finite",
           "save_arrays"]
