"""The ``--workers`` and ``--ray-address`` options shared by the commands that run many
independent episodes (``gear collect``, ``gear run``, ``gear evaluate``, ``sweep``,
``pipeline``)."""

from typing import Any

import typer


def workers_option() -> Any:
    """``--workers auto|N`` (a string; :func:`dynoplan.parallel.parse_workers` reads it):
    ``auto``, the default, is every CPU of the machine when Ray is installed and 1
    otherwise; 1 runs in this process without Ray; more start a local Ray runtime of N
    CPUs."""
    return typer.Option("auto", "--workers", metavar="auto|N",
                        help="Parallel workers. 'auto' (the default): one per CPU when Ray "
                        "is installed, else 1. 1 runs here without importing Ray; N > 1 "
                        "runs episodes as Ray tasks on N local CPUs. Results are the same "
                        "for any N.")


def ray_address_option() -> Any:
    """``--ray-address ADDR``: run on an existing Ray cluster."""
    return typer.Option(None, "--ray-address", help="Run the episodes on this Ray cluster "
                        "('auto', or ray://HOST:PORT); every node needs dynoplan and the "
                        "input files at the same paths.")
