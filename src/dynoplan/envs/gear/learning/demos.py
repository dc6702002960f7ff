"""Demonstrations of the gear assembly, saved in the project's dataset format.

``record_demos`` runs a demonstrator (:mod:`dynoplan.envs.gear.demonstrations`: the
scripted expert, or the operator chaining the option policies, which ``gear run`` and
``gear demos`` use, :func:`dynoplan.envs.gear.stages.demonstrations`) on seeded
episodes, with the human schedule drawn per episode (away, crossing or blocking), and
writes them with option labels and progress as a Minari-layout dataset
(``docs/dataset-format.md``).
"""

from collections import Counter
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from dynoplan.data import DatasetMetadata, Episode, write_dataset
from dynoplan.envs import GEAR_ASSEMBLY_ID, GEAR_PEG_POSE_ID
from dynoplan.envs.gear.demonstrations import record_expert_episodes
from dynoplan.envs.gear.options.catalog import gear_option_names
from dynoplan.envs.gear.peg_pose import PegWorkspace
from dynoplan.io import ensure_writable_dir
from dynoplan.parallel import SERIAL, Workers

DATASET_ID = "dynoplan/gear-assembly/expert-v0"
"""Dataset id of demonstrations by either demonstrator (``metadata.extra`` names it)."""


def to_dataset_episode(raw: dict[str, Any]) -> Episode:
    """The expert's per-episode arrays as a validated :class:`~dynoplan.data.Episode`."""
    return Episode(
        observations=raw["observations"],
        actions=raw["actions"],
        rewards=raw["rewards"],
        terminations=raw["terminations"],
        truncations=raw["truncations"],
        infos=dict(raw["infos"]),
        seed=int(raw["seed"]),
    )


def record_demos(n: int, seed: int, out: Path, progress: bool = True,
                 human_mode: str | None = None, demonstrator: str = "expert",
                 models: Path | None = None, workers: Workers = SERIAL,
                 peg: PegWorkspace | None = None) -> dict[str, Any]:
    """Record ``n`` demonstrations into the dataset folder ``out``; return a summary.

    ``demonstrator``: ``expert`` (the scripted expert) or ``options`` (an operator
    chaining the option policies, whose networks are read from ``models``). ``peg``: in
    the downstream task's environment (``dynoplan/GearPegPose-v0`` on that workspace,
    :mod:`~dynoplan.envs.gear.peg_pose`). The episodes run on ``workers``; the dataset is
    the same on one worker or many."""
    ensure_writable_dir(out.parent if out.parent != Path("") else Path("."))
    raw = record_expert_episodes(n, seed, progress=progress, human_mode=human_mode,
                                 demonstrator=demonstrator, models=models, workers=workers,
                                 peg=peg)
    episodes = [to_dataset_episode(r) for r in raw]
    modes = [str(r["human_mode"]) for r in raw]
    env_id = GEAR_ASSEMBLY_ID if peg is None else GEAR_PEG_POSE_ID
    env = gym.make(env_id)
    try:
        spec = env.spec.to_json() if env.spec is not None else None
        obs_space, act_space = env.observation_space, env.action_space
        assert isinstance(obs_space, gym.spaces.Box) and isinstance(act_space, gym.spaces.Box)
        metadata = DatasetMetadata(
            dataset_id=DATASET_ID,
            env_id=env_id,
            env_spec=spec,
            option_names=list(gear_option_names()),
            seed=seed,
            extra={"human_modes": modes, "demonstrator": demonstrator,
                   "state": "observations[:, 0:12] (arm joint angles)",
                   "progress": "progress[t] = (t + 1) / T describes observations[t + 1]"},
            observation_space=obs_space,
            action_space=act_space,
        )
    finally:
        env.close()
    write_dataset(out, episodes, metadata)
    successes = [bool(np.asarray(r["infos"]["success"])[-1]) for r in raw]
    return {
        "dataset": str(out),
        "episodes": n,
        "steps": int(sum(len(e) for e in episodes)),
        "success_rate": float(np.mean(successes)),
        "human_modes": dict(Counter(modes)),
        "option_steps": {gear_option_names()[k]: int(v) for k, v in sorted(Counter(
            int(o) for e in episodes for o in e.infos["option"]).items())},
    }
