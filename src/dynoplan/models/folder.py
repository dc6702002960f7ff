"""A models folder: the model files of one task and ``models.json``, their manifest.

One format for every task (the generic pipeline's and the gear assembly's). The manifest
says what the folder holds and how to read it back::

    {"kind": "dynoplan_models", "format_version": 3,
     "task": "MountainCarContinuous-v0", "state_dim": 2, "option_names": [...],
     "stride": 5, "use_regions": true,
     "goal": {"file": "goal.safetensors", "sha256": "...", "features": null},
     "regions": {"file": "regions.safetensors", "sha256": "...", "features": null},
     "dynamics": {"<option>": {"file": "dynamics-<option>.safetensors", "sha256": "..."}},
     "initiation": {"file": "initiation.safetensors", "sha256": "...", "features": null},
     ...}

``initiation`` (optional, ``null`` or absent when not learned) is the initiation learned
from the options' own outcomes (:mod:`dynoplan.models.outcome_initiation`); ``failure``
(absent when no run failed) the chance that an option's run ends its episode in failure
(:mod:`dynoplan.pipeline.fit_failure`).

``features`` names the feature map a model reads (``null``: the planner state itself);
any further top-level field (the seed, the settings, what fitting measured) is kept as
it is. :func:`write_manifest` writes it after the model files (so a folder with a
manifest is complete) and :func:`read_manifest` checks it: the kind and version, every
field's type, every file inside the folder and with the SHA-256 the manifest records.
Every problem is one :class:`~dynoplan.errors.DynoplanError` line naming the file.
"""

import hashlib
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from dynoplan.errors import DynoplanError
from dynoplan.io import read_json_object, write_json

MANIFEST_FILE = "models.json"
KIND = "dynoplan_models"
FORMAT_VERSION = 3
"""3: one format for every task. Older folders (1: the generic pipeline's index without a
kind; 2: ``gear_models``) are rejected: train the models again."""
GOAL_FILE = "goal.safetensors"
REGIONS_FILE = "regions.safetensors"
INITIATION_FILE = "initiation.safetensors"
FAILURE_FILE = "failure.safetensors"
_CORE = ("kind", "format_version", "task", "state_dim", "option_names", "stride",
         "use_regions", "goal", "regions", "dynamics", "initiation", "failure")


def dynamics_file(option: str) -> str:
    """File name of option ``option``'s dynamics model inside a models folder."""
    return f"dynamics-{option}.safetensors"


def file_sha256(path: Path) -> str:
    """The SHA-256 of a file's bytes, as 64 hex digits."""
    digest = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


@dataclass(frozen=True)
class ModelEntry:
    """One model file of the folder.

    Attributes:
        path: the file (inside the folder, checked against the manifest's SHA-256).
        features: the feature map the model reads (``None``: the planner state).
    """

    path: Path
    features: str | None = None


@dataclass(frozen=True)
class Manifest:
    """A checked ``models.json``.

    Attributes:
        folder: the models folder.
        task: the task's name.
        state_dim: planner-state size every model is queried with.
        option_names: all options, in label order.
        stride: environment steps per dynamics-model step.
        use_regions: whether the regions are the options' initiation sets.
        goal: the goal network's file.
        regions: the regions' file (``None``: not fitted).
        dynamics: per option its dynamics file (``None``: a model that cannot be saved).
        extra: every other top-level field (seed, settings, report, ...).
        initiation: the initiation learned from outcomes (``None``: not learned).
        failure: the options' chance to fail (``None``: no run failed).
    """

    folder: Path
    task: str
    state_dim: int
    option_names: list[str]
    stride: int
    use_regions: bool
    goal: ModelEntry
    regions: ModelEntry | None
    dynamics: dict[str, Path | None]
    extra: dict[str, Any] = field(default_factory=dict)
    initiation: ModelEntry | None = None
    failure: ModelEntry | None = None


def write_manifest(folder: str | os.PathLike[str], *, task: str, state_dim: int,
                   option_names: Sequence[str], stride: int, use_regions: bool,
                   goal: tuple[str, str | None], regions: tuple[str, str | None] | None,
                   dynamics: Mapping[str, str | None],
                   extra: Mapping[str, Any] | None = None,
                   initiation: tuple[str, str | None] | None = None,
                   failure: str | None = None) -> dict[str, Any]:
    """Write ``folder/models.json`` for model files already in ``folder``; return it.

    Args:
        goal: ``(file, features)`` of the goal network.
        regions: ``(file, features)`` of the regions, or ``None``.
        dynamics: per option its file name (``None``: not saved).
        extra: further top-level fields (JSON-serialisable; not one of the core fields).
        initiation: ``(file, features)`` of the initiation learned from outcomes, or
            ``None``.
        failure: the file of the options' chance to fail (``None``: the field is left
            out).
    """
    root = Path(folder)

    def entry(file: str, features: str | None = None,
              with_features: bool = True) -> dict[str, Any]:
        out: dict[str, Any] = {"file": file, "sha256": file_sha256(root / file)}
        if with_features:
            out["features"] = features
        return out

    clash = sorted(set(extra or {}) & set(_CORE))
    if clash:
        raise ValueError(f"extra manifest fields {clash} are core fields")
    manifest: dict[str, Any] = {
        "kind": KIND,
        "format_version": FORMAT_VERSION,
        "task": task,
        "state_dim": int(state_dim),
        "option_names": list(option_names),
        "stride": int(stride),
        "use_regions": bool(use_regions),
        "goal": entry(*goal),
        "regions": None if regions is None else entry(*regions),
        "dynamics": {name: None if file is None else entry(file, with_features=False)
                     for name, file in dynamics.items()},
        "initiation": None if initiation is None else entry(*initiation),
        **({} if failure is None else {"failure": entry(failure)}),
        **(extra or {}),
    }
    write_json(root / MANIFEST_FILE, manifest)
    return manifest


def read_manifest(folder: str | os.PathLike[str], retrain: str = "train the models again",
                  with_initiation: bool = True,
                  known_options: Sequence[str] | None = None) -> Manifest:
    """Read and check ``folder/models.json`` (module docstring); no model is loaded.

    Args:
        retrain: how to make a new folder, said when the folder is missing or old.
        known_options: the options the task has (``None``: any name); a name of field
            ``option_names`` not among them is refused.
        with_initiation: ``False`` leaves the learned initiation out (not checked, and
            ``None`` in the result): for replacing it.

    Raises:
        DynoplanError: one line: no or unreadable manifest, another kind or format
            version, a malformed field, a file outside the folder, missing, or whose
            SHA-256 differs from the manifest (truncated, modified or from another run).
    """
    root = Path(folder)
    path = root / MANIFEST_FILE
    if root.exists() and not root.is_dir():
        raise DynoplanError(f"{root}: is a file, expected a models folder")
    if not path.is_file():
        raise DynoplanError(f"{path}: not found, not a models folder ({retrain})")
    doc = read_json_object(path, "models manifest")
    _refuse_newer(path, doc, retrain)
    kind, version = doc.get("kind"), doc.get("format_version")
    older = kind == "gear_models" or (kind is None and "option_names" in doc)
    if kind != KIND and not older:
        raise DynoplanError(f"{path}: not a models manifest (kind {kind!r})")
    if older or version != FORMAT_VERSION:
        raise DynoplanError(f"{path}: format_version {version!r} is not {FORMAT_VERSION}, the "
                            f"one this dynoplan reads ({retrain})")

    def need(key: str, kind: type | tuple[type, ...], what: str) -> Any:
        value = doc.get(key)
        if not isinstance(value, kind) or (isinstance(value, bool) and kind is not bool):
            raise DynoplanError(f"{path}: field '{key}' must be {what}")
        return value

    task = need("task", str, "a string")
    state_dim = need("state_dim", int, "a positive integer")
    stride = need("stride", int, "a positive integer")
    if state_dim < 1 or stride < 1:
        raise DynoplanError(f"{path}: fields 'state_dim' and 'stride' must be positive")
    names = need("option_names", list, "a list of option names")
    if not names or not all(isinstance(n, str) and n for n in names) or \
            len(set(names)) != len(names):
        raise DynoplanError(f"{path}: field 'option_names' must list distinct names")
    unknown = [n for n in names if known_options is not None and n not in known_options]
    if unknown:
        raise DynoplanError(f"{path}: field 'option_names' names unknown option(s) "
                            f"{', '.join(map(repr, unknown))}; this task's options are "
                            f"{', '.join(known_options or ())}")
    use_regions = need("use_regions", bool, "true or false")

    def inside(entry: Any, what: str) -> Path:
        if not isinstance(entry, dict) or not isinstance(entry.get("file"), str):
            raise DynoplanError(f"{path}: no file given for {what}")
        file = (root / entry["file"]).resolve()
        if not file.is_relative_to(root.resolve()) or Path(entry["file"]).is_absolute():
            raise DynoplanError(f"{path}: the file of {what} ({entry['file']!r}) is outside "
                                "the models folder")
        if not file.is_file():
            raise DynoplanError(f"{root / entry['file']}: model file not found ({what})")
        if file_sha256(file) != entry.get("sha256"):
            raise DynoplanError(f"{root / entry['file']}: does not match {MANIFEST_FILE} "
                                "(truncated, modified or from another training run)")
        return file

    def model(key: str, what: str) -> ModelEntry:
        entry = doc.get(key)
        features = entry.get("features") if isinstance(entry, dict) else None
        if features is not None and not isinstance(features, str):
            raise DynoplanError(f"{path}: {what} features must name a feature map or be null")
        return ModelEntry(inside(entry, what), features)

    goal = model("goal", "the goal heuristic")
    regions = None if doc.get("regions") is None else model("regions", "the safety regions")
    entries = doc.get("dynamics")
    if not isinstance(entries, dict) or sorted(entries) != sorted(names):
        raise DynoplanError(f"{path}: field 'dynamics' must list the options of field "
                            f"'option_names', {names}")
    dynamics = {name: None if entries[name] is None else inside(entries[name],
                                                                f"dynamics of {name}")
                for name in names}
    initiation = (None if doc.get("initiation") is None or not with_initiation
                  else model("initiation", "the learned initiation"))
    failure = None if doc.get("failure") is None else model("failure", "the failure model")
    return Manifest(root, task, state_dim, [str(n) for n in names], stride, use_regions,
                    goal, regions, dynamics, {k: v for k, v in doc.items() if k not in _CORE},
                    initiation, failure)


def check_format_version(folder: str | os.PathLike[str],
                         retrain: str = "train the models again") -> None:
    """Refuse a models folder whose ``models.json`` declares a newer format than this
    dynoplan reads; a folder without one passes (commands that read only some files of
    it, such as the gear's option networks, call it before any work).

    Raises:
        DynoplanError: one line naming the version declared and the one this dynoplan
            reads; an unreadable manifest.
    """
    path = Path(folder) / MANIFEST_FILE
    if path.is_file():
        _refuse_newer(path, read_json_object(path, "models manifest"), retrain)


def _refuse_newer(path: Path, doc: Mapping[str, Any], retrain: str) -> None:
    version = doc.get("format_version")
    if isinstance(version, int) and not isinstance(version, bool) and \
            version > FORMAT_VERSION:
        raise DynoplanError(f"{path}: format_version {version}: this dynoplan reads "
                            f"{FORMAT_VERSION} (a newer dynoplan wrote these models: "
                            f"upgrade dynoplan, or {retrain})")


def set_initiation(folder: str | os.PathLike[str], file: str,
                   features: str | None = None) -> dict[str, Any]:
    """Record the initiation learned from outcomes (``folder/file``, already written) in
    the manifest of the complete models folder ``folder``, replacing any initiation
    recorded there; return the new manifest."""
    m = read_manifest(folder, with_initiation=False)
    return write_manifest(
        m.folder, task=m.task, state_dim=m.state_dim, option_names=m.option_names,
        stride=m.stride, use_regions=m.use_regions,
        goal=(m.goal.path.name, m.goal.features),
        regions=None if m.regions is None else (m.regions.path.name, m.regions.features),
        dynamics={n: None if p is None else p.name for n, p in m.dynamics.items()},
        extra=m.extra, initiation=(file, features),
        failure=None if m.failure is None else m.failure.path.name)


__all__ = ["FAILURE_FILE", "FORMAT_VERSION", "GOAL_FILE", "INITIATION_FILE", "KIND",
           "MANIFEST_FILE", "REGIONS_FILE", "Manifest", "ModelEntry", "check_format_version",
           "dynamics_file", "file_sha256", "read_manifest", "set_initiation", "write_manifest"]
