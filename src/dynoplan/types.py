"""Array type aliases used across the library.

Shapes are written in docstrings as tuples of named axes, for example
``(options, samples, state_dim)``. States are always ``float64`` in the planner's
numpy code; neural models convert to ``float32`` internally.
"""

from typing import TypeAlias

import numpy as np
import numpy.typing as npt

FloatArray: TypeAlias = npt.NDArray[np.float64]
IntArray: TypeAlias = npt.NDArray[np.int64]
BoolArray: TypeAlias = npt.NDArray[np.bool_]
Generator: TypeAlias = np.random.Generator
