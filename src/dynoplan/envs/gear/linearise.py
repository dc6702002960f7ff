"""A function of the six joints of one arm, linearised about a joint vector by central
differences, with the linearisations kept for reuse (:func:`linearised`)."""

from collections.abc import Callable

import numpy as np

from dynoplan.types import FloatArray

STEP = 1e-3
"""The central differences' step (rad)."""


def linearised(fn: Callable[[FloatArray], FloatArray], q0: FloatArray,
               cache: dict[bytes, tuple[FloatArray, FloatArray]], limit: int
               ) -> tuple[FloatArray, FloatArray]:
    """``(fn(q0), J)``: the value ``(3,)`` of ``fn`` at the joints ``q0`` ``(6,)`` and its
    Jacobian ``(3, 6)`` by central differences of :data:`STEP`, from ``cache`` (keyed by
    ``q0``'s bytes) when it holds them; a new pair is stored, after clearing ``cache`` when
    it holds more than ``limit``."""
    key = q0.tobytes()
    hit = cache.get(key)
    if hit is None:
        if len(cache) > limit:
            cache.clear()
        jacobian = np.empty((3, 6))
        for j in range(6):
            dq = np.zeros(6)
            dq[j] = STEP
            jacobian[:, j] = (fn(q0 + dq) - fn(q0 - dq)) / (2 * STEP)
        hit = cache[key] = (fn(q0), jacobian)
    return hit
