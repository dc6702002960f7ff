"""``dynoplan``: run the paper's experiments and the library's pipeline from a shell.

User mistakes (bad arguments, unreadable files, unknown names, an output folder that
cannot be written) print one line, ``dynoplan: error: ...``, and exit with status 2; no
traceback. SIGINT (Ctrl-C) and SIGTERM print ``dynoplan: aborted`` and exit with status
130 and 143, from the first instruction of :func:`main` to the last of the process.

This module imports the standard library only: :func:`main` installs the signal handling
(:mod:`dynoplan.cli.interrupts`) before it imports the command tree
(:mod:`dynoplan.cli.app`), which imports what a command runs only when it runs.
"""

import sys
from typing import Any

from dynoplan.cli import interrupts


def main() -> None:
    """Console entry point: one line per user error, exit status 2; ``dynoplan: aborted``
    and status 130 (SIGINT, Ctrl-C) or 143 (SIGTERM) when interrupted, also while modules
    import and while the interpreter shuts down."""
    try:  # a signal may land while the handlers are installed: inside the try too
        interrupts.install()
        code = _run()
    except SystemExit:  # aborted() in _run
        raise
    except KeyboardInterrupt:
        interrupts.aborted()
    except BaseException:
        if interrupts.received:  # e.g. an ImportError of a module interrupted as it loaded
            interrupts.aborted()
        raise
    if interrupts.received:
        interrupts.aborted()
    sys.exit(code)


def _run() -> int:
    """Run the command line; the exit status. User errors are printed here."""
    import typer

    from dynoplan.cli.app import app
    from dynoplan.cli.lines import warnings_as_lines
    from dynoplan.errors import DynoplanError

    try:
        with warnings_as_lines():
            code = app(standalone_mode=False)
    except (typer.Abort, KeyboardInterrupt):
        interrupts.aborted()
    except typer.Exit as exc:
        return int(exc.exit_code)
    except typer.TyperException as exc:  # usage errors of the vendored click
        fmt = getattr(exc, "format_message", None)
        message = fmt() if callable(fmt) else str(exc)
        if message:  # else "no arguments": the help text has been shown
            sys.stderr.write(f"dynoplan: error: {message}\n")
        return int(getattr(exc, "exit_code", 2))
    except DynoplanError as exc:
        sys.stderr.write(f"dynoplan: error: {exc}\n")
        return 2
    finally:  # the command is over: a signal from now on ends the process at once
        interrupts.at_shutdown()
    return code if isinstance(code, int) else 0


def __getattr__(name: str) -> Any:
    """``app``, the typer application (:mod:`dynoplan.cli.app`), imported when asked for."""
    if name == "app":
        from dynoplan.cli.app import app

        return app
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["main"]

if __name__ == "__main__":
    main()
