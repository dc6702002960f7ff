"""The stages of ``dynoplan gear run`` that have a command of their own, one function each.

``gear run`` (:mod:`dynoplan.experiments.gear_run`) and the commands ``gear demos``,
``gear collect``, ``gear train``, ``gear figures`` and ``gear outcomes`` call these
functions, and take their sizes from the same settings
(:func:`~dynoplan.experiments.gear_run.run_settings`), so the commands
chained into one folder write what ``gear run --out DIR`` writes there for the same seed
(add ``--quick`` to each for ``gear run --quick``)::

    dynoplan gear demos --models DIR/models --out DIR/demos
    dynoplan gear demos --heldout --models DIR/models --out DIR/heldout
    dynoplan gear collect --models DIR/models --out DIR/transitions
    dynoplan gear train --demos DIR/demos --transitions DIR/transitions \\
        --heldout DIR/heldout --out DIR/models
    dynoplan gear figures --models DIR/models --demos DIR/demos --heldout DIR/heldout \\
        --out DIR/figures

``tests/test_gear_stages.py`` runs this chain and compares it with ``gear run --quick``.
"""

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from dynoplan.data import read_dataset
from dynoplan.envs.gear.learning.data import HELDOUT_SEED_OFFSET
from dynoplan.envs.gear.learning.files import HELDOUT_DIR
from dynoplan.envs.gear.learning.settings import (
    DEFAULT_METRICS,
    DEFAULT_SETTINGS,
    GearMetricsSettings,
)
from dynoplan.envs.gear.options.catalog import network_files
from dynoplan.errors import DynoplanError
from dynoplan.io import staged_folder, write_json
from dynoplan.parallel import SERIAL, Workers
from dynoplan.pipeline.fit import FitSettings

if TYPE_CHECKING:
    from dynoplan.pipeline.collect import OptionRunSettings

DEMONSTRATOR = "options"
"""Who records the demonstrations and the held-out trials: the operator chaining the four
option policies (:class:`~dynoplan.envs.gear.operator.OptionOperator`); ``expert``, the
scripted expert with privileged state, is the other choice."""

FIGURE_POINTS = 1500
"""States embedded by t-SNE in Fig. 3(b) at most (:data:`QUICK_FIGURE_POINTS` with
``--quick``)."""
QUICK_FIGURE_POINTS = 400


def _silent(_: str) -> None:
    pass


def option_networks(models: Path, seed: int, only: Sequence[str] | None = None,
                    workers: Workers = SERIAL,
                    log: Callable[[str], None] = _silent) -> dict[str, Any]:
    """Stage ``networks``: train the networks of the options ``only`` (default: every
    registered option with a network,
    :func:`~dynoplan.envs.gear.options.catalog.network_files`) that are missing from
    ``models``; their training reports by option name (empty when none was missing).

    Always on full settings (160 data episodes, about 35 s on one core, and 10 s of
    fits), also under ``--quick``: quick networks fail too often for ten successful
    demonstrations."""
    from dynoplan.envs.gear.options.catalog import train_option_networks

    missing = tuple(n for n, f in network_files().items()
                    if (only is None or n in only) and not (models / f).is_file())
    if not missing:
        return {}
    log(f"training the {' and '.join(missing)} network{'s' * (len(missing) > 1)} "
        f"into {models} ...")
    return train_option_networks(models, seed, quick=False, only=missing, workers=workers)


def demonstrations(n: int, seed: int, out: Path, models: Path, heldout: bool = False,
                   demonstrator: str = DEMONSTRATOR, human_mode: str | None = None,
                   progress: bool = True, workers: Workers = SERIAL,
                   log: Callable[[str], None] = _silent) -> dict[str, Any]:
    """Stage ``demos``: ``n`` demonstrations by ``demonstrator`` into the dataset folder
    ``out``, from ``seed``; with ``heldout``, the held-out trials instead, from ``seed +
    HELDOUT_SEED_OFFSET`` (disjoint episodes). ``gear run`` records both, ``n`` = 10.

    The operator's networks are read from ``models``, and trained there first (from
    ``seed``, :func:`option_networks`) when missing. Returns
    :func:`~dynoplan.envs.gear.learning.demos.record_demos`'s summary."""
    from dynoplan.envs.gear.demonstrations import check_request
    from dynoplan.envs.gear.learning.demos import record_demos

    check_request(n, human_mode, demonstrator, count_flag="--n")  # before any training
    if demonstrator == "options":
        option_networks(models, seed, workers=workers, log=log)
    return record_demos(n, seed + HELDOUT_SEED_OFFSET if heldout else seed, out, progress,
                        human_mode=human_mode, demonstrator=demonstrator, models=models,
                        workers=workers)


def option_transitions(models: Path, runs: int, seed: int, out: Path, max_decisions: int,
                       progress: bool = True, workers: Workers = SERIAL,
                       log: Callable[[str], None] = _silent) -> dict[str, Any]:
    """Stage ``collect``: ``runs`` runs of every option, at most ``max_decisions``
    decisions each, into the dataset folder ``out``
    (:func:`~dynoplan.envs.gear.learning.transitions.collect_gear_transitions`); the options'
    networks read from ``models`` (trained there first when missing)."""
    from dynoplan.envs.gear.learning.transitions import check_collection, collect_gear_transitions

    check_collection(runs, max_decisions)
    option_networks(models, seed, workers=workers, log=log)
    return collect_gear_transitions(models, runs, seed, out, max_decisions=max_decisions,
                               progress=progress, workers=workers)


def learned_models(demos: Path, transitions: Path | None, models: Path, seed: int,
                   heldout: Path | None, fit: FitSettings = DEFAULT_SETTINGS,
                   metrics: GearMetricsSettings = DEFAULT_METRICS, progress: bool = True,
                   workers: Workers = SERIAL,
                   log: Callable[[str], None] = _silent) -> dict[str, Any]:
    """Stage ``train``: the goal heuristic, the safety regions and the dynamics fitted as
    ``fit`` says into ``models``, measured as ``metrics`` says
    (:func:`~dynoplan.envs.gear.learning.training.train_gear_models`; ``gear run``'s
    ``fit`` and ``metrics``: :data:`~dynoplan.envs.gear.learning.settings.DEFAULT_SETTINGS`
    and ``DEFAULT_METRICS``, ``--quick`` ``QUICK_SETTINGS`` and ``QUICK_METRICS``); the
    content of ``metrics.json``.

    ``heldout`` ``None``: ``metrics.heldout_episodes`` held-out trials (10; ``--quick``
    3) are recorded into ``models/heldout-demos`` by the demonstrator that recorded
    ``demos``, as :func:`demonstrations` records them (kept when they are there
    already)."""
    from dynoplan.envs.gear.learning.training import train_gear_models

    if heldout is None:
        heldout = heldout_trials(demos, metrics.heldout_episodes, seed, models / HELDOUT_DIR,
                                 models, progress, workers, log)
    # the previous models stay loadable until the new folder is complete
    with staged_folder(models, keep=True) as staged:
        return train_gear_models(demos, transitions, staged, seed, heldout, False,
                                 progress=progress, settings=fit, measures=metrics)


def learned_initiation(models: Path, out: Path, seed: int, settings: "OptionRunSettings",
                       progress: bool = True, workers: Workers = SERIAL) -> dict[str, Any]:
    """Stage ``outcomes``: the outcome runs (``out``) and the initiation learned from them,
    written into ``models`` (``gear outcomes`` with the run's sizes); returns the runs'
    summary and the fit's report per option (``models/initiation.json`` too)."""
    from dynoplan.envs.gear.learning.outcomes import collect_outcomes, fit_gear_initiation

    runs = collect_outcomes(models, seed, out, settings, progress=progress, workers=workers)
    write_json(out / "outcomes.json", runs)
    report = fit_gear_initiation(models, out, seed)
    write_json(models / "initiation.json", report)
    return {"runs": runs["runs"], "starts": runs["starts"], "ended_well": runs["ended_well"],
            "options": report["options"]}


def heldout_trials(demos: Path, n: int, seed: int, out: Path, models: Path,
                   progress: bool = True, workers: Workers = SERIAL,
                   log: Callable[[str], None] = _silent) -> Path:
    """``n`` held-out trials in ``out`` by the demonstrator named in the dataset
    ``demos`` (:data:`DEMONSTRATOR` when it names none), recorded by
    :func:`demonstrations` unless ``out`` holds them already; ``out``."""
    demonstrator = read_dataset(demos).metadata.extra.get("demonstrator", DEMONSTRATOR)
    if (out / "data").is_dir():
        try:
            there = read_dataset(out)
            meta = there.metadata
            if (meta.seed == seed + HELDOUT_SEED_OFFSET and len(there) == n
                    and meta.extra.get("demonstrator") == demonstrator):
                return out
        except DynoplanError:
            pass  # unreadable: record them again
    log(f"recording {n} held-out trials ({demonstrator}) into {out} ...")
    demonstrations(n, seed, out, models, heldout=True, demonstrator=demonstrator,
                   progress=progress, workers=workers, log=log)
    return out


def figures(models: Path, demos: Path, heldout: Path | None, out: Path, seed: int,
            points: int = FIGURE_POINTS, trial: int = 0,
            progress: bool = False) -> dict[str, Any]:
    """Stage ``figures``: Fig. 3(a) and 3(b) into ``out``
    (:func:`~dynoplan.reports.gear_figures.make_gear_figures`), t-SNE on ``points``
    states at most (:data:`FIGURE_POINTS`; ``--quick``: :data:`QUICK_FIGURE_POINTS`); the
    content of ``figures.json``."""
    from dynoplan.reports.gear_figures import make_gear_figures

    return make_gear_figures(models, demos, heldout, out, seed=seed, trial=trial,
                             max_points=points, progress=progress)


__all__ = ["DEMONSTRATOR", "FIGURE_POINTS", "QUICK_FIGURE_POINTS", "demonstrations",
           "figures", "heldout_trials", "learned_initiation", "learned_models",
           "option_networks", "option_transitions"]
