"""The gear's evaluation: which controller runs on which seeded episodes.

Every row of ``gear run``'s and ``gear evaluate``'s tables is a
:class:`~dynoplan.pipeline.evaluate.ControllerJob` of a :class:`GearTask` with its
episodes; :func:`~dynoplan.pipeline.jobs.evaluate_rows` runs the rows as one map and
:func:`~dynoplan.envs.gear.reports.results.results_rows` makes the table. Episode ``i`` of
every row resets the env with the same seed (gear pose and human schedule), and an
episode depends on its seed alone, so the metrics are the same on one worker or many.
"""

from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from dynoplan.envs.gear.controllers import CONTROLLERS, TUNED_CHANGES
from dynoplan.envs.gear.flat_policy import FLAT_POLICY
from dynoplan.envs.gear.metrics import human_mode, seconds
from dynoplan.envs.gear.options.catalog import CAUTIOUS_MOVE
from dynoplan.envs.gear.pipeline_task import GearTask
from dynoplan.pipeline.control_settings import ControllerSettings
from dynoplan.pipeline.evaluate import ControllerJob, EpisodeRecord
from dynoplan.seeding import EpisodeSeed, episode_seeds

EVAL_SEED_OFFSET = 7
"""Evaluation episodes use seeds derived from ``seed + EVAL_SEED_OFFSET`` (disjoint from
the demonstrations' and the held-out trials')."""

VARIANT_ROWS = ("dynoplan+rules",)
"""Rows of ``results.csv`` after :data:`CONTROLLERS` and the flat policy, on every
episode: DynoPlan with each option's hand-written conditions added to its learned region
(:data:`~dynoplan.envs.gear.controllers.VARIANTS`), the rules the learned parts
replace."""

ABLATION_ROWS: dict[str, tuple[str, dict[str, Any]]] = {
    "dynoplan_regions": ("dynoplan_regions", {}),
    "dynoplan epistemic=0.3": ("dynoplan", {"epistemic": 0.3}),
    "dynoplan gear-tuned": ("dynoplan", TUNED_CHANGES),
}
"""The last rows of ``results.csv``, each on the first ``ablation_episodes`` episodes:
row name -> (controller of :data:`~dynoplan.envs.gear.controllers.VARIANTS`, the
planner settings it changes). Beside DynoPlan on the same episodes they show what each
learned part does: ``dynoplan_regions`` plans on the paper's Eq. 5 regions alone (no
initiation learned from outcomes, rollouts not stopped at the continuation set),
``epistemic=0.3`` penalises the dynamics ensemble's disagreement; ``gear-tuned`` plans
with the gear's own former settings in place of the library's defaults
(:data:`~dynoplan.envs.gear.controllers.GEAR_TUNED`)."""

IMPROVE_SEED_OFFSET = 2000
"""The improvement rounds' own episodes use seeds derived from ``seed +
IMPROVE_SEED_OFFSET`` (disjoint from the evaluation's and the demonstrations')."""

ORACLE_FIRST = ("oracle",)
"""Rows whose episodes are submitted first (the oracle's cost ten times the others'), so
that no long episode is left running alone at the end of the stage."""

Rows = dict[str, tuple[ControllerJob, Sequence[EpisodeSeed]]]
"""Row name -> the controller job and the episodes it runs."""


def evaluation_seeds(seed: int, episodes: int) -> list[EpisodeSeed]:
    """The evaluation episodes of ``gear run`` / ``gear evaluate`` with ``--seed seed``."""
    return episode_seeds(seed + EVAL_SEED_OFFSET, episodes)


def improvement_seeds(seed: int, episodes: int) -> list[EpisodeSeed]:
    """The own episodes of ``gear run``'s improvement rounds with ``--seed seed``."""
    return episode_seeds(seed + IMPROVE_SEED_OFFSET, episodes)


def controller_rows(models: Path, seeds: Sequence[EpisodeSeed], planner: ControllerSettings,
                    names: Sequence[str] = CONTROLLERS, flat_folder: Path | None = None,
                    task: GearTask = GearTask(), extra: Sequence[str] = (),
                    ablation: Mapping[str, tuple[str, Mapping[str, Any]]] = {},
                    oracle_episodes: int | None = None, ablation_episodes: int | None = None,
                    ) -> Rows:
    """The controllers ``names`` (of :data:`CONTROLLERS`), the flat policy if
    ``flat_folder``, the variants ``extra`` (of
    :data:`~dynoplan.envs.gear.controllers.VARIANTS`), on ``seeds``; the oracle on the
    first ``oracle_episodes`` of them and the ``ablation`` rows (row name -> controller
    and planner-setting changes, as :data:`ABLATION_ROWS`) on the first
    ``ablation_episodes`` (``None``: all; ``0``: those rows are left out, as the oracle's
    with ``oracle_episodes`` 0). ``task``: the gear as the episodes see it (the human
    behaviours they draw from, the runtime monitor)."""
    gear = replace(task, flat_folder=flat_folder)
    rows: Rows = {name: (ControllerJob(gear, models, name, planner),
                         seeds[:oracle_episodes] if name == "oracle" else seeds)
                  for name in names}
    if flat_folder is not None:
        rows[FLAT_POLICY] = (ControllerJob(gear, models, FLAT_POLICY, planner), seeds)
    for name in extra:
        rows[name] = (ControllerJob(gear, models, name, planner), seeds)
    for label, (name, changes) in ablation.items():
        rows[label] = (ControllerJob(gear, models, name, replace(planner, **changes)),
                       seeds[:ablation_episodes])
    return {name: row for name, row in rows.items() if len(row[1])}


def fault_rows(models: Path, seeds: Sequence[EpisodeSeed], planner: ControllerSettings,
               dynamics_noise: float, observation_noise: float) -> Rows:
    """DynoPlan under each fault on ``seeds``: noise of std ``dynamics_noise`` on every
    learned prediction, observation noise of std ``observation_noise`` (m, rad), a grasp
    slip."""
    return {
        "dynamics_noise": (ControllerJob(GearTask(), models, "dynoplan", replace(
            planner, dynamics_noise=dynamics_noise)), seeds),
        "observation_noise": (ControllerJob(
            GearTask(fault="observation_noise", observation_noise=observation_noise),
            models, "dynoplan", planner), seeds),
        "grasp_slip": (ControllerJob(GearTask(fault="grasp_slip"), models, "dynoplan",
                                     planner), seeds),
    }


def video_episode(episodes: Sequence[EpisodeRecord]) -> int:
    """Which evaluated DynoPlan episode the video shows (its index in ``episodes``): one
    in which it switched to the cautious move if any, else one with the human
    interfering if any; among those, a success if any, and the shortest (the quickest to
    render), the first of equals."""
    return min(range(len(episodes)), key=lambda i: (
        CAUTIOUS_MOVE.name not in episodes[i].options, human_mode(episodes[i]) == "away",
        not episodes[i].success, seconds(episodes[i]), i))


__all__ = ["ABLATION_ROWS", "EVAL_SEED_OFFSET", "IMPROVE_SEED_OFFSET", "ORACLE_FIRST",
           "VARIANT_ROWS", "Rows", "controller_rows", "evaluation_seeds", "fault_rows",
           "improvement_seeds", "video_episode"]
