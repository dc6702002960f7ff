"""SIGINT and SIGTERM of the command line: ``dynoplan: aborted``, exit 130 or 143, at any
moment of the process, never a traceback.

Standard library only: :func:`install` runs before anything else is imported (start-up
takes a while when a command imports torch), and :func:`at_shutdown` once the command is
over (a signal then would land in another library's ``atexit`` callback).
"""

import contextlib
import os
import signal
import sys
from types import FrameType
from typing import NoReturn

SIGNALS = (signal.SIGINT, signal.SIGTERM)

received: list[int] = []
"""The interrupting signals received, in order (the first decides the exit status)."""


def install() -> None:
    """Make SIGINT and SIGTERM unwind the run as Ctrl-C does (a ``KeyboardInterrupt``), so
    that ``finally`` blocks remove temporary files and staged folders
    (:mod:`dynoplan.io`) and the previous outputs stay. SIGINT too when the process was
    started with it ignored (a background job of a shell script)."""
    for signum in SIGNALS:
        signal.signal(signum, _interrupt)


def _interrupt(signum: int, _frame: FrameType | None) -> None:
    received.append(signum)
    raise KeyboardInterrupt


def at_shutdown() -> None:
    """From now on, a signal ends the process at once with ``dynoplan: aborted`` and its
    status (the command's work is over; nothing is left to unwind)."""
    for signum in SIGNALS:
        signal.signal(signum, _exit_now)


def _exit_now(signum: int, _frame: FrameType | None) -> None:
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):  # the handler may interrupt a write of it
            stream.flush()
    os.write(2, b"dynoplan: aborted\n")
    os._exit(128 + signum)


def aborted(signum: int | None = None) -> NoReturn:
    """Print ``dynoplan: aborted`` and exit with 128 + the first signal received (SIGINT,
    130, when none was: a ``KeyboardInterrupt`` of another origin). Later signals end the
    process the same way at once."""
    at_shutdown()
    first = received[0] if received else signal.SIGINT if signum is None else signum
    sys.stderr.write("dynoplan: aborted\n")
    sys.exit(128 + first)


__all__ = ["aborted", "at_shutdown", "install", "received"]
