"""Checks of command-line values that typer's types do not make (counts and seeds use
typer's ``min``/``max`` with the bounds of :mod:`dynoplan.limits`)."""

import importlib.util
from pathlib import Path
from typing import Any

import typer

from dynoplan.errors import DynoplanError
from dynoplan.io import check_writable
from dynoplan.limits import SETTING_BOUNDS

GEAR_MODULES = ("mujoco", "ompl", "mink", "daqp", "imageio", "stable_baselines3")
"""What the gear's commands import: the ``gear`` extra (the core install has none)."""


def setting_bounds(key: str) -> dict[str, Any]:
    """typer's ``min``/``max`` of setting ``key`` (:data:`~dynoplan.limits.SETTING_BOUNDS`)."""
    low, high = SETTING_BOUNDS[key]
    return {k: v for k, v in (("min", low), ("max", high)) if abs(v) != float("inf")}


def folder(value: Path | None) -> Path | None:
    """typer callback of a folder option (``--out``, ``--models``, a dataset): the path
    may be missing (an output is created), but not a file.

    Raises:
        typer.BadParameter: ``Invalid value for '--flag': PATH is a file, expected a
            folder`` (one line, exit 2).
    """
    if value is not None and value.exists() and not value.is_dir():
        raise typer.BadParameter(f"{value} is a file, expected a folder")
    return value


def out_folder(value: Path | None) -> Path | None:
    """typer callback of an output folder option (``--out``): as :func:`folder`, then
    :func:`dynoplan.io.check_writable`, so that a folder that cannot be written is
    reported before any work and nothing is left beside it.

    Raises:
        typer.BadParameter: the path is a file (one line, exit 2).
        DynoplanError: ``cannot write to FOLDER: permission denied`` (one line, exit 2).
    """
    value = folder(value)
    if value is not None:
        check_writable(value)
    return value


def models_folder(value: Path | None) -> Path | None:
    """typer callback of a models folder option (``--models``): as :func:`folder`, then
    :func:`dynoplan.models.folder.check_format_version` (a ``models.json`` of a newer
    dynoplan is refused before any work, also by commands that read only the option
    networks of the folder).

    Raises:
        typer.BadParameter: the path is a file (one line, exit 2).
        DynoplanError: a newer format version (one line, exit 2).
    """
    value = folder(value)
    if value is not None and (value / "models.json").is_file():
        from dynoplan.models.folder import check_format_version

        check_format_version(value)
    return value


def human_mode(value: str | None) -> str | None:
    """typer callback of ``--human``: one of the gear's human modes, checked before any
    work (an option's networks are trained before its trials run).

    Raises:
        typer.BadParameter: another value (one line, exit 2).
    """
    from dynoplan.envs.gear.human import HUMAN_MODES

    if value is not None and value not in HUMAN_MODES:
        raise typer.BadParameter(f"expected one of {', '.join(HUMAN_MODES)}, got {value!r}")
    return value


def require_gear() -> None:
    """Check that the ``gear`` extra is installed, before a gear command starts.

    Raises:
        DynoplanError: one line naming the missing modules and the install command.
    """
    missing = [m for m in GEAR_MODULES if importlib.util.find_spec(m) is None]
    if missing:
        raise DynoplanError(f"the gear needs {', '.join(missing)}, which the core install "
                            "does not have: pip install 'dynoplan[gear]'")


__all__ = ["GEAR_MODULES", "folder", "human_mode", "models_folder", "out_folder", "require_gear"]
