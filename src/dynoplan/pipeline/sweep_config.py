"""The configuration of a sweep (:mod:`dynoplan.pipeline.sweep`; the gear's: ``dynoplan
sweep``): a grid of planner settings, controllers and seeds over one models folder, read
from TOML or JSON.

.. code-block:: toml

    models = "../results/gear/models"  # relative to this file's folder
    episodes = 20                       # per cell
    controller = "dynoplan"             # unless the grid sweeps it
    seed = 0                            # unless the grid sweeps it

    [grid]                              # every combination is one cell
    horizon = [6, 10]
    samples = [32, 64]
    dynamics_noise = [0.0, 0.02]
    seed = [0, 1]

Grid keys: fields of :class:`~dynoplan.pipeline.control_settings.ControllerSettings`
(``horizon``, ``samples``, ``oracle_horizon``, ``oracle_samples``, ``margin``,
``dynamics_noise``, ``epistemic``), ``controller`` (one of the task's controllers) and
``seed``; the settings not swept are the task's. Any mistake is one
:class:`~dynoplan.errors.DynoplanError` naming the file and the field.
"""

import dataclasses
import itertools
import json
import math
import tomllib
from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

from dynoplan.errors import DynoplanError
from dynoplan.limits import CELLS_MAX, EPISODES_MAX, HORIZON_MAX, SAMPLES_MAX, SEED_MAX
from dynoplan.pipeline.control_settings import ControllerSettings

INT_KEYS = ("horizon", "samples", "oracle_horizon", "oracle_samples")
"""Grid keys of positive integers (at most :data:`~dynoplan.limits.HORIZON_MAX` for the
horizons, :data:`~dynoplan.limits.SAMPLES_MAX` for the samples)."""
FLOAT_KEYS = ("margin", "dynamics_noise", "epistemic")
"""Grid keys of non-negative numbers."""
GRID_KEYS = (*INT_KEYS, *FLOAT_KEYS, "controller", "seed")
TOP_KEYS = ("models", "episodes", "controller", "seed", "grid")


@dataclass(frozen=True)
class Cell:
    """One combination of the grid: a controller with planner settings, on the
    ``episodes`` episodes derived from ``seed``."""

    controller: str
    seed: int
    episodes: int
    planner: ControllerSettings

    def settings(self) -> dict[str, Any]:
        """Everything that determines the cell's result, as plain JSON values."""
        return {"controller": self.controller, "seed": self.seed, "episodes": self.episodes,
                **asdict(self.planner)}


@dataclass(frozen=True)
class SweepConfig:
    """A parsed sweep configuration (see the module docstring).

    Attributes:
        path: the file it was read from.
        models: the models folder (resolved against the file's folder).
        episodes: episodes per cell.
        grid: key -> values, in the file's order.
        control: the planner settings the grid changes.
        controller, seed: the values of keys the grid does not sweep.
    """

    path: Path
    models: Path
    episodes: int
    grid: tuple[tuple[str, tuple[Any, ...]], ...]
    control: ControllerSettings = dataclasses.field(default_factory=ControllerSettings)
    controller: str = "dynoplan"
    seed: int = 0

    @property
    def swept(self) -> tuple[str, ...]:
        """The grid's keys, in order."""
        return tuple(k for k, _ in self.grid)

    def cells(self) -> list[Cell]:
        """Every combination, the last key varying fastest."""
        out = []
        for values in itertools.product(*(v for _, v in self.grid)):
            chosen = dict(zip(self.swept, values, strict=True))
            planner = replace(self.control, **{k: v for k, v in chosen.items()
                                                    if k in INT_KEYS + FLOAT_KEYS})
            out.append(Cell(chosen.get("controller", self.controller),
                            chosen.get("seed", self.seed), self.episodes, planner))
        return out


def load_sweep_config(path: Path, controllers: Sequence[str],
                      control: ControllerSettings = ControllerSettings()) -> SweepConfig:
    """Read and check a sweep configuration (``.toml`` or ``.json``) of the controllers
    ``controllers``, whose settings not swept are ``control``.

    Raises:
        DynoplanError: (one line) unreadable file, unknown or missing key, wrong type
            or range of a value (bounds of :mod:`dynoplan.limits`), empty grid or more
            than :data:`~dynoplan.limits.CELLS_MAX` cells.
    """
    raw = _read(path)
    unknown = sorted(set(raw) - set(TOP_KEYS))
    if unknown:
        raise DynoplanError(f"{path}: unknown key(s) {', '.join(unknown)}; expected "
                            f"{', '.join(TOP_KEYS)}")
    models = raw.get("models")
    if not isinstance(models, str) or not models:
        raise DynoplanError(f"{path}: models: expected the models folder (a string)")
    episodes = _integer(path, "episodes", raw.get("episodes", 20), 1, EPISODES_MAX)
    seed = _integer(path, "seed", raw.get("seed", 0), 0, SEED_MAX)
    controller = _controller(path, "controller", raw.get("controller", "dynoplan"),
                             controllers)
    grid = raw.get("grid")
    if not isinstance(grid, dict) or not grid:
        raise DynoplanError(f"{path}: grid: expected a table of key = [values] with at "
                            f"least one of {', '.join(GRID_KEYS)}")
    checked = []
    for key, values in grid.items():
        if key not in GRID_KEYS:
            raise DynoplanError(f"{path}: grid.{key}: unknown key; expected one of "
                                f"{', '.join(GRID_KEYS)}")
        if not isinstance(values, list) or not values:
            raise DynoplanError(f"{path}: grid.{key}: expected a non-empty list of values")
        field = f"grid.{key}"
        if key in INT_KEYS:
            top = HORIZON_MAX if key.endswith("horizon") else SAMPLES_MAX
            vals: tuple[Any, ...] = tuple(_integer(path, field, v, 1, top) for v in values)
        elif key in FLOAT_KEYS:
            vals = tuple(_number(path, field, v) for v in values)
        elif key == "seed":
            vals = tuple(_integer(path, field, v, 0, SEED_MAX) for v in values)
        else:
            vals = tuple(_controller(path, field, v, controllers) for v in values)
        if len(set(vals)) != len(vals):
            raise DynoplanError(f"{path}: {field}: repeated values {list(vals)}")
        checked.append((key, vals))
    cells = math.prod(len(v) for _, v in checked)
    if cells > CELLS_MAX:
        raise DynoplanError(f"{path}: grid: {cells} cells, expected at most {CELLS_MAX}")
    folder = Path(models)
    if not folder.is_absolute():
        folder = path.parent / folder
    return SweepConfig(path, folder, episodes, tuple(checked), control, controller, seed)


def _read(path: Path) -> dict[str, Any]:
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise DynoplanError(f"{path}: cannot read the sweep configuration "
                            f"({exc.strerror})") from None
    except UnicodeDecodeError:
        raise DynoplanError(f"{path}: not a text file") from None
    suffix = path.suffix.lower()
    try:
        if suffix == ".toml":
            raw: Any = tomllib.loads(text)
        elif suffix == ".json":
            raw = json.loads(text)
        else:
            raise DynoplanError(f"{path}: expected a .toml or .json sweep configuration")
    except tomllib.TOMLDecodeError as exc:
        raise DynoplanError(f"{path}: not valid TOML ({exc})") from None
    except json.JSONDecodeError as exc:
        raise DynoplanError(f"{path}: not valid JSON ({exc.msg}, line {exc.lineno})") from None
    if not isinstance(raw, dict):
        raise DynoplanError(f"{path}: expected a table (a JSON object) at the top")
    return raw


def _integer(path: Path, field: str, value: Any, minimum: int, maximum: int) -> int:
    if (isinstance(value, bool) or not isinstance(value, int)
            or not minimum <= value <= maximum):
        raise DynoplanError(f"{path}: {field}: expected an integer in {minimum}.."
                            f"{maximum}, got {value!r}")
    return value


def _number(path: Path, field: str, value: Any) -> float:
    if (isinstance(value, bool) or not isinstance(value, int | float)
            or not math.isfinite(value) or value < 0):
        raise DynoplanError(f"{path}: {field}: expected a number >= 0, got {value!r}")
    return float(value)


def _controller(path: Path, field: str, value: Any, controllers: Sequence[str]) -> str:
    if value not in controllers:
        raise DynoplanError(f"{path}: {field}: expected one of "
                            f"{', '.join(controllers)}, got {value!r}")
    return str(value)


__all__ = ["FLOAT_KEYS", "GRID_KEYS", "INT_KEYS", "Cell", "SweepConfig", "load_sweep_config"]
