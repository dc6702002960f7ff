"""The four gear options by name: training their networks and building their policies.

The two neural parts live in one models folder:

- ``grasp_recognizer.safetensors``: the pick option's grasp recogniser
  (:mod:`.recognition`);
- ``insert_policy.safetensors``: the behaviour-cloned insertion network (:mod:`.insert`).

:func:`policy_factories` loads them once and returns, per option name, a factory that
builds that option's policy on a given environment.
"""

from collections.abc import Callable
from pathlib import Path
from typing import Any

from dynoplan.envs.gear.env import GearAssemblyEnv
from dynoplan.envs.gear.options.base import GearOptionPolicy
from dynoplan.envs.gear.task import OPTION_NAMES
from dynoplan.errors import DynoplanError

RECOGNIZER_FILE = "grasp_recognizer.safetensors"
INSERT_FILE = "insert_policy.safetensors"
NEURAL_FILES = {"pick": RECOGNIZER_FILE, "insert": INSERT_FILE}

PolicyFactory = Callable[[GearAssemblyEnv], GearOptionPolicy]


def train_option_networks(models: Path, seed: int, quick: bool = False,
                          only: tuple[str, ...] = ("pick", "insert")) -> dict[str, Any]:
    """Generate data and train the recogniser and/or the insertion network into
    ``models``; returns each one's training report by option name."""
    from dynoplan.envs.gear.options.insert_training import train_insertion
    from dynoplan.envs.gear.options.recognition import train_recognizer

    models.mkdir(parents=True, exist_ok=True)
    reports: dict[str, Any] = {}
    if "pick" in only:
        reports["pick"] = train_recognizer(models / RECOGNIZER_FILE, seed=seed,
                                           episodes=24 if quick else 80,
                                           epochs=100 if quick else 150)
    if "insert" in only:
        reports["insert"] = train_insertion(models / INSERT_FILE, demos=24 if quick else 80,
                                            seed=seed)
    return reports


def policy_factory(name: str, models: Path | None) -> PolicyFactory:
    """A factory of ``name``'s policy; neural options read their network from ``models``."""
    from dynoplan.envs.gear.options.moves import CautiousMovePolicy, FastMovePolicy

    if name not in OPTION_NAMES:
        raise DynoplanError(f"unknown option {name!r}; expected one of {', '.join(OPTION_NAMES)}")
    if name == "fast_move":
        return FastMovePolicy
    if name == "cautious_move":
        return CautiousMovePolicy
    if models is None:
        raise DynoplanError(f"option {name!r} needs a models folder with {NEURAL_FILES[name]}")
    path = models / NEURAL_FILES[name]
    if not path.is_file():
        raise DynoplanError(f"{path}: no such model file (train it with `dynoplan gear "
                            f"option {name} --train` or `dynoplan gear run`)")
    if name == "pick":
        from dynoplan.envs.gear.options.pick import PickPolicy
        from dynoplan.envs.gear.options.recognition import GraspRecognizer

        recognizer = GraspRecognizer.load(path)
        return lambda env: PickPolicy(env, recognizer)
    from dynoplan.envs.gear.options.insert import InsertionNetwork, InsertPolicy

    network = InsertionNetwork.load(path)
    return lambda env: InsertPolicy(env, network)


def policy_factories(models: Path | None) -> dict[str, PolicyFactory]:
    """:func:`policy_factory` of every option, in :data:`OPTION_NAMES` order."""
    return {name: policy_factory(name, models) for name in OPTION_NAMES}


__all__ = ["INSERT_FILE", "NEURAL_FILES", "RECOGNIZER_FILE", "PolicyFactory",
           "policy_factories", "policy_factory", "train_option_networks"]
