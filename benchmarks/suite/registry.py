"""The suite's tasks, and how one is loaded: a task whose package is missing is skipped.

Each entry names the task module (the contract is in :mod:`benchmarks.suite.tasks`),
the module its package installs (looked up with ``importlib.util.find_spec`` before the
task module is imported, so a missing package never raises) and the ``pyproject.toml``
extra that installs it.
"""

import importlib
import importlib.util
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import gymnasium as gym

from dynoplan.errors import DynoplanError
from dynoplan.pipeline import GymTask


@dataclass(frozen=True)
class SuiteEntry:
    """One task of the suite.

    Attributes:
        name: the task's name in tables and output folders.
        module: the task module (``benchmarks.suite.tasks.<name>``).
        package: the module its third-party package installs (``Box2D``, ``panda_gym``).
        extra: the optional extra of ``pyproject.toml`` that installs it.
    """

    name: str
    module: str
    package: str
    extra: str

    def missing(self) -> str | None:
        """One line saying why the task is skipped, or ``None`` when its package is
        installed."""
        if importlib.util.find_spec(self.package) is not None:
            return None
        return (f"skipped {self.name}: needs the '{self.package}' package "
                f"(pip install 'dynoplan[{self.extra}]')")

    def load(self) -> "SuiteTask":
        """The task module, checked against the contract.

        Raises:
            DynoplanError: the module lacks a name of the contract.
        """
        module = importlib.import_module(self.module)
        for name in ("ENV_ID", "make_options", "make_demonstrator", "success", "state_fn",
                     "disturb", "DISTURBANCE"):
            if not hasattr(module, name):
                raise DynoplanError(f"suite task {self.module} defines no {name}")
        return SuiteTask(self, module)


@dataclass(frozen=True)
class SuiteTask:
    """A loaded suite task: its environment as the pipeline runs it, and its references
    (a :class:`~dynoplan.pipeline.GymTask` that workers can rebuild)."""

    entry: SuiteEntry
    module: ModuleType

    def ref(self, name: str) -> str | None:
        """``MODULE:NAME`` of the module's ``name`` (``None`` when it is ``None``)."""
        return None if getattr(self.module, name) is None else f"{self.entry.module}:{name}"

    @property
    def gym_task(self) -> GymTask:
        return GymTask(self.module.ENV_ID, self.ref("make_options") or "",
                       self.ref("success"), self.ref("state_fn"),
                       self.ref("make_demonstrator"), self.ref("disturb"))

    def make_env(self, disturbed: bool = False) -> gym.Env[Any, Any]:
        """The environment with the task's success and state functions, under its
        disturbance when ``disturbed`` (:meth:`~dynoplan.pipeline.GymTask.make_env`: the
        disturbance wraps the environment itself, so it sees the raw observation)."""
        return self.gym_task.make_env(disturbed)


TASKS: tuple[SuiteEntry, ...] = (
    SuiteEntry("lunar-lander", "benchmarks.suite.tasks.lunar_lander", "Box2D", "box2d"),
    SuiteEntry("cartpole-move", "benchmarks.suite.tasks.cartpole_move", "gymnasium",
               "suite"),
    SuiteEntry("panda-push", "benchmarks.suite.tasks.panda_push", "panda_gym", "panda"),
    SuiteEntry("panda-stack", "benchmarks.suite.tasks.panda_stack", "panda_gym", "panda"),
    SuiteEntry("metaworld-pick-place", "benchmarks.suite.tasks.metaworld_pick_place",
               "metaworld", "metaworld"),
    SuiteEntry("metaworld-drawer", "benchmarks.suite.tasks.metaworld_drawer", "metaworld",
               "metaworld"),
    SuiteEntry("minigrid-doorkey", "benchmarks.suite.tasks.minigrid_doorkey", "minigrid",
               "minigrid"),
)
"""Every task of the suite, in the order of its table."""


def select(names: str | None) -> list[SuiteEntry]:
    """The entries named (comma-separated), or all.

    Raises:
        DynoplanError: an unknown name.
    """
    if not names:
        return list(TASKS)
    by_name = {e.name: e for e in TASKS}
    unknown = [n for n in names.split(",") if n not in by_name]
    if unknown:
        raise DynoplanError(f"unknown suite task(s) {', '.join(unknown)} (known: "
                            f"{', '.join(by_name)})")
    return [by_name[n] for n in names.split(",")]
