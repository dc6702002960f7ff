"""The stages of ``dynoplan gear run`` that have a command of their own, one function each.

``gear run``'s stages (:class:`~dynoplan.envs.gear.pipeline_stages.GearStages`) and the
commands ``gear demos``, ``collect``, ``train``, ``figures`` and ``outcomes`` call them
with the same sizes (:func:`~dynoplan.envs.gear.pipeline_stages.run_settings`), so
chained into one folder they write what ``gear run --out DIR`` writes for the same seed
(``--quick``: add it to each)::

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
from dynoplan.data.dataset import check_dataset_target
from dynoplan.envs.gear.learning.data import HELDOUT_SEED_OFFSET
from dynoplan.envs.gear.learning.settings import (
    DEFAULT_METRICS,
    DEFAULT_SETTINGS,
    GearMetricsSettings,
)
from dynoplan.envs.gear.models_folder import HELDOUT_DIR
from dynoplan.envs.gear.options.catalog import network_files
from dynoplan.errors import DynoplanError
from dynoplan.io import staged_folder, write_json
from dynoplan.parallel import SERIAL, Workers
from dynoplan.pipeline.fit import FitSettings

if TYPE_CHECKING:
    from dynoplan.pipeline.collect import OptionRunSettings

DEMONSTRATOR = "options"
"""Who records the demonstrations and held-out trials: the operator chaining the option
policies (:class:`~dynoplan.envs.gear.operator.OptionOperator`); or ``expert``."""

FIGURE_POINTS = 1500
"""States embedded by t-SNE in Fig. 3(b) at most (``--quick``: the next)."""
QUICK_FIGURE_POINTS = 400


def _silent(_: str) -> None:
    pass


def option_networks(models: Path, seed: int, only: Sequence[str] | None = None,
                    workers: Workers = SERIAL,
                    log: Callable[[str], None] = _silent) -> dict[str, Any]:
    """Stage ``networks``: train into ``models`` the networks missing there of the options
    ``only`` (default: all, :func:`~dynoplan.envs.gear.options.catalog.network_files`);
    their training reports by option name. Full settings also under ``--quick`` (quick
    networks fail too often for ten successful demonstrations)."""
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
    ``out`` from ``seed`` (``heldout``: from ``seed + HELDOUT_SEED_OFFSET``), the
    operator's networks from ``models`` (:func:`option_networks` first); the summary of
    :func:`~dynoplan.envs.gear.demonstrations.record_demos`."""
    from dynoplan.envs.gear.demonstrations import check_request, record_demos

    check_request(n, human_mode, demonstrator, count_flag="--n")  # before any training
    check_dataset_target(out)
    if demonstrator == "options":
        option_networks(models, seed, workers=workers, log=log)
    return record_demos(n, seed + HELDOUT_SEED_OFFSET if heldout else seed, out, progress,
                        human_mode=human_mode, demonstrator=demonstrator, models=models,
                        workers=workers)


STARTS_DIR = "starts"
"""The run's folder of start states labelled by the operator (``region_starts``)."""


def start_states(n: int, seed: int, out: Path, models: Path) -> dict[str, Any]:
    """Stage ``starts``: ``n`` start states of the gear assembly (resets of the seed stream
    :func:`~dynoplan.pipeline.run_settings.starts_seed` of ``seed``), each labelled with
    the option the operator starts there
    (:func:`~dynoplan.pipeline.collect.start_choices`), as a dataset in ``out`` that
    widens the regions where the options start (stage ``train``), with the metadata of
    the demonstrations beside it (``out.parent / "demos"``, stage ``demos``); the
    operator's networks from ``models``.
    Returns its size and the options chosen."""
    from collections import Counter
    from dataclasses import replace

    from dynoplan.data.dataset import write_dataset
    from dynoplan.envs.gear.env import GearAssemblyEnv
    from dynoplan.envs.gear.operator import OptionOperator
    from dynoplan.envs.gear.options.catalog import gear_option_names, policy_factories
    from dynoplan.pipeline.collect import start_choices
    from dynoplan.pipeline.run_settings import starts_seed

    check_dataset_target(out)
    env = GearAssemblyEnv()
    try:
        names = gear_option_names()
        episode = start_choices(env, OptionOperator(env, policy_factories(models)), names,
                                starts_seed(seed), n)
    finally:
        env.close()
    if episode is None:
        raise DynoplanError("the operator starts no option at any of the start states")
    demos = read_dataset(out.parent / "demos").metadata
    write_dataset(out, [episode], replace(
        demos, dataset_id="dynoplan/gear-assembly/start-states-v0", seed=seed,
        extra={"labels": "the operator's first choice at each start state; no step taken"}))
    chosen = Counter(names[int(k)] for k in episode.infos["option"])
    return {"dataset": str(out), "states": len(episode), "chosen": dict(sorted(chosen.items()))}


def option_transitions(models: Path, runs: int, seed: int, out: Path, max_decisions: int,
                       progress: bool = True, workers: Workers = SERIAL,
                       log: Callable[[str], None] = _silent) -> dict[str, Any]:
    """Stage ``collect``: ``runs`` runs of every option of at most ``max_decisions``
    decisions into the dataset folder ``out``, the networks from ``models``
    (:func:`option_networks` first); the collection's summary."""
    from dynoplan.envs.gear.option_runs import check_collection, collect_gear_transitions

    check_collection(runs, max_decisions)
    check_dataset_target(out)
    option_networks(models, seed, workers=workers, log=log)
    return collect_gear_transitions(models, runs, seed, out, max_decisions=max_decisions,
                               progress=progress, workers=workers)


def learned_models(demos: Path, transitions: Path | None, models: Path, seed: int,
                   heldout: Path | None, fit: FitSettings = DEFAULT_SETTINGS,
                   metrics: GearMetricsSettings = DEFAULT_METRICS, progress: bool = True,
                   workers: Workers = SERIAL, log: Callable[[str], None] = _silent,
                   region_demos: Path | None = None,
                   region_starts: Path | None = None,
                   own_states: bool = False) -> dict[str, Any]:
    """Stage ``train``: goal heuristic, safety regions (on ``region_demos``, default
    ``demos``, widened by the labelled start states ``region_starts`` when given) and dynamics
    (``own_states``: on the options' own states where they declare one) fitted as ``fit``
    says into ``models`` and measured as ``metrics`` says; the content of
    ``metrics.json``. ``heldout`` ``None``: :func:`heldout_trials` into
    ``models/heldout-demos``."""
    from dynoplan.envs.gear.learning.training import train_gear_models

    if heldout is None:
        heldout = heldout_trials(demos, metrics.heldout_episodes, seed, models / HELDOUT_DIR,
                                 models, progress, workers, log)
    # the previous models stay loadable until the new folder is complete
    with staged_folder(models, keep=True) as staged:
        return train_gear_models(demos, transitions, staged, seed, heldout, False,
                                 progress=progress, settings=fit, measures=metrics,
                                 region_demos=region_demos, region_starts=region_starts,
                                 own_states=own_states)


def learned_initiation(models: Path, out: Path, seed: int, settings: "OptionRunSettings",
                       progress: bool = True, workers: Workers = SERIAL) -> dict[str, Any]:
    """Stage ``outcomes`` of ``gear run``: :func:`outcome_initiation`; the summary of its
    runs and fit."""
    runs, _, report = outcome_initiation(models, out, seed, settings, progress, workers)
    assert runs is not None  # collected
    return {"runs": runs["runs"], "starts": runs["starts"], "ended_well": runs["ended_well"],
            "options": report["options"]}


def outcome_initiation(models: Path, out: Path, seed: int, settings: "OptionRunSettings",
                       progress: bool = True, workers: Workers = SERIAL,
                       collect: bool = True, merge: Path | None = None,
                       networks: Path | None = None,
                       ) -> tuple[dict[str, Any] | None, dict[str, Any] | None, dict[str, Any]]:
    """The outcome runs of every option into the dataset folder ``out`` (``outcomes.json``:
    their summary; ``collect`` False: the runs already there), with ``merge`` also the
    collected transitions ``merge`` and the runs' as one dataset ``out/transitions-beyond``,
    and the initiation learned from the runs into ``models`` (``initiation.json``: the
    fit's report), the option networks read from ``networks`` (default ``models``; ``gear
    outcomes`` writes into a staged copy of the folder it reads). ``gear run``'s stage
    (:func:`learned_initiation`) and ``gear outcomes`` both run it.

    Returns:
        The runs' summary (``None`` without ``collect``), the merged dataset's (``None``
        without ``merge``) and the fit's report.
    """
    from dynoplan.envs.gear.learning.outcomes import (
        collect_outcomes,
        fit_gear_initiation,
        transitions_beyond,
    )

    runs = None
    if collect:
        runs = collect_outcomes(models if networks is None else networks, seed, out,
                                settings, progress=progress, workers=workers)
        write_json(out / "outcomes.json", runs)
    merged = (None if merge is None
              else transitions_beyond(merge, out, out / "transitions-beyond"))
    report = fit_gear_initiation(models, out, seed)
    write_json(models / "initiation.json", report)
    return runs, merged, report


def heldout_trials(demos: Path, n: int, seed: int, out: Path, models: Path,
                   progress: bool = True, workers: Workers = SERIAL,
                   log: Callable[[str], None] = _silent) -> Path:
    """``out``, holding ``n`` held-out trials by ``demos``' demonstrator (recorded by
    :func:`demonstrations` unless there already)."""
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
    """Stage ``figures``: Fig. 3(a) and 3(b) into ``out``, t-SNE on ``points`` states at
    most; the content of ``figures.json``."""
    from dynoplan.envs.gear.reports.figures import make_gear_figures

    return make_gear_figures(models, demos, heldout, out, seed=seed, trial=trial,
                             max_points=points, progress=progress)


__all__ = ["DEMONSTRATOR", "FIGURE_POINTS", "QUICK_FIGURE_POINTS", "demonstrations",
           "figures", "heldout_trials", "learned_initiation", "learned_models",
           "option_networks", "option_transitions", "outcome_initiation"]
