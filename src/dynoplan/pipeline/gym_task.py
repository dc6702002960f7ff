"""The task of a user's Gymnasium environment, and the wrappers that make any environment
one the pipeline can run.

:class:`GymTask` is the :class:`~dynoplan.pipeline.task.Task` of a user's Gymnasium
environment with user-written options
(``dynoplan pipeline --env ID --options MODULE:FUNCTION``);
:class:`~dynoplan.envs.gear.pipeline_task.GearTask` is the gear assembly's.

**Success and the planner state.** A task's environment says when an episode succeeded
(``info["is_success"]`` at its last step, else ``terminated``). A task that never
terminates (most continuous-control tasks) gets a *success function*
``success(observation, info) -> bool``, called after every step
(:class:`EndOnSuccess`): the episode ends at the first success, so "steps to success"
is the step of the first success. An observation that is not a ``Box`` (a ``Dict``)
is mapped to the planner state by a ``state_fn`` (or flattened, with a warning) and
every part of the pipeline, the options included, sees that state
(:class:`StateObservation`). :func:`task_env` applies both.
"""

import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from dynoplan.adapters.spec import OptionSpec, as_spec
from dynoplan.errors import DynoplanError, DynoplanWarning
from dynoplan.imports import import_user_module
from dynoplan.pipeline.control_settings import ControllerSettings
from dynoplan.pipeline.jobs import EpisodeRunner
from dynoplan.types import FloatArray

SuccessFn = Callable[[Any, dict[str, Any]], Any]
"""``success(observation, info) -> bool``: whether the task is done after a step (the
observation as the environment gives it, before any ``state_fn``)."""
StateFn = Callable[[Any], Any]
"""``state_fn(observation) -> (d,)``: the planner state of an observation."""


class EndOnSuccess(gym.Wrapper[Any, Any, Any, Any]):
    """Success defined by a function: ``success(observation, info)`` after every step.

    Every step's ``info["is_success"]`` is its value; the first success terminates the
    episode. ``name`` names the function in errors.

    Raises:
        DynoplanError: the function raised, or returned something that is not one truth
            value (one line naming the function and the step).
    """

    def __init__(self, env: gym.Env[Any, Any], success: SuccessFn, name: str = "success"
                 ) -> None:
        super().__init__(env)
        self.success = success
        self.name = name
        self._steps = 0

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        self._steps = 0
        return self.env.reset(**kwargs)

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._steps += 1
        try:
            done = bool(self.success(obs, info))
        except Exception as exc:
            raise DynoplanError(
                f"success function {self.name} failed at step {self._steps}: "
                f"{type(exc).__name__}: {exc}") from None
        return obs, reward, bool(terminated) or done, truncated, {**info, "is_success": done}


class StateObservation(gym.ObservationWrapper[Any, Any, Any]):
    """The environment with the planner state ``state_fn(observation)`` ``(d,)`` float64
    as its observation (a ``Box``), so that datasets, models and options all see it."""

    def __init__(self, env: gym.Env[Any, Any], state_fn: StateFn, name: str = "state_fn"
                 ) -> None:
        super().__init__(env)
        self.state_fn = state_fn
        self.name = name
        state = self.observation(env.observation_space.sample())
        if state.ndim != 1 or state.shape[0] < 1:
            raise DynoplanError(f"{name} must return a vector (state_dim,), got shape "
                                f"{state.shape}")
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, state.shape, np.float64)

    def observation(self, observation: Any) -> FloatArray:
        try:
            return np.asarray(self.state_fn(observation), dtype=np.float64)
        except Exception as exc:
            raise DynoplanError(f"{self.name} failed on an observation: "
                                f"{type(exc).__name__}: {exc}") from None


@dataclass(frozen=True)
class FlattenedObservation:
    """The default ``state_fn`` of a ``Dict`` (or ``Tuple``) observation: its values
    flattened in the space's key order (``gymnasium.spaces.flatten``; a ``Discrete``
    becomes one-hot)."""

    space: gym.spaces.Space[Any]

    def __call__(self, observation: Any) -> FloatArray:
        return np.asarray(gym.spaces.flatten(self.space, observation), dtype=np.float64)


def task_env(env: gym.Env[Any, Any], success: SuccessFn | None = None,
             state_fn: StateFn | None = None, success_name: str = "success",
             state_name: str = "state_fn") -> gym.Env[Any, Any]:
    """The environment as the pipeline runs it: ``success`` ends an episode at its first
    success (:class:`EndOnSuccess`, on the environment's own observation), then
    ``state_fn`` maps the observation to the planner state (:class:`StateObservation`).

    Without ``state_fn``, a ``Box`` observation is the state as it is, and a ``Dict`` or
    ``Tuple`` of spaces that flatten to real vectors is flattened, with a warning.

    Raises:
        DynoplanError: an observation space that neither is a ``Box`` nor flattens to one
            and no ``state_fn`` (one line: write a state_fn).
    """
    if success is not None:
        env = EndOnSuccess(env, success, success_name)
    space = env.observation_space
    if state_fn is not None:
        return StateObservation(env, state_fn, state_name)
    if isinstance(space, gym.spaces.Box):
        return env
    name = env.spec.id if env.spec is not None else type(env.unwrapped).__name__
    flat = gym.spaces.flatten_space(space) if isinstance(
        space, gym.spaces.Dict | gym.spaces.Tuple) else None
    if not isinstance(flat, gym.spaces.Box):
        raise DynoplanError(
            f"environment '{name}': observation space is {space}, but the pipeline needs a "
            "Box (real-valued vector), or a Dict of spaces that flatten to one; give a "
            "state_fn (observation -> (d,) vector; on the command line --state-fn "
            "MODULE:FUNCTION)")
    warnings.warn(
        f"environment '{name}': {type(space).__name__} observation flattened to "
        f"{flat.shape[0]} values in key order ({', '.join(_keys(space))}); give a state_fn "
        "(--state-fn) to choose the planner state", DynoplanWarning, stacklevel=2)
    return StateObservation(env, FlattenedObservation(space), "the flattened observation")


def _keys(space: gym.spaces.Space[Any]) -> list[str]:
    if isinstance(space, gym.spaces.Dict):
        return [str(k) for k in space.spaces]
    return [str(i) for i in range(len(space.spaces))] if isinstance(
        space, gym.spaces.Tuple) else []

@dataclass(frozen=True)
class GymTask:
    """A registered Gymnasium environment with the user's options.

    Attributes:
        env_id: the Gymnasium id (``gymnasium.make``).
        options: ``MODULE:FUNCTION`` returning the options (a list of
            :func:`~dynoplan.adapters.option_spec`); see :func:`load_object`.
        success: ``MODULE:FUNCTION``, the task's :data:`SuccessFn` (``None``: the
            environment's own ``info["is_success"]`` or ``terminated``).
        state_fn: ``MODULE:FUNCTION``, the :data:`StateFn` (``None``: a ``Box``
            observation as it is, a ``Dict`` flattened).
        demonstrator: ``MODULE:FUNCTION`` returning the demonstrator, for its row of the
            evaluation on workers (``None``: no such row).
        disturbance: ``MODULE:FUNCTION``, ``env -> env``: the environment wrapped in a
            disturbance its user expects (a push, an object moved), where the improvement
            rounds may rehearse (``improve_disturbed``; ``None``: none given).
    """

    env_id: str
    options: str
    success: str | None = None
    state_fn: str | None = None
    demonstrator: str | None = None
    disturbance: str | None = None

    @property
    def name(self) -> str:
        return self.env_id

    def make_env(self, disturbed: bool = False) -> gym.Env[Any, Any]:
        """``gymnasium.make(env_id)``, after importing the options' module (which may
        register the environment: a worker process has not imported it yet), as the
        pipeline runs it (:func:`task_env`); ``disturbed``: wrapped in the task's
        ``disturbance`` first (so that it sees the raw observation).

        Raises:
            DynoplanError: ``disturbed`` without a ``disturbance``, or one that fails.
        """
        from dynoplan.pipeline.collect import make_env

        load_object(self.options)
        success = None if self.success is None else load_function(self.success, "success")
        state_fn = None if self.state_fn is None else load_function(self.state_fn, "state_fn")
        env = make_env(self.env_id)
        if disturbed:
            if self.disturbance is None:
                raise DynoplanError(f"{self.env_id}: no disturbance given (--disturbance "
                                    "MODULE:FUNCTION)")
            wrap = load_function(self.disturbance, "disturbance")
            try:
                env = wrap(env)
            except Exception as exc:
                raise DynoplanError(f"'{self.disturbance}': wrapping the environment failed: "
                                    f"{type(exc).__name__}: {exc}") from None
            if not isinstance(env, gym.Env):
                raise DynoplanError(f"'{self.disturbance}' must return an environment, got "
                                    f"{type(env).__name__}")
        return task_env(env, success, state_fn, f"'{self.success}'", f"'{self.state_fn}'")

    def make_options(self) -> list[OptionSpec]:
        made = call_factory(self.options, "options")
        if not isinstance(made, list | tuple) or not made:
            raise DynoplanError(f"'{self.options}' must return a non-empty list of options, "
                                f"got {type(made).__name__}")
        return [as_spec(o) for o in made]

    def make_runner(self, controller: str, models: Path,
                    settings: ControllerSettings) -> EpisodeRunner:
        """The options with the learned models of ``models``
        (:meth:`~dynoplan.pipeline.fit.FittedModels.build`), under controller
        ``controller`` (:func:`~dynoplan.pipeline.evaluate.make_controller`, or the
        demonstrator's :class:`~dynoplan.pipeline.evaluate.DemonstratorRunner`); starts
        outside the learned regions count as out of region
        (:func:`~dynoplan.pipeline.evaluate.learned_regions`)."""
        from dynoplan.pipeline.collect import demonstrator_from
        from dynoplan.pipeline.evaluate import (
            DEMONSTRATOR,
            ControllerRunner,
            DemonstratorRunner,
            learned_regions,
            make_controller,
            planning_settings,
        )
        from dynoplan.pipeline.fit import FittedModels

        fitted = FittedModels.load(models)
        env = self.make_env()
        if controller == DEMONSTRATOR:
            if self.demonstrator is None:
                raise DynoplanError(f"task {self.name} has no demonstrator for its row")
            return DemonstratorRunner(env, self.make_options(), demonstrator_from(
                call_factory(self.demonstrator, "demonstrator")), learned_regions(fitted))
        run_options, planner_options = fitted.build(self.make_options())
        return ControllerRunner(env, make_controller(
            controller, run_options, fitted.goal, planning_settings(settings, fitted),
            planner_options, env.action_space, fitted.state_scale),
            regions=learned_regions(fitted))


def load_object(reference: str) -> Any:
    """The object named by ``"package.module:name"`` or ``"path/to/file.py:name"``.

    The current folder is searched first, so ``examples.mountain_car.options:make_options``
    works from the repository root.

    Raises:
        DynoplanError: a malformed reference, a module that cannot be imported, or a
            missing name.
    """
    module_name, sep, attr = reference.partition(":")
    if not sep or not module_name or not attr:
        raise DynoplanError(
            f"'{reference}': expected MODULE:NAME, e.g. examples.mountain_car.options:make_options")
    module = import_user_module(module_name, f"'{reference}'")
    try:
        return getattr(module, attr)
    except AttributeError:
        raise DynoplanError(f"'{reference}': module '{module_name}' has no '{attr}'") from None


def load_function(reference: str, what: str) -> Callable[..., Any]:
    """The callable named by ``reference`` (see :func:`load_object`).

    Raises:
        DynoplanError: as :func:`load_object`, or the object is not callable.
    """
    function = load_object(reference)
    if not callable(function):
        raise DynoplanError(f"'{reference}': the {what} is not callable")
    return function


def call_factory(reference: str, what: str) -> Any:
    """Call the factory named by ``reference`` (see :func:`load_object`) with no arguments."""
    factory = load_function(reference, f"{what} factory")
    try:
        return factory()
    except DynoplanError:
        raise
    except Exception as exc:
        raise DynoplanError(
            f"'{reference}': making the {what} failed: {type(exc).__name__}: {exc}") from None


__all__ = ["EndOnSuccess", "FlattenedObservation", "GymTask", "StateFn", "StateObservation",
           "SuccessFn", "call_factory", "load_function", "load_object", "task_env"]
