"""``dynoplan gear ...``: the simulated gear assembly (expert runs, pictures, videos)."""

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from dynoplan.cli.params import (
    folder,
    human_mode,
    models_folder,
    out_folder,
    require_gear,
    setting_bounds,
)
from dynoplan.cli.workers import ray_address_option, workers_option
from dynoplan.limits import (
    DEPTH_MAX,
    EPISODES_MAX,
    HORIZON_MAX,
    POINTS_MAX,
    SAMPLES_MAX,
    SEED_MAX,
    STEPS_MAX,
)

if TYPE_CHECKING:
    from dynoplan.envs.gear.pipeline_task import GearTask
    from dynoplan.pipeline.control_settings import ControllerSettings

def _horizon_option() -> Any:
    return typer.Option(None, min=1, max=HORIZON_MAX,
                        help="Planner horizon (default 10; gear run --quick: 6).")


def _samples_option() -> Any:
    return typer.Option(None, min=1, max=SAMPLES_MAX,
                        help="Monte-Carlo rollouts per option (default 64; gear run "
                        "--quick: 32).")


def _depth_option() -> Any:
    return typer.Option(None, min=1, max=DEPTH_MAX,
                        help="Options per imagined sequence of DynoPlan's planner (default "
                        "1: the paper's Eq. 1; 2 looks one option further).")


def _epistemic_option() -> Any:
    return typer.Option(None, min=0.0, max=1e6, help="Weight of the dynamics ensemble's "
                        "disagreement in the planner's score (default 0).")


def _end_inside_option() -> Any:
    return typer.Option(False, "--end-inside", help="The planner's rollouts that leave an "
                        "option's continuation set end at their last state inside it "
                        "(scored where the dynamics had data).")


def _regions_without_gain_option() -> Any:
    return typer.Option(True, "--regions-without-gain/--no-regions-without-gain",
                        help="Where the learned sets admit options but none is predicted to "
                        "gain, the admissible option whose learned region holds the state "
                        "most likely runs (depth 1; the library's "
                        "control.regions_without_gain).")


def _repeat_option() -> Any:
    return typer.Option(False, "--repeat-no-effect", help="Let an option that ended where "
                        "it started (within 1 % of each coordinate's spread) start there "
                        "again (the controller without the no-effect rule, an ablation).")


def _human_option() -> Any:
    return typer.Option(
        None, "--human", help="Human behaviours the episodes draw from, uniformly: "
        "comma-separated of away, cross, block (the demonstrations' mix, the default) and "
        "reach, linger, fast_cross, two_passes (never demonstrated), or 'unseen' (those "
        "four) or 'all'.")


def _shield_option() -> Any:
    return typer.Option(False, "--shield", help="Run every episode under the runtime "
                        "monitor: a protective stop whenever the arm moves closer to the "
                        "hand than ISO/TS 15066's S_p.")


gear_app = typer.Typer(
    help="The simulated PR2 gear assembly: scripted expert, demonstrations, renders.",
    no_args_is_help=True,
)

DEFAULT_MODELS = Path("results/gear-models")


@gear_app.callback()
def _gear() -> None:
    """The simulated PR2 gear assembly (the ``gear`` extra: pip install 'dynoplan[gear]')."""
    require_gear()


@gear_app.command("expert")
def expert(
    episodes: int = typer.Option(100, min=1, max=EPISODES_MAX, help="Seeded episodes to run."),
    seed: int = typer.Option(0, min=0, max=SEED_MAX,
                             help="Seed from which every episode's seed is derived."),
    out: Path = typer.Option(Path("results/gear-expert"), callback=out_folder,
                             help="Output folder."),
    human: str | None = typer.Option(None, callback=human_mode,
                                     help="Force the human: away, cross or block."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
) -> None:
    """Run the scripted expert; write OUT/summary.json (success, contacts, speed)."""
    from dynoplan.envs.gear.demonstrations import run_expert
    from dynoplan.io import staged_folder

    with staged_folder(out) as folder:
        summary = run_expert(episodes, seed, folder, progress=not quiet, human_mode=human)
    typer.echo(
        f"success {summary['success_rate']:.1%} ({summary['successes']}/{summary['episodes']}),"
        f" robot-human contacts {summary['contacts']}, min distance "
        f"{summary['min_human_distance']:.3f} m, env.step {summary['realtime_factor']:.1f}x "
        f"real time -> {out}/summary.json"
    )


QUICK_STAGE_HELP = "Sizes of gear run --quick instead of gear run's."


@gear_app.command("demos")
def demos(
    n: int | None = typer.Option(None, "--n", min=1, max=EPISODES_MAX,
                                 help="Demonstrations to record (default: gear "
                                 "run's, 10 as in the paper)."),
    seed: int = typer.Option(0, min=0, max=SEED_MAX,
                             help="Seed from which every episode's seed is derived."),
    out: Path = typer.Option(Path("results/gear-demos"), callback=out_folder,
                             help="Dataset folder to write."),
    heldout: bool = typer.Option(False, "--heldout", help="Record the held-out trials "
                                 "instead (gear run's OUT/heldout): episodes of seeds "
                                 "disjoint from the demonstrations'."),
    human: str | None = typer.Option(None, callback=human_mode,
                                     help="Force the human: away, cross or block."),
    demonstrator: str | None = typer.Option(None, help="options (the default, as gear run: "
                                            "an operator chaining the four option "
                                            "policies) or expert (the scripted expert, "
                                            "with privileged state)."),
    models: Path = typer.Option(DEFAULT_MODELS, callback=models_folder,
                                help="Folder of the neural options' networks "
                                "for --demonstrator options (trained there first if "
                                "missing)."),
    quick: bool = typer.Option(False, "--quick", help=QUICK_STAGE_HELP),
    workers: str = workers_option(),
    ray_address: str | None = ray_address_option(),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
) -> None:
    """Record demonstrations with option labels and progress as a dataset (gear run's
    demos stage)."""
    import torch

    from dynoplan.envs.gear.pipeline_stages import run_settings
    from dynoplan.envs.gear.stages import DEMONSTRATOR, demonstrations
    from dynoplan.parallel import parse_workers, ray_session

    pool = parse_workers(workers, ray_address)
    torch.set_num_threads(1)
    count = run_settings(quick).demos if n is None else n
    demonstrator = demonstrator or DEMONSTRATOR
    with ray_session(pool):
        summary = demonstrations(count, seed, out, models, heldout=heldout,
                                 demonstrator=demonstrator, human_mode=human,
                                 progress=not quiet, workers=pool, log=typer.echo)
    modes = ", ".join(f"{k} {v}" for k, v in summary["human_modes"].items())
    typer.echo(f"{summary['episodes']} {'held-out trials' if heldout else 'demonstrations'} "
               f"({demonstrator}), {summary['steps']} steps, success "
               f"{summary['success_rate']:.0%}, human: {modes} -> {out}")


@gear_app.command("render")
def render(
    seed: int = typer.Option(0, min=0, max=SEED_MAX, help="Episode seed."),
    out: Path = typer.Option(Path("results/gear-render"), callback=out_folder,
                             help="Output folder."),
    video: bool = typer.Option(True, "--video/--no-video", help="Also write episode.mp4."),
    human: str | None = typer.Option(None, callback=human_mode,
                                     help="Force the human: away, cross or block."),
) -> None:
    """Write OUT/scene.png and OUT/episode.mp4 of the expert's episode (offscreen)."""
    # Headless machines: MuJoCo picks its GL backend when first imported.
    os.environ.setdefault("MUJOCO_GL", "egl")
    from dynoplan.envs.gear.demonstrations import render_scene
    from dynoplan.io import staged_folder

    with staged_folder(out) as folder:
        written = render_scene(folder, seed=seed, video=video, human_mode=human)
    typer.echo(" ".join(str(out / p.name) for p in written.values()))


@gear_app.command("option")
def option(
    name: str = typer.Argument(..., help="pick, fast_move, cautious_move, insert, or an option "
                               "registered by a module named in DYNOPLAN_GEAR_OPTIONS."),
    trials: int = typer.Option(100, min=1, max=EPISODES_MAX,
                               help="Seeded trials from the option's own start region."),
    seed: int = typer.Option(0, min=0, max=SEED_MAX,
                             help="Trial i uses numpy default_rng([seed, i])."),
    out: Path = typer.Option(Path("results/gear-option"), callback=out_folder,
                             help="Output folder."),
    models: Path = typer.Option(DEFAULT_MODELS, callback=models_folder,
                                help="Folder of the neural options' networks "
                                "(trained there first if missing)."),
    human: str | None = typer.Option(None, callback=human_mode,
                                     help="Human mode (default: the option's own; "
                                     "block for cautious_move, away for the others)."),
    max_steps: int = typer.Option(600, min=1, max=STEPS_MAX,
                                  help="Env steps per trial before giving up."),
    video: bool = typer.Option(False, "--video", help="Also render trial 0 to OUT/NAME.mp4."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
) -> None:
    """Run one option alone from its own starting region; write OUT/summary.json."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    import torch

    from dynoplan.envs.gear.options.catalog import gear_option
    from dynoplan.envs.gear.options.trials import run_option_trials
    from dynoplan.envs.gear.stages import option_networks

    registered = gear_option(name)
    torch.set_num_threads(1)
    extra: dict[str, object] = {}
    trained = option_networks(models, seed, only=(name,), log=typer.echo)
    if trained:
        extra["network_training"] = trained[name]
    extra.update(registered.trial_notes)
    summary = run_option_trials(name, registered.factory(models), trials, seed, out,
                                human_mode=human, max_steps=max_steps, video=video,
                                progress=not quiet, extra=extra)
    plan = summary["plan_ms_p50"]
    typer.echo(f"{name}: success {summary['success_rate']:.1%} ({summary['successes']}/"
               f"{summary['trials']}), contacts {summary['contacts']}, min human distance "
               f"{summary['min_human_distance']:.3f} m, plan p50 "
               f"{'-' if plan is None else f'{plan:.1f} ms'} -> {out}/summary.json")


@gear_app.command("collect")
def collect(
    runs: int | None = typer.Option(None, min=1, max=EPISODES_MAX,
                                    help="Runs per option (default: gear run's)."),
    seed: int = typer.Option(0, min=0, max=SEED_MAX,
                             help="Run r of option k uses default_rng([seed, k, r])."),
    out: Path = typer.Option(Path("results/gear-transitions"), callback=out_folder,
                             help="Dataset folder."),
    models: Path = typer.Option(DEFAULT_MODELS, callback=models_folder,
                                help="Folder of the neural options' networks "
                                "(trained there first if missing)."),
    max_decisions: int | None = typer.Option(None, min=1, max=STEPS_MAX,
                                             help="Decisions (0.5 s each) per run at "
                                             "most (default: gear run's)."),
    quick: bool = typer.Option(False, "--quick", help=QUICK_STAGE_HELP),
    workers: str = workers_option(),
    ray_address: str | None = ray_address_option(),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
) -> None:
    """Collect option transitions at the decision rate for the dynamics models (gear run's
    collect stage)."""
    import torch

    from dynoplan.envs.gear.pipeline_stages import run_settings
    from dynoplan.envs.gear.stages import option_transitions
    from dynoplan.parallel import parse_workers, ray_session

    pool = parse_workers(workers, ray_address)
    torch.set_num_threads(1)
    sizes = run_settings(quick)
    with ray_session(pool):
        summary = option_transitions(
            models, sizes.collect.runs if runs is None else runs, seed, out,
            sizes.collect.max_decisions if max_decisions is None else max_decisions,
            progress=not quiet, workers=pool, log=typer.echo)
    counts = ", ".join(f"{k} {v}" for k, v in summary["transitions"].items())
    typer.echo(f"{summary['runs']} runs, transitions: {counts} -> {out}")


@gear_app.command("outcomes")
def outcomes(
    models: Path = typer.Option(DEFAULT_MODELS, callback=models_folder,
                                help="Models folder (gear train, or gear "
                                "run's OUT/models): the option networks are read from it and "
                                "the learned initiation is written into it."),
    out: Path = typer.Option(Path("results/gear-outcomes"), callback=out_folder,
                             help="Dataset folder of the outcome runs."),
    runs: int | None = typer.Option(None, min=1, max=EPISODES_MAX,
                                    help="Runs per option (default: gear run's, 30; 2 "
                                    "with --quick)."),
    max_decisions: int | None = typer.Option(None, min=1, max=STEPS_MAX,
                                             help="Decisions (0.5 s each) an option may run "
                                             "(default 30; 6 with --quick)."),
    lead_decisions: int | None = typer.Option(None, min=0, max=STEPS_MAX,
                                              help="Decisions the source option may run "
                                              "first (default 12; 2 with --quick)."),
    quick: bool = typer.Option(False, "--quick", help="The sizes of gear run --quick."),
    seed: int = typer.Option(0, min=0, max=SEED_MAX,
                             help="Run r of option o uses default_rng([seed, 17, o, r])."),
    collect: bool = typer.Option(True, "--collect/--fit-only", help="Run the options first "
                                 "(else fit on the dataset OUT as it is)."),
    merge: Path | None = typer.Option(None, help="Also write, into OUT/transitions-beyond, "
                                      "these collected transitions (gear collect) with the "
                                      "outcome runs', for gear train --transitions."),
    workers: str = workers_option(),
    ray_address: str | None = ray_address_option(),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
) -> None:
    """Run every option from starts beyond its own region and learn, from what came of
    it, where each option may start (initiation from outcomes, Bagaria et al. 2023)."""
    import json
    from dataclasses import replace

    import torch

    from dynoplan.data.dataset import DATA_DIR
    from dynoplan.envs.gear.pipeline_stages import run_settings
    from dynoplan.envs.gear.stages import outcome_initiation
    from dynoplan.io import check_writable, retarget, staged_folder
    from dynoplan.parallel import SERIAL, parse_workers, ray_session

    check_writable(models)  # initiation.json goes there, after the runs
    sizes = run_settings(quick).outcomes
    runs = sizes.runs if runs is None else runs
    max_decisions = sizes.max_decisions if max_decisions is None else max_decisions
    lead_decisions = sizes.lead_decisions if lead_decisions is None else lead_decisions
    pool = parse_workers(workers, ray_address)
    torch.set_num_threads(1)
    # OUT (the runs' dataset, outcomes.json, transitions-beyond) and MODELS (the
    # initiation) staged: both or neither; --fit-only fits on a copy of OUT as it is, new
    # runs replace a previous run's outputs together (its transitions-beyond too, made of
    # its runs, goes without --merge); other files of OUT stay
    previous = (DATA_DIR, "outcomes.json", "transitions-beyond") if collect else ()
    with staged_folder(out, keep=not collect, drop=previous) as stage, \
            staged_folder(models, keep=True) as staged_models, \
            ray_session(pool if collect else SERIAL):  # Ray for the runs only
        summary, merged, report = retarget(retarget(outcome_initiation(
            staged_models, stage, seed, replace(sizes, runs=runs, max_decisions=max_decisions,
                                                lead_decisions=lead_decisions),
            progress=not quiet, workers=pool, collect=collect, merge=merge, networks=models),
            stage, out), staged_models, models)
    if summary is not None:
        typer.echo(f"{summary['runs']} runs; starts that ended well: " + ", ".join(
            f"{n} {summary['ended_well'][n]}/{summary['starts'][n]}"
            for n in summary["starts"]))
    if merged is not None:
        typer.echo(f"{merged['episodes']} episodes -> {merged['dataset']}")
    typer.echo(json.dumps(report["options"]))
    typer.echo(f"-> {out}, {report['file']}, {models}/initiation.json")


@gear_app.command("train")
def train(
    demos: Path = typer.Option(Path("results/gear-demos"), callback=folder,
                               help="Demonstrations dataset."),
    transitions: Path | None = typer.Option(None, callback=folder,
                                            help="Option transitions dataset "
                                            "(default: the demonstrations subsampled)."),
    heldout: Path | None = typer.Option(None, callback=folder,
                                        help="Held-out trials (gear demos --heldout; "
                                        "default: recorded into OUT/heldout-demos by the "
                                        "demonstrations' demonstrator)."),
    out: Path = typer.Option(DEFAULT_MODELS, callback=out_folder,
                             help="Models folder (metrics.json too; the "
                             "option networks too, trained there first if the held-out "
                             "trials need them)."),
    seed: int = typer.Option(0, min=0, max=SEED_MAX, help="Seed of every fit."),
    quick: bool = typer.Option(False, "--quick", help="Small settings (those of gear run "
                               "--quick)."),
    goal_ranking: float | None = typer.Option(None, help="Weight of the goal network's "
                                              "ranking loss along demonstrations (default "
                                              "0: none)."),
    goal_features: str | None = typer.Option(None, help="The feature map the goal "
                                             "heuristic reads: task, pose, relative or "
                                             "objects (default: objects)."),
    workers: str = workers_option(),
    ray_address: str | None = ray_address_option(),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
) -> None:
    """Fit the goal heuristic, the safety regions and the per-option dynamics (gear run's
    train stage)."""
    from dataclasses import replace

    import torch

    from dynoplan.envs.gear.pipeline_stages import run_settings
    from dynoplan.envs.gear.stages import learned_models
    from dynoplan.parallel import parse_workers, ray_session

    pool = parse_workers(workers, ray_address)
    torch.set_num_threads(1)
    sizes = run_settings(quick)
    fit = sizes.fit if goal_ranking is None else replace(sizes.fit, goal_ranking=goal_ranking)
    if goal_features is not None:
        from dynoplan.envs.gear.features import feature_map

        fit = replace(fit, goal_features=feature_map(goal_features).name)
    with ray_session(pool):
        m = learned_models(demos, transitions, out, seed, heldout, fit, sizes.metrics,
                           progress=not quiet, workers=pool, log=typer.echo)
    typer.echo(f"goal spearman {m['goal_spearman']:.3f}, mae {m['goal_mae']:.3f}; regions "
               f"inside {m['region_inside_rate']:.3f}, far outside "
               f"{m['region_far_outside_rate']:.3f}; dynamics coverage_90 "
               f"{m['dynamics_coverage_90']:.3f} -> {out}/metrics.json")


@gear_app.command("figures")
def figures(
    models: Path = typer.Option(DEFAULT_MODELS, callback=models_folder,
                                help="Models folder (dynoplan gear train)."),
    demos: Path = typer.Option(Path("results/gear-demos"), callback=folder,
                               help="Demonstrations dataset."),
    heldout: Path | None = typer.Option(None, callback=folder, help="Held-out trials (default: "
                                        "MODELS/heldout-demos)."),
    out: Path = typer.Option(Path("results/gear-figures"), callback=out_folder,
                             help="Output folder."),
    seed: int = typer.Option(0, min=0, max=SEED_MAX, help="t-SNE seed."),
    trial: int = typer.Option(0, min=0, max=EPISODES_MAX - 1,
                              help="Held-out trial drawn in Fig. 3(a)."),
    points: int | None = typer.Option(None, min=10, max=POINTS_MAX,
                                      help="States embedded by t-SNE at most "
                                      "(default: gear run's)."),
    quick: bool = typer.Option(False, "--quick", help=QUICK_STAGE_HELP),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
) -> None:
    """Draw Fig. 3(a) (goal heuristic vs truth) and Fig. 3(b) (t-SNE with regions), as gear
    run's figures stage."""
    from dynoplan.envs.gear.pipeline_stages import run_settings
    from dynoplan.envs.gear.stages import figures as draw_figures

    info = draw_figures(models, demos, heldout, out, seed,
                        run_settings(quick).figure_points if points is None else points,
                        trial=trial, progress=not quiet)
    typer.echo(" ".join(str(v["file"]) for v in info.values()
                        if isinstance(v, dict) and "file" in v) or str(out))


@gear_app.command("run")
def run(
    out: Path = typer.Option(Path("results/gear"), callback=out_folder,
                             help="Output folder (everything goes here)."),
    seed: int = typer.Option(0, min=0, max=SEED_MAX, help="Seed of every stage."),
    quick: bool = typer.Option(False, "--quick", help="Small settings of every stage (under "
                               "2 minutes on two free cores; the defaults: under 10)."),
    episodes: int | None = typer.Option(None, min=1, max=EPISODES_MAX,
                                        help="Evaluation episodes per controller "
                                        "(default 100; --quick 6)."),
    oracle_episodes: int | None = typer.Option(None, min=0, max=EPISODES_MAX,
                                               help="Episodes of the simulator "
                                               "oracle (the first of the same list)."),
    ablation_episodes: int | None = typer.Option(None, min=0, max=EPISODES_MAX,
                                                 help="Episodes of each ablation row (the "
                                                 "first of the same list; default 30)."),
    improve: int | None = typer.Option(
        None, "--improve", **setting_bounds("improve"),
        help="Rounds of learning from DynoPlan's own episodes before the evaluation, the "
             "best models kept (0: the paper's pipeline) [the pipeline's default]."),
    region_starts: int | None = typer.Option(
        None, "--region-starts", **setting_bounds("region_starts"),
        help="Start states labelled by the operator's first choice, which the regions fit "
             "too (0: none) [0]."),
    improve_explore: float | None = typer.Option(
        None, "--improve-explore", **setting_bounds("improve_explore"),
        help="In the improvement round's own episodes, the probability at each decision of "
             "a random admissible option (the pipeline's improve_explore) [0.2]."),
    improve_demos: int | None = typer.Option(
        None, "--improve-demos", **setting_bounds("improve_demos"),
        help="After each improvement round's own episodes, the operator runs from the starts "
             "of up to this many of them that failed; its successes join the "
             "demonstrations (the pipeline's improve_demos) [5]."),
    regions_without_gain: bool = _regions_without_gain_option(),
    own_states: bool = typer.Option(
        False, "--own-states/--planner-state",
        help="Fit and roll each option that declares its own state (the insertion: its "
             "arm, gripper, tool, gear and the human's hand) on it, not on the planner "
             "state [planner state]."),
    no_video: bool = typer.Option(False, "--no-video", help="Do not render an episode."),
    workers: str = workers_option(),
    ray_address: str | None = ray_address_option(),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
) -> None:
    """Demonstrations, option networks, data, models, figures, baselines, evaluation."""
    from dataclasses import replace

    os.environ.setdefault("MUJOCO_GL", "egl")  # the video renders offscreen

    from dynoplan.envs.gear.pipeline_stages import run_settings
    from dynoplan.errors import DynoplanError
    from dynoplan.experiments.gear_run import run_gear_pipeline
    from dynoplan.parallel import parse_workers

    pool = parse_workers(workers, ray_address)

    settings = run_settings(quick)
    sizes = settings.evaluation
    n = sizes.episodes if episodes is None else episodes
    oracle = sizes.oracle_episodes if oracle_episodes is None else oracle_episodes
    ablation = sizes.ablation_episodes if ablation_episodes is None else ablation_episodes
    if n < 1 or oracle < 0:
        raise DynoplanError("--episodes must be >= 1 and --oracle-episodes >= 0")
    planner = replace(sizes.planner, regions_without_gain=regions_without_gain)
    improvement = replace(settings.improvement,
                          rounds=settings.improvement.rounds if improve is None else improve)
    if improve_explore is not None:
        improvement = replace(improvement, explore=improve_explore)
    if improve_demos is not None:
        improvement = replace(improvement, demos=improve_demos)
    settings = replace(settings, evaluation=replace(
        sizes, episodes=n, oracle_episodes=min(oracle, n), ablation_episodes=min(ablation, n),
        planner=planner),
        faults=replace(settings.faults, episodes=min(settings.faults.episodes, n)),
        video=not no_video,
        region_starts=settings.region_starts if region_starts is None else region_starts,
        improvement=improvement, own_states=own_states)
    summary = run_gear_pipeline(out, seed, settings, progress=not quiet,
                                log=(lambda _: None) if quiet else typer.echo, workers=pool)
    _echo_results(summary["results"])
    typer.echo(f"-> {out}/results.md, results.csv, summary.json")


@gear_app.command("task-fit")
def task_fit(
    options_models: Path = typer.Option(
        ..., "--options-models", callback=folder,
        help="The options folder: a gear run's --out (its models/ with the option networks)."),
    out: Path = typer.Option(Path("results/gear-peg-task"), callback=out_folder,
                             help="Output folder: demos/ and task/."),
    seed: int = typer.Option(0, min=0, max=SEED_MAX, help="Seed of the demonstrations, "
                             "the fit and the evaluation episodes."),
    episodes: int = typer.Option(100, min=1, max=EPISODES_MAX,
                                 help="DynoPlan's evaluation episodes."),
    demos: int = typer.Option(10, min=1, max=EPISODES_MAX,
                              help="The task's demonstrations (the operator's)."),
    peg_frame: bool = typer.Option(
        False, "--peg-frame/--planner-state",
        help="Roll the options' dynamics in the first task's frame (PegFrame) [no]."),
    quick: bool = typer.Option(False, "--quick", help="The fit and planner of gear run "
                               "--quick (a smoke test, not a measurement)."),
    workers: str = workers_option(),
    ray_address: str | None = ray_address_option(),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
) -> None:
    """The downstream task (the peg held elsewhere each episode) on a gear run's option
    dynamics, unchanged: only its goal heuristic and regions are fitted, from its own
    demonstrations."""
    import shlex
    import sys

    from dynoplan.envs.gear.task_fit import gear_task_fit
    from dynoplan.parallel import parse_workers, ray_session

    pool = parse_workers(workers, ray_address)
    command = "dynoplan " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    with ray_session(pool):
        result = gear_task_fit(options_models, out, seed, episodes, demos, peg_frame, quick,
                               pool, command, progress=not quiet)
    fit, row = result.summary["task_fit"], result.evaluation["dynoplan"]
    typer.echo(f"dynoplan: success {row['success_rate']:.0%} of {row['episodes']}; the task "
               f"needed {fit['demonstrations']} demonstrations ({fit['demonstration_steps']} "
               f"steps) and {fit['goal_fit_seconds']:.1f} s of goal fit "
               f"({fit['fit_seconds']:.1f} s in all) -> {out}/task/results.md")


@gear_app.command("seeds")
def seeds(
    runs: list[Path] = typer.Argument(..., help="Folders of gear runs that differ only in "
                                      "--seed (each with its summary.json)."),
    out: Path = typer.Option(Path("results/gear-seeds.md"), help="The table (markdown)."),
) -> None:
    """One table over several seeds' gear runs: each controller's mean and range."""
    from dynoplan.io import check_writable, write_text
    from dynoplan.reports.seed_table import read_runs, seed_markdown

    check_writable(out.parent)
    table = seed_markdown(read_runs(runs))
    out.parent.mkdir(parents=True, exist_ok=True)
    write_text(out, "Produced by `dynoplan gear seeds " + " ".join(map(str, runs))
               + f" --out {out}`.\n\n" + table)
    typer.echo(table, nl=False)


@gear_app.command("evaluate")
def evaluate(
    models: Path = typer.Option(DEFAULT_MODELS, callback=models_folder,
                                help="Models folder (gear train, or gear "
                                "run's OUT/models)."),
    out: Path = typer.Option(Path("results/gear-eval"), callback=out_folder,
                             help="Output folder."),
    controllers: str = typer.Option("dynoplan", help="Comma-separated controllers (learned "
                                    "parts only): dynoplan, random, oracle, fixed_script, "
                                    "flat_ppo; or a variant: dynoplan+rules, random+rules, "
                                    "oracle+rules (hand-written conditions added), "
                                    "dynoplan_regions, random_regions (Eq. 5 regions alone), "
                                    "dynoplan_everywhere, random_everywhere, dynoplan_safe, "
                                    "dynoplan+rules_safe (chance-constrained Eq. 1)."),
    episodes: int = typer.Option(100, min=1, max=EPISODES_MAX, help="Episodes per controller."),
    seed: int = typer.Option(0, min=0, max=SEED_MAX,
                             help="Episodes are gear run's for the same seed."),
    horizon: int | None = _horizon_option(),
    samples: int | None = _samples_option(),
    depth: int | None = _depth_option(),
    epistemic: float | None = _epistemic_option(),
    end_inside: bool = _end_inside_option(),
    regions_without_gain: bool = _regions_without_gain_option(),
    repeat_no_effect: bool = _repeat_option(),
    flat: Path | None = typer.Option(None, callback=folder,
                                     help="The flat policy's folder for flat_ppo "
                                     "(default: MODELS/../flat_ppo)."),
    human: str | None = _human_option(),
    shield: bool = _shield_option(),
    workers: str = workers_option(),
    ray_address: str | None = ray_address_option(),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
) -> None:
    """Evaluate controllers on trained models only; writes results and the wall time."""
    from dynoplan.experiments.gear_evaluate import run_gear_evaluation
    from dynoplan.io import staged_folder
    from dynoplan.parallel import parse_workers

    pool = parse_workers(workers, ray_address)
    planner = _planner_settings(horizon, samples, epistemic, end_inside, repeat_no_effect,
                                depth, regions_without_gain)
    task = _gear_task(human, shield)
    names = tuple(c.strip() for c in controllers.split(",") if c.strip())
    with staged_folder(out) as folder:
        summary = run_gear_evaluation(models, folder, names, episodes, seed, planner,
                                      flat or models.parent / "flat_ppo", pool,
                                      progress=not quiet,
                                      task=task)
    _echo_results(summary["results"])
    typer.echo(f"{summary['wall_s']:.1f} s on {pool.count} worker(s) -> {out}/results.md, "
               "results.csv, episodes.json, summary.json")


def _planner_settings(horizon: int | None, samples: int | None, epistemic: float | None,
                      end_inside: bool, repeat_no_effect: bool = False,
                      depth: int | None = None,
                      regions_without_gain: bool = True) -> "ControllerSettings":
    """The gear's default controller settings with what the command line changed."""
    from dataclasses import replace

    from dynoplan.envs.gear.controllers import GEAR_CONTROL

    planner = GEAR_CONTROL
    if horizon is not None:
        planner = replace(planner, horizon=horizon)
    if samples is not None:
        planner = replace(planner, samples=samples)
    if epistemic is not None:
        planner = replace(planner, epistemic=epistemic)
    if depth is not None:
        planner = replace(planner, depth=depth)
    if end_inside:
        planner = replace(planner, end_inside=True)
    planner = replace(planner, regions_without_gain=regions_without_gain)
    if repeat_no_effect:
        planner = replace(planner, no_effect_tolerance=None, no_effect_share=None)
    return planner


@gear_app.command("episode")
def episode(
    index: int = typer.Option(..., min=0, max=EPISODES_MAX - 1,
                              help="Evaluation episode, 0-based (as in episodes.json)."),
    models: Path = typer.Option(DEFAULT_MODELS, callback=models_folder,
                                help="Models folder (gear train, or gear "
                                "run's OUT/models)."),
    controller: str = typer.Option("dynoplan", help="dynoplan, oracle, fixed_script, random "
                                   "or a variant (see gear evaluate --help)."),
    seed: int = typer.Option(0, min=0, max=SEED_MAX,
                             help="Episodes are gear run's for the same seed."),
    out: Path = typer.Option(Path("results/gear-episode"), callback=out_folder,
                             help="Output folder."),
    video: bool = typer.Option(False, "--video", help="Also render the episode offscreen "
                               "to OUT/episode.mp4."),
    horizon: int | None = _horizon_option(),
    samples: int | None = _samples_option(),
    depth: int | None = _depth_option(),
    epistemic: float | None = _epistemic_option(),
    end_inside: bool = _end_inside_option(),
    regions_without_gain: bool = _regions_without_gain_option(),
    repeat_no_effect: bool = _repeat_option(),
    human: str | None = _human_option(),
    shield: bool = _shield_option(),
) -> None:
    """Replay one evaluation episode; write its decisions (OUT/trace.csv) and metrics."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    import torch

    from dynoplan.envs.gear.metrics import seconds
    from dynoplan.envs.gear.reports.episode import episode_summary, inspect_episode, save_video
    from dynoplan.io import staged_folder, write_csv, write_json
    from dynoplan.reports.video import video_clip

    torch.set_num_threads(1)
    frames: list[Any] | None = [] if video else None  # the replay renders itself
    planner = _planner_settings(horizon, samples, epistemic, end_inside, repeat_no_effect,
                                depth, regions_without_gain)
    task = _gear_task(human, shield)
    metrics, rows, schedule = inspect_episode(models, controller, index, seed, planner,
                                              frames=frames, task=task)
    summary = episode_summary(metrics, controller, index, seed, schedule)
    with staged_folder(out) as folder:
        write_csv(folder / "trace.csv", rows)
        if frames is not None:
            clip = video_clip(frames, metrics.success,
                              [o for o in metrics.options if o != "hold"])
            summary["video"] = save_video(clip, metrics, index, folder / "episode.mp4")
        write_json(folder / "summary.json", summary)
    events = ", ".join(schedule["events"]) or "away"
    measured = metrics.task_metrics
    typer.echo(f"episode {index} ({events}): {controller} "
               f"{'succeeded' if metrics.success else 'failed'} in {seconds(metrics):.2f} s, "
               f"{measured['contacts']} contacts, min human distance "
               f"{measured['min_human_distance']:.3f} m, {metrics.switches} switches, "
               f"{metrics.no_admissible} holds")
    for row in rows:
        if row["contacts"]:
            typer.echo(f"  contact at {row['time_s']:.2f} s during {row['option']} "
                       f"({row['contacts']} contacts, tool-hand {row['tool_hand_m']:.2f} m "
                       f"at the decision, admissible: {row['admissible'] or 'none'})")
    typer.echo(f"-> {out}/trace.csv, summary.json{', episode.mp4' if video else ''}")


def _echo_results(rows: list[dict[str, Any]]) -> None:
    for row in rows:
        ms = row["decision_ms_p50"]
        typer.echo(f"{row['controller']:>12}: success {row['success_rate']:.0%} of "
                   f"{row['episodes']}, contacts {row['contacts']}, out-of-region starts "
                   f"{row['out_of_region_starts']}, decision p50 "
                   f"{'-' if ms is None else f'{ms:.2f} ms'}")


def _gear_task(human: str | None, shield: bool) -> "GearTask":
    """The gear as ``--human`` and ``--shield`` ask: ``--human`` None (the
    demonstrations' mix), or the behaviours it names (``unseen``, ``all`` or a list)."""
    from dynoplan.envs.gear.human import BEHAVIOURS, UNSEEN_BEHAVIOURS
    from dynoplan.envs.gear.pipeline_task import GearTask
    from dynoplan.errors import DynoplanError

    if human is None:
        return GearTask(shield=shield)
    names = {"all": BEHAVIOURS, "unseen": UNSEEN_BEHAVIOURS}.get(
        human.strip(), tuple(h.strip() for h in human.split(",") if h.strip()))
    unknown = [n for n in names if n not in BEHAVIOURS]
    if unknown or not names:
        raise DynoplanError(f"--human: unknown behaviour(s) {', '.join(unknown) or '(none)'}; "
                            f"expected some of {', '.join(BEHAVIOURS)}, 'unseen' or 'all'")
    return GearTask(human=tuple(names), shield=shield)
