"""``dynoplan gear run``: the gear assembly end to end, into one output folder.

Stages (each timed in ``summary.json``):

1. ``networks``: the registered options' networks (the pick option's grasp recogniser
   and the insertion network; ``models/``);
2. ``demos``: 10 demonstrations by an operator chaining the options
   (:class:`~dynoplan.envs.gear.operator.OptionOperator`), and as many held-out ones
   from other seeds (``demos/``, ``heldout/``);
3. ``collect``: option transitions at the decision rate (``transitions/``);
4. ``train``: goal heuristic, safety regions and per-option dynamics
   (``models/metrics.json``);
5. ``figures``: Fig. 3(a) and 3(b) (``figures/``);
6. ``flat_ppo``: the flat end-to-end baseline (``flat_ppo/``);
7. ``outcomes``: every option run from starts beyond its own region, and the initiation
   learned from those outcomes (``outcomes/``, ``models/initiation.safetensors``; see
   :mod:`dynoplan.envs.gear.learning.outcomes`), part of every controller's learned
   initiation sets;
8. ``evaluate``: every controller on the same seeded episodes (human: none, crossing or
   blocking), the named variants (:data:`VARIANT_ROWS`) and, on the first of those
   episodes, the ablation (:data:`ABLATION_ROWS`); ``results.csv`` and ``results.md``;
9. ``faults``: DynoPlan under corrupted dynamics, observation noise and a grasp slip;
10. ``video``: one DynoPlan episode with the human interfering (``episode.mp4``).

Stages 1-5 are the functions of :mod:`dynoplan.experiments.gear_stages`, which the
commands ``gear demos``, ``gear collect``, ``gear train`` and ``gear figures`` call too
(the first two train the networks when they are missing).

On one worker the stages run one after another in this process. On several (Ray), the
stages made of independent episodes (the networks' data, the demonstrations, collection,
evaluation, faults) spread them over the workers, and two stages run beside the others
as one Ray task each: the flat PPO training from the start of the run (it needs nothing
but the seed) and the video beside the faults. Their ``stages_s`` entries are then their
own durations, which overlap other stages; ``wall_s`` is the whole run's. Every result
is the same on one worker or many.
"""

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, TypeVar

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
from dynoplan.experiments.gear_stages import FIGURE_POINTS, QUICK_FIGURE_POINTS
from dynoplan.io import ensure_writable_dir, write_json, write_text
from dynoplan.parallel import SERIAL, Workers, ray_session, run_in_background
from dynoplan.pipeline.collect import OptionRunSettings
from dynoplan.pipeline.evaluate import ControllerSettings, evaluate_rows
from dynoplan.pipeline.fit import FitSettings
from dynoplan.reports.gear_results import results_markdown, results_rows, summarise, write_results

T = TypeVar("T")


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
    """The ``evaluate`` stage: every controller on ``episodes`` evaluation episodes, the
    oracle on the first ``oracle_episodes`` of them (it simulates every option at every
    decision, which costs real time), each ablation row on the first
    ``ablation_episodes``; every controller plans and runs as ``planner`` says (horizon,
    samples, margin, ...), in the faults and the video too."""

    episodes: int = 100
    oracle_episodes: int = 10
    ablation_episodes: int = 30
    planner: ControllerSettings = GEAR_CONTROL


@dataclass(frozen=True)
class GearRunSettings:
    """Sizes of every stage (recorded in ``summary.json``).

    Attributes:
        demos: demonstrations (and held-out trials) recorded.
        collect: the option runs of every option for the dynamics data (runs per option,
            decisions per run at most).
        fit, metrics: how the learned models (goal, regions, dynamics) are fitted and
            measured on held-out data.
        figure_points: states embedded by t-SNE in Fig. 3(b) at most.
        ppo_steps: environment steps of the flat PPO baseline.
        evaluation: the evaluate stage.
        faults: the faults stage.
        video: render one episode.
        outcomes: the outcome runs (``runs`` 0: no outcome stage; the learned initiation
            sets are then the Eq. 5 regions alone).
    """

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
    """Run every stage (module docstring) into ``out``; return ``summary.json``'s content.

    The stages made of independent episodes run them on ``workers`` (one Ray runtime for
    the whole run), and on several workers the flat PPO training and the video run
    beside the other stages; the results are the same on one worker or many."""
    t0 = time.perf_counter()
    with ray_session(workers):
        summary = _run_stages(out, seed, settings, progress, log, workers)
    summary["wall_s"] = round(time.perf_counter() - t0, 2)
    write_text(out / "results.md", results_markdown(summary))
    write_json(out / "summary.json", summary)
    return summary


def _run_stages(out: Path, seed: int, settings: GearRunSettings, progress: bool,
                log: Callable[[str], None], workers: Workers) -> dict[str, Any]:
    import torch

    from dynoplan.baselines.flat_policy import fit_flat_policy, save_flat_policy
    from dynoplan.experiments.gear_stages import (
        demonstrations,
        figures,
        learned_initiation,
        learned_models,
        option_networks,
        option_transitions,
    )
    from dynoplan.reports.gear_episode import render_video, save_video

    torch.set_num_threads(1)
    ensure_writable_dir(out)
    models_dir = out / "models"
    stages: dict[str, float] = {}
    summary: dict[str, Any] = {"seed": seed, "settings": asdict(settings), "stages_s": stages,
                               "workers": asdict(workers)}

    def stage(name: str, fn: Callable[[], T]) -> T:
        log(f"[{name}]")
        t0 = time.perf_counter()
        result = fn()
        stages[name] = round(time.perf_counter() - t0, 2)
        return result

    def start(name: str, fn: Callable[..., T], *args: Any) -> Callable[[], T]:
        """Stage ``name``, ``fn(*args)``: run now on one worker, started as a Ray task
        beside the next stages on several; the returned function waits for the result
        (and records the stage's own duration)."""
        log(f"[{name}]" + (" (beside the next stages)" if workers.parallel else ""))
        wait = run_in_background(_timed, (fn, *args), workers)

        def finish() -> T:
            seconds, result = wait()
            stages[name] = round(seconds, 2)
            return result

        return finish

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
    return summary


def _timed(fn: Callable[..., T], *args: Any) -> tuple[float, T]:
    """``(wall seconds, fn(*args))``: a stage run as one task, and how long it took."""
    t0 = time.perf_counter()
    result = fn(*args)
    return time.perf_counter() - t0, result


__all__ = ["QUICK_RUN", "EvaluationSettings", "FaultSettings", "GearRunSettings",
           "run_gear_pipeline", "run_settings"]
