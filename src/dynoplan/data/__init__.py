"""Episodes with option labels and their on-disk datasets (Minari's HDF5 layout).

- :class:`Episode` -- one trajectory: observations ``(T+1, ...)``, actions, rewards,
  terminations, truncations ``(T, ...)`` and per-step ``infos`` such as ``"option"``
  and ``"progress"``.
- :func:`write_dataset` / :func:`read_dataset` -- a dataset folder that Minari and
  plain ``h5py`` can read too; the layout is documented in ``docs/dataset-format.md``.
  :class:`DatasetMetadata` names the options (``option_names[k]`` for label ``k``),
  the environment and the provenance.

The arrays the safety regions and dynamics models are trained on are cut from episodes
by :mod:`dynoplan.pipeline.fit_data`.
"""

from dynoplan.data.dataset import Dataset, dataset_path, read_dataset, write_dataset
from dynoplan.data.episodes import (
    OPTION_KEY,
    PROGRESS_KEY,
    Episode,
    EpisodeFieldError,
    check_option_labels,
)
from dynoplan.data.metadata import FORMAT_VERSION, DatasetMetadata

__all__ = [
    "FORMAT_VERSION",
    "OPTION_KEY",
    "PROGRESS_KEY",
    "Dataset",
    "DatasetMetadata",
    "Episode",
    "EpisodeFieldError",
    "check_option_labels",
    "dataset_path",
    "read_dataset",
    "write_dataset",
]
