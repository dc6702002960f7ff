"""Option-level transitions of the gear assembly at the decision rate (the data the
per-option dynamics models ``D_w`` learn from).

Every run starts one option from a seeded state of its starting region
(:func:`~dynoplan.envs.gear.options.starts.reach_start`), with the human away, crossing
or blocking, and, in a fraction of the runs, with the arm displaced by a random joint
offset first (perturbed starts). The option then runs until it finishes, the episode
ends or ``max_decisions`` decisions pass. Each run gives one episode per phase offset of
the decision period (:data:`~dynoplan.envs.gear.state.DECISION_STEPS` environment
steps), in the project's dataset format: observations ``(T+1, 50)`` one decision apart,
actions ``(T,)`` the option's index, ``infos["option"]`` the same index.
"""

from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from dynoplan.data import DatasetMetadata, Episode, write_dataset
from dynoplan.envs import GEAR_ASSEMBLY_ID
from dynoplan.envs.gear.env import GRIPPER_CLOSED, GRIPPER_OPEN, GearAssemblyEnv
from dynoplan.envs.gear.human import HUMAN_MODES
from dynoplan.envs.gear.options.base import GearPolicyFactory
from dynoplan.envs.gear.options.catalog import GEAR_OPTIONS, policy_factories
from dynoplan.envs.gear.options.motion import reseed_ompl
from dynoplan.envs.gear.options.starts import reach_start
from dynoplan.envs.gear.state import DECISION_STEPS
from dynoplan.errors import DynoplanError
from dynoplan.parallel import SERIAL, Workers, parallel_map
from dynoplan.types import FloatArray, Generator

DATASET_ID = "dynoplan/gear-assembly/option-transitions-v0"
PERTURBED_FRACTION = 0.3
PERTURBATION_STD = 0.05  # rad, left-arm joint offset of perturbed starts


def collect_run(env: GearAssemblyEnv, policy: Any, option: str, rng: Generator,
                human_mode: str, perturb: bool, max_decisions: int) -> list[Episode]:
    """One option run, as up to :data:`DECISION_STEPS` episodes at the decision rate: the
    episode of offset ``o`` holds the observations at env steps ``o, o + 10, o + 20, ...``
    (every phase of the run is a valid decision-rate trajectory). Offsets that give no
    full decision are left out."""
    start = reach_start(env, option, rng, human_mode=human_mode)
    obs, info = start.observation, start.info
    if perturb:
        obs, info = _perturb(env, rng, held=int(info["pads_on_gear"]) >= 2)
    policy.reset(obs, rng)
    label = GEAR_OPTIONS.index(option)
    observations: list[FloatArray] = [obs]
    contacts: list[int] = [0]
    for _ in range(max_decisions * DECISION_STEPS):
        obs, _, terminated, truncated, info = env.step(policy.act(obs))
        observations.append(obs)
        contacts.append(int(info["human_contacts"]))
        if policy.finished() or terminated or truncated:
            break
    all_obs, all_contacts = np.asarray(observations), np.cumsum(contacts)
    episodes = []
    for offset in range(DECISION_STEPS):
        rows = np.arange(offset, len(all_obs), DECISION_STEPS)
        steps = len(rows) - 1
        if steps < 1:
            continue
        episodes.append(Episode(
            observations=all_obs[rows],
            actions=np.full(steps, label, dtype=np.int64),
            rewards=np.zeros(steps),
            terminations=np.zeros(steps, dtype=bool),
            truncations=np.zeros(steps, dtype=bool),
            infos={"option": np.full(steps, label, dtype=np.int64),
                   "human_contacts": np.diff(all_contacts[rows]).astype(np.int64)},
            seed=start.env_seed,
        ))
    return episodes


@dataclass(frozen=True)
class CollectJob:
    """Collection runs as a worker rebuilds them (see :func:`collect_transitions`):
    the option policies come from ``factories``, or from the models folder ``models``
    (:func:`~dynoplan.envs.gear.options.catalog.policy_factories`) when ``factories`` is
    None, which is what workers in other processes get."""

    models: Path | None
    options: tuple[str, ...]
    seed: int
    max_decisions: int
    factories: Mapping[str, GearPolicyFactory] | None = field(default=None, hash=False,
                                                          compare=False)


@dataclass
class CollectState:
    """What a worker holds for a :class:`CollectJob`: the env and every option's policy
    bound to it."""

    job: CollectJob
    env: GearAssemblyEnv
    policies: dict[str, Any]


def build_collection(job: CollectJob) -> CollectState:
    """The environment and the options' policies (once per process)."""
    import torch

    torch.set_num_threads(1)  # as in the command line: identical predictions everywhere
    factories = job.factories if job.factories is not None else policy_factories(job.models)
    env = GearAssemblyEnv()
    return CollectState(job, env, {name: factories[name](env) for name in job.options})


def collect_option_run(state: CollectState, run: tuple[str, int]) -> tuple[str, list[Episode]]:
    """Run ``index`` of option ``name`` (``run = (name, index)``): its human mode and its
    episodes. Every random choice (and OMPL) is seeded from ``[seed, option's index,
    index]`` alone, so a run gives the same episodes on any worker, after any other run."""
    name, index = run
    key = [state.job.seed, GEAR_OPTIONS.index(name), index]
    reseed_ompl(int(np.random.SeedSequence(key).generate_state(1)[0]))
    rng = np.random.default_rng(key)
    mode = HUMAN_MODES[int(rng.integers(len(HUMAN_MODES)))]
    perturb = bool(rng.random() < PERTURBED_FRACTION)
    return mode, collect_run(state.env, state.policies[name], name, rng, mode, perturb,
                             state.job.max_decisions)


def check_collection(runs_per_option: int, max_decisions: int) -> None:
    """One error line for a collection that cannot run (before any work is done)."""
    if runs_per_option < 1 or max_decisions < 1:
        raise DynoplanError("--runs and --max-decisions must be >= 1")


def collect_transitions(factories: Mapping[str, GearPolicyFactory] | Path, runs_per_option: int,
                        seed: int, out: Path, max_decisions: int = 30,
                        progress: bool = True, workers: Workers = SERIAL) -> dict[str, Any]:
    """Collect ``runs_per_option`` runs of every option in ``factories``; write the
    dataset folder ``out``; return a summary (runs, transitions per option).

    ``factories`` is either the option policies' factories or a models folder (every
    registered option, built by :func:`~dynoplan.envs.gear.options.catalog.policy_factories`); runs
    on several ``workers`` need the folder (workers rebuild the policies from files). The
    runs are written in the same order, so the dataset is the same for one worker or many.
    """
    registered = GEAR_OPTIONS.names()
    if isinstance(factories, Path):
        models: Path | None = factories
        names: tuple[str, ...] = registered
        given = None
    else:
        unknown = set(factories) - set(registered)
        if unknown:
            raise DynoplanError(f"unknown options {sorted(unknown)}; expected {registered}")
        if workers.parallel:
            raise DynoplanError("collection on several workers needs the models folder, "
                                "not policy factories")
        models, names, given = None, tuple(n for n in registered if n in factories), factories
    check_collection(runs_per_option, max_decisions)
    if models is not None:
        policy_factories(models)  # a missing or broken network: one error here, not per run
    job = CollectJob(models, names, seed, max_decisions, given)
    runs = [(name, run) for name in names for run in range(runs_per_option)]
    episodes: list[Episode] = []
    modes: list[str] = []
    for mode, run_episodes in parallel_map(build_collection, collect_option_run, job, runs,
                                           workers, "collect option runs", progress):
        episodes += run_episodes
        modes += [mode] * len(run_episodes)
    env = GearAssemblyEnv()
    obs_space = env.observation_space
    env.close()
    assert isinstance(obs_space, gym.spaces.Box)
    metadata = DatasetMetadata(
        dataset_id=DATASET_ID, env_id=GEAR_ASSEMBLY_ID, option_names=list(registered),
        seed=seed,
        extra={"decision_steps": DECISION_STEPS, "human_modes": modes,
               "actions": "the option's index (one run of one option per episode)",
               "perturbed_fraction": PERTURBED_FRACTION},
        observation_space=obs_space)
    write_dataset(out, episodes, metadata)
    counts: Counter[str] = Counter()
    for e in episodes:
        counts[registered[int(e.actions[0])]] += len(e)
    return {"dataset": str(out), "runs": len(runs), "episodes": len(episodes),
            "transitions": dict(counts),
            "human_modes": dict(Counter(modes))}


def _perturb(env: GearAssemblyEnv, rng: Generator,
             held: bool) -> tuple[FloatArray, dict[str, Any]]:
    """Hold the left arm at a random joint offset for half a decision."""
    q = env.arm_qpos
    q[:6] += rng.normal(0.0, PERTURBATION_STD, size=6)
    lim = env.joint_limits
    action = np.concatenate([np.clip(q, lim[:, 0], lim[:, 1]),
                             [GRIPPER_CLOSED if held else GRIPPER_OPEN]])
    obs, info = env.set_human_schedule(env.schedule)
    for _ in range(DECISION_STEPS // 2):
        obs, _, _, _, info = env.step(action)
    return obs, info


__all__ = ["DATASET_ID", "CollectJob", "CollectState", "build_collection", "check_collection",
           "collect_option_run", "collect_run", "collect_transitions"]
