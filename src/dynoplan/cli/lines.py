"""Library warnings as command-line lines."""

import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import typer

from dynoplan.errors import DynoplanWarning


@contextmanager
def warnings_as_lines() -> Iterator[None]:
    """Print every :class:`DynoplanWarning` as one line on stderr, when it is raised."""
    shown = warnings.showwarning

    def show(message: Warning | str, category: type[Warning], filename: str, lineno: int,
             file: Any = None, line: str | None = None) -> None:
        if issubclass(category, DynoplanWarning):
            typer.echo(f"dynoplan: warning: {message}", err=True)
        else:
            shown(message, category, filename, lineno, file, line)

    with warnings.catch_warnings():
        warnings.simplefilter("always", DynoplanWarning)
        warnings.showwarning = show
        try:
            yield
        finally:
            warnings.showwarning = shown


__all__ = ["warnings_as_lines"]
