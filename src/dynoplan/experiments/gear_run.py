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
   :mod:`dynoplan.experiments.gear_outcomes`), part of every controller's learned
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

import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, TypeVar

from dynoplan.control.controller import EpisodeTrace
from dynoplan.envs.gear.controllers import CONTROLLERS, GEAR_CONTROL
from dynoplan.envs.gear.env import CONTROL_DT
from dynoplan.envs.gear.learning.files import load_gear_models
from dynoplan.envs.gear.pipeline_task import FLAT_POLICY, GearTask
from dynoplan.experiments.gear_eval import (
    RESULT_COLUMNS,
    behaviour_table,
    human_mode,
    seconds,
    summarise,
    write_results,
)
from dynoplan.io import ensure_writable_dir, write_json, write_text, write_with
from dynoplan.parallel import SERIAL, Workers, ray_session, run_in_background
from dynoplan.pipeline.evaluate import (
    ControllerJob,
    ControllerRunner,
    ControllerSettings,
    EpisodeRecord,
    evaluate_many,
)
from dynoplan.reports.tables import markdown_table
from dynoplan.seeding import EpisodeSeed, episode_seeds

T = TypeVar("T")

VARIANT_ROWS = ("dynoplan+rules",)
"""Rows of ``results.csv`` after :data:`CONTROLLERS` and the flat policy, on every
episode: DynoPlan with each option's hand-written conditions added to its learned region
(:data:`~dynoplan.envs.gear.controllers.VARIANTS`), the rules the learned parts
replace."""

ABLATION_ROWS: dict[str, tuple[str, dict[str, Any]]] = {
    "dynoplan_regions": ("dynoplan_regions", {}),
    "dynoplan epistemic=0.3": ("dynoplan", {"epistemic": 0.3}),
}
"""The last rows of ``results.csv``, each on the first ``ablation_episodes`` episodes:
row name -> (controller of :data:`~dynoplan.envs.gear.controllers.VARIANTS`, the
planner settings it changes). Beside DynoPlan on the same episodes they show what each
learned part does: ``dynoplan_regions`` plans on the paper's Eq. 5 regions alone (no
initiation learned from outcomes, rollouts not stopped at the continuation set),
``epistemic=0.3`` penalises the dynamics ensemble's disagreement."""

EVAL_SEED_OFFSET = 7
"""Evaluation episodes use seeds derived from ``seed + EVAL_SEED_OFFSET`` (disjoint from
the demonstrations' and the held-out trials')."""


@dataclass(frozen=True)
class GearRunSettings:
    """Sizes of every stage (recorded in ``summary.json``).

    Attributes:
        demos: demonstrations (and held-out trials) recorded.
        collect_runs: option runs per option for the dynamics data.
        collect_max_decisions: decisions per collection run at most.
        quick_models: small training settings for the learned models (goal, regions,
            dynamics).
        ppo_steps: environment steps of the flat PPO baseline.
        episodes: evaluation episodes of every controller.
        oracle_episodes: episodes of the oracle (the first ones of the same list: it
            simulates every option at every decision, which costs real time).
        ablation_episodes: episodes of each :data:`ABLATION_ROWS` row (the first ones of
            the same list).
        fault_episodes: episodes per fault.
        dynamics_noise: std of the noise added to the learned predictions in the
            dynamics fault.
        observation_noise: std (m, rad) of the observation-noise fault.
        planner: how the controllers plan and run (horizon, samples, margin, ...).
        video: render one episode.
        outcome_runs: runs per option of the outcome stage (0: no outcome stage; the
            learned initiation sets are then the Eq. 5 regions alone).
        outcome_max_decisions: decisions an outcome run may last.
        outcome_lead_decisions: decisions another option may run before it, at most.
    """

    demos: int = 10
    collect_runs: int = 40
    collect_max_decisions: int = 30
    quick_models: bool = False
    ppo_steps: int = 30_000
    episodes: int = 100
    oracle_episodes: int = 10
    ablation_episodes: int = 30
    fault_episodes: int = 30
    dynamics_noise: float = 0.02
    observation_noise: float = 0.005
    planner: ControllerSettings = GEAR_CONTROL
    video: bool = True
    outcome_runs: int = 30
    outcome_max_decisions: int = 30
    outcome_lead_decisions: int = 12


QUICK_RUN = GearRunSettings(
    demos=10, collect_runs=4, collect_max_decisions=15, quick_models=True, ppo_steps=2048,
    episodes=6, oracle_episodes=2, ablation_episodes=2, fault_episodes=3,
    planner=replace(GEAR_CONTROL, horizon=6, samples=32, oracle_horizon=3),
    outcome_runs=2, outcome_max_decisions=6, outcome_lead_decisions=2)
"""``--quick``: every stage on small settings (CI, a first look)."""


def run_settings(quick: bool) -> GearRunSettings:
    """The sizes of ``gear run`` (:data:`QUICK_RUN` with ``quick``), which the standalone
    stage commands (``gear demos``, ``gear collect``) take as their defaults too."""
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
        learned_models,
        option_networks,
        option_transitions,
    )

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
    quick = settings.quick_models
    summary["networks"] = stage("networks", lambda: option_networks(
        models_dir, seed, workers=workers))
    summary["demos"] = stage("demos", lambda: [
        demonstrations(settings.demos, seed, out / "demos", models_dir, progress=progress,
                       workers=workers),
        demonstrations(settings.demos, seed, out / "heldout", models_dir, heldout=True,
                       progress=progress, workers=workers)])
    summary["collect"] = stage("collect", lambda: option_transitions(
        models_dir, settings.collect_runs, seed, out / "transitions",
        settings.collect_max_decisions, progress=progress, workers=workers))
    metrics = stage("train", lambda: learned_models(
        out / "demos", out / "transitions", models_dir, seed, out / "heldout", quick,
        progress=progress, workers=workers))
    summary["model_metrics"] = {k: v for k, v in metrics.items() if not isinstance(v, dict)}
    summary["figures"] = stage("figures", lambda: figures(
        models_dir, out / "demos", out / "heldout", out / "figures", seed, quick))
    if flat is None:
        flat = start("flat_ppo", fit_flat_policy, settings.ppo_steps, seed)
    summary["flat_ppo"] = save_flat_policy(flat(), out / "flat_ppo")

    if settings.outcome_runs:  # after every stage whose results it could touch
        summary["outcomes"] = stage("outcomes", lambda: learned_initiation(
            models_dir, out / "outcomes", seed, settings, progress, workers))
    load_gear_models(models_dir)  # checked here once: workers load it again
    seeds = episode_seeds(seed + EVAL_SEED_OFFSET, settings.episodes)
    rows, episodes = stage("evaluate", lambda: evaluate_gear_controllers(
        models_dir, seeds, settings, out / "flat_ppo", progress, workers,
        extra=VARIANT_ROWS, ablation=ABLATION_ROWS))
    summary["results"] = rows
    summary["ablation"] = [summarise(name, episodes[name][:settings.ablation_episodes])
                           for name in (*CONTROLLERS[:2], *VARIANT_ROWS, *ABLATION_ROWS)]
    write_results(out, rows, episodes)

    video = None
    if settings.video:
        shown = video_episode(episodes["dynoplan"])
        video = start("video", render_video, models_dir, seeds[shown], settings.planner)
    summary["faults"] = stage("faults", lambda: evaluate_faults(
        models_dir, seeds[:settings.fault_episodes], settings, progress, workers))
    if video is not None:
        summary["video"] = save_video(video(), episodes["dynoplan"][shown], shown,
                                      out / "episode.mp4")
    return summary


def learned_initiation(models_dir: Path, out: Path, seed: int, settings: GearRunSettings,
                       progress: bool, workers: Workers = SERIAL) -> dict[str, Any]:
    """Stage ``outcomes``: the outcome runs (``out``) and the initiation learned from them,
    written into ``models_dir`` (``gear outcomes`` with the run's sizes); returns the
    runs' summary and the fit's report per option (``models/initiation.json`` too)."""
    from dynoplan.experiments.gear_outcomes import (
        OutcomeSettings,
        collect_outcomes,
        fit_gear_initiation,
    )

    runs = collect_outcomes(models_dir, seed, out, OutcomeSettings(
        settings.outcome_runs, settings.outcome_max_decisions,
        settings.outcome_lead_decisions), progress=progress, workers=workers)
    write_json(out / "outcomes.json", runs)
    report = fit_gear_initiation(models_dir, out, seed)
    write_json(models_dir / "initiation.json", report)
    return {"runs": runs["runs"], "starts": runs["starts"], "ended_well": runs["ended_well"],
            "options": report["options"]}


def _timed(fn: Callable[..., T], *args: Any) -> tuple[float, T]:
    """``(wall seconds, fn(*args))``: a stage run as one task, and how long it took."""
    t0 = time.perf_counter()
    result = fn(*args)
    return time.perf_counter() - t0, result


ORACLE_FIRST = ("oracle",)
"""Controllers whose episodes are submitted first (the oracle's cost ten times the
others'), so that no long episode is left running alone at the end of the stage."""


def evaluate_gear_controllers(models_dir: Path, seeds: Sequence[EpisodeSeed],
                              settings: GearRunSettings, flat_folder: Path | None,
                              progress: bool, workers: Workers = SERIAL,
                              names: Sequence[str] = CONTROLLERS,
                              task: GearTask = GearTask(), extra: Sequence[str] = (),
                              ablation: Mapping[str, tuple[str, Mapping[str, Any]]] = {},
                              ) -> tuple[list[dict[str, Any]], dict[str, list[EpisodeRecord]]]:
    """The controllers ``names`` (of :data:`CONTROLLERS`), the flat policy if
    ``flat_folder``, the variants ``extra`` (of
    :data:`~dynoplan.envs.gear.controllers.VARIANTS`), on ``seeds``; the oracle on
    the first ``settings.oracle_episodes`` of them and the ``ablation`` rows (row name ->
    controller and planner-setting changes, as :data:`ABLATION_ROWS`) on the first
    ``settings.ablation_episodes``. All their episodes are one map on ``workers`` (the
    oracle's first), each worker rebuilding the controllers from ``models_dir``; rows
    (named as given) and episodes come back in that order. ``task``: the gear as the
    episodes see it (the human behaviours they draw from, the runtime monitor)."""
    gear = replace(task, flat_folder=flat_folder)
    jobs = {name: (ControllerJob(gear, models_dir, name, settings.planner),
                   seeds[:settings.oracle_episodes] if name == "oracle" else seeds)
            for name in names}
    if flat_folder is not None:
        jobs[FLAT_POLICY] = (ControllerJob(gear, models_dir, FLAT_POLICY, settings.planner),
                             seeds)
    for name in extra:
        jobs[name] = (ControllerJob(gear, models_dir, name, settings.planner), seeds)
    for label, (name, changes) in ablation.items():
        jobs[label] = (ControllerJob(gear, models_dir, name, replace(settings.planner, **changes)),
                     seeds[:settings.ablation_episodes])
    order = sorted(jobs, key=lambda name: name not in ORACLE_FIRST)  # stable
    done = dict(zip(order, evaluate_many([jobs[name] for name in order], workers,
                                         f"evaluate ({len(order)} controllers)", progress),
                    strict=True))
    rows, episodes = [], {}
    for name in jobs:
        episodes[name] = done[name]
        row = summarise(name, done[name])
        if name == FLAT_POLICY:
            row["out_of_region_starts"] = row["switches"] = row["holds"] = None  # no options
        rows.append(row)
    return rows, episodes


def evaluate_faults(models_dir: Path, seeds: Sequence[EpisodeSeed], settings: GearRunSettings,
                    progress: bool, workers: Workers = SERIAL) -> list[dict[str, Any]]:
    """DynoPlan with each fault on ``seeds`` (rows like ``results.csv`` plus ``fault``);
    the episodes of all faults are one map on ``workers``."""
    jobs = {
        "dynamics_noise": ControllerJob(GearTask(), models_dir, "dynoplan", replace(
            settings.planner, dynamics_noise=settings.dynamics_noise)),
        "observation_noise": ControllerJob(
            GearTask(fault="observation_noise", observation_noise=settings.observation_noise),
            models_dir, "dynoplan", settings.planner),
        "grasp_slip": ControllerJob(GearTask(fault="grasp_slip"), models_dir, "dynoplan",
                                    settings.planner),
    }
    results = evaluate_many([(job, seeds) for job in jobs.values()], workers,
                            f"faults ({len(jobs)})", progress)
    return [{"fault": fault, **summarise("dynoplan", eps)}
            for fault, eps in zip(jobs, results, strict=True)]


def video_episode(episodes: Sequence[EpisodeRecord]) -> int:
    """Which evaluated DynoPlan episode the video shows (its index in ``episodes``): one
    in which it switched to the cautious move if any, else one with the human
    interfering if any; among those, a success if any, and the shortest (the quickest to
    render), the first of equals."""
    return min(range(len(episodes)), key=lambda i: (
        "cautious_move" not in episodes[i].options, human_mode(episodes[i]) == "away",
        not episodes[i].success, seconds(episodes[i]), i))


def render_video(models_dir: Path, seed: EpisodeSeed, planner: ControllerSettings,
                 controller_name: str = "dynoplan") -> dict[str, Any]:
    """Controller ``controller_name``'s episode ``seed`` rendered offscreen, built and run
    as the evaluation builds and runs it (:meth:`GearTask.make_runner`): :func:`video_clip`
    of it. Writes nothing but a temporary file, so it can run as a task on any worker."""
    runner = GearTask(render=True).make_runner(controller_name, models_dir, planner)
    assert isinstance(runner, ControllerRunner)
    frames: list[Any] = []
    try:
        trace = runner.run(seed, frames)
    finally:
        runner.env.close()
    caption_gear_frames(frames, trace)
    return video_clip(frames, trace.success,
                      [d.option for d in trace.decisions if d.option is not None])


def caption_gear_frames(frames: list[Any], trace: EpisodeTrace) -> None:
    """Draw the decision on every frame of a gear episode, in place
    (:func:`~dynoplan.reports.video.caption_frames`): the running option, every option's
    score at the last decision and the robot's distance to the human's hand."""
    from dynoplan.reports.video import caption_frames

    caption_frames(frames, trace, CONTROL_DT, "min_human_distance", "robot-hand distance")


def video_clip(frames: Sequence[Any], success: bool, options: Sequence[str]) -> dict[str, Any]:
    """An episode's ``frames`` (RGB arrays, 20 per second) as ``{"mp4": bytes of the H.264
    file, "success", "options"}`` (the options it ran, consecutive repeats collapsed)."""
    from dynoplan.reports.video import write_mp4

    with tempfile.TemporaryDirectory() as tmp:
        mp4 = write_mp4(Path(tmp) / "episode.mp4", frames, fps=20).read_bytes()
    return {"mp4": mp4, "success": success, "options": _runs(options)}


def save_video(video: dict[str, Any], evaluated: EpisodeRecord, index: int,
               path: Path) -> dict[str, Any]:
    """Write :func:`video_clip`'s file to ``path``; its entry of ``summary.json``."""
    def write(tmp: Path) -> None:
        tmp.write_bytes(video["mp4"])

    write_with(path, write)
    return {"file": path.name, "episode": index, "human_mode": human_mode(evaluated),
            "success": video["success"], "options": video["options"]}


def _runs(options: Sequence[str]) -> list[str]:
    """Consecutive repeats collapsed: ``[a, a, b, a] -> [a, b, a]``."""
    return [o for k, o in enumerate(options) if k == 0 or options[k - 1] != o]


def results_markdown(summary: dict[str, Any]) -> str:
    """``results.md``: the controllers' table, the faults, the models and the stages."""
    lines = ["# Gear assembly: DynoPlan and baselines", ""]
    s = summary["settings"]
    lines.append(f"Seed {summary['seed']}; {s['episodes']} evaluation episodes per controller "
                 f"(oracle: the first {s['oracle_episodes']}); planner horizon "
                 f"{s['planner']['horizon']}, samples {s['planner']['samples']}; flat PPO "
                 f"{s['ppo_steps']} env steps.")
    lines += ["", markdown_table(summary["results"], RESULT_COLUMNS), "",
              "Success by human mode:", "", behaviour_table(summary["results"])]
    if summary.get("ablation"):
        lines += ["", "## Ablation: what each learned part does", "",
                  f"The same first {s['ablation_episodes']} episodes for every row. "
                  "`dynoplan` and `random` choose on the learned sets (Eq. 5 regions and the "
                  "initiation learned from outcomes); `dynoplan+rules` adds the hand-written "
                  "conditions; `dynoplan_regions` plans on the Eq. 5 regions alone (the "
                  "paper's method); `epistemic=0.3` penalises the dynamics ensemble's "
                  "disagreement.", "",
                  markdown_table(summary["ablation"], RESULT_COLUMNS)]
    lines += ["", "## Faults (DynoPlan)", "",
              markdown_table(summary["faults"], ("fault", "episodes", "success_rate",
                                                 "contacts", "switches", "holds")),
              "", "## Learned models", "",
              markdown_table([summary["model_metrics"]],
                             ("goal_spearman", "goal_mae", "region_inside_rate",
                              "region_far_outside_rate", "dynamics_coverage_90")),
              "", "## Stages (s)", "", markdown_table([summary["stages_s"]])]
    if "wall_s" in summary:
        workers = summary["workers"]
        on = workers["address"] or f"{workers['count']} worker(s)"
        lines += ["", f"Whole run: {summary['wall_s']} s on {on}"
                  + ("; flat_ppo and video ran beside the other stages." if
                     workers["count"] > 1 or workers["address"] else ".")]
    return "\n".join(lines)


__all__ = [
    "ABLATION_ROWS",
    "EVAL_SEED_OFFSET",
    "ORACLE_FIRST",
    "QUICK_RUN",
    "VARIANT_ROWS",
    "GearRunSettings",
    "evaluate_faults",
    "evaluate_gear_controllers",
    "render_video",
    "results_markdown",
    "run_gear_pipeline",
    "run_settings",
    "save_video",
    "video_clip",
    "video_episode",
]

