"""``metadata.json``: Minari's dataset metadata plus our ``"dynoplan"`` block.

See ``docs/dataset-format.md`` for every field. Spaces are stored in Minari's JSON
serialisation; only ``Box`` and ``Discrete`` are supported.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.envs.registration import EnvSpec

from dynoplan import __version__
from dynoplan.errors import DynoplanError
from dynoplan.io import read_json_object

FORMAT_VERSION = 1
"""Version of the ``dynoplan`` block this library writes; readers accept ``<=`` it."""
MINARI_VERSION = "0.5.4"
"""Minari dataset version recorded in ``metadata.json`` (the layout we follow)."""
METADATA_FILE = "metadata.json"

# Minari's dataset id, with the version required: (namespace/)name-v<version>.
_DATASET_ID = re.compile(r"^(?:[-_\w][-_\w/]*[-_\w]+/)?[-_\w]+?-v\d+$")

Space = gym.spaces.Box | gym.spaces.Discrete


@dataclass
class DatasetMetadata:
    """What a dataset is: its id, environment, option names and provenance.

    Attributes:
        dataset_id: Minari id ``(namespace/)name-v<version>``,
            e.g. ``"dynoplan/gear-assembly/expert-v0"``.
        env_id: Gymnasium id of the environment that produced the data.
        env_spec: ``gymnasium.EnvSpec.to_json()`` of that environment, when available.
        option_names: ``option_names[k]`` names the option labelled ``k`` in
            ``infos["option"]``.
        seed: the seed the whole collection was run from.
        dynoplan_version: library version that wrote the dataset.
        format_version: version of the ``dynoplan`` metadata block; ``0`` marks a plain
            Minari dataset read without one.
        extra: free JSON-serialisable metadata.
        observation_space: ``Box``; inferred from the episodes when ``None``.
        action_space: ``Box`` or ``Discrete``; inferred when ``None`` (``Box`` for float
            actions, ``Discrete(max + 1)`` for integer actions ``(T,)``).

    Raises:
        DynoplanError: a field is malformed (named in the message).
    """

    dataset_id: str
    env_id: str | None = None
    env_spec: str | None = None
    option_names: list[str] = field(default_factory=list)
    seed: int | None = None
    dynoplan_version: str = __version__
    format_version: int = FORMAT_VERSION
    extra: dict[str, Any] = field(default_factory=dict)
    observation_space: Space | None = None
    action_space: Space | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.dataset_id, str) or not _DATASET_ID.match(self.dataset_id):
            raise DynoplanError(
                f"dataset_id {self.dataset_id!r}: expected Minari's form "
                "(namespace/)name-v<version>, e.g. 'dynoplan/gear-assembly/expert-v0'"
            )
        names = self.option_names
        if not isinstance(names, list) or not all(isinstance(n, str) and n for n in names):
            raise DynoplanError(
                f"option_names: expected a list of non-empty strings, got {names!r}"
            )
        if len(set(names)) != len(names):
            raise DynoplanError(f"option_names: names must be unique, got {names}")
        if self.env_spec is not None:
            try:
                EnvSpec.from_json(self.env_spec)
            except (TypeError, ValueError) as exc:
                raise DynoplanError(
                    f"env_spec: expected EnvSpec.to_json() output ({exc})"
                ) from None
        if self.seed is not None and (
            isinstance(self.seed, bool) or not isinstance(self.seed, int)
        ):
            raise DynoplanError(f"seed: expected an int or None, got {self.seed!r}")
        version = self.format_version
        if isinstance(version, bool) or not isinstance(version, int):
            raise DynoplanError(f"format_version: expected an int, got {version!r}")
        if not 0 <= version <= FORMAT_VERSION:
            raise DynoplanError(
                f"format_version {version}: this dynoplan ({__version__}) reads versions "
                f"0..{FORMAT_VERSION}; a newer dynoplan wrote this dataset"
            )
        try:
            json.dumps(self.extra)
        except (TypeError, ValueError) as exc:
            raise DynoplanError(f"extra: expected JSON-serialisable values ({exc})") from None
        for name in ("observation_space", "action_space"):
            space = getattr(self, name)
            if space is not None and not isinstance(space, gym.spaces.Box | gym.spaces.Discrete):
                raise DynoplanError(f"{name}: expected a Box or Discrete space, got {space}")


def metadata_to_json(
    metadata: DatasetMetadata,
    *,
    total_episodes: int,
    total_steps: int,
    observation_space: Space,
    action_space: Space,
    size_mb: float,
) -> dict[str, Any]:
    """The content of ``metadata.json`` (Minari's fields, then our ``"dynoplan"`` block)."""
    doc: dict[str, Any] = {
        "dataset_id": metadata.dataset_id,
        "total_episodes": total_episodes,
        "total_steps": total_steps,
        "data_format": "hdf5",
        "jpeg_encoding": False,
        "observation_space": _serialize_space(observation_space),
        "action_space": _serialize_space(action_space),
    }
    if metadata.env_spec is not None:
        doc["env_spec"] = metadata.env_spec
    doc["minari_version"] = MINARI_VERSION
    doc["dataset_size"] = size_mb
    doc["dynoplan"] = {
        "format_version": FORMAT_VERSION,
        "dynoplan_version": metadata.dynoplan_version,
        "env_id": metadata.env_id,
        "option_names": list(metadata.option_names),
        "seed": metadata.seed,
        "extra": metadata.extra,
    }
    return doc


def read_metadata(file: Path) -> tuple[DatasetMetadata, int, int]:
    """Parse ``metadata.json``; return the metadata, ``total_episodes`` and ``total_steps``.

    Raises:
        DynoplanError: unreadable JSON, a missing or malformed field (named), or no
            episodes (``write_dataset`` writes none such).
    """
    raw = read_json_object(file, "dataset metadata file")

    def get(doc: dict[str, Any], key: str, kind: type | tuple[type, ...], prefix: str = "") -> Any:
        if key not in doc:
            raise DynoplanError(f"{file}: field '{prefix}{key}' is missing")
        value = doc[key]
        kinds = kind if isinstance(kind, tuple) else (kind,)
        # JSON true/false are Python bools, which are ints: not a valid count or seed.
        if not isinstance(value, kinds) or (isinstance(value, bool) and bool not in kinds):
            names = " or ".join("null" if k is type(None) else k.__name__ for k in kinds)
            raise DynoplanError(f"{file}: field '{prefix}{key}': expected {names}, got {value!r}")
        return value

    if get(raw, "data_format", str) != "hdf5":
        raise DynoplanError(
            f"{file}: field 'data_format': expected 'hdf5', got {raw['data_format']!r}"
        )
    total_episodes = get(raw, "total_episodes", int)
    total_steps = get(raw, "total_steps", int)
    if total_episodes < 1 or total_steps < 0:  # every reader needs an episode to learn from
        raise DynoplanError(f"{file}: field 'total_episodes' is {total_episodes} and "
                            f"'total_steps' {total_steps}: expected at least one episode")
    spaces: dict[str, Any] = {
        name: _deserialize_space(get(raw, name, str), file, name)
        for name in ("observation_space", "action_space")
    }
    env_spec = get(raw, "env_spec", str) if "env_spec" in raw else None
    fields: dict[str, Any] = {"dataset_id": get(raw, "dataset_id", str), "env_spec": env_spec}
    if "dynoplan" in raw:
        block = get(raw, "dynoplan", dict)
        p = "dynoplan."
        version = get(block, "format_version", int, p)
        if version > FORMAT_VERSION or version < 1:
            hint = "; a newer dynoplan wrote it, upgrade" if version > FORMAT_VERSION else ""
            raise DynoplanError(
                f"{file}: field 'dynoplan.format_version' is {version}, this dynoplan "
                f"({__version__}) reads 1..{FORMAT_VERSION}{hint}"
            )
        names = get(block, "option_names", list, p)
        if not all(isinstance(n, str) for n in names):
            raise DynoplanError(
                f"{file}: field 'dynoplan.option_names': expected strings, got {names}"
            )
        fields.update(
            format_version=version,
            dynoplan_version=get(block, "dynoplan_version", str, p),
            env_id=get(block, "env_id", (str, type(None)), p),
            option_names=names,
            seed=get(block, "seed", (int, type(None)), p),
            extra=get(block, "extra", dict, p),
        )
    else:  # a plain Minari dataset: keep its descriptive fields
        known = {*fields, *spaces, "total_episodes", "total_steps", "data_format"}
        known |= {"jpeg_encoding", "minari_version", "dataset_size"}
        fields.update(
            format_version=0,
            dynoplan_version="",
            env_id=EnvSpec.from_json(env_spec).id if env_spec else None,
            extra={k: v for k, v in raw.items() if k not in known},
        )
    try:
        metadata = DatasetMetadata(**fields, **spaces)
    except DynoplanError as exc:
        raise DynoplanError(f"{file}: {exc}") from None
    return metadata, total_episodes, total_steps


# --- Gymnasium spaces in Minari's JSON form ----------------------------------------


def _serialize_space(space: Space) -> str:
    if isinstance(space, gym.spaces.Box):
        doc: dict[str, Any] = {
            "type": "Box",
            "dtype": str(space.dtype),
            "shape": list(space.shape),
            "low": space.low.tolist(),
            "high": space.high.tolist(),
        }
    else:
        doc = {"type": "Discrete", "dtype": "int64", "start": int(space.start), "n": int(space.n)}
    return json.dumps(doc)


def _deserialize_space(text: str, file: Path, name: str) -> Space:
    try:
        doc = json.loads(text)
        if doc["type"] == "Box":
            dtype = np.dtype(doc["dtype"])
            return gym.spaces.Box(
                low=np.array(doc["low"], dtype=dtype),
                high=np.array(doc["high"], dtype=dtype),
                shape=tuple(doc["shape"]),
                dtype=dtype.type,
            )
        if doc["type"] == "Discrete":
            return gym.spaces.Discrete(n=int(doc["n"]), start=int(doc["start"]))
    except (ValueError, TypeError, KeyError) as exc:
        raise DynoplanError(
            f"{file}: field '{name}': not a serialised Box or Discrete space ({exc!r})"
        ) from None
    raise DynoplanError(
        f"{file}: field '{name}': {doc['type']} spaces are not supported (Box or Discrete only)"
    )
