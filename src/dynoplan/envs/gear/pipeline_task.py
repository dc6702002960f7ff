"""The gear assembly as a :class:`~dynoplan.pipeline.task.Task` of the pipeline.

A :class:`GearTask` is what a worker rebuilds a gear controller from: the environment
(with a fault wrapped around it, or rendering for a video), and, from a models folder,
the options bound to that environment under one of the controllers of
:mod:`~dynoplan.envs.gear.controllers` (or the flat PPO policy). Its episodes are
the pipeline's (:class:`~dynoplan.pipeline.evaluate.ControllerRunner`): OMPL is reseeded
from the episode's seed first, the gear measures its own metrics (the human's behaviour,
contacts, the smallest robot-human distance), and out-of-region starts are counted
against the learned regions for every controller, so that the fixed script, which ignores
them, is measured on the same sets.

Jobs are :class:`~dynoplan.pipeline.evaluate.ControllerJob` ``(GearTask(...), models,
controller, settings)``; an episode depends on its seed alone, so the metrics are the same
on one worker or many (only the measured decision latencies differ).
"""

from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import gymnasium as gym

from dynoplan.envs.gear.controllers import VARIANTS, StopWhereItIs
from dynoplan.envs.gear.env import GearAssemblyEnv
from dynoplan.envs.gear.flat_policy import FLAT_POLICY, FlatPolicy, FlatPolicyRunner
from dynoplan.envs.gear.human import BEHAVIOURS
from dynoplan.envs.gear.metrics import episode_metrics
from dynoplan.envs.gear.models_folder import TASK_NAME
from dynoplan.envs.gear.peg_pose import (
    PEG_TASK_NAME,
    GearPegPoseEnv,
    PegFrame,
    PegWorkspace,
    initiation_in_frame,
)
from dynoplan.envs.gear.runs import RUN_INFO_KEYS, beyond_start, ended_well, own_start
from dynoplan.envs.gear.state import DECISION_STEPS
from dynoplan.errors import DynoplanError
from dynoplan.options.option import OptionPolicy
from dynoplan.pipeline.collect import OptionRuns, PolicyMaker, Recording, RunStart
from dynoplan.pipeline.control_settings import ControllerSettings
from dynoplan.pipeline.evaluate import ControllerRunner, make_controller, planning_settings
from dynoplan.pipeline.jobs import EpisodeRunner
from dynoplan.safety.shield import SeparationShield
from dynoplan.types import BoolArray, Generator

FAULTS = ("observation_noise", "grasp_slip")
"""Environment faults a :class:`GearTask` can wrap around the env (dynamics noise is a
controller setting: ``ControllerSettings.dynamics_noise``)."""


@dataclass(frozen=True)
class GearTask:
    """The gear assembly, as workers rebuild it.

    Attributes:
        fault: None, or one of :data:`FAULTS` wrapped around the environment.
        observation_noise: std (m, rad) of the ``observation_noise`` fault.
        flat_folder: the flat policy's folder (for the :data:`FLAT_POLICY` controller).
        render: make the environment with ``render_mode="rgb_array"`` (for a video).
        human: the human behaviours an episode draws from, uniformly (of
            :data:`~dynoplan.envs.gear.human.BEHAVIOURS`; ``None``: the demonstrations'
            mix of ``away``, ``cross`` and ``block``).
        shield: wrap the environment in the runtime monitor
            (:class:`~dynoplan.safety.shield.SeparationShield`, outermost): a protective
            stop (the arm held where it is) on every step that starts with the arm moving
            closer to the hand than ``S_p``.
        peg: the downstream task (:mod:`~dynoplan.envs.gear.peg_pose`): the peg module
            held at a pose drawn from this workspace each episode; ``None``: the first
            task, the peg always at ``RIGHT_HOLD``.
        networks: the folder the option networks (the pick's recognizer, the insertion
            policy) are read from; ``None``: the models folder itself (a task fitted on an
            options folder, :func:`~dynoplan.pipeline.task_fit.run_task`, has only the
            task's models: give the options folder's).
        peg_frame: the planner rolls every option's dynamics in the first task's frame
            (:class:`~dynoplan.envs.gear.peg_pose.PegFrame`, the options' own state space):
            for the first task's dynamics on the downstream task.
    """

    fault: str | None = None
    observation_noise: float = 0.005
    flat_folder: Path | None = None
    render: bool = False
    human: tuple[str, ...] | None = None
    shield: bool = False
    peg: PegWorkspace | None = None
    networks: Path | None = None
    peg_frame: bool = False

    def __post_init__(self) -> None:
        if self.fault is not None and self.fault not in FAULTS:
            raise DynoplanError(f"unknown fault {self.fault!r}; expected one of "
                                f"{', '.join(FAULTS)}")
        unknown = [b for b in self.human or () if b not in BEHAVIOURS]
        if unknown or self.human == ():
            raise DynoplanError(f"unknown human behaviour(s) {', '.join(unknown) or '(none)'}; "
                                f"expected some of {', '.join(BEHAVIOURS)}")

    @property
    def name(self) -> str:
        return TASK_NAME if self.peg is None else PEG_TASK_NAME

    def make_env(self) -> gym.Env[Any, Any]:
        """The gear environment, wrapped by the fault if any (``env.unwrapped`` is the
        :class:`~dynoplan.envs.gear.env.GearAssemblyEnv`, with ``peg`` a
        :class:`~dynoplan.envs.gear.peg_pose.GearPegPoseEnv`)."""
        from dynoplan.envs.gear.faults import GraspSlip, ObservationNoise

        render_mode = "rgb_array" if self.render else None
        gear_env = (GearAssemblyEnv(render_mode=render_mode, human_behaviours=self.human)
                    if self.peg is None else
                    GearPegPoseEnv(self.peg, render_mode=render_mode,
                                   human_behaviours=self.human))
        env: gym.Env[Any, Any] = gear_env
        if self.fault == "observation_noise":
            env = ObservationNoise(gear_env, self.observation_noise)
        elif self.fault == "grasp_slip":
            env = GraspSlip(gear_env)
        if self.shield:
            env = SeparationShield(env, StopWhereItIs(gear_env))
        return env

    def make_runner(self, controller: str, models: Path,
                    settings: ControllerSettings) -> EpisodeRunner:
        """Controller ``controller`` (of :data:`~dynoplan.envs.gear.controllers.VARIANTS` or
        :data:`FLAT_POLICY`) on a
        new environment, built from the models folder ``models`` (once per process) by
        the pipeline's one factory (:func:`~dynoplan.pipeline.evaluate.make_controller`):
        the variant's options on its sets
        (:func:`~dynoplan.envs.gear.controllers.gear_options`) and what the gear adds
        (:func:`~dynoplan.envs.gear.controllers.gear_control`).
        PyTorch runs on one thread, as in the serial command line, so predictions, and
        hence episodes, are bit-identical in every process."""
        import torch

        from dynoplan.envs.gear.controllers import gear_control, gear_options
        from dynoplan.envs.gear.models_folder import load_gear_models
        from dynoplan.envs.gear.options.catalog import policy_factories
        from dynoplan.envs.gear.options.motion import reseed_ompl

        if controller not in (*VARIANTS, FLAT_POLICY):
            raise DynoplanError(f"unknown controller {controller!r}; expected one of "
                                f"{', '.join((*VARIANTS, FLAT_POLICY))}")
        torch.set_num_threads(1)
        env = self.make_env()
        gear_env = env.unwrapped
        assert isinstance(gear_env, GearAssemblyEnv)
        if controller == FLAT_POLICY:
            if self.flat_folder is None:
                raise DynoplanError(f"{FLAT_POLICY} needs the flat policy's folder")
            return FlatPolicyRunner(gear_env, FlatPolicy(self.flat_folder, gear_env).act)
        fitted = load_gear_models(models, self.name)
        factories = policy_factories(self.networks or models)
        variant = VARIANTS[controller]
        frame = PegFrame() if self.peg_frame else None
        if frame is not None and fitted.learned_initiation is not None:
            fitted = replace(fitted, learned_initiation=initiation_in_frame(
                fitted.learned_initiation, frame))
        options = gear_options(gear_env, fitted, factories, variant.sets)
        if frame is not None:
            own = [o.name for o in options if o.state_map is not None]
            if own:
                raise DynoplanError(f"{models}: the peg frame maps the planner state, and "
                                    f"{', '.join(own)} already roll on their own states")
            options = [replace(o, state_map=frame) for o in options]
        return ControllerRunner(
            env, make_controller(variant, options,
                                 fitted.goal, planning_settings(settings, fitted),
                                 action_space=env.action_space,
                                 state_scale=fitted.state_scale,
                                 task=gear_control(gear_env, factories)),
            task_metrics=episode_metrics, regions=fitted.regions, before_episode=reseed_ompl)

    # --- option runs (:class:`~dynoplan.pipeline.collect.OptionRunTask`) ---------------

    @property
    def option_names(self) -> tuple[str, ...]:
        """The registered options, in label order."""
        from dynoplan.envs.gear.options.catalog import GEAR_OPTIONS

        return GEAR_OPTIONS.names()

    @property
    def decision_steps(self) -> int:
        return DECISION_STEPS

    @property
    def run_info_keys(self) -> tuple[str, ...]:
        return RUN_INFO_KEYS

    def policy_makers(self, models: Path | None) -> Mapping[str, PolicyMaker]:
        """The registered options' policies, their networks read from ``models``
        (:func:`~dynoplan.envs.gear.options.catalog.policy_factories`); PyTorch on one
        thread, as in the evaluation."""
        import torch

        from dynoplan.envs.gear.options.catalog import policy_factories

        torch.set_num_threads(1)
        return policy_factories(models)

    def before_run(self, seed: int) -> None:
        """OMPL reseeded from the run's seed."""
        from dynoplan.envs.gear.options.motion import reseed_ompl

        reseed_ompl(seed)

    def run_start(self, runs: OptionRuns, option: str, rng: Generator) -> RunStart:
        """:func:`~dynoplan.envs.gear.runs.beyond_start` for outcome runs, else
        :func:`~dynoplan.envs.gear.runs.own_start`."""
        return (beyond_start if runs.job.outcomes else own_start)(runs, option, rng)

    def run_outcomes(self, policy: OptionPolicy, recording: Recording) -> BoolArray:
        return ended_well(policy, recording)


__all__ = ["FAULTS", "GearTask"]
