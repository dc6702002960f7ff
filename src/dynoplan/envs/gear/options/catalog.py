"""The four gear options by name: training their networks and building their policies.

The two neural parts live in one models folder:

- ``grasp_recognizer.safetensors``: the pick option's grasp recogniser
  (:mod:`.recognition`);
- ``insert_policy.safetensors``: the behaviour-cloned insertion network (:mod:`.insert`).

:func:`policy_factories` loads them once and returns, per option name, a factory that
builds that option's policy on a given environment.
"""

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from dynoplan.envs.gear.env import GearAssemblyEnv
from dynoplan.envs.gear.options.base import GearPolicyFactory
from dynoplan.envs.gear.task import OPTION_NAMES
from dynoplan.errors import DynoplanError
from dynoplan.parallel import SERIAL, Workers, imap_unordered

RECOGNIZER_FILE = "grasp_recognizer.safetensors"
INSERT_FILE = "insert_policy.safetensors"
NEURAL_FILES = {"pick": RECOGNIZER_FILE, "insert": INSERT_FILE}



@dataclass(frozen=True)
class NetworkData:
    """The training episodes of ``option``'s network (``pick``: the grasp recogniser's
    perturbed picks; ``insert``: the insertion network's noisy teacher insertions) for
    ``seed``, as a worker rebuilds them (:mod:`dynoplan.parallel`)."""

    option: str
    seed: int


def build_network_data(job: NetworkData) -> tuple[NetworkData, GearAssemblyEnv, Any]:
    """The job, a data environment and what acts in it (once per process)."""
    from dynoplan.envs.gear.options.insert_training import ScriptedInserter
    from dynoplan.envs.gear.options.pick import PickPolicy
    from dynoplan.envs.gear.options.starts import DATA_EPISODE_STEPS

    env = GearAssemblyEnv(max_episode_steps=DATA_EPISODE_STEPS)
    actor = PickPolicy(env, recognizer=None) if job.option == "pick" else ScriptedInserter()
    return job, env, actor


def network_data_episode(state: tuple[NetworkData, GearAssemblyEnv, Any], episode: int) -> Any:
    """Training episode ``episode`` of the job: what
    :func:`~dynoplan.envs.gear.options.recognition.grasp_episode` or
    :func:`~dynoplan.envs.gear.options.insert_training.insertion_episode` returns (it
    depends on the seed and the index alone)."""
    from dynoplan.envs.gear.options.insert_training import insertion_episode
    from dynoplan.envs.gear.options.recognition import grasp_episode

    job, env, actor = state
    if job.option == "pick":
        return grasp_episode(env, actor, job.seed, episode)
    return insertion_episode(env, actor, job.seed, episode)


def train_option_networks(models: Path, seed: int, quick: bool = False,
                          only: tuple[str, ...] = ("pick", "insert"),
                          workers: Workers = SERIAL) -> dict[str, Any]:
    """Generate data and train the recogniser and/or the insertion network into
    ``models``; returns each one's training report by option name.

    The data episodes of both networks are one map on ``workers`` (each episode depends on
    the seed and its index alone, so the data, and the networks, are the same on one
    worker or many); the two fits run here, one after the other. The reports'
    ``data_seconds`` is then the map's wall time, shared by both."""
    from dynoplan.envs.gear.options.insert_training import (
        DEFAULT_NOISE_STD,
        insertion_demos,
        train_insertion,
    )
    from dynoplan.envs.gear.options.recognition import grasp_data, train_recognizer

    models.mkdir(parents=True, exist_ok=True)
    sizes = {name: 24 if quick else 80 for name in ("pick", "insert") if name in only}
    tasks = [(NetworkData(name, seed), e) for name, n in sizes.items() for e in range(n)]
    t0 = time.perf_counter()
    episodes: list[Any] = [None] * len(tasks)
    for i, episode in imap_unordered(build_network_data, network_data_episode, tasks, workers,
                                     "option networks' data"):
        episodes[i] = episode
    data_seconds = time.perf_counter() - t0
    reports: dict[str, Any] = {}
    if "pick" in sizes:
        reports["pick"] = train_recognizer(models / RECOGNIZER_FILE,
                                           grasp_data(episodes[:sizes["pick"]]), seed=seed,
                                           epochs=100 if quick else 150)
    if "insert" in sizes:
        reports["insert"] = train_insertion(
            models / INSERT_FILE, insertion_demos(episodes[-sizes["insert"]:], seed,
                                                  DEFAULT_NOISE_STD), seed=seed)
    for report in reports.values():
        report["data_seconds"] = round(data_seconds, 2)
    return reports


def policy_factory(name: str, models: Path | None) -> GearPolicyFactory:
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


def policy_factories(models: Path | None) -> dict[str, GearPolicyFactory]:
    """:func:`policy_factory` of every option, in :data:`OPTION_NAMES` order."""
    return {name: policy_factory(name, models) for name in OPTION_NAMES}


__all__ = [
    "INSERT_FILE",
    "NEURAL_FILES",
    "RECOGNIZER_FILE",
    "GearPolicyFactory",
    "NetworkData",
    "build_network_data",
    "network_data_episode",
    "policy_factories",
    "policy_factory",
    "train_option_networks",
]
