"""The gear models' data: datasets read and checked, cut into arrays and split.

- :func:`read_demos` / :func:`read_labelled`: datasets of the gear assembly with option
  labels (``infos["option"]``) and, for demonstrations, ``infos["progress"]``;
  held-out trials come from ``seed + HELDOUT_SEED_OFFSET``
  (:func:`~dynoplan.envs.gear.stages.demonstrations`) and :func:`check_disjoint`
  rejects shared seeds with the demonstrations.
- :func:`demo_arrays`: per demonstration, planner states ``(T+1, 22)``, progress
  ``(T+1,)`` and option labels ``(T,)``.
- :func:`write_demonstration_transitions`: option transitions at the decision rate cut
  from demonstrations by the pipeline's :func:`~dynoplan.pipeline.fit_data.decision_runs`
  (a stand-in for ``dynoplan gear collect``), as a dataset;
  :func:`option_trajectories` gives the planner states of one option's runs (the
  pipeline's :func:`~dynoplan.pipeline.fit_data.split_runs` holds out whole runs).
"""

from collections.abc import Sequence
from pathlib import Path

import gymnasium as gym
import numpy as np

from dynoplan.data import (
    Dataset,
    DatasetMetadata,
    Episode,
    read_dataset,
    write_dataset,
)
from dynoplan.envs.gear.env import OBS_DIM
from dynoplan.envs.gear.options.catalog import CAUTIOUS_MOVE, PAPER_OPTIONS, gear_option_names
from dynoplan.envs.gear.state import DECISION_STEPS, PlannerState
from dynoplan.errors import DynoplanError
from dynoplan.pipeline.fit_data import decision_runs
from dynoplan.types import FloatArray, IntArray

HELDOUT_SEED_OFFSET = 1000
"""Held-out trials are recorded from ``seed + HELDOUT_SEED_OFFSET`` (disjoint episodes)."""
CAUTIOUS = PAPER_OPTIONS.index(CAUTIOUS_MOVE.name)
"""The cautious move's label (a held-out trial the human interrupted has it)."""
TRANSITIONS_ID = "dynoplan/gear-assembly/demo-transitions-v0"


def write_demonstration_transitions(demos: Path, out: Path,
                                    decision_steps: int = DECISION_STEPS) -> Path:
    """Write the option transitions at the decision rate cut from the dataset ``demos``
    (the pipeline's :func:`~dynoplan.pipeline.fit_data.decision_runs`) as a dataset."""
    source = read_dataset(demos)
    episodes = decision_runs(list(source), decision_steps)
    if not episodes:
        raise DynoplanError(f"{demos}: no option run lasts {decision_steps} steps")
    meta = source.metadata
    metadata = DatasetMetadata(
        dataset_id=TRANSITIONS_ID, env_id=meta.env_id, env_spec=meta.env_spec,
        option_names=list(meta.option_names), seed=meta.seed,
        extra={"decision_steps": decision_steps, "source": str(demos),
               "note": "expert demonstrations subsampled every decision_steps steps, one "
                       "episode per option run and offset (stand-in for collected "
                       "option transitions)"},
        observation_space=meta.observation_space,
        action_space=gym.spaces.Discrete(len(meta.option_names)))
    return write_dataset(out, episodes, metadata)


def read_labelled(path: Path, what: str) -> Dataset:
    dataset = read_dataset(path)
    names = list(dataset.metadata.option_names)
    registered = list(gear_option_names())
    if not names or names != registered[:len(names)]:  # labels index the registered options
        raise DynoplanError(f"{path}: {what} name options {names}, expected {registered}")
    for i, episode in enumerate(dataset):
        if episode.options is None:
            raise DynoplanError(f"{path}: {what} episode {i} has no infos['option'] labels")
        if episode.observations.shape[1:] != (OBS_DIM,):
            raise DynoplanError(f"{path}: {what} episode {i} has observations of shape "
                                f"{episode.observations.shape[1:]}, expected ({OBS_DIM},) "
                                "(the gear assembly's)")
    return dataset


def read_demos(path: Path, what: str) -> Dataset:
    dataset = read_labelled(path, what)
    for i, episode in enumerate(dataset):
        if "progress" not in episode.infos:
            raise DynoplanError(f"{path}: {what} episode {i} has no infos['progress']")
    return dataset


def demo_arrays(dataset: Dataset, planner: PlannerState
                 ) -> list[tuple[FloatArray, FloatArray, IntArray]]:
    """Per episode: planner states ``(T+1, 22)``, progress ``(T+1,)`` (0 at the reset) and
    the option label of each step ``(T,)``.

    Raises:
        DynoplanError: an episode without ``infos["option"]`` or ``infos["progress"]``.
    """
    out = []
    for episode in dataset:
        labels = episode.options
        if labels is None or "progress" not in episode.infos:
            raise DynoplanError(f"{dataset.path}: trials need infos['option'] and "
                                "infos['progress']")
        out.append((planner(episode.observations), np.r_[0.0, episode.infos["progress"]],
                    labels))
    return out


def check_disjoint(train: Dataset, held: Dataset, where: Path) -> None:
    shared = {e.seed for e in train if e.seed is not None} & {
        e.seed for e in held if e.seed is not None}
    if shared:
        raise DynoplanError(f"{where}: held-out trials share episode seeds {sorted(shared)} "
                            "with the training demonstrations; use disjoint seeds")


def option_trajectories(episodes: Sequence[Episode], planner: PlannerState,
                        k: int) -> list[FloatArray]:
    """Planner states of the held-out episodes run by option ``k`` only."""
    out = []
    for episode in episodes:
        labels = episode.options
        if labels is not None and (labels == k).all():
            out.append(planner(episode.observations))
    return out

