"""The ``dynoplan`` command tree (typer): the top-level commands and the ``gear``,
``pipeline`` and ``task`` groups.

Importing it imports no simulator, no torch and no pipeline: every command imports what
it runs inside its function, so that ``--help`` and usage errors answer at once.
:func:`dynoplan.cli.main.main` runs it.
"""

from pathlib import Path

import typer

from dynoplan.cli.gear import gear_app
from dynoplan.cli.generic import generic_app
from dynoplan.cli.params import out_folder, require_gear
from dynoplan.cli.task import task_app
from dynoplan.cli.workers import ray_address_option, workers_option
from dynoplan.limits import (
    DEPTH_MAX,
    HORIZON_MAX,
    RANDOM_WALK_EPISODES_MAX,
    SAMPLES_MAX,
    SEED_MAX,
    STEPS_MAX,
)

app = typer.Typer(
    name="dynoplan",
    help="DynoPlan: plan over options with learned dynamics, safely.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)


@app.callback()
def _root() -> None:
    """DynoPlan: plan over options with learned dynamics, safely."""


@app.command("random-walk")
def random_walk(
    out: Path = typer.Option(Path("results/random-walk"), callback=out_folder,
                             help="Output folder."),
    episodes: int = typer.Option(1000, min=1, max=RANDOM_WALK_EPISODES_MAX,
                                 help="Episodes per controller and noise level."),
    noise: float = typer.Option(0.2, help="Misprediction probability of the models."),
    seed: int = typer.Option(0, min=0, max=SEED_MAX, help="Seed of every random choice."),
    horizon: int = typer.Option(20, min=1, max=HORIZON_MAX, help="Rollout horizon n (steps)."),
    samples: int = typer.Option(128, min=1, max=SAMPLES_MAX,
                                help="Monte-Carlo rollouts per option."),
    max_decisions: int = typer.Option(50, min=1, max=STEPS_MAX,
                                      help="Planning steps before an episode fails."),
    depth: int = typer.Option(1, min=1, max=DEPTH_MAX,
                              help="Options per imagined sequence (1: Eq. 1; 2: look one "
                                   "option further)."),
    lockstep: bool = typer.Option(True, "--lockstep/--one-by-one",
                                  help="Run the episodes side by side, every episode's "
                                       "decision of one step in one planner call (the same "
                                       "distribution of results), or one after another."),
    start_state: int = typer.Option(0, min=0, help="Start state of the walk (0..19)."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
) -> None:
    """Reproduce the paper's Simulated MDP (Fig. 2b) with baselines and robustness."""
    from dynoplan.experiments.random_walk import RandomWalkSettings, run_random_walk
    from dynoplan.io import staged_folder

    settings = RandomWalkSettings(episodes=episodes, noise=noise, seed=seed, horizon=horizon,
                                  samples=samples, max_decisions=max_decisions,
                                  depth=depth, lockstep=lockstep, start_state=start_state)
    with staged_folder(out) as folder:
        summary = run_random_walk(settings, folder, progress=not quiet)
    typer.echo(
        f"success {summary['success_rate']:.1%}, planning steps median "
        f"{summary['planning_steps_median']}, p90 {summary['planning_steps_p90']}, "
        f"{summary['episodes']} episodes in {summary['seconds']:.2f} s -> {out}/summary.json"
    )


@app.command("trap-walk")
def trap_walk(
    out: Path = typer.Option(Path("results/trap-walk"), callback=out_folder,
                             help="Output folder."),
    episodes: int = typer.Option(1000, min=1, max=RANDOM_WALK_EPISODES_MAX,
                                 help="Episodes per depth (the same episodes at every depth)."),
    depth: list[int] = typer.Option([1, 2], "--depth", min=1, max=DEPTH_MAX,
                                    help="Options per imagined sequence; repeat for several."),
    seed: int = typer.Option(0, min=0, max=SEED_MAX, help="Seed of every random choice."),
    horizon: int = typer.Option(20, min=1, max=HORIZON_MAX, help="Rollout horizon per option."),
    samples: int = typer.Option(64, min=1, max=SAMPLES_MAX,
                                help="Monte-Carlo rollouts per option sequence."),
    max_decisions: int = typer.Option(50, min=1, max=STEPS_MAX,
                                      help="Planning steps before an episode fails."),
) -> None:
    """The look-ahead's known answer: the trap walk at depth 1 (stalls) and 2 (does not)."""
    from dynoplan.experiments.trap import TrapSettings, run_trap
    from dynoplan.io import staged_folder

    settings = TrapSettings(episodes=episodes, depths=tuple(depth), seed=seed,
                            horizon=horizon, samples=samples, max_decisions=max_decisions)
    with staged_folder(out) as folder:
        summary = run_trap(settings, folder)
    for row in summary["rows"]:
        typer.echo(f"depth {row['depth']}: success {row['success_rate']:.1%}, planning steps "
                   f"median {row['planning_steps_median']}, {row['episodes']} episodes in "
                   f"{row['seconds']:.2f} s")
    typer.echo(f"-> {out}/summary.json")


@app.command("sweep")
def sweep(
    config: Path = typer.Argument(..., help="Sweep configuration (.toml or .json)."),
    out: Path | None = typer.Option(None, callback=out_folder,
                                    help="Output folder (default: results/sweep-"
                                    "CONFIG_NAME). Finished cells wait in "
                                    ".OUT_NAME.sweep-cells beside it until the sweep "
                                    "completes; re-running resumes from them."),
    workers: str = workers_option(),
    ray_address: str | None = ray_address_option(),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
) -> None:
    """Evaluate a grid of planner settings and seeds on gear models (resumable)."""
    import os

    require_gear()
    os.environ.setdefault("MUJOCO_GL", "egl")
    from dynoplan.experiments.sweep import run_sweep
    from dynoplan.parallel import parse_workers
    from dynoplan.pipeline.sweep import check_sweep_writable

    folder = out if out is not None else Path("results") / f"sweep-{config.stem}"
    check_sweep_writable(folder)  # OUT, and the resume folder beside it
    pool = parse_workers(workers, ray_address)
    summary = run_sweep(config, folder, pool, progress=not quiet,
                        log=(lambda _: None) if quiet else typer.echo)
    typer.echo(f"{summary['cells']} cells ({summary['cells_run']} run, "
               f"{summary['cells_reused']} already finished) in {summary['wall_s']:.1f} s "
               f"-> {folder}/results.md, results.csv, sweep.png")


app.add_typer(gear_app, name="gear")
app.add_typer(generic_app, name="pipeline")
app.add_typer(task_app, name="task")
