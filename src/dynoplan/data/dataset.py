"""Datasets of episodes on disk, in Minari's HDF5 layout (see ``docs/dataset-format.md``).

A dataset is a folder::

    <folder>/data/main_data.hdf5   one group per episode: episode_0, episode_1, ...
    <folder>/data/metadata.json    Minari's metadata, plus our block under "dynoplan"

This is the layout Minari 0.5 writes, so ``minari.MinariDataset("<folder>/data")``
reads our datasets, and a folder at ``$MINARI_DATASETS_PATH/<dataset_id>`` (see
:func:`dataset_path`) is found by ``minari.load_dataset(dataset_id)``. We write it
with ``h5py`` alone, without Minari's writer and the ``jax`` it needs.

One convention differs between the file and :class:`Episode`: Minari stores ``T+1``
rows of ``infos`` (the reset info first, then one per step), an :class:`Episode` holds
the ``T`` per-step rows. The writer puts a fill row first (NaN, -1 or False), the
reader drops the first row.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym
import h5py
import numpy as np

from dynoplan.data.episodes import Episode, EpisodeFieldError, check_option_labels
from dynoplan.data.metadata import (
    METADATA_FILE,
    DatasetMetadata,
    Space,
    metadata_to_json,
    read_metadata,
)
from dynoplan.errors import DynoplanError
from dynoplan.io import staged_folder, write_json
from dynoplan.limits import DATASET_BYTES_MAX

DATA_DIR = "data"
MAIN_FILE = "main_data.hdf5"
STEP_FIELDS = ("observations", "actions", "rewards", "terminations", "truncations")


@dataclass(eq=False)
class Dataset:
    """Episodes with their metadata, as read by :func:`read_dataset`.

    Iterating yields the episodes in order; ``len`` is the number of episodes.
    """

    metadata: DatasetMetadata
    episodes: list[Episode]
    path: Path | None = None

    def __len__(self) -> int:
        return len(self.episodes)

    def __iter__(self) -> Iterator[Episode]:
        return iter(self.episodes)

    def __getitem__(self, index: int) -> Episode:
        return self.episodes[index]

    @property
    def total_steps(self) -> int:
        """Steps (actions) summed over all episodes."""
        return sum(len(episode) for episode in self.episodes)


def dataset_path(dataset_id: str, root: str | os.PathLike[str] | None = None) -> Path:
    """The folder where ``minari.load_dataset(dataset_id)`` looks for a dataset.

    ``root`` defaults to ``$MINARI_DATASETS_PATH``, else ``~/.minari/datasets``.
    """
    DatasetMetadata(dataset_id)  # validates the id
    if root is None:
        root = os.environ.get("MINARI_DATASETS_PATH") or Path.home() / ".minari" / "datasets"
    return Path(root) / dataset_id


def write_dataset(
    path: str | os.PathLike[str], episodes: Sequence[Episode], metadata: DatasetMetadata
) -> Path:
    """Write ``episodes`` as a dataset folder at ``path`` and return the folder.

    The dataset is written to a temporary folder beside ``path`` and renamed into place
    when complete: readers see the old dataset or the new one, never a part. An
    existing dataset folder at ``path`` is replaced; any other existing folder is left
    alone and reported.

    Raises:
        DynoplanError: no episodes, episodes that disagree on shapes or info keys,
            labels outside ``metadata.option_names``, data outside the given spaces, or
            a ``path`` that holds something other than a dataset.
    """
    target = Path(path)
    episodes = list(episodes)
    if not episodes:
        raise DynoplanError(f"{target}: no episodes to write")
    for index, episode in enumerate(episodes):
        if not isinstance(episode, Episode):
            raise DynoplanError(
                f"episode {index}: expected an Episode, got {type(episode).__name__}"
            )
        _check_consistent(episode, episodes[0], index)
        try:
            check_option_labels(episode, len(metadata.option_names))
        except EpisodeFieldError as exc:
            raise DynoplanError(f"episode {index}: {exc.field}: {exc.detail}") from None
    obs_space = metadata.observation_space
    if obs_space is None:
        obs_space = _infer_observation_space(episodes[0])
    act_space = metadata.action_space
    if act_space is None:
        act_space = _infer_action_space(episodes)
    for index, episode in enumerate(episodes):
        problem = _space_mismatch(episode, obs_space, act_space)
        if problem:
            raise DynoplanError(f"episode {index}: {problem}")
    check_dataset_target(target)

    with staged_folder(target) as tmp:
        data = tmp / DATA_DIR
        data.mkdir()
        _write_hdf5(data / MAIN_FILE, episodes)
        size_mb = round((data / MAIN_FILE).stat().st_size / 1e6, 1)
        doc = metadata_to_json(
            metadata,
            total_episodes=len(episodes),
            total_steps=sum(len(e) for e in episodes),
            observation_space=obs_space,
            action_space=act_space,
            size_mb=size_mb,
        )
        write_json(data / METADATA_FILE, doc)
    return target


def read_dataset(path: str | os.PathLike[str]) -> Dataset:
    """Read the dataset folder at ``path`` (or its ``data`` subfolder), fully validated.

    Also reads plain Minari datasets with Box observations and Box or Discrete actions;
    their metadata has ``format_version == 0`` and no option names.

    Raises:
        DynoplanError: a missing folder or file, malformed metadata, a truncated or
            corrupt HDF5 file, a missing episode or field, wrong shapes, non-finite
            observations, an unknown format version or out-of-range option labels. The
            message names the file and the field.
    """
    folder = Path(path)
    if not folder.is_dir():
        raise DynoplanError(f"{folder}: dataset folder not found")
    data = folder / DATA_DIR
    if not data.is_dir() and any((folder / f).exists() for f in (MAIN_FILE, METADATA_FILE)):
        data = folder  # the path names the data folder itself, as minari.MinariDataset takes
    meta_file, main_file = data / METADATA_FILE, data / MAIN_FILE
    for needed in (meta_file, main_file):
        if not needed.is_file():
            raise DynoplanError(
                f"{needed}: file not found (a dataset folder holds "
                f"{DATA_DIR}/{MAIN_FILE} and {DATA_DIR}/{METADATA_FILE})"
            )
    metadata, total_episodes, total_steps = read_metadata(meta_file)
    episodes = _read_hdf5(main_file, total_episodes, total_steps)
    for index, episode in enumerate(episodes):
        where = f"{main_file}: episode_{index}"
        problem = _space_mismatch(episode, metadata.observation_space, metadata.action_space)
        if problem:
            raise DynoplanError(f"{where}: {problem} (from {METADATA_FILE})")
        if metadata.format_version > 0:
            try:
                check_option_labels(episode, len(metadata.option_names))
            except EpisodeFieldError as exc:
                raise DynoplanError(f"{where}/{exc.field}: {exc.detail}") from None
    found = sum(len(e) for e in episodes)
    if found != total_steps:
        raise DynoplanError(
            f"{meta_file}: total_steps is {total_steps} but the episodes hold {found} steps"
        )
    return Dataset(metadata, episodes, path=data.parent)


# --- writing -----------------------------------------------------------------------


def _write_hdf5(file: Path, episodes: list[Episode]) -> None:
    with h5py.File(file, "w", track_order=True) as h5:
        for index, episode in enumerate(episodes):
            group = h5.create_group(f"episode_{index}")
            group.attrs["id"] = np.int64(index)
            group.attrs["total_steps"] = np.int64(len(episode))
            if episode.seed is not None:
                group.attrs["seed"] = np.int64(episode.seed)
            for name in STEP_FIELDS:
                _create_dataset(group, name, getattr(episode, name))
            if episode.infos:
                infos = group.create_group("infos")
                for key, values in episode.infos.items():
                    _create_dataset(infos, key, np.concatenate([_fill_row(values), values]))


def _create_dataset(group: h5py.Group, name: str, values: np.ndarray) -> None:
    # Chunked and growable along time, as Minari creates them (it appends to them).
    group.create_dataset(name, data=values, chunks=True, maxshape=(None, *values.shape[1:]))


def _fill_row(values: np.ndarray) -> np.ndarray:
    """Row 0 of a stored info: Minari's slot for the reset info, which we do not record."""
    if np.issubdtype(values.dtype, np.floating):
        fill: float | int | bool = np.nan
    elif np.issubdtype(values.dtype, np.signedinteger):
        fill = -1
    elif values.dtype == np.bool_:
        fill = False
    else:
        fill = 0
    return np.full((1, *values.shape[1:]), fill, dtype=values.dtype)


def check_dataset_target(target: Path) -> None:
    """Check that :func:`write_dataset` may write ``target``: missing, an empty folder or
    a dataset folder (never delete other data). Commands call it before any work.

    Raises:
        DynoplanError: one line: ``target`` is a file, or a folder holding other things.
    """
    if not target.exists():
        return
    if not target.is_dir():
        raise DynoplanError(f"{target}: exists and is not a folder; choose a dataset folder path")
    entries = sorted(os.listdir(target))
    data = target / DATA_DIR
    inside = sorted(os.listdir(data)) if data.is_dir() else []
    if entries in ([], [DATA_DIR]) and set(inside) <= {MAIN_FILE, METADATA_FILE}:
        return
    raise DynoplanError(
        f"{target}: exists and is not a dataset folder (holds {', '.join(entries)}); "
        "refusing to replace it"
    )


# --- checks shared by writer and reader ----------------------------------------------


def _check_consistent(episode: Episode, first: Episode, index: int) -> None:
    """Episodes of one dataset share observation, action and info shapes and dtypes."""

    def layout(ep: Episode) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
        arrays = {"observations": ep.observations, "actions": ep.actions}
        arrays.update({f"infos/{k}": v for k, v in ep.infos.items()})
        return {name: (a.shape[1:], a.dtype) for name, a in arrays.items()}

    mine, theirs = layout(episode), layout(first)
    if mine.keys() != theirs.keys():
        raise DynoplanError(
            f"episode {index}: fields {sorted(mine)} differ from episode 0's {sorted(theirs)}"
        )
    for name, (shape, dtype) in mine.items():
        if (shape, dtype) != theirs[name]:
            raise DynoplanError(
                f"episode {index}: {name} has rows of shape {shape} and dtype {dtype}, "
                f"episode 0 has {theirs[name][0]} and {theirs[name][1]}"
            )


def _infer_observation_space(episode: Episode) -> gym.spaces.Box:
    obs = episode.observations
    return gym.spaces.Box(-np.inf, np.inf, shape=obs.shape[1:], dtype=obs.dtype.type)


def _infer_action_space(episodes: list[Episode]) -> Space:
    actions = episodes[0].actions
    if np.issubdtype(actions.dtype, np.floating):
        return gym.spaces.Box(-np.inf, np.inf, shape=actions.shape[1:], dtype=actions.dtype.type)
    low = min(int(e.actions.min()) for e in episodes)
    high = max(int(e.actions.max()) for e in episodes)
    if actions.ndim != 1 or low < 0:
        raise DynoplanError(
            f"actions: integer actions of shape {actions.shape} and minimum {low} do not "
            "fit Discrete(n); pass DatasetMetadata(action_space=...)"
        )
    return gym.spaces.Discrete(high + 1)


def _space_mismatch(episode: Episode, obs_space: Space | None, act_space: Space | None) -> str:
    """Describe how ``episode`` falls outside the spaces, or return ``""``."""
    if obs_space is not None:
        if not isinstance(obs_space, gym.spaces.Box):
            return f"observation_space must be a Box, got {obs_space}"
        if episode.observations.shape[1:] != obs_space.shape:
            return (
                f"observations have rows of shape {episode.observations.shape[1:]}, "
                f"observation_space has shape {obs_space.shape}"
            )
    actions = episode.actions
    if isinstance(act_space, gym.spaces.Box) and actions.shape[1:] != act_space.shape:
        return (
            f"actions have rows of shape {actions.shape[1:]}, "
            f"action_space has shape {act_space.shape}"
        )
    if isinstance(act_space, gym.spaces.Discrete):
        start, n = int(act_space.start), int(act_space.n)
        if actions.ndim != 1 or not np.issubdtype(actions.dtype, np.integer):
            got = f"{actions.dtype} {actions.shape}"
            return f"actions: expected integers (T,) for {act_space}, got {got}"
        bad = np.flatnonzero((actions < start) | (actions >= start + n))
        if bad.size:
            step = int(bad[0])
            return f"actions: {int(actions[step])} at step {step} is outside {act_space}"
    return ""


# --- reading -----------------------------------------------------------------------


def _read_hdf5(file: Path, total_episodes: int, total_steps: int) -> list[Episode]:
    budget = _Budget(file, total_steps + 1, DATASET_BYTES_MAX)
    try:
        with h5py.File(file, "r") as h5:
            return [_read_episode(h5, i, total_episodes, file, budget)
                    for i in range(total_episodes)]
    except (OSError, RuntimeError) as exc:  # h5py's report of a truncated or corrupt file
        message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise DynoplanError(
            f"{file}: not a readable HDF5 file, truncated or corrupt ({message})"
        ) from None


class _Budget:
    """What the arrays of one HDF5 file may declare, checked before each is read (a
    chunked dataset declares any shape without storing it, and reading it would allocate
    all of it): at most ``rows`` rows each (``total_steps + 1`` of the metadata) and
    ``nbytes`` bytes in all."""

    def __init__(self, file: Path, rows: int, nbytes: int) -> None:
        self.file, self.rows, self.left = file, rows, nbytes

    def read(self, node: h5py.Dataset, where: str) -> np.ndarray:
        """``node``'s values, once its declared shape fits.

        Raises:
            DynoplanError: more rows than the metadata's steps allow, or more bytes than
                :data:`~dynoplan.limits.DATASET_BYTES_MAX` with the arrays read before.
        """
        shape = tuple(int(n) for n in node.shape or ())
        if shape and shape[0] > self.rows:
            raise DynoplanError(
                f"{self.file}: {where}: declares {shape[0]} rows, more than total_steps + 1 "
                f"= {self.rows} of {METADATA_FILE}")
        size = math.prod(shape) * node.dtype.itemsize
        if size > self.left:
            raise DynoplanError(
                f"{self.file}: {where}: declares shape {shape} of {node.dtype} ({size} "
                f"bytes), beyond the {DATASET_BYTES_MAX} bytes a dataset may hold")
        self.left -= size
        return node[()]


def _read_episode(h5: h5py.File, index: int, total: int, file: Path,
                  budget: _Budget) -> Episode:
    name = f"episode_{index}"
    group = h5.get(name)
    if not isinstance(group, h5py.Group):
        raise DynoplanError(
            f"{file}: group '{name}' is missing ({METADATA_FILE} says total_episodes = {total})"
        )
    arrays: dict[str, np.ndarray] = {}
    for key in STEP_FIELDS:
        node = group.get(key)
        if not isinstance(node, h5py.Dataset):
            raise DynoplanError(f"{file}: {name}/{key}: dataset is missing")
        arrays[key] = budget.read(node, f"{name}/{key}")
    if np.ndim(arrays["rewards"]) != 1:
        shape = np.shape(arrays["rewards"])
        raise DynoplanError(f"{file}: {name}/rewards: expected shape (T,), got {shape}")
    steps = len(arrays["rewards"])
    infos: dict[str, np.ndarray] = {}
    node = group.get("infos")
    if isinstance(node, h5py.Group):
        for key, values in _flatten(node, budget, f"{name}/infos/").items():
            if values.ndim < 1 or values.shape[0] != steps + 1:
                raise DynoplanError(
                    f"{file}: {name}/infos/{key}: expected T+1 = {steps + 1} rows (the reset "
                    f"info, then one per step), got shape {values.shape}"
                )
            infos[key] = values[1:]
    seed = group.attrs.get("seed")
    try:
        return Episode(**arrays, infos=infos, seed=None if seed is None else int(seed))
    except EpisodeFieldError as exc:
        raise DynoplanError(f"{file}: {name}/{exc.field}: {exc.detail}") from None


def _flatten(group: h5py.Group, budget: _Budget, where: str,
             prefix: str = "") -> dict[str, np.ndarray]:
    """Nested info groups become ``"outer/inner"`` keys, as Minari nests dict infos."""
    out: dict[str, np.ndarray] = {}
    for key, node in group.items():
        if isinstance(node, h5py.Group):
            out.update(_flatten(node, budget, where, f"{prefix}{key}/"))
        elif isinstance(node, h5py.Dataset):
            out[f"{prefix}{key}"] = budget.read(node, f"{where}{prefix}{key}")
    return out
