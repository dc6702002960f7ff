"""The gear options started beyond their own start regions, and what came of it: the data
of the initiation learned from outcomes (:mod:`dynoplan.models.outcome_initiation`) and
of dynamics that have seen where an option does not belong.

The pipeline's outcome runs (:func:`~dynoplan.pipeline.collect.collect_option_runs` with
``outcomes``): run ``r`` of option ``o`` (everything seeded from ``[seed,
OUTCOME_STREAM, o, r]``) starts at a start of ``o`` or of another option, which may run
first (:func:`~dynoplan.envs.gear.runs.beyond_start`); ``o`` then runs until it
finishes, the episode ends or ``max_decisions`` decisions pass, and each of its decision
states is a start with a known outcome (:func:`~dynoplan.envs.gear.runs.ended_well`).
The runs are written in the dataset format of ``gear collect`` (one episode per phase
offset of the decision period, observations one decision apart, ``infos["option"]``),
plus ``infos["outcome"]`` ``(T,)``: the outcome of starting at each observation.
"""

from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from dynoplan.data import DatasetMetadata, Episode, read_dataset, write_dataset
from dynoplan.envs.gear.features import RELATIVE
from dynoplan.envs.gear.option_runs import write_runs
from dynoplan.envs.gear.options.catalog import GEAR_OPTIONS
from dynoplan.envs.gear.pipeline_task import GearTask
from dynoplan.envs.gear.state import DECISION_STEPS, PlannerState
from dynoplan.errors import DynoplanError
from dynoplan.parallel import SERIAL, Workers
from dynoplan.pipeline.collect import OptionRunSettings, OptionRunsJob, collect_option_runs
from dynoplan.pipeline.fit import fit_initiation_from_outcomes, outcome_starts

DATASET_ID = "dynoplan/gear-assembly/option-outcomes-v0"
OUTCOME_STREAM = 17
"""Seed stream of the outcome runs (disjoint from ``gear collect``'s ``[seed, o, r]``)."""


def collect_outcomes(models: Path, seed: int, out: Path,
                     settings: OptionRunSettings = OptionRunSettings(), progress: bool = True,
                     workers: Workers = SERIAL) -> dict[str, Any]:
    """Run every registered option ``settings.runs`` times from starts beyond its own
    region (module docstring); write the dataset ``out``; return a summary (runs, starts
    and good outcomes per option). The same on one worker or many."""
    if settings.runs < 1 or settings.max_decisions < 1 or settings.lead_decisions < 0:
        raise DynoplanError("outcome runs need runs >= 1, max_decisions >= 1 and "
                            "lead_decisions >= 0")
    names = GEAR_OPTIONS.names()
    job = OptionRunsJob(GearTask(), models, names, seed,
                        settings.max_decisions * DECISION_STEPS, outcomes=True,
                        lead_decisions=settings.lead_decisions, stream=(OUTCOME_STREAM,))
    episodes: list[Episode] = []
    sources: list[str] = []
    modes: list[str] = []
    firsts: list[Episode] = []  # offset 0 of every run: its decisions, counted once
    for tags, run_episodes in collect_option_runs(job, settings.runs, workers,
                                                  "outcome runs", progress):
        episodes += run_episodes
        sources += [tags["source"]] * len(run_episodes)
        modes += [tags["human_mode"]] * len(run_episodes)
        firsts += run_episodes[:1]
    write_runs(out, episodes, DATASET_ID, seed,
               {"decision_steps": DECISION_STEPS, "human_modes": modes, "sources": sources,
                "settings": {"runs": settings.runs, "max_decisions": settings.max_decisions,
                             "lead_decisions": settings.lead_decisions},
                "actions": "the option's index (one run of one option per episode)",
                "outcome": "infos['outcome'][t]: the option, started at observation t, "
                           "reached its own end and did not finish at once"})
    _, ok = outcome_starts(firsts, names, PlannerState())
    return {"dataset": str(out), "runs": len(names) * settings.runs,
            "episodes": len(episodes),
            "starts": {n: len(ok[n]) for n in names},
            "ended_well": {n: int(ok[n].sum()) for n in names},
            "sources": dict(Counter(sources)), "human_modes": dict(Counter(modes))}


def fit_gear_initiation(models: Path, outcomes: Path, seed: int,
                        features: str = RELATIVE.name) -> dict[str, Any]:
    """The initiation learned from the outcome runs ``outcomes`` (:func:`collect_outcomes`)
    on the feature map ``features`` of the planner state, written into the models folder
    ``models`` (:func:`~dynoplan.pipeline.fit.fit_initiation_from_outcomes`, inside
    :func:`~dynoplan.models.trainer.deterministic_training`: the same file to the bit for
    the same runs and ``seed`` on one machine); the fit's report."""
    from dynoplan.envs.gear.features import feature_map
    from dynoplan.models.trainer import deterministic_training

    runs = read_outcomes(outcomes)
    with deterministic_training():
        return fit_initiation_from_outcomes(models, runs, GEAR_OPTIONS.names(),
                                            PlannerState(), feature_map(features), seed)


def transitions_beyond(transitions: Path, outcomes: Path, out: Path) -> dict[str, Any]:
    """The option transitions of ``gear collect`` (``transitions``) and those of the
    outcome runs (``outcomes``, options started beyond their own regions) as one dataset
    ``out`` for ``gear train --transitions``: dynamics that have seen where each option
    does not belong. Only ``infos["option"]`` is kept."""
    source = read_dataset(transitions)
    episodes = [Episode(e.observations, e.actions, e.rewards, e.terminations, e.truncations,
                        {"option": np.asarray(e.infos["option"])}, e.seed)
                for e in [*source, *read_outcomes(outcomes)]]
    meta = source.metadata
    metadata = DatasetMetadata(
        dataset_id="dynoplan/gear-assembly/option-transitions-beyond-v0", env_id=meta.env_id,
        option_names=list(meta.option_names), seed=meta.seed,
        extra={**meta.extra, "human_modes": None, "sources": [str(transitions), str(outcomes)]},
        observation_space=meta.observation_space)
    write_dataset(out, episodes, metadata)
    return {"dataset": str(out), "episodes": len(episodes)}


def read_outcomes(path: Path) -> list[Episode]:
    """The episodes of an outcome dataset (:func:`collect_outcomes`), checked."""
    dataset = read_dataset(path)
    if list(dataset.metadata.option_names) != list(GEAR_OPTIONS.names()):
        raise DynoplanError(f"{path}: outcome runs of options {dataset.metadata.option_names}, "
                            f"expected the registered {list(GEAR_OPTIONS.names())}")
    return list(dataset)


__all__ = ["DATASET_ID", "OUTCOME_STREAM", "collect_outcomes",
           "fit_gear_initiation", "read_outcomes", "transitions_beyond"]
