"""A sweep: evaluate a grid of planner settings and seeds on one task's trained models (the
configuration: :mod:`dynoplan.pipeline.sweep_config`), resumably; the gear's is
``dynoplan sweep CONFIG`` (:mod:`dynoplan.experiments.sweep`).

Every cell's episodes are tasks of one map (:func:`dynoplan.parallel.imap_unordered`),
so many workers share the whole grid, not one cell at a time. As soon as a cell's last
episode is in, its result is written to ``<key>.json`` in the resume folder beside
``OUT``, ``PARENT/.OUT_NAME.sweep-cells`` (:func:`resume_folder`; a temporary file renamed
onto the name, :mod:`dynoplan.io`). A re-run reads the cell files back, from the resume
folder and from ``OUT/cells`` (the cells of a completed sweep, or of an interrupted one
of an earlier dynoplan, which kept them there), and skips the cells whose file is valid:
it parses, has this format, the cell's exact settings, the same models (the SHA-256 of
``models.json``) and one metric row of the right episode count. Anything else (an
interrupted write leaves only a hidden temporary file; a truncated or edited file;
models trained again) is computed again. So an interrupted sweep loses only its
unfinished cells.

Outputs in ``OUT``: ``results.csv`` and ``results.md`` (one row per cell: the swept
settings, then the task's metric columns, :class:`SweepTask`), ``sweep.png``,
``summary.json`` and ``cells/`` (every cell file: this grid's, and those of other grids
that ``OUT/cells`` or the resume folder held, so that a later grid reuses them), staged as
one (:func:`~dynoplan.io.staged_folder`): they replace the previous ones together when
the sweep completes, or none does, and the resume folder is removed after the move. A
sweep stopped in any way (Ctrl-C, SIGTERM, SIGKILL, a lost head node, an error) leaves
``OUT`` as it was; its finished cells stay in the resume folder (the one thing it adds
beside ``OUT``, and only once a cell has finished), and a stop that unwinds says how
many in one :class:`~dynoplan.errors.DynoplanWarning`. The resume folder's name is not a
staging folder's (``.NAME.PID.XXXX.staging``), so no later write removes it as a leftover.
"""

import hashlib
import json
import os
import shutil
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from dynoplan.errors import DynoplanError, DynoplanWarning
from dynoplan.io import check_writable, staged_folder, write_csv, write_json, write_text
from dynoplan.models.folder import MANIFEST_FILE, check_format_version
from dynoplan.parallel import SERIAL, Workers, imap_unordered
from dynoplan.pipeline.control_settings import ControllerSettings
from dynoplan.pipeline.evaluate import ControllerJob, EpisodeRecord
from dynoplan.pipeline.jobs import build_runner, runner_episode
from dynoplan.pipeline.sweep_config import Cell, SweepConfig, load_sweep_config
from dynoplan.pipeline.task import Task
from dynoplan.reports.tables import markdown_table
from dynoplan.seeding import EpisodeSeed

CELL_FORMAT = "dynoplan-sweep-cell"
CELL_VERSION = 1
RESUME_SUFFIX = ".sweep-cells"
"""The resume folder of ``OUT`` is ``.OUT_NAME`` + this, beside ``OUT``."""


@dataclass(frozen=True)
class SweepTask:
    """What a sweep evaluates and how.

    Attributes:
        task: the task whose controllers run
            (:class:`~dynoplan.pipeline.evaluate.ControllerJob`).
        controllers: the controllers a configuration may name.
        control: the planner settings the grid changes.
        seeds: ``seeds(seed, episodes)``, the episodes of a cell.
        summarise: ``summarise(controller, records)``, a cell's row.
        columns: the metric columns of a row (the swept settings come first).
    """

    task: Task
    controllers: tuple[str, ...]
    control: ControllerSettings
    seeds: Callable[[int, int], list[EpisodeSeed]]
    summarise: Callable[[str, Sequence[EpisodeRecord]], dict[str, Any]]
    columns: tuple[str, ...]

    def config(self, path: Path) -> SweepConfig:
        """The sweep configuration in ``path``, checked (:func:`load_sweep_config`)."""
        return load_sweep_config(path, self.controllers, self.control)


def cell_key(cell: Cell) -> str:
    """A file name for ``cell``: a hash of its settings (stable across runs)."""
    text = json.dumps(cell.settings(), sort_keys=True)
    return "cell-" + hashlib.sha256(text.encode()).hexdigest()[:16]


def read_cell(path: Path, cell: Cell, models_sha256: str, columns: Sequence[str]
              ) -> dict[str, Any] | None:
    """The row stored in ``path`` if it is a finished result of ``cell`` on the models
    with ``models_sha256`` (module docstring); None otherwise (missing, damaged, stale)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    if not isinstance(data, dict) or data.get("format") != CELL_FORMAT \
            or data.get("version") != CELL_VERSION:
        return None
    row = data.get("row")
    if data.get("settings") != cell.settings() or data.get("models_sha256") != models_sha256 \
            or not isinstance(row, dict) or any(c not in row for c in columns) \
            or row.get("episodes") != cell.episodes:
        return None
    return row


def write_cell(path: Path, cell: Cell, models_sha256: str,
               episodes: Sequence[EpisodeRecord], sweep: SweepTask) -> dict[str, Any]:
    """Write ``cell``'s result (its row: ``sweep.summarise``) atomically; return its row."""
    row = sweep.summarise(cell.controller, episodes)
    write_json(path, {"format": CELL_FORMAT, "version": CELL_VERSION,
                      "settings": cell.settings(), "models_sha256": models_sha256,
                      "row": row, "episodes": [asdict(e) for e in episodes]})
    return row


def resume_folder(out: Path) -> Path:
    """Where a sweep into ``out`` keeps its finished cells until it completes:
    ``PARENT/.OUT_NAME.sweep-cells`` (module docstring)."""
    target = out if out.name not in ("", "..") else Path(os.path.abspath(out))
    return target.parent / f".{target.name}{RESUME_SUFFIX}"


def check_sweep_writable(out: Path) -> None:
    """:func:`~dynoplan.io.check_writable` of ``out`` and of its resume folder (itself when
    it exists; else the folder above, where it is made), creating nothing.

    Raises:
        DynoplanError: ``cannot write to FOLDER: REASON``, or a file in the way.
    """
    check_writable(out)
    check_writable(resume_folder(out))


def run_sweep(config_path: Path, out: Path, sweep: SweepTask, workers: Workers = SERIAL,
              progress: bool = True,
              log: Callable[[str], None] = lambda _: None, *,
              setup: Callable[[ControllerJob], Any] = build_runner,
              run: Callable[[Any, EpisodeSeed], EpisodeRecord] = runner_episode,
              ) -> dict[str, Any]:
    """Run (or finish) the sweep of ``config_path`` (of ``sweep``) into ``out``; return
    the summary.

    ``setup``/``run`` are the job's functions (:func:`~dynoplan.pipeline.jobs.build_runner`,
    :func:`~dynoplan.pipeline.jobs.runner_episode`);
    tests replace them.

    On any exception (``KeyboardInterrupt`` included) ``out`` is as it was and the
    finished cells are in :func:`resume_folder`; when it holds any of this grid's, one
    :class:`~dynoplan.errors.DynoplanWarning` says how many, before the exception goes on.

    Raises:
        DynoplanError: a bad configuration, no ``models.json`` in the models folder, an
            unwritable ``out`` or resume folder.
    """
    config = sweep.config(config_path)
    manifest = config.models / MANIFEST_FILE
    check_format_version(config.models)  # finished cells are reused without loading them
    try:
        models_sha256 = hashlib.sha256(manifest.read_bytes()).hexdigest()
    except OSError:
        raise DynoplanError(f"{config_path}: models: {manifest} not found (train models "
                            "with 'dynoplan gear run' or 'dynoplan gear train')") from None
    check_sweep_writable(out)  # before any cell; the resume folder comes with the first
    resume = resume_folder(out)
    cells = config.cells()
    rows: dict[int, dict[str, Any]] = {}
    files: dict[str, Path] = {}  # this grid's cell files: where each finished one is
    for i, cell in enumerate(cells):
        name = f"{cell_key(cell)}.json"
        for folder in (resume, out / "cells"):
            row = read_cell(folder / name, cell, models_sha256, sweep.columns)
            if row is not None:
                rows[i], files[name] = row, folder / name
                break
    todo = [i for i in range(len(cells)) if i not in rows]
    log(f"{len(cells)} cells: {len(rows)} finished, {len(todo)} to run "
        f"({len(todo) * config.episodes} episodes)")
    t0 = time.perf_counter()
    tasks, owner = [], []
    for i in todo:
        cell = cells[i]
        job = ControllerJob(sweep.task, config.models, cell.controller, cell.planner)
        for s in sweep.seeds(cell.seed, cell.episodes):
            tasks.append((job, s))
            owner.append(i)
    buffers: dict[int, dict[int, EpisodeRecord]] = {i: {} for i in todo}
    try:
        for t, metrics in imap_unordered(setup, run, tasks, workers, "sweep episodes",
                                         progress):
            i = owner[t]
            buffers[i][t] = metrics
            if len(buffers[i]) == cells[i].episodes:
                finished = buffers.pop(i)
                name = f"{cell_key(cells[i])}.json"
                rows[i] = write_cell(resume / name, cells[i], models_sha256,
                                     [finished[k] for k in sorted(finished)], sweep)
                files[name] = resume / name
        table = [{**_swept(config, cells[i]), **{c: rows[i].get(c) for c in sweep.columns}}
                 for i in range(len(cells))]
        summary = {"config": str(config_path), "models": str(config.models),
                   "models_sha256": models_sha256, "swept": list(config.swept),
                   "cells": len(cells), "cells_run": len(todo),
                   "cells_reused": len(cells) - len(todo),
                   "episodes_per_cell": config.episodes, "workers": asdict(workers),
                   "wall_s": round(time.perf_counter() - t0, 2), "results": table}
        with staged_folder(out) as stage:  # the results and the cells together, or none
            _copy_cells(stage / "cells", files, (out / "cells", resume))
            write_csv(stage / "results.csv", table)
            write_text(stage / "results.md", results_markdown(config, table))
            from dynoplan.reports.sweep_figures import plot_sweep

            plot_sweep(table, config.swept, stage / "sweep.png")
            write_json(stage / "summary.json", summary)
    except BaseException:
        kept = sum(1 for path in files.values() if path.parent == resume)
        if kept:
            warnings.warn(f"kept {kept} finished cell{'s' if kept != 1 else ''} of "
                          f"{len(cells)} in {resume}; run the same command again to "
                          "resume", DynoplanWarning, stacklevel=2)
        raise
    shutil.rmtree(resume, ignore_errors=True)  # its cells are in OUT/cells now
    return summary


def _copy_cells(folder: Path, files: dict[str, Path], sources: Sequence[Path]) -> None:
    """Fill ``folder`` with every cell file: ``files`` (this grid's, by name), then the
    other ``cell-*.json`` of ``sources`` (a later source's file wins)."""
    every: dict[str, Path] = {}
    for source in sources:
        if source.is_dir():
            every.update((p.name, p) for p in source.glob("cell-*.json") if p.is_file())
    every.update(files)
    folder.mkdir()
    for name, path in sorted(every.items()):
        shutil.copyfile(path, folder / name)


def _swept(config: SweepConfig, cell: Cell) -> dict[str, Any]:
    """The cell's values of the swept keys (the table's first columns)."""
    values = cell.settings()
    return {k: values[k] for k in config.swept}


def results_markdown(config: SweepConfig, table: Sequence[dict[str, Any]]) -> str:
    """``results.md``: what was swept over which models, then one row per cell."""
    fixed = {k: v for k, v in (("controller", config.controller), ("seed", config.seed))
             if k not in config.swept}
    head = ", ".join(f"{k} {v}" for k, v in fixed.items())
    return "\n".join([
        f"# Sweep: {config.path.name}", "",
        f"Models {config.models}; {config.episodes} episodes per cell"
        f"{'; ' + head if head else ''}; other planner settings at their defaults.", "",
        markdown_table(table)])


__all__ = ["CELL_FORMAT", "CELL_VERSION", "RESUME_SUFFIX", "SweepTask", "cell_key",
           "check_sweep_writable", "read_cell", "results_markdown", "resume_folder",
           "run_sweep", "write_cell"]
