"""Gear evaluation episodes as a job for :func:`dynoplan.parallel.parallel_map`.

An :class:`EvalJob` names a controller (and optionally a fault) by paths and frozen
settings only; every worker process rebuilds the environment, loads the models from the
folder and builds the controller once (:func:`build_evaluation`), then runs seeded
episodes on it (:func:`evaluate_episode`). Networks are never pickled: a worker reads
the same files the caller would. Since an episode depends on its
:class:`~dynoplan.seeding.EpisodeSeed` alone, the metrics are the same on
one worker or many (only the measured decision latencies differ).
"""

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym

from dynoplan.control import Controller
from dynoplan.envs.gear.env import GearAssemblyEnv
from dynoplan.errors import DynoplanError
from dynoplan.experiments.gear_controllers import VARIANTS, PlannerSettings
from dynoplan.experiments.gear_eval import controller_episode, policy_episode
from dynoplan.options.initiation import RegionModel
from dynoplan.parallel import SERIAL, Workers
from dynoplan.pipeline.evaluate import EpisodeRecord, evaluate_many
from dynoplan.seeding import EpisodeSeed
from dynoplan.types import FloatArray

FLAT_POLICY = "flat_ppo"
"""The flat end-to-end baseline's controller name (it needs ``EvalJob.flat_folder``)."""

FAULTS = ("observation_noise", "grasp_slip")
"""Environment faults an :class:`EvalJob` can wrap around the env (dynamics noise is a
planner setting: ``PlannerSettings.dynamics_noise``)."""


@dataclass(frozen=True)
class EvalJob:
    """One controller on seeded gear episodes, as a worker rebuilds it.

    Attributes:
        models: the models folder (``models.json`` and the option networks).
        controller: one of :data:`~dynoplan.experiments.gear_controllers.VARIANTS`, or
            :data:`FLAT_POLICY`.
        planner: horizon, samples, margin and dynamics noise of the controller.
        fault: None, or one of :data:`FAULTS` wrapped around the environment.
        observation_noise: std (m, rad) of the ``observation_noise`` fault.
        flat_folder: the flat policy's folder (for :data:`FLAT_POLICY`).
        render: build the environment with ``render_mode="rgb_array"`` (for a video).
    """

    models: Path
    controller: str
    planner: PlannerSettings = field(default_factory=PlannerSettings)
    fault: str | None = None
    observation_noise: float = 0.005
    flat_folder: Path | None = None
    render: bool = False

    def __post_init__(self) -> None:
        if self.controller not in (*VARIANTS, FLAT_POLICY):
            raise DynoplanError(f"unknown controller {self.controller!r}; expected one of "
                                f"{', '.join((*VARIANTS, FLAT_POLICY))}")
        if self.fault is not None and self.fault not in FAULTS:
            raise DynoplanError(f"unknown fault {self.fault!r}; expected one of "
                                f"{', '.join(FAULTS)}")
        if self.controller == FLAT_POLICY and self.flat_folder is None:
            raise DynoplanError(f"{FLAT_POLICY} needs the flat policy's folder")

    def build(self) -> "EvalState":
        """:func:`build_evaluation` of this job (what a worker holds)."""
        return build_evaluation(self)


@dataclass
class EvalState:
    """What a worker holds for one :class:`EvalJob`: the env (wrapped by the fault, if
    any), the bare gear env, and either a controller or a flat policy's ``act``."""

    env: gym.Env[Any, Any]
    gear_env: GearAssemblyEnv
    controller: Controller | None
    act: Callable[[FloatArray], FloatArray] | None
    regions: RegionModel | None

    def episode(self, seed: EpisodeSeed) -> EpisodeRecord:
        """:func:`evaluate_episode` on this state."""
        return evaluate_episode(self, seed)


def build_evaluation(job: EvalJob) -> EvalState:
    """Build ``job``'s environment and controller from its files (once per process).
    PyTorch runs on one thread, as in the serial command line, so predictions, and hence
    episodes, are bit-identical in every process."""
    import torch

    from dynoplan.envs.gear.faults import GraspSlip, ObservationNoise

    torch.set_num_threads(1)
    gear_env = GearAssemblyEnv(render_mode="rgb_array" if job.render else None)
    env: gym.Env[Any, Any] = gear_env
    if job.fault == "observation_noise":
        env = ObservationNoise(gear_env, job.observation_noise)
    elif job.fault == "grasp_slip":
        env = GraspSlip(gear_env)
    if job.controller == FLAT_POLICY:
        from dynoplan.baselines.flat_policy import FlatPolicy

        assert job.flat_folder is not None  # checked by EvalJob
        return EvalState(env, gear_env, None, FlatPolicy(job.flat_folder, gear_env).act, None)
    from dynoplan.envs.gear.options.catalog import policy_factories
    from dynoplan.experiments.gear_controllers import make_gear_controller
    from dynoplan.experiments.gear_model_files import load_gear_models

    models = load_gear_models(job.models)
    controller = make_gear_controller(job.controller, gear_env, models,
                                      policy_factories(job.models), job.planner)
    return EvalState(env, gear_env, controller, None, models.regions)


def evaluate_episode(state: EvalState, seed: EpisodeSeed) -> EpisodeRecord:
    """One seeded episode on a worker's state (the ``run`` of the job)."""
    if state.controller is not None:
        return controller_episode(state.env, state.gear_env, state.controller, seed,
                                  state.regions)
    assert state.act is not None
    return policy_episode(state.gear_env, state.act, seed)


def evaluate(job: EvalJob, seeds: Sequence[EpisodeSeed], workers: Workers = SERIAL,
             description: str | None = None, progress: bool = False) -> list[EpisodeRecord]:
    """``job`` on every seed, on ``workers``; one result per seed, in order."""
    return evaluate_many([(job, seeds)], workers, description or job.controller, progress)[0]


__all__ = ["FAULTS", "FLAT_POLICY", "EvalJob", "EvalState", "build_evaluation", "evaluate",
           "evaluate_episode"]
