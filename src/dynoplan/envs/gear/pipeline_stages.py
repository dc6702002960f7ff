"""The gear assembly's stages of the one pipeline
(:func:`~dynoplan.pipeline.run.run_pipeline`), and their sizes.

:class:`GearStages` is what ``dynoplan gear run`` does at each of the pipeline's stages
(:class:`~dynoplan.pipeline.task.TaskStages`), timed by name in ``summary.json``'s
``stages_s``, with what they write into the run's folder: ``networks`` (the options'
networks, ``models/``), ``demos`` (demonstrations by
:class:`~dynoplan.envs.gear.operator.OptionOperator` and held-out ones, ``demos/``,
``heldout/``), ``collect`` (``transitions/``), ``train`` (goal, regions, dynamics;
``models/metrics.json``), ``figures`` (Fig. 3(a), 3(b); ``figures/``), ``flat_ppo``
(``flat_ppo/``), ``outcomes`` (outcome runs and the initiation learned from them;
``outcomes/``, ``models/initiation.safetensors``), ``improve`` (the improvement rounds,
:mod:`dynoplan.envs.gear.improve`; ``improve/``, the kept models in ``models/``),
``evaluate`` (every controller, the
variants :data:`~dynoplan.envs.gear.evaluation.VARIANT_ROWS` and the ablation
:data:`~dynoplan.envs.gear.evaluation.ABLATION_ROWS` on the same seeded episodes;
``results.csv``, ``episodes.json``), ``faults`` and ``video`` (``episode.mp4``). The
first five are :mod:`dynoplan.envs.gear.stages`, shared with the stage commands, which
take the same sizes (:func:`run_settings`).

On several workers (Ray) the episode stages spread over them, and ``flat_ppo`` (from
the start) and ``video`` (beside ``faults``) run as one task each: their ``stages_s``
are their own durations. Results are the same on one worker or many.
"""

from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
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
from dynoplan.envs.gear.learning.settings import (
    DEFAULT_METRICS,
    DEFAULT_SETTINGS,
    QUICK_METRICS,
    QUICK_SETTINGS,
    GearMetricsSettings,
)
from dynoplan.envs.gear.models_folder import METRICS_FILE, load_gear_models
from dynoplan.envs.gear.reports.results import results_rows, summarise, write_results
from dynoplan.envs.gear.stages import FIGURE_POINTS, QUICK_FIGURE_POINTS
from dynoplan.errors import DynoplanError
from dynoplan.io import read_json_object
from dynoplan.pipeline.collect import OptionRunSettings
from dynoplan.pipeline.control_settings import ControllerSettings
from dynoplan.pipeline.evaluate import EpisodeRecord
from dynoplan.pipeline.fit import FitSettings
from dynoplan.pipeline.improve import ImprovementSettings
from dynoplan.pipeline.jobs import evaluate_rows
from dynoplan.pipeline.task import PipelineRun


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
    ``outcomes``' runs (``runs`` 0: no outcomes stage, the Eq. 5 regions alone), the
    ``improvement`` rounds on DynoPlan's own episodes (the pipeline's defaults),
    ``region_starts`` start states labelled by the operator's first choice for the
    regions (the pipeline's ``region_starts``; 0: none), ``own_states``: every option
    whose registry record declares its own state has its dynamics fitted and rolled on it
    (:func:`~dynoplan.envs.gear.learning.training.train_gear_models`; off: every option
    on the planner state)."""

    demos: int = 10
    region_starts: int = 0
    collect: OptionRunSettings = TRANSITION_RUNS
    fit: FitSettings = DEFAULT_SETTINGS
    metrics: GearMetricsSettings = DEFAULT_METRICS
    figure_points: int = FIGURE_POINTS
    ppo_steps: int = 30_000
    evaluation: EvaluationSettings = EvaluationSettings()
    faults: FaultSettings = FaultSettings()
    video: bool = True
    outcomes: OptionRunSettings = OUTCOME_RUNS
    improvement: ImprovementSettings = field(default_factory=ImprovementSettings)
    own_states: bool = False


QUICK_RUN = GearRunSettings(
    collect=OptionRunSettings(runs=4, max_decisions=15, lead_decisions=0),
    fit=QUICK_SETTINGS, metrics=QUICK_METRICS,
    figure_points=QUICK_FIGURE_POINTS, ppo_steps=2048,
    evaluation=EvaluationSettings(6, 2, 2, replace(GEAR_CONTROL, horizon=6, samples=32,
                                                   oracle_horizon=3)),
    faults=FaultSettings(episodes=3),
    outcomes=OptionRunSettings(runs=2, max_decisions=6, lead_decisions=2),
    improvement=ImprovementSettings(episodes=3))
"""``--quick``: every stage on small settings (CI, a first look)."""


def run_settings(quick: bool) -> GearRunSettings:
    """The sizes of ``gear run`` (:data:`QUICK_RUN` with ``quick``), which the standalone
    stage commands (``gear demos``, ``gear collect``, ...) take as their defaults too."""
    return QUICK_RUN if quick else GearRunSettings()


class GearStages:
    """The gear assembly's stages of :func:`~dynoplan.pipeline.run.run_pipeline`
    (:class:`~dynoplan.pipeline.task.TaskStages`) from ``seed`` with ``settings``, into
    the run's folder (module docstring); each stage's data is the folder it wrote, and
    :meth:`report` returns ``summary.json``'s content but ``wall_s``
    (:func:`~dynoplan.experiments.gear_run.run_gear_pipeline` adds it).

    - ``prepare``: the option networks the operator and the options run (the flat PPO
      baseline started beside the next stages on several workers);
    - ``demonstrations``: the operator's demonstrations and held-out trials;
    - ``option_runs``: every option's runs from its own starts;
    - ``fit``: goal, regions and dynamics, measured on the held-out trials;
    - ``after_fit``: the flat PPO baseline, the initiation learned from outcome runs
      (after every stage whose results it could touch), the improvement rounds and Fig. 3
      of the models kept;
    - ``evaluate``: every controller, the flat baseline, the variants and the ablation
      rows (the oracle on the first episodes) on the same seeded episodes;
    - ``report``: the faults and the video.
    """

    def __init__(self, seed: int = 0, settings: GearRunSettings = GearRunSettings()) -> None:
        self.seed, self.settings = seed, settings
        self.summary: dict[str, Any] = {}
        self._flat: Callable[[], Any] | None = None

    def prepare(self, run: PipelineRun) -> None:
        if run.out is None:
            raise DynoplanError("the gear's run writes into a folder: give one (out=...)")
        import torch

        from dynoplan.envs.gear.flat_policy import fit_flat_policy
        from dynoplan.envs.gear.stages import option_networks

        torch.set_num_threads(1)
        self.summary = {"seed": self.seed, "settings": asdict(self.settings), "stages_s": {},
                        "workers": asdict(run.workers)}
        if run.workers.parallel:
            self._flat = run.clock.start("flat_ppo", fit_flat_policy, self.settings.ppo_steps,
                                         self.seed, workers=run.workers)
        self.summary["networks"] = run.clock.stage("networks", lambda: option_networks(
            _folder(run) / "models", self.seed, workers=run.workers))

    def demonstrations(self, run: PipelineRun) -> Path:
        from dynoplan.envs.gear.stages import demonstrations

        out, seed, n = _folder(run), self.seed, self.settings.demos
        self.summary["demos"] = run.clock.stage("demos", lambda: [
            demonstrations(n, seed, out / "demos", out / "models", progress=run.progress,
                           workers=run.workers),
            demonstrations(n, seed, out / "heldout", out / "models", heldout=True,
                           progress=run.progress, workers=run.workers)])
        if self.settings.region_starts:
            from dynoplan.envs.gear.stages import STARTS_DIR, start_states

            self.summary["starts"] = run.clock.stage("starts", lambda: start_states(
                self.settings.region_starts, seed, out / STARTS_DIR, out / "models"))
        return out / "demos"

    def option_runs(self, run: PipelineRun, demos: Path) -> Path:
        from dynoplan.envs.gear.stages import option_transitions

        out, collect = _folder(run), self.settings.collect
        self.summary["collect"] = run.clock.stage("collect", lambda: option_transitions(
            out / "models", collect.runs, self.seed, out / "transitions",
            collect.max_decisions, progress=run.progress, workers=run.workers))
        return out / "transitions"

    def fit(self, run: PipelineRun, demos: Path, runs: Path) -> Path:
        from dynoplan.envs.gear.stages import learned_models

        out, settings = _folder(run), self.settings
        metrics = run.clock.stage("train", lambda: learned_models(
            demos, runs, out / "models", self.seed, out / "heldout", settings.fit,
            settings.metrics, progress=run.progress, workers=run.workers,
            region_starts=_starts(out, settings), own_states=settings.own_states))
        self.summary["model_metrics"] = _headline(metrics)
        return out / "models"

    def after_fit(self, run: PipelineRun, models: Path) -> Path:
        from dynoplan.envs.gear.flat_policy import fit_flat_policy, save_flat_policy
        from dynoplan.envs.gear.improve import improved_models
        from dynoplan.envs.gear.stages import figures, learned_initiation

        out, seed, settings = _folder(run), self.seed, self.settings
        if self._flat is None:
            self._flat = run.clock.start("flat_ppo", fit_flat_policy, settings.ppo_steps, seed,
                                         workers=run.workers)
        self.summary["flat_ppo"] = save_flat_policy(self._flat(), out / "flat_ppo")
        if settings.outcomes.runs:  # after every stage whose results it could touch
            self.summary["outcomes"] = run.clock.stage("outcomes", lambda: learned_initiation(
                models, out / "outcomes", seed, settings.outcomes, run.progress,
                run.workers))
        if settings.improvement.rounds:
            self.summary["improvement"] = run.clock.stage("improve", lambda: improved_models(
                out, seed, settings.improvement, settings.fit, settings.metrics,
                settings.outcomes, settings.evaluation.planner, run.progress, run.workers,
                region_starts=_starts(out, settings), own_states=settings.own_states))
            self.summary["model_metrics"] = _headline(read_json_object(
                models / METRICS_FILE, "the kept models' metrics"))
        self.summary["figures"] = run.clock.stage("figures", lambda: figures(
            models, out / "demos", out / "heldout", out / "figures", seed,
            settings.figure_points))
        return models

    def evaluate(self, run: PipelineRun, models: Path) -> dict[str, list[EpisodeRecord]]:
        out, sizes = _folder(run), self.settings.evaluation
        load_gear_models(models)  # checked here once: workers load it again
        seeds = evaluation_seeds(self.seed, sizes.episodes)
        rows = controller_rows(models, seeds, sizes.planner, flat_folder=out / "flat_ppo",
                               extra=VARIANT_ROWS, ablation=ABLATION_ROWS,
                               oracle_episodes=sizes.oracle_episodes,
                               ablation_episodes=sizes.ablation_episodes)
        episodes = run.clock.stage("evaluate", lambda: evaluate_rows(
            rows, run.workers, f"evaluate ({len(rows)} controllers)", run.progress,
            ORACLE_FIRST))
        self.summary["results"] = results_rows(episodes)
        self.summary["ablation"] = [  # none with --ablation-episodes 0
            summarise(name, episodes[name][:sizes.ablation_episodes])
            for name in (*CONTROLLERS[:2], *VARIANT_ROWS, *ABLATION_ROWS)
            if sizes.ablation_episodes and name in episodes]
        write_results(out, self.summary["results"], episodes)
        return episodes

    def report(self, run: PipelineRun, episodes: dict[str, list[EpisodeRecord]]
               ) -> dict[str, Any]:
        from dynoplan.envs.gear.reports.episode import render_video, save_video

        out, sizes, faults = _folder(run), self.settings.evaluation, self.settings.faults
        models = out / "models"
        seeds = evaluation_seeds(self.seed, sizes.episodes)
        video = None
        if self.settings.video:
            shown = video_episode(episodes["dynoplan"])
            video = run.clock.start("video", render_video, models, seeds[shown],
                                    sizes.planner, workers=run.workers)
        fault_runs = fault_rows(models, seeds[:faults.episodes], sizes.planner,
                                faults.dynamics_noise, faults.observation_noise)
        self.summary["faults"] = run.clock.stage("faults", lambda: [
            {"fault": fault, **summarise("dynoplan", records)}
            for fault, records in evaluate_rows(fault_runs, run.workers,
                                                f"faults ({len(fault_runs)})",
                                                run.progress).items()])
        if video is not None:
            self.summary["video"] = save_video(video(), episodes["dynoplan"][shown], shown,
                                               out / "episode.mp4")
        self.summary["stages_s"] = run.clock.rounded(2)
        return self.summary


def _headline(metrics: dict[str, Any]) -> dict[str, Any]:
    """``metrics.json``'s top-level numbers (``summary.json``'s ``model_metrics``)."""
    return {k: v for k, v in metrics.items() if not isinstance(v, dict)}


def _starts(out: Path, settings: GearRunSettings) -> Path | None:
    """The run's labelled start states for the regions, when it records them."""
    from dynoplan.envs.gear.stages import STARTS_DIR

    return out / STARTS_DIR if settings.region_starts else None


def _folder(run: PipelineRun) -> Path:
    assert run.out is not None  # checked by GearStages.prepare
    return run.out


__all__ = ["OUTCOME_RUNS", "QUICK_RUN", "TRANSITION_RUNS", "EvaluationSettings",
           "FaultSettings", "GearRunSettings", "GearStages", "run_settings"]
