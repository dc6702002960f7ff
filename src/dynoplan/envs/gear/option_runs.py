"""Option-level transitions of the gear assembly at the decision rate (the data the
per-option dynamics models ``D_w`` learn from): the pipeline's option runs
(:func:`~dynoplan.pipeline.collect.collect_option_runs`) of every registered option from
its own starts (:func:`~dynoplan.envs.gear.runs.own_start`: the human away, crossing or
blocking, and in a fraction of the runs the arm displaced first), each until it
finishes, the episode ends or ``max_decisions`` decisions pass. Each run gives one
episode per phase offset of the decision period
(:data:`~dynoplan.envs.gear.state.DECISION_STEPS` environment steps), in the project's
dataset format: observations ``(T+1, 50)`` one decision apart, actions ``(T,)`` the
option's index, ``infos["option"]`` the same index, ``infos["human_contacts"]``.
"""

from collections import Counter
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import gymnasium as gym

from dynoplan.data import DatasetMetadata, Episode, write_dataset
from dynoplan.envs import GEAR_ASSEMBLY_ID
from dynoplan.envs.gear.env import GearAssemblyEnv
from dynoplan.envs.gear.options.base import GearPolicyFactory
from dynoplan.envs.gear.options.catalog import GEAR_OPTIONS, policy_factories
from dynoplan.envs.gear.pipeline_task import GearTask
from dynoplan.envs.gear.runs import PERTURBED_FRACTION
from dynoplan.envs.gear.state import DECISION_STEPS
from dynoplan.errors import DynoplanError
from dynoplan.parallel import SERIAL, Workers
from dynoplan.pipeline.collect import OptionRunsJob, collect_option_runs

DATASET_ID = "dynoplan/gear-assembly/option-transitions-v0"


def write_runs(out: Path, episodes: list[Episode], dataset_id: str, seed: int,
               extra: dict[str, Any]) -> None:
    """Write option runs of the registered gear options as the dataset folder ``out``."""
    env = GearAssemblyEnv()
    obs_space = env.observation_space
    env.close()
    assert isinstance(obs_space, gym.spaces.Box)
    write_dataset(out, episodes, DatasetMetadata(
        dataset_id=dataset_id, env_id=GEAR_ASSEMBLY_ID, option_names=list(GEAR_OPTIONS.names()),
        seed=seed, extra=extra, observation_space=obs_space))


def check_collection(runs_per_option: int, max_decisions: int) -> None:
    """One error line for a collection that cannot run (before any work is done)."""
    if runs_per_option < 1 or max_decisions < 1:
        raise DynoplanError("--runs and --max-decisions must be >= 1")


def collect_gear_transitions(factories: Mapping[str, GearPolicyFactory] | Path,
                             runs_per_option: int, seed: int, out: Path,
                             max_decisions: int = 30, progress: bool = True,
                             workers: Workers = SERIAL,
                             task: GearTask | None = None) -> dict[str, Any]:
    """Collect ``runs_per_option`` runs of every option in ``factories``; write the
    dataset folder ``out``; return a summary (runs, transitions per option).

    ``factories`` is either the option policies' factories or a models folder (every
    registered option, built by :func:`~dynoplan.envs.gear.options.catalog.policy_factories`); runs
    on several ``workers`` need the folder (workers rebuild the policies from files). The
    runs are written in the same order, so the dataset is the same for one worker or many.
    ``task``: the gear task whose environment the runs are in (default: the first task,
    :class:`~dynoplan.envs.gear.pipeline_task.GearTask`).
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
    job = OptionRunsJob(task or GearTask(), models, names, seed, max_decisions * DECISION_STEPS,
                        factories=given)
    episodes: list[Episode] = []
    modes: list[str] = []
    for tags, run_episodes in collect_option_runs(job, runs_per_option, workers,
                                                  "collect option runs", progress):
        episodes += run_episodes
        modes += [tags["human_mode"]] * len(run_episodes)
    write_runs(out, episodes, DATASET_ID, seed,
               {"decision_steps": DECISION_STEPS, "human_modes": modes,
                "task": (task or GearTask()).name,
                "actions": "the option's index (one run of one option per episode)",
                "perturbed_fraction": PERTURBED_FRACTION})
    counts: Counter[str] = Counter()
    for e in episodes:
        counts[registered[int(e.actions[0])]] += len(e)
    return {"dataset": str(out), "runs": len(names) * runs_per_option,
            "episodes": len(episodes),
            "transitions": dict(counts),
            "human_modes": dict(Counter(modes))}


__all__ = ["DATASET_ID", "check_collection", "collect_gear_transitions", "write_runs"]
