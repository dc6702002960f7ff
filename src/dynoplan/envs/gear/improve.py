"""The gear's improvement rounds: the pipeline's one loop
(:func:`~dynoplan.pipeline.improve.improvement_rounds`) on the gear's datasets and models
folders, the ``improve`` stage of ``gear run``
(:class:`~dynoplan.envs.gear.pipeline_stages.GearStages`).

Each round runs DynoPlan, as the evaluation builds it, on episodes of its own
(:func:`improvement_seeds`, disjoint from the evaluation's), on the run's workers
(:func:`~dynoplan.pipeline.improve.task_own_episodes`). Then, in ``improve/round-<r>/``:

- ``demos/``: the run's demonstrations and every own episode that succeeded without
  holding (its progress ``t / T``);
- ``transitions/``: the run's option transitions and every option run of the own
  episodes, cut at the decision rate (:func:`~dynoplan.pipeline.fit_data.decision_runs`);
- ``models/``: a copy of the run's models folder (the option networks, the initiation)
  with the goal, the regions and the dynamics fitted again on those two datasets
  (:func:`~dynoplan.envs.gear.stages.learned_models`, the same held-out trials), and the
  initiation fitted again on the run's outcome runs.

The datasets keep the infos the fit reads: ``option`` (and ``progress`` for
demonstrations). The models the settings keep are copied into the run's ``models/``,
which every later stage reads.
"""

import shutil
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from dynoplan.data import Dataset, Episode, read_dataset, write_dataset
from dynoplan.envs.gear.demonstrations import (
    DemoJob,
    build_demonstrator,
    demonstrated_episode,
    succeeded,
    to_dataset_episode,
)
from dynoplan.envs.gear.evaluation import improvement_seeds
from dynoplan.envs.gear.learning.settings import GearMetricsSettings
from dynoplan.envs.gear.options.catalog import gear_option_names
from dynoplan.envs.gear.pipeline_task import GearTask
from dynoplan.envs.gear.stages import learned_models, outcome_initiation
from dynoplan.envs.gear.state import DECISION_STEPS
from dynoplan.parallel import SERIAL, Workers, parallel_map
from dynoplan.pipeline.collect import OptionRunSettings
from dynoplan.pipeline.control_settings import ControllerSettings
from dynoplan.pipeline.fit import FitSettings
from dynoplan.pipeline.fit_data import decision_runs
from dynoplan.pipeline.improve import (
    ImprovementSettings,
    OwnEpisode,
    improvement_rounds,
    task_own_episodes,
)
from dynoplan.seeding import EpisodeSeed

IMPROVE_DIR = "improve"
"""The rounds' datasets and models, inside the run's folder."""


def improved_models(out: Path, seed: int, settings: ImprovementSettings, fit: FitSettings,
                    metrics: GearMetricsSettings, outcomes: OptionRunSettings,
                    planner: ControllerSettings, progress: bool = False,
                    workers: Workers = SERIAL,
                    say: Callable[[str], None] = lambda _: None,
                    region_starts: Path | None = None,
                    own_states: bool = False) -> list[dict[str, Any]]:
    """``settings.rounds`` improvement rounds on the gear run in ``out`` (its ``demos/``,
    ``heldout/``, ``transitions/``, ``outcomes/`` and ``models/``; ``outcomes.runs`` 0: no
    initiation learned from outcomes), DynoPlan planning as ``planner`` says, the regions
    refitted with the labelled start states ``region_starts`` when given (the dynamics on
    the options' own states with ``own_states``, as the first fit); the models
    ``settings.keep`` says end in ``out/models``. The learning curve
    (:func:`~dynoplan.pipeline.improve.improvement_rounds`)."""
    folder = out / IMPROVE_DIR
    shutil.rmtree(folder, ignore_errors=True)  # a previous run's rounds
    first = out / "models"
    demos_set, runs_set = read_dataset(out / "demos"), read_dataset(out / "transitions")
    demos = [_with_infos(e, ("option", "progress")) for e in demos_set]
    runs = [_with_infos(e, ("option",)) for e in runs_set]
    names = tuple(gear_option_names())

    def play(models: Path, seeds: Sequence[EpisodeSeed], explore: float) -> list[OwnEpisode]:
        return task_own_episodes(GearTask(), models, planner, names, seeds, explore, workers,
                                 progress)

    def refit(r: int, own: list[OwnEpisode]) -> Path:
        demos.extend(_with_infos(e.demonstration, ("option", "progress"))
                     for e in own if e.demonstration is not None)
        runs.extend(_with_infos(e, ("option",)) for e in decision_runs(
            [piece for e in own for piece in e.pieces], DECISION_STEPS))
        round_dir = folder / f"round-{r + 1}"
        _write_like(demos_set, round_dir / "demos", demos, r + 1)
        _write_like(runs_set, round_dir / "transitions", runs, r + 1)
        models = round_dir / "models"
        shutil.copytree(first, models)
        learned_models(round_dir / "demos", round_dir / "transitions", models, seed,
                       out / "heldout", fit, metrics, progress=progress, workers=workers,
                       region_demos=None if settings.regions else out / "demos",
                       region_starts=region_starts, own_states=own_states)
        if outcomes.runs:
            outcome_initiation(models, out / "outcomes", seed, outcomes, progress, workers,
                               collect=False)
        return models

    def demonstrate(seeds: Sequence[EpisodeSeed]) -> list[Episode]:
        return operator_demonstrations(first, seeds, workers, progress)

    kept, curve = improvement_rounds(first, settings,
                                     improvement_seeds(seed, settings.seeds),
                                     play, refit, say, demonstrate)
    if kept != first:
        shutil.copytree(kept, first, dirs_exist_ok=True)
    return curve


def operator_demonstrations(models: Path, seeds: Sequence[EpisodeSeed],
                            workers: Workers = SERIAL,
                            progress: bool = False) -> list[Episode]:
    """The operator (the options' demonstrator, its networks in ``models``) from the
    starts of ``seeds`` (each with its seed's own human behaviour, as in the evaluation):
    its successful episodes, in order, with the infos of the run's demonstrations
    (``option``, ``progress``); the improvement rounds' ``improve_demos``."""
    raw = parallel_map(build_demonstrator, demonstrated_episode, DemoJob("options", models),
                       [(s.env_seed, None) for s in seeds], workers,
                       "gear demos where DynoPlan failed", progress)
    return [_with_infos(to_dataset_episode(r), ("option", "progress")) for r in raw
            if succeeded(r)]


def _with_infos(episode: Episode, keys: Sequence[str]) -> Episode:
    """``episode`` with only the infos ``keys`` (the datasets' episodes agree on them)."""
    return replace(episode, infos={k: episode.infos[k] for k in keys})


def _write_like(source: Dataset, out: Path, episodes: list[Episode], round_: int) -> None:
    """``episodes`` as a dataset at ``out`` with ``source``'s metadata, the round named."""
    meta = source.metadata
    write_dataset(out, episodes, replace(meta, extra={
        **{k: v for k, v in meta.extra.items() if k != "human_modes"},
        "improvement_round": round_,
        "note": "the run's episodes and DynoPlan's own from the improvement rounds"}))


__all__ = ["IMPROVE_DIR", "improved_models", "operator_demonstrations"]
