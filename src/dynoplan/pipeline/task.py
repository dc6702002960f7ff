"""Tasks: what the one pipeline needs to know of an environment.

A *task* names an environment and the options that act in it, in a form that any worker
process can rebuild from (references, not live objects): the pipeline's stages take a
task, and the evaluation ships it to Ray workers, which rebuild the environment, the
options and the controller from it and from the models folder
(:class:`~dynoplan.pipeline.evaluate.ControllerJob`).

:class:`GymTask` is the task of a user's Gymnasium environment with user-written options
(``dynoplan pipeline --env ID --options MODULE:FUNCTION``);
:class:`~dynoplan.experiments.gear_task.GearTask` is the gear assembly's.
"""

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import gymnasium as gym

from dynoplan.adapters.spec import OptionSpec, as_spec
from dynoplan.errors import DynoplanError
from dynoplan.imports import import_user_module

if TYPE_CHECKING:
    from dynoplan.pipeline.evaluate import ControllerSettings, EpisodeRunner


class Task(Protocol):
    """What a stage of the pipeline rebuilds, here or on a worker.

    A task is small, frozen and hashable (workers keep what they built per task), and
    picklable (it is shipped to them).
    """

    @property
    def name(self) -> str:
        """Shown in tables and recorded in summaries."""
        ...

    def make_env(self) -> gym.Env[Any, Any]:
        """A new instance of the task's environment."""
        ...

    def make_runner(self, controller: str, models: Path,
                    settings: "ControllerSettings") -> "EpisodeRunner":
        """Controller ``controller`` on a new environment, built from the models folder
        ``models``: what runs and records the task's seeded episodes (an
        :class:`~dynoplan.pipeline.evaluate.EpisodeRunner`, usually a
        :class:`~dynoplan.pipeline.evaluate.ControllerRunner`)."""
        ...


@dataclass(frozen=True)
class GymTask:
    """A registered Gymnasium environment with the user's options.

    Attributes:
        env_id: the Gymnasium id (``gymnasium.make``).
        options: ``MODULE:FUNCTION`` returning the options (a list of
            :func:`~dynoplan.adapters.option_spec`); see :func:`load_object`.
    """

    env_id: str
    options: str

    @property
    def name(self) -> str:
        return self.env_id

    def make_env(self) -> gym.Env[Any, Any]:
        """``gymnasium.make(env_id)``, after importing the options' module (which may
        register the environment: a worker process has not imported it yet)."""
        from dynoplan.pipeline.collect import make_env

        load_object(self.options)
        return make_env(self.env_id)

    def make_options(self) -> list[OptionSpec]:
        made = call_factory(self.options, "options")
        if not isinstance(made, list | tuple) or not made:
            raise DynoplanError(f"'{self.options}' must return a non-empty list of options, "
                                f"got {type(made).__name__}")
        return [as_spec(o) for o in made]

    def make_runner(self, controller: str, models: Path,
                    settings: "ControllerSettings") -> "EpisodeRunner":
        """The options with the learned models of ``models``
        (:meth:`~dynoplan.pipeline.fit.FittedModels.build`), under controller
        ``controller`` (:func:`~dynoplan.pipeline.evaluate.make_controller`)."""
        from dynoplan.pipeline.evaluate import ControllerRunner, make_controller
        from dynoplan.pipeline.fit import FittedModels

        fitted = FittedModels.load(models)
        run_options, planner_options = fitted.build(self.make_options())
        env = self.make_env()
        return ControllerRunner(env, make_controller(
            controller, run_options, fitted.goal, settings, planner_options, env.action_space))


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


def call_factory(reference: str, what: str) -> Any:
    """Call the factory named by ``reference`` (see :func:`load_object`) with no arguments."""
    factory = load_object(reference)
    if not callable(factory):
        raise DynoplanError(f"'{reference}': {what} factory is not callable")
    try:
        return factory()
    except DynoplanError:
        raise
    except Exception as exc:
        raise DynoplanError(
            f"'{reference}': making the {what} failed: {type(exc).__name__}: {exc}") from None
