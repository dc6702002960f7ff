"""``dynoplan pipeline``: DynoPlan on any Gymnasium environment from the command line.

Mounted by ``cli/main.py`` as ``app.add_typer(generic_app, name="pipeline")``::

    dynoplan pipeline --env MountainCarContinuous-v0 \\
        --options examples.mountain_car.options:make_options --out results/mountain-car
"""

import shlex
import sys
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import typer

from dynoplan.cli.params import folder
from dynoplan.cli.workers import ray_address_option, workers_option
from dynoplan.errors import DynoplanError, DynoplanWarning
from dynoplan.limits import (
    EPISODES_MAX,
    EPOCHS_MAX,
    HORIZON_MAX,
    SAMPLES_MAX,
    SEED_MAX,
    STEPS_MAX,
    STRIDE_MAX,
)

generic_app = typer.Typer(
    help="DynoPlan on any Gymnasium environment with a Box observation space.",
    pretty_exceptions_enable=False,
    add_completion=False,
)


@contextmanager
def warnings_as_lines() -> Iterator[None]:
    """Print every :class:`DynoplanWarning` as one line on stderr, when it is raised."""
    shown = warnings.showwarning

    def show(message: Warning | str, category: type[Warning], filename: str, lineno: int,
             file: Any = None, line: str | None = None) -> None:
        if issubclass(category, DynoplanWarning):
            typer.echo(f"dynoplan: warning: {message}", err=True)
        else:
            shown(message, category, filename, lineno, file, line)

    with warnings.catch_warnings():
        warnings.simplefilter("always", DynoplanWarning)
        warnings.showwarning = show
        try:
            yield
        finally:
            warnings.showwarning = shown


@generic_app.callback(invoke_without_command=True)
def pipeline(
    env: str = typer.Option(..., "--env", help="Gymnasium environment id."),
    options: str = typer.Option(
        ..., "--options", help="MODULE:FUNCTION returning the options (a list of option_spec)."),
    demonstrator: str | None = typer.Option(
        None, "--demonstrator",
        help="MODULE:FUNCTION returning the scripted demonstrator "
             "(default: make_demonstrator in the --options module)."),
    demo_dataset: Path | None = typer.Option(
        None, "--demo-dataset", callback=folder,
        help="Use recorded demonstrations (a dataset folder) instead."),
    demos: int = typer.Option(5, "--demos", min=1, max=EPISODES_MAX,
                              help="Demonstrations to record."),
    explore: int = typer.Option(20, "--explore", min=1, max=EPISODES_MAX,
                                help="Episodes of random options for the dynamics models."),
    episodes: int = typer.Option(100, "--episodes", min=1, max=EPISODES_MAX,
                                 help="Evaluation episodes per controller."),
    seed: int = typer.Option(0, "--seed", min=0, max=SEED_MAX, help="Seed of every random choice."),
    out: Path = typer.Option(Path("results/pipeline"), "--out", callback=folder,
                             help="Output folder."),
    stride: int = typer.Option(1, "--stride", min=1, max=STRIDE_MAX,
                               help="Environment steps per model step."),
    horizon: int = typer.Option(20, "--horizon", min=1, max=HORIZON_MAX,
                                help="Planning horizon n, in model steps."),
    samples: int = typer.Option(32, "--samples", min=1, max=SAMPLES_MAX,
                                help="Monte-Carlo rollouts per option."),
    replan_every: int = typer.Option(
        10, "--replan-every", min=0, max=STEPS_MAX,
        help="Plan again after this many steps (0: only when the "
                                   "option stops)."),
    hold: bool = typer.Option(True, "--hold/--no-hold",
                              help="Where no option is admissible, hold the zero action "
                              "of a Box action space until one is (--no-hold: end the "
                              "episode there)."),
    regions: bool = typer.Option(True, "--regions/--no-regions",
                                 help="Fit the safety regions (Eq. 5) and enforce them."),
    region_fit: str = typer.Option(
        "heldout", "--region-fit",
        help="heldout: components and thresholds chosen on held-out demonstrations; "
             "bic: BIC and in-sample thresholds (the paper's reading)."),
    region_coverage: float = typer.Option(
        0.95, "--region-coverage", min=0.0, max=1.0,
        help="Share of (held-out) demonstration states of an option inside its region."),
    region_slack: float = typer.Option(
        0.0, "--region-slack", min=0.0, help="Nats subtracted from every region threshold."),
    region_components: int | None = typer.Option(
        None, "--region-components", min=1, max=100,
        help="Mixture size per option (default: chosen by the fit)."),
    outcome_initiation: bool = typer.Option(
        False, "--outcome-initiation/--no-outcome-initiation",
        help="Also learn where each option may start from the outcomes of its exploration "
             "runs (did the goal heuristic rise?), intersected with its region."),
    region_undemonstrated: str = typer.Option(
        "runs", "--region-undemonstrated",
        help="Region of an option no demonstration shows: runs (from its own exploration "
             "runs), none (never admissible), everywhere (its own initiation set)."),
    dynamics_epochs: int = typer.Option(30, "--dynamics-epochs", min=1, max=EPOCHS_MAX,
                                        help="Epochs per ensemble."),
    goal_epochs: int = typer.Option(150, "--goal-epochs", min=1, max=EPOCHS_MAX,
                                    help="Epochs of the goal network."),
    workers: str = workers_option(),
    ray_address: str | None = ray_address_option(),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
) -> None:
    """Collect, fit dynamics/goal/regions, run DynoPlan and compare with each option alone
    and random choice; writes OUT/summary.json, OUT/results.md, datasets and models."""
    from dynoplan.data.dataset import read_dataset
    from dynoplan.io import staged_folder
    from dynoplan.parallel import parse_workers
    from dynoplan.pipeline import (
        ControllerSettings,
        FitSettings,
        GymTask,
        PipelineSettings,
        call_factory,
        load_object,
        run_pipeline,
    )

    pool = parse_workers(workers, ray_address)
    task = GymTask(env, options)
    made = task.make_options()
    demo_data = read_dataset(demo_dataset) if demo_dataset is not None else None
    demo_maker = None
    if demo_data is None:
        reference = demonstrator or f"{options.partition(':')[0]}:make_demonstrator"
        if demonstrator is None:
            try:
                load_object(reference)
            except DynoplanError:
                raise DynoplanError(
                    f"'{options.partition(':')[0]}' defines no make_demonstrator(); give "
                    "--demonstrator MODULE:FUNCTION or --demo-dataset PATH") from None
        demo_maker = call_factory(reference, "demonstrator")
    settings = PipelineSettings(
        demos=demos, exploration_episodes=explore, episodes=episodes, seed=seed,
        fit=FitSettings(stride=stride, regions=regions, dynamics_epochs=dynamics_epochs,
                        goal_epochs=goal_epochs, region_fit=region_fit,
                        region_coverage=region_coverage, region_slack=region_slack,
                        region_components=region_components,
                        region_undemonstrated=region_undemonstrated,
                        outcome_initiation=outcome_initiation),
        control=ControllerSettings(horizon=horizon, samples=samples,
                                   replan_every=replan_every or None, hold=hold))
    command = "dynoplan " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    settings.validate()
    with staged_folder(out) as folder, warnings_as_lines():
        # nothing of a failed run, the previous run's kept
        result = run_pipeline(env, list(made), demonstrator=demo_maker, demos=demo_data,
                              settings=settings, out=folder, progress=not quiet,
                              status=None if quiet else lambda m: typer.echo(f"-- {m}",
                                                                             err=True),
                              command=command, workers=pool, task=task)
    typer.echo(result.table)
    typer.echo(result.admissibility_table)
    stages = ", ".join(f"{k} {v:.1f} s" for k, v in result.summary["stage_seconds"].items())
    typer.echo(f"{result.summary['seconds']:.1f} s ({stages}) -> {out}/summary.json")
