"""What defines a pipeline run (:class:`PipelineSettings`), the run's seed streams
(:func:`run_seeds`) and the conversion of its records to JSON (:func:`jsonable`).

Seeds: one ``seed`` is split (``numpy.random.SeedSequence.spawn``) into independent
streams for the demonstrations, the exploration episodes, model fitting and the
evaluation episodes, so changing the number of one never changes the others.
"""

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from dynoplan.errors import DynoplanError
from dynoplan.pipeline.control_settings import ControllerSettings
from dynoplan.pipeline.fit import (
    FitSettings,
)
from dynoplan.pipeline.improve import ImprovementSettings


@dataclass(frozen=True)
class PipelineSettings:
    """Everything that defines a pipeline run (recorded in ``summary.json``).

    Attributes:
        demos: successful demonstrations to record (when none are given).
        exploration_episodes: episodes of randomly chosen options for the dynamics.
        exploration_option_steps: most steps an option runs while exploring.
        exploration_branches: further exploration episodes that branch off a
            demonstration (start where it was after a random step) instead of starting
            at ``env.reset`` (:func:`~dynoplan.pipeline.collect.collect_transitions`;
            0, the default: none; a named variant of the composition suite).
        episodes: evaluation episodes per controller.
        seed: the one seed every random choice derives from.
        fit: how the models are learned.
        control: how DynoPlan plans and every controller runs.
        controllers: which controllers to evaluate (default: DynoPlan, each option
            alone, random choice).
        demo_detours: further demonstrations, each with one detour: an option drawn at
            random acts for a while and the demonstrator recovers from where it left the
            task (:class:`~dynoplan.pipeline.collect.Detour`; with a demonstrator only;
            0: none).
        region_starts: start states of the task (resets of a seed stream of their own)
            at which the demonstrator's first choice is asked
            (:func:`~dynoplan.pipeline.collect.start_choices`); each option chosen
            there gets a region of its own on those states, joined to its region on the
            demonstrations (:func:`~dynoplan.pipeline.fit_regions.start_regions`; 0:
            none, the regions fit the demonstrations alone).
        improve, improve_episodes, improve_regions, improve_keep, improve_explore,
            improve_demos, improve_disturbed, improve_takeover: how the run learns from
            DynoPlan's own episodes before the evaluation
            (:mod:`~dynoplan.pipeline.improve`): the ``rounds``, ``episodes``,
            ``regions``, ``keep``, ``explore``, ``demos``, ``disturbed`` and ``takeover`` of
            :class:`~dynoplan.pipeline.improve.ImprovementSettings` (:attr:`improvement`).
    """

    demos: int = 5
    exploration_episodes: int = 20
    exploration_option_steps: int = 100
    exploration_branches: int = 0
    demo_detours: int = 0
    region_starts: int = 0
    episodes: int = 100
    seed: int = 0
    fit: FitSettings = field(default_factory=FitSettings)
    control: ControllerSettings = field(default_factory=ControllerSettings)
    controllers: tuple[str, ...] | None = None
    improve: int = ImprovementSettings.rounds
    improve_episodes: int = ImprovementSettings.episodes
    improve_regions: bool = ImprovementSettings.regions
    improve_keep: str = ImprovementSettings.keep
    improve_explore: float = ImprovementSettings.explore
    improve_demos: int = ImprovementSettings.demos
    improve_disturbed: float = ImprovementSettings.disturbed
    improve_takeover: bool = ImprovementSettings.takeover

    def validate(self) -> None:
        for name in ("demos", "exploration_episodes", "exploration_option_steps", "episodes"):
            if getattr(self, name) < 1:
                raise DynoplanError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.region_starts < 0:
            raise DynoplanError(f"region_starts must be >= 0, got {self.region_starts}")
        if self.demo_detours < 0:
            raise DynoplanError(f"demo_detours must be >= 0, got {self.demo_detours}")
        if self.exploration_branches < 0:
            raise DynoplanError("exploration_branches must be >= 0, got "
                                f"{self.exploration_branches}")
        self.improvement.validate()
        self.fit.validate()
        self.control.validate()

    @property
    def improvement(self) -> ImprovementSettings:
        """The improvement rounds' settings."""
        return ImprovementSettings(self.improve, self.improve_episodes, self.improve_regions,
                                   self.improve_keep, self.improve_explore,
                                   self.improve_demos, self.improve_disturbed,
                                   self.improve_takeover)


def starts_seed(demos_seed: int) -> int:
    """The seed stream of a run's start states (``region_starts``), apart from every other
    stream of :func:`run_seeds` (derived from the demonstrations' so that those stay the
    same with or without it)."""
    return _demos_child(demos_seed, 7)


def detours_seed(demos_seed: int) -> int:
    """The seed stream of a run's demonstrations with detours (``demo_detours``), apart
    from every other stream (derived as :func:`starts_seed`)."""
    return _demos_child(demos_seed, 8)


def _demos_child(demos_seed: int, key: int) -> int:
    """A seed stream derived from the demonstrations' seed and ``key``: apart from every
    stream of :func:`run_seeds`, and from the other keys'."""
    return int(np.random.SeedSequence([int(demos_seed), key]).generate_state(1)[0] % 2**31)


def run_seeds(seed: int, improve: bool = False) -> dict[str, int]:
    """The run's seed streams; ``improve`` adds the improvement rounds' (the others are
    the same with or without it)."""
    names = ("demos", "exploration", "fit", "evaluation", *(("improve",) if improve else ()))
    children = np.random.SeedSequence(seed).spawn(len(names))
    return {n: int(c.generate_state(1)[0] % 2**31) for n, c in zip(names, children, strict=True)}


def jsonable(value: Any) -> Any:
    """``value`` with every numpy array and scalar, in dicts, lists and tuples, made a plain
    Python value (tuples become lists), as ``summary.json`` records it."""
    if isinstance(value, dict):
        return {k: jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


__all__ = ["PipelineSettings", "detours_seed", "jsonable", "run_seeds", "starts_seed"]
