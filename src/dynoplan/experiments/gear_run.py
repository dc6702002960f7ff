"""``dynoplan gear run``: the gear assembly end to end, into one output folder: the one
pipeline (:func:`~dynoplan.pipeline.run.run_pipeline`) on the gear's stages
(:class:`~dynoplan.envs.gear.pipeline_stages.GearStages`, whose module lists what each
writes), then the gear's reports (``results.md``, ``summary.json``).

The whole folder is staged (:func:`~dynoplan.io.staged_folder`, starting as a copy of
the previous ``out``, whose option networks are reused): it replaces ``out`` only when
every stage has finished; a failure or an interrupt leaves ``out`` as it was. The paths
recorded in the outputs name ``out``. One Ray runtime serves the whole run on several
workers; ``summary.json``'s ``wall_s`` is the run's wall time.
"""

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from dynoplan.envs.gear.pipeline_stages import GearRunSettings, GearStages
from dynoplan.envs.gear.reports.results import results_markdown
from dynoplan.io import retarget, staged_folder, write_json, write_text
from dynoplan.parallel import SERIAL, Workers, ray_session
from dynoplan.pipeline.run import run_pipeline


def run_gear_pipeline(out: Path, seed: int = 0, settings: GearRunSettings = GearRunSettings(),
                      progress: bool = True, log: Callable[[str], None] = lambda _: None,
                      workers: Workers = SERIAL) -> dict[str, Any]:
    """:func:`~dynoplan.pipeline.run.run_pipeline` on the gear's stages
    (:class:`~dynoplan.envs.gear.pipeline_stages.GearStages`) into ``out``, staged as a
    whole, on ``workers`` (one Ray runtime for the run), ``log`` told of each stage as it
    starts; then ``results.md`` and ``summary.json``; return ``summary.json``'s content.

    Raises:
        DynoplanError: ``out`` cannot be written (checked before any stage runs).
    """
    t0 = time.perf_counter()
    with staged_folder(out, keep=True) as stage:
        with ray_session(workers):
            summary = run_pipeline(stages=GearStages(seed, settings), out=stage,
                                   progress=progress, status=lambda name: log(f"[{name}]"),
                                   workers=workers)
        summary = retarget(summary, stage, out)
        summary["wall_s"] = round(time.perf_counter() - t0, 2)
        write_text(stage / "results.md", results_markdown(summary))
        write_json(stage / "summary.json", summary)
    return summary


__all__ = ["run_gear_pipeline"]
