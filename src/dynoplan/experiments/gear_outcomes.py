"""The gear options started beyond their own start regions, and what came of it: the data
of the initiation learned from outcomes (:mod:`dynoplan.models.outcome_initiation`) and
of dynamics that have seen where an option does not belong.

Run ``r`` of option ``o`` (everything seeded from ``[seed, OUTCOME_STREAM, o, r]``):

1. with probability ``own_fraction`` the env is driven to a start of ``o`` itself, else
   to a start of another registered option, the *source*
   (:func:`~dynoplan.envs.gear.options.starts.reach_start`, the human in a random mode);
2. another source runs for a random number of decisions (0 to ``lead_decisions``), so
   that the starts cover the states the other options visit, not only where they begin;
3. option ``o`` starts there and runs until it finishes, the episode ends or
   ``max_decisions`` decisions pass.

Each decision state ``s_i`` of ``o``'s run is a start with a known outcome: the run from
``s_i`` on *ended well* (:func:`run_outcomes`) when the option reached its own end
(``status == "done"`` and its own ``succeeded(info)``) without touching the human, and
did not finish at once: more than one decision remained, or the step ended the task with
success. The runs are
written in the dataset format of ``gear collect`` (one episode per phase offset of the
decision period, observations one decision apart, ``infos["option"]``), plus
``infos["outcome"]`` ``(T,)``: the outcome of starting at each observation.
"""

from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from dynoplan.data import DatasetMetadata, Episode, read_dataset, write_dataset
from dynoplan.envs import GEAR_ASSEMBLY_ID
from dynoplan.envs.gear.env import GearAssemblyEnv
from dynoplan.envs.gear.human import HUMAN_MODES
from dynoplan.envs.gear.options.catalog import GEAR_OPTIONS
from dynoplan.envs.gear.options.motion import reseed_ompl
from dynoplan.envs.gear.options.starts import reach_start
from dynoplan.envs.gear.state import DECISION_STEPS, PlannerState
from dynoplan.errors import DynoplanError
from dynoplan.experiments.gear_collect import CollectJob, CollectState, build_collection
from dynoplan.parallel import SERIAL, Workers, parallel_map
from dynoplan.types import BoolArray, FloatArray, IntArray

DATASET_ID = "dynoplan/gear-assembly/option-outcomes-v0"
OUTCOME_KEY = "outcome"
OUTCOME_STREAM = 17
"""Seed stream of the outcome runs (disjoint from ``gear collect``'s ``[seed, o, r]``)."""


@dataclass(frozen=True)
class OutcomeSettings:
    """Sizes of the outcome runs.

    Attributes:
        runs: runs per option.
        max_decisions: decisions (0.5 s each) the option may run.
        lead_decisions: decisions another source option may run first (drawn uniformly
            in ``0..lead_decisions``).
        own_fraction: share of the runs started in the option's own start region (no
            lead), so that where it works is as well sampled as where it does not.
    """

    runs: int = 40
    max_decisions: int = 30
    lead_decisions: int = 12
    own_fraction: float = 0.5


def run_outcomes(contacts: IntArray, reached_end: bool, task_success: bool) -> BoolArray:
    """Outcomes of starting the option at each step of a run: ``(T,)`` booleans for a run
    of ``T`` env steps with ``contacts`` ``(T,)`` robot-human contacts per step.

    From step ``t`` the option ended well when the run reached the option's own end
    (``reached_end``), no contact happened from ``t`` on, and from there it took more
    than one decision (:data:`DECISION_STEPS` steps), unless its last step was the task's
    success: an option that would finish at once where it starts is not admissible
    there."""
    c = np.asarray(contacts, dtype=np.int64)
    steps = len(c)
    later = np.cumsum(c[::-1])[::-1]  # contacts from step t on
    remaining = steps - np.arange(steps)
    out: BoolArray = reached_end & (later == 0) & ((remaining > DECISION_STEPS)
                                                   | task_success)
    return out


def outcome_run(state: CollectState, run: tuple[str, int], settings: OutcomeSettings
                ) -> tuple[str, str, list[Episode]]:
    """Run ``run = (option, index)`` (module docstring); returns the source option, the
    human mode and the run's episodes (one per phase offset)."""
    option, index = run
    env = state.env
    names = GEAR_OPTIONS.names()
    key = [state.job.seed, OUTCOME_STREAM, GEAR_OPTIONS.index(option), index]
    reseed_ompl(int(np.random.SeedSequence(key).generate_state(1)[0]))
    rng = np.random.default_rng(key)
    own = bool(rng.random() < settings.own_fraction)
    others = [n for n in names if n != option] or [option]
    source = option if own else others[int(rng.integers(len(others)))]
    mode = HUMAN_MODES[int(rng.integers(len(HUMAN_MODES)))]
    start = reach_start(env, source, rng, human_mode=mode)
    obs, info = start.observation, start.info
    lead = 0 if own else int(rng.integers(settings.lead_decisions + 1)) * DECISION_STEPS
    if lead:
        lead_policy = state.policies[source]
        lead_policy.reset(obs, rng)
        for _ in range(lead):
            obs, _, terminated, truncated, info = env.step(lead_policy.act(obs))
            if lead_policy.finished() or terminated or truncated:
                break
    policy = state.policies[option]
    label = GEAR_OPTIONS.index(option)
    observations: list[FloatArray] = [obs]
    terminated = truncated = False
    contacts: list[int] = []
    if not (bool(info.get("is_success")) or bool(info.get("gear_dropped"))):
        policy.reset(obs, rng)
        for _ in range(settings.max_decisions * DECISION_STEPS):
            obs, _, terminated, truncated, info = env.step(policy.act(obs))
            observations.append(obs)
            contacts.append(int(info["human_contacts"]))
            if policy.finished() or terminated or truncated:
                break
    steps = len(observations) - 1
    success = bool(info.get("is_success"))
    # the task's success ends the episode before the policy can say it is done
    reached_end = (steps > 0 and (policy.status == "done" or success)
                   and bool(policy.succeeded(info)))
    outcomes = run_outcomes(np.asarray(contacts, dtype=np.int64), reached_end, success)
    all_obs = np.asarray(observations)
    episodes = []
    for offset in range(min(DECISION_STEPS, len(all_obs) - 1)):
        rows = np.arange(offset, len(all_obs), DECISION_STEPS)
        if rows[-1] != len(all_obs) - 1:  # end where the run ended (within a decision)
            rows = np.r_[rows, len(all_obs) - 1]
        n = len(rows) - 1
        if n < 1:
            continue
        # the outcome of starting at rows[:-1]: that of the decision it falls in
        start_outcome = outcomes[rows[:-1]]
        episodes.append(Episode(
            observations=all_obs[rows], actions=np.full(n, label, dtype=np.int64),
            rewards=np.zeros(n), terminations=np.zeros(n, dtype=bool),
            truncations=np.zeros(n, dtype=bool),
            infos={"option": np.full(n, label, dtype=np.int64),
                   OUTCOME_KEY: np.asarray(start_outcome, dtype=bool)},
            seed=start.env_seed))
    if steps == 0:  # nothing ran (the task was over at the start): no data
        episodes = []
    return source, mode, episodes


def _outcome_item(state: CollectState, item: tuple[str, int, OutcomeSettings]
                  ) -> tuple[str, str, list[Episode]]:
    option, index, settings = item
    return outcome_run(state, (option, index), settings)


def collect_outcomes(models: Path, seed: int, out: Path,
                     settings: OutcomeSettings = OutcomeSettings(), progress: bool = True,
                     workers: Workers = SERIAL) -> dict[str, Any]:
    """Run every registered option ``settings.runs`` times from starts beyond its own
    region (module docstring); write the dataset ``out``; return a summary (runs, starts
    and good outcomes per option). The same on one worker or many."""
    if settings.runs < 1 or settings.max_decisions < 1 or settings.lead_decisions < 0:
        raise DynoplanError("outcome runs need runs >= 1, max_decisions >= 1 and "
                            "lead_decisions >= 0")
    names = GEAR_OPTIONS.names()
    job = CollectJob(models, names, seed, settings.max_decisions)
    items = [(name, r, settings) for name in names for r in range(settings.runs)]
    episodes: list[Episode] = []
    sources: list[str] = []
    modes: list[str] = []
    firsts: list[Episode] = []  # offset 0 of every run: its decisions, counted once
    for source, mode, run_episodes in parallel_map(build_collection, _outcome_item, job,
                                                   items, workers, "outcome runs", progress):
        episodes += run_episodes
        sources += [source] * len(run_episodes)
        modes += [mode] * len(run_episodes)
        firsts += run_episodes[:1]
    env = GearAssemblyEnv()
    obs_space = env.observation_space
    env.close()
    assert isinstance(obs_space, gym.spaces.Box)
    metadata = DatasetMetadata(
        dataset_id=DATASET_ID, env_id=GEAR_ASSEMBLY_ID, option_names=list(names), seed=seed,
        extra={"decision_steps": DECISION_STEPS, "human_modes": modes, "sources": sources,
               "settings": {"runs": settings.runs, "max_decisions": settings.max_decisions,
                            "lead_decisions": settings.lead_decisions},
               "actions": "the option's index (one run of one option per episode)",
               "outcome": "infos['outcome'][t]: the option, started at observation t, "
                          "reached its own end and did not finish at once"},
        observation_space=obs_space)
    write_dataset(out, episodes, metadata)
    _, ok = outcome_starts(firsts, PlannerState())
    return {"dataset": str(out), "runs": len(items), "episodes": len(episodes),
            "starts": {n: len(ok[n]) for n in names},
            "ended_well": {n: int(ok[n].sum()) for n in names},
            "sources": dict(Counter(sources)), "human_modes": dict(Counter(modes))}


def outcome_starts(episodes: Iterable[Episode], planner: PlannerState,
                   ) -> tuple[dict[str, FloatArray], dict[str, BoolArray]]:
    """Per registered option, the planner states ``(N, 22)`` its runs started from (every
    observation but the last of every episode) and their outcomes ``(N,)``."""
    names = GEAR_OPTIONS.names()
    states: dict[str, list[FloatArray]] = {n: [] for n in names}
    labels: dict[str, list[BoolArray]] = {n: [] for n in names}
    for episode in episodes:
        if OUTCOME_KEY not in episode.infos or episode.options is None:
            raise DynoplanError("outcome runs need infos['outcome'] and infos['option']")
        k = int(episode.options[0])
        states[names[k]].append(planner(episode.observations[:-1]))
        labels[names[k]].append(np.asarray(episode.infos[OUTCOME_KEY], dtype=bool))
    return ({n: np.concatenate(v) if v else np.zeros((0, 22)) for n, v in states.items()},
            {n: np.concatenate(v) if v else np.zeros(0, dtype=bool) for n, v in labels.items()})


def fit_gear_initiation(models: Path, outcomes: Path, seed: int,
                        features: str = "relative") -> dict[str, Any]:
    """Fit the initiation learned from outcomes on the outcome runs ``outcomes``
    (:func:`collect_outcomes`), reading the feature map ``features`` of the planner state;
    write it into the models folder ``models`` (``initiation.safetensors``, recorded in
    ``models.json``); return the fit's report per option, with ``admissible_share``: the
    share of the runs' start states where the option is now admissible (learned
    initiation alone)."""
    from dynoplan.envs.gear.features import feature_map
    from dynoplan.models.folder import INITIATION_FILE, set_initiation
    from dynoplan.models.outcome_initiation import OutcomeInitiation, fit_report_dict

    fmap = feature_map(features)
    starts, ok = outcome_starts(read_outcomes(outcomes), PlannerState())
    x = {n: fmap(s) for n, s in starts.items() if len(s)}
    fitted, report = OutcomeInitiation.fit(x, {n: ok[n] for n in x}, seed=seed)
    fitted.save(models / INITIATION_FILE)
    set_initiation(models, INITIATION_FILE, fmap.name)
    pooled = np.concatenate(list(x.values()))
    out = fit_report_dict(report)
    for name in out:
        out[name]["admissible_share"] = float(fitted.contains(pooled, name).mean())
    missing = [n for n in GEAR_OPTIONS.names() if n not in x]
    return {"options": out, "without_runs": missing, "features": fmap.name,
            "file": str(models / INITIATION_FILE)}


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


__all__ = [
    "DATASET_ID",
    "OUTCOME_KEY",
    "OutcomeSettings",
    "collect_outcomes",
    "fit_gear_initiation",
    "outcome_run",
    "outcome_starts",
    "read_outcomes",
    "run_outcomes",
    "transitions_beyond",
]
