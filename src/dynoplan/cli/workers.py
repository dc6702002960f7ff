"""The ``--workers`` and ``--ray-address`` options shared by the commands that run many
independent episodes (``gear collect``, ``gear run``, ``gear evaluate``, ``sweep``)."""

from typing import Any

import typer


def workers_option() -> Any:
    """``--workers N``: 1 runs in this process without Ray; more start a local Ray
    runtime of N CPUs."""
    return typer.Option(1, "--workers", help="Parallel workers: 1 runs here without Ray; "
                        "N > 1 runs episodes as Ray tasks on N local CPUs.")


def ray_address_option() -> Any:
    """``--ray-address ADDR``: run on an existing Ray cluster."""
    return typer.Option(None, "--ray-address", help="Run the episodes on this Ray cluster "
                        "('auto', or ray://HOST:PORT); every node needs dynoplan and the "
                        "input files at the same paths.")
