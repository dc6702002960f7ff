"""``dynoplan gear run``: the gear assembly end to end, into one output folder.

Stages, each timed in ``summary.json``'s ``stages_s``, with what they write:
``networks`` (the options' networks, ``models/``), ``demos`` (demonstrations by
:class:`~dynoplan.envs.gear.operator.OptionOperator` and held-out ones, ``demos/``,
``heldout/``), ``collect`` (``transitions/``), ``train`` (goal, regions, dynamics;
``models/metrics.json``), ``figures`` (Fig. 3(a), 3(b); ``figures/``), ``flat_ppo``
(``flat_ppo/``), ``outcomes`` (outcome runs and the initiation learned from them;
``outcomes/``, ``models/initiation.safetensors``), ``evaluate`` (every controller, the
variants :data:`VARIANT_ROWS` and the ablation :data:`ABLATION_ROWS` on the same seeded
episodes; ``results.csv``, ``results.md``), ``faults`` and ``video`` (``episode.mp4``).
The first five are :mod:`dynoplan.experiments.gear_stages`, shared with the stage commands.

The whole folder is staged (:func:`~dynoplan.io.staged_folder`, starting as a copy of
the previous ``out``, whose option networks are reused): it replaces ``out`` only when
every stage has finished; a failure or an interrupt leaves ``out`` as it was. The paths
recorded in the outputs name ``out``.

On several workers (Ray) the episode stages spread over them, and ``flat_ppo`` (from
the start) and ``video`` (beside ``faults``) run as one task each: their ``stages_s``
are their own durations, ``wall_s`` the run's. Results are the same on one worker or many.
"""

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from functools import partial
from pathlib import Path
from typing import Any

from dynoplan.envs.gear.controllers import CONTROLLERS, GEAR_CONTROL
from dynoplan.envs.gear.evaluation import (
    ABLATION_ROWS,
    ORACLE_FIRST,
    VARIANT_ROWS,
    controller_rows,
    evaluation_seeds,
    fault_rows,
    video_episode,
)
from dynoplan.envs.gear.learning.files import load_gear_models
from dynoplan.envs.gear.learning.settings import (
    DEFAULT_METRICS,
    DEFAULT_SETTINGS,
    QUICK_METRICS,
    QUICK_SETTINGS,
    GearMetricsSettings,
)
from dynoplan.envs.gear.reports.results import (
    results_markdown,
    results_rows,
    summarise,
    write_results,
)
from dynoplan.experiments.gear_stages import FIGURE_POINTS, QUICK_FIGURE_POINTS
from dynoplan.io import retarget, staged_folder, write_json, write_text
from dynoplan.parallel import SERIAL, Workers, ray_session
from dynoplan.pipeline.collect import OptionRunSettings
from dynoplan.pipeline.control_settings import ControllerSettings
from dynoplan.pipeline.fit import FitSettings
from dynoplan.pipeline.jobs import evaluate_rows
from dynoplan.timing import StageClock


@dataclass(frozen=True)
class FaultSettings:
    """The ``faults`` stage: DynoPlan on the first ``episodes`` evaluation episodes under
    noise of std ``dynamics_noise`` on every learned prediction, under observation noise
    of std ``observation_noise`` (m, rad), and with a grasp slip."""

    episodes: int = 30
    dynamics_noise: float = 0.02
    observation_noise: float = 0.005


TRANSITION_RUNS = OptionRunSettings(runs=40, max_decisions=30, lead_decisions=0)
"""The collect stage's option runs: from every option's own starts."""
OUTCOME_RUNS = OptionRunSettings(runs=30, max_decisions=30, lead_decisions=12)
"""The outcomes stage's option runs: from starts beyond every option's own."""


@dataclass(frozen=True)
class EvaluationSettings:
    """The ``evaluate`` stage: every controller on ``episodes`` episodes, the (slow) oracle
    on the first ``oracle_episodes``, each ablation row on the first ``ablation_episodes``;
    ``planner``: how every controller plans (in the faults and the video too)."""

    episodes: int = 100
    oracle_episodes: int = 10
    ablation_episodes: int = 30
    planner: ControllerSettings = GEAR_CONTROL


@dataclass(frozen=True)
class GearRunSettings:
    """Sizes of every stage (recorded in ``summary.json``): ``demos`` demonstrations (and
    held-out trials), ``collect``'s option runs, how the models are fitted (``fit``) and
    measured (``metrics``), t-SNE ``figure_points``, ``ppo_steps`` of the flat baseline,
    ``outcomes``' runs (``runs`` 0: no outcomes stage, the Eq. 5 regions alone)."""

    demos: int = 10
    collect: OptionRunSettings = TRANSITION_RUNS
    fit: FitSettings = DEFAULT_SETTINGS
    metrics: GearMetricsSettings = DEFAULT_METRICS
    figure_points: int = FIGURE_POINTS
    ppo_steps: int = 30_000
    evaluation: EvaluationSettings = EvaluationSettings()
    faults: FaultSettings = FaultSettings()
    video: bool = True
    outcomes: OptionRunSettings = OUTCOME_RUNS


QUICK_RUN = GearRunSettings(
    collect=OptionRunSettings(runs=4, max_decisions=15, lead_decisions=0),
    fit=QUICK_SETTINGS, metrics=QUICK_METRICS,
    figure_points=QUICK_FIGURE_POINTS, ppo_steps=2048,
    evaluation=EvaluationSettings(6, 2, 2, replace(GEAR_CONTROL, horizon=6, samples=32,
                                                   oracle_horizon=3)),
    faults=FaultSettings(episodes=3),
    outcomes=OptionRunSettings(runs=2, max_decisions=6, lead_decisions=2))
"""``--quick``: every stage on small settings (CI, a first look)."""


def run_settings(quick: bool) -> GearRunSettings:
    """The sizes of ``gear run`` (:data:`QUICK_RUN` with ``quick``), which the standalone
    stage commands (``gear demos``, ``gear collect``, ...) take as their defaults too."""
    return QUICK_RUN if quick else GearRunSettings()


def run_gear_pipeline(out: Path, seed: int = 0, settings: GearRunSettings = GearRunSettings(),
                      progress: bool = True, log: Callable[[str], None] = lambda _: None,
                      workers: Workers = SERIAL) -> dict[str, Any]:
    """Run every stage (module docstring) into ``out``, staged as a whole, on ``workers``
    (one Ray runtime for the run); return ``summary.json``'s content.

    Raises:
        DynoplanError: ``out`` cannot be written (checked before any stage runs).
    """
    t0 = time.perf_counter()
    with staged_folder(out, keep=True) as stage:
        with ray_session(workers):
            summary = _run_stages(stage, seed, settings, progress, log, workers)
        summary = retarget(summary, stage, out)
        summary["wall_s"] = round(time.perf_counter() - t0, 2)
        write_text(stage / "results.md", results_markdown(summary))
        write_json(stage / "summary.json", summary)
    return summary


def _run_stages(out: Path, seed: int, settings: GearRunSettings, progress: bool,
                log: Callable[[str], None], workers: Workers) -> dict[str, Any]:
    import torch

    from dynoplan.envs.gear.flat_policy import fit_flat_policy, save_flat_policy
    from dynoplan.envs.gear.reports.episode import render_video, save_video
    from dynoplan.experiments.gear_stages import (
        demonstrations,
        figures,
        learned_initiation,
        learned_models,
        option_networks,
        option_transitions,
    )

    torch.set_num_threads(1)
    models_dir = out / "models"
    clock = StageClock(log, "[{}]")
    stage = clock.stage
    summary: dict[str, Any] = {"seed": seed, "settings": asdict(settings), "stages_s": {},
                               "workers": asdict(workers)}
    start = partial(clock.start, workers=workers)
    flat = (start("flat_ppo", fit_flat_policy, settings.ppo_steps, seed)
            if workers.parallel else None)
    summary["networks"] = stage("networks", lambda: option_networks(
        models_dir, seed, workers=workers))
    summary["demos"] = stage("demos", lambda: [
        demonstrations(settings.demos, seed, out / "demos", models_dir, progress=progress,
                       workers=workers),
        demonstrations(settings.demos, seed, out / "heldout", models_dir, heldout=True,
                       progress=progress, workers=workers)])
    summary["collect"] = stage("collect", lambda: option_transitions(
        models_dir, settings.collect.runs, seed, out / "transitions",
        settings.collect.max_decisions, progress=progress, workers=workers))
    metrics = stage("train", lambda: learned_models(
        out / "demos", out / "transitions", models_dir, seed, out / "heldout", settings.fit,
        settings.metrics, progress=progress, workers=workers))
    summary["model_metrics"] = {k: v for k, v in metrics.items() if not isinstance(v, dict)}
    summary["figures"] = stage("figures", lambda: figures(
        models_dir, out / "demos", out / "heldout", out / "figures", seed,
        settings.figure_points))
    if flat is None:
        flat = start("flat_ppo", fit_flat_policy, settings.ppo_steps, seed)
    summary["flat_ppo"] = save_flat_policy(flat(), out / "flat_ppo")

    if settings.outcomes.runs:  # after every stage whose results it could touch
        summary["outcomes"] = stage("outcomes", lambda: learned_initiation(
            models_dir, out / "outcomes", seed, settings.outcomes, progress, workers))
    load_gear_models(models_dir)  # checked here once: workers load it again
    sizes = settings.evaluation
    seeds = evaluation_seeds(seed, sizes.episodes)
    rows = controller_rows(models_dir, seeds, sizes.planner, flat_folder=out / "flat_ppo",
                           extra=VARIANT_ROWS, ablation=ABLATION_ROWS,
                           oracle_episodes=sizes.oracle_episodes,
                           ablation_episodes=sizes.ablation_episodes)
    episodes = stage("evaluate", lambda: evaluate_rows(
        rows, workers, f"evaluate ({len(rows)} controllers)", progress, ORACLE_FIRST))
    summary["results"] = results_rows(episodes)
    summary["ablation"] = [summarise(name, episodes[name][:sizes.ablation_episodes])
                           for name in (*CONTROLLERS[:2], *VARIANT_ROWS, *ABLATION_ROWS)]
    write_results(out, summary["results"], episodes)

    video = None
    if settings.video:
        shown = video_episode(episodes["dynoplan"])
        video = start("video", render_video, models_dir, seeds[shown], sizes.planner)
    faults = settings.faults
    fault_runs = fault_rows(models_dir, seeds[:faults.episodes], sizes.planner,
                            faults.dynamics_noise, faults.observation_noise)
    summary["faults"] = stage("faults", lambda: [
        {"fault": fault, **summarise("dynoplan", records)}
        for fault, records in evaluate_rows(fault_runs, workers, f"faults ({len(fault_runs)})",
                                            progress).items()])
    if video is not None:
        summary["video"] = save_video(video(), episodes["dynoplan"][shown], shown,
                                      out / "episode.mp4")
    summary["stages_s"] = clock.rounded(2)
    return summary


__all__ = ["QUICK_RUN", "EvaluationSettings", "FaultSettings", "GearRunSettings",
           "run_gear_pipeline", "run_settings"]
