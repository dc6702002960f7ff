"""Tasks: what the one pipeline needs to know of an environment.

A *task* names an environment and the options that act in it, in a form that any worker
process can rebuild from (references, not live objects): the pipeline's stages take a
task, and the evaluation ships it to Ray workers, which rebuild the environment, the
options and the controller from it and from the models folder
(:class:`~dynoplan.pipeline.evaluate.ControllerJob`).

:class:`~dynoplan.pipeline.gym_task.GymTask` is the task of a user's Gymnasium
environment with user-written options;
:class:`~dynoplan.envs.gear.pipeline_task.GearTask` is the gear assembly's.
"""

from pathlib import Path
from typing import Any, Protocol

import gymnasium as gym

from dynoplan.pipeline.control_settings import ControllerSettings
from dynoplan.pipeline.jobs import EpisodeRunner


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
        """A new instance of the task's environment, which defines success: an episode
        succeeded when its last step's ``info["is_success"]`` says so, else when it
        terminated (a task with a success function wraps its environment in
        :class:`~dynoplan.pipeline.gym_task.EndOnSuccess`, as
        :func:`~dynoplan.pipeline.gym_task.task_env` does)."""
        ...

    def make_runner(self, controller: str, models: Path,
                    settings: ControllerSettings) -> EpisodeRunner:
        """Controller ``controller`` on a new environment, built from the models folder
        ``models``: what runs and records the task's seeded episodes (an
        :class:`~dynoplan.pipeline.jobs.EpisodeRunner`, usually a
        :class:`~dynoplan.pipeline.evaluate.ControllerRunner`)."""
        ...


__all__ = ["Task"]
