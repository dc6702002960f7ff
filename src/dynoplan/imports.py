"""Importing the user's own code named on the command line or in an environment variable."""

import importlib
import importlib.util
import sys
from pathlib import Path
from types import ModuleType

from dynoplan.errors import DynoplanError


def import_user_module(name: str, what: str) -> ModuleType:
    """Import ``name``: a path ending in ``.py``, or a module name (the current folder is
    searched first, so ``examples.mountain_car.options`` works from the repository root).

    Raises:
        DynoplanError: one line starting with ``what``: no such file, a module that cannot
            be imported, or an exception raised while importing it.
    """
    try:
        if name.endswith(".py"):
            path = Path(name)
            if not path.is_file():
                raise DynoplanError(f"{what}: file {path} not found")
            spec = importlib.util.spec_from_file_location(path.stem, path)
            if spec is None or spec.loader is None:
                raise DynoplanError(f"{what}: cannot load {path}")
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
            return module
        if "" not in sys.path and str(Path.cwd()) not in sys.path:
            sys.path.insert(0, str(Path.cwd()))
        return importlib.import_module(name)
    except DynoplanError:
        raise
    except ImportError as exc:
        raise DynoplanError(f"{what}: cannot import module '{name}' ({exc})") from None
    except Exception as exc:  # the user's module raised while importing
        raise DynoplanError(f"{what}: importing failed: {type(exc).__name__}: {exc}") from None


__all__ = ["import_user_module"]
