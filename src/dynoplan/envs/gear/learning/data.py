"""The gear models' data: datasets read and checked, cut into arrays and split.

- :func:`read_demos` / :func:`read_labelled`: datasets of the gear assembly with option
  labels (``infos["option"]``) and, for demonstrations, ``infos["progress"]``;
  held-out trials come from ``seed + HELDOUT_SEED_OFFSET``
  (:func:`~dynoplan.experiments.gear_stages.demonstrations`) and :func:`check_disjoint`
  rejects shared seeds with the demonstrations.
- :func:`demo_arrays`: per demonstration, planner states ``(T+1, 22)``, progress
  ``(T+1,)`` and option labels ``(T,)``.
- :func:`demonstration_transitions`: option transitions at the decision rate cut from
  demonstrations (a stand-in for ``dynoplan gear collect``);
  :func:`option_trajectories` gives the planner states of one option's runs (the
  pipeline's :func:`~dynoplan.pipeline.fit_data.split_runs` holds out whole runs).
"""

from collections.abc import Iterable, Sequence
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
from dynoplan.pipeline.collect import decision_rows
from dynoplan.types import FloatArray, IntArray

HELDOUT_SEED_OFFSET = 1000
"""Held-out trials are recorded from ``seed + HELDOUT_SEED_OFFSET`` (disjoint episodes)."""
CAUTIOUS = PAPER_OPTIONS.index(CAUTIOUS_MOVE.name)
"""The cautious move's label (a held-out trial the human interrupted has it)."""
TRANSITIONS_ID = "dynoplan/gear-assembly/demo-transitions-v0"


def demonstration_transitions(demos: Iterable[Episode],
                              decision_steps: int = DECISION_STEPS) -> list[Episode]:
    """A stand-in for collected option transitions, cut from expert demonstrations.

    Every maximal run of one option label in a demonstration becomes ``decision_steps``
    episodes, one per offset ``o``: its observations ``o, o + k, o + 2k, ...`` (``k =
    decision_steps``) up to the run's last observation, so each step is one decision of
    that option. ``actions`` and ``infos["option"]`` are the option index; rewards are 0.
    Runs shorter than ``k`` steps give nothing.
    """
    out: list[Episode] = []
    for index, episode in enumerate(demos):
        labels = episode.options
        if labels is None:
            raise DynoplanError(f"demonstration {index} has no infos['option'] labels")
        starts = np.flatnonzero(np.r_[True, labels[1:] != labels[:-1]])
        ends = np.r_[starts[1:], len(labels)]
        for a, b in zip(starts, ends, strict=True):
            k = int(labels[a])
            for rows in decision_rows(int(b - a), decision_steps):
                idx = a + rows
                steps = len(idx) - 1
                out.append(Episode(
                    observations=episode.observations[idx],
                    actions=np.full(steps, k, dtype=np.int64),
                    rewards=np.zeros(steps),
                    terminations=np.zeros(steps, dtype=bool),
                    truncations=np.r_[np.zeros(steps - 1, dtype=bool), True],
                    infos={"option": np.full(steps, k, dtype=np.int64)},
                    seed=episode.seed,
                ))
    return out


def write_demonstration_transitions(demos: Path, out: Path,
                                    decision_steps: int = DECISION_STEPS) -> Path:
    """Write :func:`demonstration_transitions` of the dataset ``demos`` as a dataset."""
    source = read_dataset(demos)
    episodes = demonstration_transitions(source, decision_steps)
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

