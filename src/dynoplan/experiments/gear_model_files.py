"""A gear models folder: file names, the manifest, and reading the models back.

:func:`~dynoplan.experiments.gear_models.train_gear_models` writes one safetensors file
per model (:data:`GOAL_FILE`, :data:`REGIONS_FILE`, :func:`dynamics_file` per option),
``metrics.json`` and ``models.json``, the manifest (:func:`models_manifest`: kind, format
version, state dimension, option names, decision rate, feature maps and each file's
SHA-256). :func:`load_gear_models` reads the folder back as :class:`GearModels`, so a
missing, truncated, modified or mismatched file is rejected with one error line.

The goal heuristic and the regions read named feature maps of the planner state
(:mod:`dynoplan.envs.gear.features`); the library's
:class:`~dynoplan.models.features.GoalOnFeatures` and
:class:`~dynoplan.models.features.RegionsOnFeatures` wrap them so that they take full
planner states ``(batch, 22)``.
"""

import hashlib
import json
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from dynoplan.envs.gear.features import FEATURE_MAPS, TASK
from dynoplan.envs.gear.options.catalog import gear_option_names
from dynoplan.envs.gear.state import DECISION_STEPS, STATE_DIM, STATE_NAMES
from dynoplan.errors import DynoplanError
from dynoplan.experiments.gear_model_settings import GearTrainSettings
from dynoplan.models.dynamics import StackedDynamics
from dynoplan.models.features import FeatureMap, GoalOnFeatures, RegionsOnFeatures
from dynoplan.models.goal_network import GoalNetwork
from dynoplan.models.neural_dynamics import MLPEnsembleDynamics
from dynoplan.models.regions import SafetyRegions

MODELS_KIND = "gear_models"
MODELS_FORMAT_VERSION = 2
"""2: feature maps are named (``"features": "task"``); 1 listed state columns."""
MANIFEST_FILE = "models.json"
METRICS_FILE = "metrics.json"
GOAL_FILE = "goal.safetensors"
REGIONS_FILE = "regions.safetensors"
HELDOUT_DIR = "heldout-demos"
GOAL_FEATURES = TASK
"""What the goal heuristic reads: arm joints, gripper, tool point and gear (no human)."""


def dynamics_file(option: str) -> str:
    """File name of option ``option``'s dynamics model inside a models folder."""
    return f"dynamics-{option}.safetensors"


@dataclass
class GearModels:
    """What :func:`load_gear_models` returns.

    Attributes:
        goal: ``G(s)`` on planner states ``(batch, 22)``.
        regions: the options' safety regions on planner states.
        dynamics: ``D_w`` by option name (keys in the registered options' order), each
            mapping planner states ``(batch, 22)`` one decision step ahead.
        manifest: the content of ``models.json``.
    """

    goal: GoalOnFeatures
    regions: RegionsOnFeatures
    dynamics: dict[str, MLPEnsembleDynamics]
    manifest: dict[str, Any] = field(default_factory=dict)

    @property
    def option_names(self) -> tuple[str, ...]:
        return tuple(self.dynamics)

    def stacked_dynamics(self) -> StackedDynamics:
        """All options' ensembles as one ``(options, samples, 22)`` sampler."""
        return MLPEnsembleDynamics.stack([self.dynamics[n] for n in self.option_names])


def file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()



def models_manifest(out: Path, seed: int, cfg: GearTrainSettings) -> dict[str, Any]:
    def entry(file: str) -> dict[str, Any]:
        return {"file": file, "sha256": file_sha256(out / file)}

    return {
        "kind": MODELS_KIND,
        "format_version": MODELS_FORMAT_VERSION,
        "state_dim": STATE_DIM,
        "state_names": list(STATE_NAMES),
        "option_names": list(gear_option_names()),
        "decision_steps": DECISION_STEPS,
        "goal": {**entry(GOAL_FILE), "features": GOAL_FEATURES.name},
        "regions": {**entry(REGIONS_FILE), "features": cfg.region_features},
        "dynamics": {name: entry(dynamics_file(name)) for name in gear_option_names()},
        "seed": seed,
        "settings": asdict(cfg),
    }



def load_gear_models(folder: str | os.PathLike[str]) -> GearModels:
    """Read the models written by
    :func:`~dynoplan.experiments.gear_models.train_gear_models` from ``folder``.

    Raises:
        DynoplanError: (one line) no or unreadable ``models.json``, another kind or a
            newer format, a state dimension, option names or decision rate other than
            this version's gear assembly, a missing file, a file whose SHA-256 differs
            from the manifest (truncated, modified or from another run), or a model that
            does not fit the manifest.
    """
    root = Path(folder)
    path = root / MANIFEST_FILE
    if not path.is_file():
        raise DynoplanError(f"{path}: not found (train models with 'dynoplan gear train')")
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DynoplanError(f"{path}: not a readable manifest ({exc})") from None
    if not isinstance(manifest, dict) or manifest.get("kind") != MODELS_KIND:
        raise DynoplanError(f"{path}: not a gear models manifest")
    version = manifest.get("format_version")
    if not isinstance(version, int) or version != MODELS_FORMAT_VERSION:
        raise DynoplanError(f"{path}: format_version {version!r} is not supported (this "
                            f"dynoplan reads {MODELS_FORMAT_VERSION}; train the models again)")
    names = list(gear_option_names())
    expected = {"state_dim": STATE_DIM, "option_names": names,
                "decision_steps": DECISION_STEPS}
    for key, value in expected.items():
        if manifest.get(key) != value:
            raise DynoplanError(f"{path}: {key} is {manifest.get(key)!r}, this version's gear "
                                f"assembly has {value!r}")

    def checked(entry: Any, what: str) -> Path:
        if not isinstance(entry, dict) or not isinstance(entry.get("file"), str):
            raise DynoplanError(f"{path}: no file given for {what}")
        file = root / entry["file"]
        if not file.is_file():
            raise DynoplanError(f"{file}: model file not found ({what})")
        if file_sha256(file) != entry.get("sha256"):
            raise DynoplanError(f"{file}: does not match {MANIFEST_FILE} (truncated, modified "
                                "or from another training run)")
        return file

    def features(entry: Any, what: str) -> FeatureMap:
        name = entry.get("features") if isinstance(entry, dict) else None
        if not isinstance(name, str) or name not in FEATURE_MAPS:
            raise DynoplanError(f"{path}: {what} features must name a feature map "
                                f"({', '.join(FEATURE_MAPS)})")
        return FEATURE_MAPS[name]

    goal_features = features(manifest.get("goal"), "goal")
    network = GoalNetwork.load(checked(manifest.get("goal"), "goal heuristic"))
    if network.state_dim != goal_features.dim:
        raise DynoplanError(f"{root / GOAL_FILE}: reads {network.state_dim} features, the "
                            f"manifest's '{goal_features.name}' has {goal_features.dim}")
    region_features = features(manifest.get("regions"), "regions")
    fitted = SafetyRegions.load(checked(manifest.get("regions"), "safety regions"))
    # regions exist for the demonstrated options only, in label order
    if fitted.option_names != [n for n in names if n in fitted.option_names] \
            or fitted.state_dim != region_features.dim:
        raise DynoplanError(f"{root / REGIONS_FILE}: options {fitted.option_names} on "
                            f"{fitted.state_dim} features, expected options of {names} on "
                            f"{region_features.dim} ('{region_features.name}')")
    entries = manifest.get("dynamics")
    if not isinstance(entries, dict) or sorted(entries) != sorted(names):
        raise DynoplanError(f"{path}: dynamics must list the options {names}")
    dynamics: dict[str, MLPEnsembleDynamics] = {}
    for name in names:
        file = checked(entries[name], f"dynamics of {name}")
        model = MLPEnsembleDynamics.load(file)
        if model.state_dim != STATE_DIM or model.option != name:
            raise DynoplanError(f"{file}: a model of option '{model.option}' on "
                                f"{model.state_dim} values, expected '{name}' on {STATE_DIM}")
        dynamics[name] = model
    return GearModels(GoalOnFeatures(network, goal_features),
                      RegionsOnFeatures(fitted, region_features),
                      dynamics, manifest)

