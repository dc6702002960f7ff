"""``dynoplan task fit``: a new task on the option dynamics of an earlier run.

Mounted by ``cli/app.py`` as ``app.add_typer(task_app, name="task")``::

    dynoplan task fit --options-models results/walk-options --env dynoplan/RandomWalk19-v0 \\
        --options dynoplan.envs.random_walk.tasks:make_options \\
        --state-fn dynoplan.envs.random_walk.tasks:walk_state \\
        --success dynoplan.envs.random_walk.tasks:reach_10 --no-regions --out results/reach-10

The task is named as ``dynoplan pipeline`` names it (``--env``, ``--options``,
``--success``, ``--state-fn``, ``--demonstrator``, ``--demo-dataset``; or ``--config``, a
``settings.toml``); only the goal heuristic (and, unless ``--no-regions``, the regions)
is fitted, from the task's own demonstrations and option runs: the options folder's, or
with ``--runs DATASET`` the task's own (for example the ``transitions/`` of a ``dynoplan
pipeline`` run on it) (:mod:`dynoplan.pipeline.task_fit`).
"""

import shlex
import sys
from pathlib import Path
from typing import Any

import typer

from dynoplan.cli.params import folder, out_folder
from dynoplan.cli.workers import ray_address_option, workers_option
from dynoplan.errors import DynoplanError
from dynoplan.limits import SETTING_BOUNDS

task_app = typer.Typer(
    help="Tasks over option models learned once: fit only a new task's goal heuristic.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)


def _bounds(key: str) -> dict[str, Any]:
    low, high = SETTING_BOUNDS[key]
    return {k: v for k, v in (("min", low), ("max", high)) if abs(v) != float("inf")}


@task_app.command("fit")
def fit(
    options_models: Path = typer.Option(
        ..., "--options-models", callback=folder,
        help="The options folder: a dynoplan pipeline run's --out (models/ and the option "
             "runs in transitions/), or a models folder."),
    env: str | None = typer.Option(None, "--env", help="Gymnasium environment id (here or in "
                                   "--config)."),
    options: str | None = typer.Option(
        None, "--options", help="MODULE:FUNCTION returning the task's options (all must be "
        "in the options folder; here or in --config)."),
    config: Path | None = typer.Option(
        None, "--config", help="TOML file of settings, as dynoplan pipeline's (for example "
        "the options run's settings.toml); flags given override it."),
    demonstrator: str | None = typer.Option(
        None, "--demonstrator", help="MODULE:FUNCTION returning the task's demonstrator "
        "(default: make_demonstrator in the --options module)."),
    demo_dataset: Path | None = typer.Option(
        None, "--demo-dataset", callback=folder,
        help="Use recorded demonstrations of the task (a dataset folder) instead."),
    runs: Path | None = typer.Option(
        None, "--runs", callback=folder,
        help="The task's own option runs (a dataset folder with option labels, as dynoplan "
             "pipeline writes under transitions/), for its goal heuristic and regions in "
             "place of the options folder's runs; the dynamics stay the folder's."),
    success: str | None = typer.Option(
        None, "--success", help="MODULE:FUNCTION, success(observation, info) -> bool: the "
        "task's success test."),
    state_fn: str | None = typer.Option(
        None, "--state-fn", help="MODULE:FUNCTION, state_fn(observation) -> (d,) vector: the "
        "planner state (the options folder's)."),
    demos: int | None = typer.Option(None, "--demos", **_bounds("demos"),
                                     help="Demonstrations of the task to record [5]."),
    episodes: int | None = typer.Option(None, "--episodes", **_bounds("episodes"),
                                        help="Evaluation episodes per controller [100]."),
    seed: int | None = typer.Option(None, "--seed", **_bounds("seed"),
                                    help="Seed of every random choice [0]."),
    controllers: str | None = typer.Option(
        None, "--controllers", help="Comma-separated controllers to evaluate: demonstrator, "
        "dynoplan, option:NAME, random [all]."),
    regions: bool | None = typer.Option(
        None, "--regions/--no-regions", help="Fit the task's own safety regions (Eq. 5) "
        "from its demonstrations and enforce them [on]."),
    improve: int | None = typer.Option(
        None, "--improve", **_bounds("improve"),
        help="Rounds of learning from DynoPlan's own episodes before the evaluation, as "
             "dynoplan pipeline's: the goal heuristic and regions refitted on them, the "
             "dynamics kept (0: the task's demonstrations alone) [1]."),
    reuse_initiation: bool = typer.Option(
        False, "--reuse-initiation",
        help="Keep the options folder's initiation learned from the options' own outcome "
             "runs (never one judged by its first task's goal), intersected with the "
             "task's regions [off]."),
    goal_epochs: int | None = typer.Option(None, "--goal-epochs", **_bounds("fit.goal_epochs"),
                                           help="Epochs of the goal network [150]."),
    horizon: int | None = typer.Option(None, "--horizon", **_bounds("control.horizon"),
                                       help="Planning horizon n, in model steps [20]."),
    samples: int | None = typer.Option(None, "--samples", **_bounds("control.samples"),
                                       help="Monte-Carlo rollouts per option [32]."),
    max_decisions: int | None = typer.Option(
        None, "--max-decisions", **_bounds("control.max_decisions"),
        help="Planning steps before an episode is given up [1000]."),
    out: Path = typer.Option(Path("results/task"), "--out", callback=out_folder,
                             help="Output folder."),
    workers: str = workers_option(),
    ray_address: str | None = ray_address_option(),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bars or stage lines."),
) -> None:
    """Fit a new task's goal heuristic (and regions) on an options folder's dynamics,
    unchanged (with --runs: and on the task's own option runs; then on its own episodes,
    --improve), and evaluate; writes
    OUT/summary.json (task_fit: demonstrations, option runs and seconds the task needed),
    OUT/results.md, OUT/settings.toml, OUT/demos, OUT/models."""
    from dynoplan.cli.lines import warnings_as_lines
    from dynoplan.data.dataset import read_dataset
    from dynoplan.io import staged_folder, write_text
    from dynoplan.parallel import parse_workers
    from dynoplan.pipeline import GymTask, call_factory, load_object
    from dynoplan.pipeline.config import (
        TASK_KEYS,
        pipeline_settings,
        read_config,
        settings_toml,
    )
    from dynoplan.pipeline.task_fit import run_task

    flags = {"env": env, "options": options, "success": success, "state_fn": state_fn,
             "demonstrator": demonstrator,
             "demo_dataset": None if demo_dataset is None else str(demo_dataset),
             "demos": demos, "episodes": episodes, "seed": seed, "controllers": controllers,
             "fit.regions": regions, "fit.goal_epochs": goal_epochs, "improve": improve,
             "control.horizon": horizon, "control.samples": samples,
             "control.max_decisions": max_decisions}
    given = {k: v for k, v in flags.items() if v is not None}
    values = {**(read_config(config) if config is not None else {}), **given}
    pipeline_settings(given)  # a flag's mistake names the flag
    settings = pipeline_settings(values, str(config) if config is not None else None)
    refs = {key: values.get(key) for key in TASK_KEYS}
    for key in ("env", "options"):
        if not isinstance(refs[key], str) or not refs[key]:
            raise DynoplanError(f"give --{key} (or {key} = \"...\" in the --config file)")
    pool = parse_workers(workers, ray_address)
    demo_data = None if refs["demo_dataset"] is None else read_dataset(
        Path(str(refs["demo_dataset"])))
    demo_maker = reference = None
    if demo_data is None:
        module = str(refs["options"]).partition(":")[0]
        reference = refs["demonstrator"] or f"{module}:make_demonstrator"
        if refs["demonstrator"] is None:
            try:
                load_object(str(reference))
            except DynoplanError:
                raise DynoplanError(
                    f"'{module}' defines no make_demonstrator(); give "
                    "--demonstrator MODULE:FUNCTION or --demo-dataset PATH") from None
        demo_maker = call_factory(str(reference), "demonstrator")
    task = GymTask(str(refs["env"]), str(refs["options"]), refs["success"], refs["state_fn"],
                   reference)
    command = "dynoplan " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    with staged_folder(out) as staged, warnings_as_lines():
        result = run_task(task.make_env(), options_models, task.make_options(),
                          demonstrator=demo_maker, demos=demo_data, settings=settings,
                          out=staged, progress=not quiet,
                          status=None if quiet else lambda m: typer.echo(f"-- {m}", err=True),
                          command=command, workers=pool, task=task, runs=runs,
                          reuse_initiation=reuse_initiation)
        write_text(staged / "settings.toml", settings_toml(refs, settings))
    typer.echo(result.table)
    fitted = result.summary["task_fit"]
    typer.echo(f"task: {fitted['demonstrations']} demonstrations "
               f"({fitted['demonstration_steps']} steps, {fitted['demonstration_seconds']:.1f} s"
               f"), goal fitted in {fitted['fit_seconds']:.1f} s on the dynamics of "
               f"{fitted['options_models']} and {fitted['option_runs']['episodes']} option "
               f"runs of {fitted['option_runs']['source'] or 'none'}; "
               f"{result.summary['seconds']:.1f} s in all -> "
               f"{out}/summary.json")
