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
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from dynoplan.data import DatasetMetadata, Episode, write_dataset
from dynoplan.envs import GEAR_ASSEMBLY_ID
from dynoplan.envs.gear.env import GRIPPER_CLOSED, GRIPPER_OPEN, GearAssemblyEnv
from dynoplan.envs.gear.human import HUMAN_MODES
from dynoplan.envs.gear.options.starts import reach_start
from dynoplan.envs.gear.state import DECISION_STEPS
from dynoplan.envs.gear.task import OPTION_NAMES
from dynoplan.errors import DynoplanError
from dynoplan.experiments.gear_options import PolicyFactory
from dynoplan.progress import track
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
    label = OPTION_NAMES.index(option)
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


def collect_transitions(factories: Mapping[str, PolicyFactory], runs_per_option: int,
                        seed: int, out: Path, max_decisions: int = 30,
                        progress: bool = True) -> dict[str, Any]:
    """Collect ``runs_per_option`` runs of every option in ``factories``; write the
    dataset folder ``out``; return a summary (runs, transitions per option)."""
    unknown = set(factories) - set(OPTION_NAMES)
    if unknown:
        raise DynoplanError(f"unknown options {sorted(unknown)}; expected {OPTION_NAMES}")
    if runs_per_option < 1 or max_decisions < 1:
        raise DynoplanError("--runs and --max-decisions must be >= 1")
    env = GearAssemblyEnv()
    episodes: list[Episode] = []
    modes: list[str] = []
    runs = 0
    try:
        jobs = [(name, run) for name in OPTION_NAMES if name in factories
                for run in range(runs_per_option)]
        policies = {name: factories[name](env) for name in factories}
        for name, run in track(jobs, "collect option runs", total=len(jobs),
                               enabled=progress):
            rng = np.random.default_rng([seed, OPTION_NAMES.index(name), run])
            mode = HUMAN_MODES[int(rng.integers(len(HUMAN_MODES)))]
            perturb = bool(rng.random() < PERTURBED_FRACTION)
            run_episodes = collect_run(env, policies[name], name, rng, mode, perturb,
                                       max_decisions)
            episodes += run_episodes
            modes += [mode] * len(run_episodes)
            runs += 1
    finally:
        env.close()
    obs_space = env.observation_space
    assert isinstance(obs_space, gym.spaces.Box)
    metadata = DatasetMetadata(
        dataset_id=DATASET_ID, env_id=GEAR_ASSEMBLY_ID, option_names=list(OPTION_NAMES),
        seed=seed,
        extra={"decision_steps": DECISION_STEPS, "human_modes": modes,
               "actions": "the option's index (one run of one option per episode)",
               "perturbed_fraction": PERTURBED_FRACTION},
        observation_space=obs_space)
    write_dataset(out, episodes, metadata)
    counts: Counter[str] = Counter()
    for e in episodes:
        counts[OPTION_NAMES[int(e.actions[0])]] += len(e)
    return {"dataset": str(out), "runs": runs, "episodes": len(episodes),
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


__all__ = ["DATASET_ID", "collect_run", "collect_transitions"]
