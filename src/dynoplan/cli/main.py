"""``dynoplan``: run the paper's experiments and the library's pipeline from a shell.

User mistakes (bad arguments, unreadable files, unknown names) print one line,
``dynoplan: error: ...``, and exit with status 2; no traceback.
"""

import signal
import sys
from pathlib import Path
from typing import NoReturn

import typer

from dynoplan.cli.gear import gear_app
from dynoplan.cli.generic import generic_app
from dynoplan.cli.params import folder, require_gear
from dynoplan.cli.workers import ray_address_option, workers_option
from dynoplan.errors import DynoplanError
from dynoplan.limits import (
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
    out: Path = typer.Option(Path("results/random-walk"), callback=folder, help="Output folder."),
    episodes: int = typer.Option(1000, min=1, max=RANDOM_WALK_EPISODES_MAX,
                                 help="Episodes per controller and noise level."),
    noise: float = typer.Option(0.2, help="Misprediction probability of the models."),
    seed: int = typer.Option(0, min=0, max=SEED_MAX, help="Seed of every random choice."),
    horizon: int = typer.Option(20, min=1, max=HORIZON_MAX, help="Rollout horizon n (steps)."),
    samples: int = typer.Option(128, min=1, max=SAMPLES_MAX,
                                help="Monte-Carlo rollouts per option."),
    max_decisions: int = typer.Option(50, min=1, max=STEPS_MAX,
                                      help="Planning steps before an episode fails."),
    start_state: int = typer.Option(0, min=0, help="Start state of the walk (0..19)."),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
) -> None:
    """Reproduce the paper's Simulated MDP (Fig. 2b) with baselines and robustness."""
    from dynoplan.experiments.random_walk import RandomWalkSettings, run_random_walk
    from dynoplan.io import staged_folder

    settings = RandomWalkSettings(episodes=episodes, noise=noise, seed=seed, horizon=horizon,
                                  samples=samples, max_decisions=max_decisions,
                                  start_state=start_state)
    with staged_folder(out) as folder:
        summary = run_random_walk(settings, folder, progress=not quiet)
    typer.echo(
        f"success {summary['success_rate']:.1%}, planning steps median "
        f"{summary['planning_steps_median']}, p90 {summary['planning_steps_p90']}, "
        f"{summary['episodes']} episodes in {summary['seconds']:.2f} s -> {out}/summary.json"
    )


@app.command("sweep")
def sweep(
    config: Path = typer.Argument(..., help="Sweep configuration (.toml or .json)."),
    out: Path | None = typer.Option(None, callback=folder,
                                    help="Output folder (default: results/sweep-"
                                    "CONFIG_NAME). Re-running into it skips finished cells."),
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

    pool = parse_workers(workers, ray_address)
    folder = out if out is not None else Path("results") / f"sweep-{config.stem}"
    summary = run_sweep(config, folder, pool, progress=not quiet,
                        log=(lambda _: None) if quiet else typer.echo)
    typer.echo(f"{summary['cells']} cells ({summary['cells_run']} run, "
               f"{summary['cells_reused']} already finished) in {summary['wall_s']:.1f} s "
               f"-> {folder}/results.md, results.csv, sweep.png")


app.add_typer(gear_app, name="gear")
app.add_typer(generic_app, name="pipeline")


_signals: list[int] = []
"""The interrupting signals received (typer turns the KeyboardInterrupt they raise into a
return code of 130, whatever the signal)."""


def _interrupt(signum: int, _frame: object) -> None:
    """SIGINT and SIGTERM handler: unwind the run as Ctrl-C does, so that ``finally``
    blocks remove temporary files and staged folders (:mod:`dynoplan.io`) and the previous
    outputs stay."""
    _signals.append(signum)
    raise KeyboardInterrupt


def _aborted(signum: int) -> NoReturn:
    sys.stderr.write("dynoplan: aborted\n")
    sys.exit(128 + signum)


def main() -> None:
    """Console entry point: one line per user error, exit status 2; ``dynoplan: aborted``
    and status 130 (SIGINT, Ctrl-C) or 143 (SIGTERM) when interrupted."""
    # SIGINT also when started with it ignored (a background job of a shell script)
    signal.signal(signal.SIGINT, _interrupt)
    signal.signal(signal.SIGTERM, _interrupt)
    try:
        code = app(standalone_mode=False)
    except (typer.Abort, KeyboardInterrupt):
        _aborted(_signals[0] if _signals else signal.SIGINT)
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except typer.TyperException as exc:  # usage errors of the vendored click
        fmt = getattr(exc, "format_message", None)
        message = fmt() if callable(fmt) else str(exc)
        if not message:  # "no arguments": the help text has been shown
            sys.exit(int(getattr(exc, "exit_code", 2)))
        sys.stderr.write(f"dynoplan: error: {message}\n")
        sys.exit(int(getattr(exc, "exit_code", 2)))
    except DynoplanError as exc:
        sys.stderr.write(f"dynoplan: error: {exc}\n")
        sys.exit(2)
    if _signals:
        _aborted(_signals[0])
    sys.exit(code if isinstance(code, int) else 0)
