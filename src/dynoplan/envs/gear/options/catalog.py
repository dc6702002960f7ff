"""The gear options the pipeline uses: the paper's four, registered first, and any others.

:data:`GEAR_OPTIONS` is the registry every stage reads (demonstrations, collection,
training, the models folder, the controllers, the figures, ``dynoplan gear option``).
It starts with the paper's four options, in label order:

- ``pick`` (:mod:`.pick`): its grasp recogniser is a network,
  ``grasp_recognizer.safetensors`` (:mod:`.recognition`);
- ``fast_move`` and ``cautious_move`` (:mod:`.moves`): planned, no network;
- ``insert`` (:mod:`.insert`): the behaviour-cloned ``insert_policy.safetensors``
  (:mod:`.insert_training`).

A fifth option is a policy file and one call, :func:`register_gear_option` (see
``docs/guide/adding-an-option.md``). Modules named in the environment variable
:data:`PLUGINS_VARIABLE` are imported before the registry is first read, so that the
command line and worker processes know the options they register.

:func:`train_option_networks` trains the registered networks into a models folder;
:func:`policy_factories` loads them once and returns, per option name, a factory that
builds that option's policy on a given environment.
"""

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from dynoplan.envs.gear.env import GearAssemblyEnv
from dynoplan.envs.gear.expert import CAUTIOUS_MOVE as CAUTIOUS_MOVE_LABEL
from dynoplan.envs.gear.expert import FAST_MOVE as FAST_MOVE_LABEL
from dynoplan.envs.gear.expert import INSERT as INSERT_LABEL
from dynoplan.envs.gear.expert import PICK as PICK_LABEL
from dynoplan.envs.gear.options.base import GearPolicyFactory
from dynoplan.envs.gear.options.insert import INSERT_NAME, INSERT_START, INSERT_STATE
from dynoplan.envs.gear.options.moves import (
    CAUTIOUS_MOVE_NAME,
    CAUTIOUS_SAFETY_DISTANCE,
    FAST_MOVE_NAME,
    CautiousMovePolicy,
    FastMovePolicy,
)
from dynoplan.envs.gear.options.pick import PICK_NAME, PICK_START
from dynoplan.envs.gear.options.preconditions import (
    FarFromGoal,
    hand_clear_of_tool,
    hand_near_tool,
    holding_gear,
    insert_may_go_on,
    insert_may_start,
    not_carried,
)
from dynoplan.envs.gear.options.registry import GearOption, GearOptionRegistry, OptionNetwork
from dynoplan.envs.gear.options.starts import (
    OptionStart,
    StartConfig,
    after_pick,
    drive_to_start,
)
from dynoplan.options.initiation import AllOf, AnyOf, InitiationFromCallable
from dynoplan.parallel import SERIAL, Workers, imap_unordered
from dynoplan.types import Generator

RECOGNIZER_FILE = "grasp_recognizer.safetensors"
INSERT_FILE = "insert_policy.safetensors"
PLUGINS_VARIABLE = "DYNOPLAN_GEAR_OPTIONS"
"""Environment variable: comma-separated modules (names, or paths of ``.py`` files) to
import before the registry is first read, for the options they register."""


# ----------------------------------------------------------------- the paper's options
def _load_pick(path: Path) -> GearPolicyFactory:
    from dynoplan.envs.gear.options.pick import PickPolicy
    from dynoplan.envs.gear.options.recognition import GraspRecognizer

    recognizer = GraspRecognizer.load(path)
    return lambda env: PickPolicy(env, recognizer)


def _pick_data_actor(env: GearAssemblyEnv) -> Any:
    from dynoplan.envs.gear.options.pick import PickPolicy

    return PickPolicy(env, recognizer=None)


def _pick_data_episode(env: GearAssemblyEnv, actor: Any, seed: int, episode: int) -> Any:
    from dynoplan.envs.gear.options.recognition import grasp_episode

    return grasp_episode(env, actor, seed, episode)


def _fit_recognizer(path: Path, episodes: list[Any], seed: int, quick: bool) -> dict[str, Any]:
    from dynoplan.envs.gear.options.recognition import grasp_data, train_recognizer

    report: dict[str, Any] = train_recognizer(path, grasp_data(episodes), seed=seed,
                                              epochs=100 if quick else 150)
    return report


def _load_insert(path: Path) -> GearPolicyFactory:
    from dynoplan.envs.gear.options.insert import InsertionNetwork, InsertPolicy

    network = InsertionNetwork.load(path)
    return lambda env: InsertPolicy(env, network)


def _insert_data_actor(env: GearAssemblyEnv) -> Any:
    from dynoplan.envs.gear.options.insert_training import ScriptedInserter

    return ScriptedInserter()


def _insert_data_episode(env: GearAssemblyEnv, actor: Any, seed: int, episode: int) -> Any:
    from dynoplan.envs.gear.options.insert_training import insertion_episode

    return insertion_episode(env, actor, seed, episode)


def _fit_insertion(path: Path, episodes: list[Any], seed: int, quick: bool) -> dict[str, Any]:
    from dynoplan.envs.gear.options.insert_training import (
        DEFAULT_NOISE_STD,
        insertion_demos,
        train_insertion,
    )

    report: dict[str, Any] = train_insertion(
        path, insertion_demos(episodes, seed, DEFAULT_NOISE_STD), seed=seed)
    return report


_FAR_FROM_GOAL = FarFromGoal()  # one forward-kinematics model for both moves
_MOVE_GOES_ON = InitiationFromCallable(holding_gear)

PICK = GearOption(
    PICK_NAME, start=PICK_START,
    initiation=AllOf(InitiationFromCallable(not_carried),
                     InitiationFromCallable(hand_clear_of_tool)),
    network=OptionNetwork(RECOGNIZER_FILE, _load_pick, _pick_data_actor, _pick_data_episode,
                          _fit_recognizer),
    color="#c51bc5")
"""Paper option 1: OMPL to a pre-grasp pose, approach, close; a recognition network
decides "grasped". Starts with the gear not carried and the hand clear of the tool."""
FAST_MOVE = GearOption(
    FAST_MOVE_NAME, FastMovePolicy, start=after_pick,
    initiation=AllOf(_MOVE_GOES_ON, _FAR_FROM_GOAL), continuation=_MOVE_GOES_ON,
    color="#2ca02c")
"""Paper option 2: one OMPL plan to the pre-insertion pose that ignores the human."""
CAUTIOUS_MOVE = GearOption(
    CAUTIOUS_MOVE_NAME, CautiousMovePolicy, start=after_pick,
    initiation=AllOf(_MOVE_GOES_ON, AnyOf(_FAR_FROM_GOAL, InitiationFromCallable(hand_near_tool))),
    continuation=_MOVE_GOES_ON, human_mode="block", color="#7fbf3f",
    trial_notes={"safety_distance": CAUTIOUS_SAFETY_DISTANCE})
"""Paper option 3: the same goal, keeping clearance from the human (see
:data:`~dynoplan.envs.gear.options.moves.CAUTIOUS_SAFETY_DISTANCE`)."""
INSERT = GearOption(
    INSERT_NAME, start=INSERT_START,
    initiation=insert_may_start, continuation=insert_may_go_on,
    network=OptionNetwork(INSERT_FILE, _load_insert, _insert_data_actor, _insert_data_episode,
                          _fit_insertion),
    color="#1f5fbf", state_map=INSERT_STATE)
"""Paper option 4: the behaviour-cloned insertion network (its own state:
:data:`~dynoplan.envs.gear.options.insert.INSERT_STATE`)."""


_PAPER = (PICK, FAST_MOVE, CAUTIOUS_MOVE, INSERT)
PAPER_OPTIONS = tuple(o.name for o in _PAPER)
"""The paper's four options' names, which the demonstrators use, in label order. They
are registered first, so they keep the labels 0..3 (the labels the scripted expert and
the operator write, :data:`~dynoplan.envs.gear.expert.PICK` ...); the options the
pipeline runs (these and any registered after them) are :func:`gear_option_names`."""
# the labels the demonstrators write are these options' indices here
assert tuple(range(len(_PAPER))) == (PICK_LABEL, FAST_MOVE_LABEL, CAUTIOUS_MOVE_LABEL,
                                     INSERT_LABEL)
GEAR_OPTIONS = GearOptionRegistry(_PAPER, plugins=PLUGINS_VARIABLE)
"""The registry the gear pipeline reads; an option's label is its index here."""


def register_gear_option(option: GearOption) -> GearOption:
    """Add ``option`` to :data:`GEAR_OPTIONS` (label: the next index); returns it."""
    return GEAR_OPTIONS.register(option)


def gear_option(name: str) -> GearOption:
    """The registered option ``name`` (:class:`DynoplanError` if there is none)."""
    return GEAR_OPTIONS.get(name)


def reach_start(env: GearAssemblyEnv, option: str, rng: Generator,
                human_mode: str | None = None,
                config: StartConfig | None = None) -> OptionStart:
    """Reset ``env`` and drive it to a start state of the registered option ``option``
    (its ``start`` sampler, :func:`~dynoplan.envs.gear.options.starts.drive_to_start`),
    with a schedule of ``human_mode`` (default: the option's) unless the option's start
    installs its own (:attr:`~dynoplan.envs.gear.options.registry.GearOption.
    start_sets_human`); all randomness from ``rng``."""
    record = gear_option(option)
    return drive_to_start(env, record.start, rng, human_mode or record.human_mode,
                          record.start_sets_human, config, option)


def gear_option_names() -> tuple[str, ...]:
    """The registered options' names, in label order."""
    return GEAR_OPTIONS.names()


@contextmanager
def temporary_gear_options(*options: GearOption) -> Iterator[GearOptionRegistry]:
    """Register ``options`` for the ``with`` block only (:meth:`GearOptionRegistry.temporary`)."""
    with GEAR_OPTIONS.temporary(*options) as registry:
        yield registry


def network_files() -> dict[str, str]:
    """The registered neural options' network file names, by option name."""
    return {o.name: o.network.file for o in GEAR_OPTIONS if o.network is not None}


# ----------------------------------------------------------------- training the networks
@dataclass(frozen=True)
class NetworkData:
    """The training episodes of ``option``'s network (``pick``: the grasp recogniser's
    perturbed picks; ``insert``: the insertion network's noisy teacher insertions) for
    ``seed``, as a worker rebuilds them (:mod:`dynoplan.parallel`)."""

    option: str
    seed: int


def build_network_data(job: NetworkData) -> tuple[NetworkData, GearAssemblyEnv, Any]:
    """The job, a data environment and what acts in it (once per process)."""
    from dynoplan.envs.gear.options.starts import DATA_EPISODE_STEPS

    network = gear_option(job.option).network
    assert network is not None
    env = GearAssemblyEnv(max_episode_steps=DATA_EPISODE_STEPS)
    return job, env, network.data_actor(env)


def network_data_episode(state: tuple[NetworkData, GearAssemblyEnv, Any], episode: int) -> Any:
    """Training episode ``episode`` of the job (the network's ``data_episode``; it depends
    on the seed and the index alone)."""
    job, env, actor = state
    network = gear_option(job.option).network
    assert network is not None
    return network.data_episode(env, actor, job.seed, episode)


def train_option_networks(models: Path, seed: int, quick: bool = False,
                          only: tuple[str, ...] | None = None,
                          workers: Workers = SERIAL) -> dict[str, Any]:
    """Generate data and train the registered options' networks (those named in
    ``only``, default all) into ``models``; returns each one's training report by option
    name.

    The data episodes of all networks are one map on ``workers`` (each episode depends on
    the seed and its index alone, so the data, and the networks, are the same on one
    worker or many); the fits run here, one after the other. The reports'
    ``data_seconds`` is then the map's wall time, shared by all."""
    models.mkdir(parents=True, exist_ok=True)
    networks = {o.name: o.network for o in GEAR_OPTIONS
                if o.network is not None and (only is None or o.name in only)}
    sizes = {name: n.quick_episodes if quick else n.episodes for name, n in networks.items()}
    tasks = [(NetworkData(name, seed), e) for name, n in sizes.items() for e in range(n)]
    t0 = time.perf_counter()
    episodes: list[Any] = [None] * len(tasks)
    for i, episode in imap_unordered(build_network_data, network_data_episode, tasks, workers,
                                     "option networks' data"):
        episodes[i] = episode
    data_seconds = time.perf_counter() - t0
    reports: dict[str, Any] = {}
    first = 0
    for name, network in networks.items():
        own = episodes[first:first + sizes[name]]
        first += sizes[name]
        reports[name] = network.fit(models / network.file, own, seed, quick)
    for report in reports.values():
        report["data_seconds"] = round(data_seconds, 2)
    return reports


def policy_factories(models: Path | None) -> dict[str, GearPolicyFactory]:
    """Every registered option's policy factory (:meth:`GearOption.factory`), by name in
    label order; neural options read their network from ``models``."""
    return {option.name: option.factory(models) for option in GEAR_OPTIONS}


__all__ = [
    "CAUTIOUS_MOVE",
    "FAST_MOVE",
    "GEAR_OPTIONS",
    "INSERT",
    "INSERT_FILE",
    "PAPER_OPTIONS",
    "PICK",
    "PLUGINS_VARIABLE",
    "RECOGNIZER_FILE",
    "GearOption",
    "GearPolicyFactory",
    "NetworkData",
    "OptionNetwork",
    "build_network_data",
    "gear_option",
    "gear_option_names",
    "network_data_episode",
    "network_files",
    "policy_factories",
    "reach_start",
    "register_gear_option",
    "temporary_gear_options",
    "train_option_networks",
]
