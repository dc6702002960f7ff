"""``dynoplan pipeline``: DynoPlan on any Gymnasium environment from the command line.

Mounted by ``cli/app.py`` as ``app.add_typer(generic_app, name="pipeline")``::

    dynoplan pipeline --env MountainCarContinuous-v0 \\
        --options examples.mountain_car.options:make_options --out results/mountain-car

Every setting of :mod:`dynoplan.pipeline.config` is a flag of the same name (``--explore``
is ``exploration_episodes``), and ``--config FILE`` reads them from TOML; a flag given
overrides the file. The effective settings are written to ``OUT/settings.toml``.
"""

import shlex
import sys
from pathlib import Path

import typer

from dynoplan.cli.lines import warnings_as_lines
from dynoplan.cli.params import folder, out_folder
from dynoplan.cli.params import setting_bounds as _bounds
from dynoplan.cli.workers import ray_address_option, workers_option
from dynoplan.errors import DynoplanError

generic_app = typer.Typer(
    help="DynoPlan on any Gymnasium environment (a Box observation, or a Dict with a "
         "state_fn or flattened).",
    pretty_exceptions_enable=False,
    add_completion=False,
)


@generic_app.callback(invoke_without_command=True)
def pipeline(
    env: str | None = typer.Option(None, "--env", help="Gymnasium environment id (required, "
                                   "here or in --config)."),
    options: str | None = typer.Option(
        None, "--options",
        help="MODULE:FUNCTION returning the options, a list of option_spec (required, here "
             "or in --config)."),
    config: Path | None = typer.Option(
        None, "--config", help="TOML file of settings (keys as these flags, in snake_case; "
        "\\[fit] and \\[control] sections; see OUT/settings.toml); flags given override it."),
    demonstrator: str | None = typer.Option(
        None, "--demonstrator",
        help="MODULE:FUNCTION returning the scripted demonstrator "
             "(default: make_demonstrator in the --options module)."),
    disturbance: str | None = typer.Option(
        None, "--disturbance",
        help="MODULE:FUNCTION wrapping the environment in a disturbance you expect (env -> "
             "env), where --improve-disturbed rehearses."),
    demo_dataset: Path | None = typer.Option(
        None, "--demo-dataset", callback=folder,
        help="Use recorded demonstrations (a dataset folder) instead."),
    success: str | None = typer.Option(
        None, "--success",
        help="MODULE:FUNCTION, success(observation, info) -> bool, called after every step; "
             "the episode ends at the first success (default: info['is_success'] at the "
             "last step, else terminated)."),
    state_fn: str | None = typer.Option(
        None, "--state-fn",
        help="MODULE:FUNCTION, state_fn(observation) -> (d,) vector: the planner state, "
             "which the options also see (default: a Box observation as it is, a Dict "
             "flattened)."),
    demos: int | None = typer.Option(None, "--demos", **_bounds("demos"),
                                     help="Demonstrations to record [5]."),
    exploration_episodes: int | None = typer.Option(
        None, "--explore", "--exploration-episodes", **_bounds("exploration_episodes"),
        help="Episodes of random options for the dynamics models [20]."),
    exploration_option_steps: int | None = typer.Option(
        None, "--exploration-option-steps", **_bounds("exploration_option_steps"),
        help="Most steps an option runs while exploring [100]."),
    exploration_branches: int | None = typer.Option(
        None, "--exploration-branches", **_bounds("exploration_branches"),
        help="Further exploration episodes that branch off a demonstration (start where "
             "it was after a random step, its reset seed replayed) [0]."),
    demo_detours: int | None = typer.Option(
        None, "--demo-detours", **_bounds("demo_detours"),
        help="Further demonstrations, each with one detour: a random option acts for a "
             "while and the demonstrator recovers (a variant) [0]."),
    region_starts: int | None = typer.Option(
        None, "--region-starts", **_bounds("region_starts"),
        help="Start states (resets of their own seeds) where the demonstrator's first "
             "choice is asked; the regions fit them too (0: none) [0]."),
    episodes: int | None = typer.Option(None, "--episodes", **_bounds("episodes"),
                                        help="Evaluation episodes per controller [100]."),
    seed: int | None = typer.Option(None, "--seed", **_bounds("seed"),
                                    help="Seed of every random choice [0]."),
    improve: int | None = typer.Option(
        None, "--improve", **_bounds("improve"),
        help="Rounds of learning from DynoPlan's own episodes before the evaluation: "
             "refit on them, their successes as demonstrations (0: the paper's pipeline) "
             "[1]."),
    improve_episodes: int | None = typer.Option(
        None, "--improve-episodes", **_bounds("improve_episodes"),
        help="DynoPlan's episodes per improvement round [30]."),
    improve_regions: bool | None = typer.Option(
        None, "--improve-regions/--no-improve-regions",
        help="The improvement rounds' successes refit the safety regions too, not only "
             "the goal heuristic [on]."),
    improve_keep: str | None = typer.Option(
        None, "--improve-keep",
        help="Models the evaluation uses after the improvement rounds: last (the last "
             "refit's) or best (those whose own episodes succeeded most often; one more "
             "batch measures the last refit) [best]."),
    improve_explore: float | None = typer.Option(
        None, "--improve-explore", **_bounds("improve_explore"),
        help="In the improvement rounds' own episodes, the probability at each decision of "
             "a random admissible option instead of DynoPlan's choice [0.2]."),
    improve_demos: int | None = typer.Option(
        None, "--improve-demos", **_bounds("improve_demos"),
        help="After each improvement round's own episodes, the demonstrator runs from the "
             "starts of up to this many of them that failed; its successes join the "
             "demonstrations [5]."),
    improve_disturbed: float | None = typer.Option(
        None, "--improve-disturbed", **_bounds("improve_disturbed"),
        help="The share of the improvement rounds' own episodes that run under the "
             "--disturbance (the demonstrator asked there too) [0]."),
    improve_takeover: bool | None = typer.Option(
        None, "--improve-takeover/--no-improve-takeover",
        help="The demonstrator asked about a failed own episode (--improve-demos) takes it "
             "over where DynoPlan's goal heuristic rated its state highest, after "
             "DynoPlan's actions up to there are replayed, instead of starting from its "
             "start [off]."),
    controllers: str | None = typer.Option(
        None, "--controllers", help="Comma-separated controllers to evaluate: demonstrator, "
        "dynoplan, option:NAME, random [all]."),
    out: Path = typer.Option(Path("results/pipeline"), "--out", callback=out_folder,
                             help="Output folder."),
    stride: int | None = typer.Option(None, "--stride", **_bounds("fit.stride"),
                                      help="Environment steps per model step [1]."),
    option_model: str | None = typer.Option(
        None, "--option-model",
        help="What each option's dynamics predict: step (the next model step; rollouts of "
             "--horizon steps) or end (where the option ends: one step per rollout) [end]."),
    dynamics_hidden: str | None = typer.Option(
        None, "--dynamics-hidden", help="Hidden layer widths of each dynamics ensemble "
        "member, comma-separated [64,64]."),
    dynamics_members: int | None = typer.Option(
        None, "--dynamics-members", **_bounds("fit.dynamics_members"),
        help="Members of each dynamics ensemble [5]."),
    dynamics_epochs: int | None = typer.Option(
        None, "--dynamics-epochs", **_bounds("fit.dynamics_epochs"),
        help="Epochs per ensemble [30]."),
    dynamics_max_updates: int | None = typer.Option(
        None, "--dynamics-max-updates", **_bounds("fit.dynamics_max_updates"),
        help="Fewer epochs when an option has so many transitions that --dynamics-epochs "
             "would take more gradient steps than this [no bound]."),
    dynamics_min_updates: int | None = typer.Option(
        None, "--dynamics-min-updates", **_bounds("fit.dynamics_min_updates"),
        help="More epochs when an option has so few transitions that --dynamics-epochs "
             "would take fewer gradient steps than this [1000]."),
    dynamics_calibration: float | None = typer.Option(
        None, "--dynamics-calibration", **_bounds("fit.dynamics_calibration"),
        help="Share of each option's runs held back from its fit to calibrate the "
             "predicted spread on (needs --option-model step) [0: none]."),
    goal_hidden: int | None = typer.Option(None, "--goal-hidden", **_bounds("fit.goal_hidden"),
                                           help="Hidden width of the goal network [64]."),
    goal_members: int | None = typer.Option(
        None, "--goal-members", **_bounds("fit.goal_members"),
        help="Members of the goal ensemble [1]."),
    goal_epochs: int | None = typer.Option(None, "--goal-epochs", **_bounds("fit.goal_epochs"),
                                           help="Epochs of the goal network [150]."),
    goal_ranking: float | None = typer.Option(
        None, "--goal-ranking", **_bounds("fit.goal_ranking"),
        help="Weight of the goal network's ranking loss along demonstrations [0]."),
    goal_off_demos: bool | None = typer.Option(
        None, "--goal-off-demos/--no-goal-off-demos",
        help="The goal heuristic also fits the exploration states, labelled below the "
             "nearest demonstration state by their distance to it [on]."),
    goal_off_radius: float | None = typer.Option(
        None, "--goal-off-radius", **_bounds("fit.goal_off_radius"),
        help="Distance from the demonstrations, in demonstration steps, at which an "
             "exploration state's label falls to exp(-1) of its nearest demonstration "
             "state's [5]."),
    goal_off_unit: str | None = typer.Option(
        None, "--goal-off-unit",
        help="How those demonstration steps are measured: path, the median distance "
             "between consecutive demonstration states; displacement, between states "
             "that many steps apart [path]."),
    goal_off_around: int | None = typer.Option(
        None, "--goal-off-around", **_bounds("fit.goal_off_around"),
        help="Copies of every demonstration state moved by noise of one label radius, "
             "fitted with their labels: the goal falls away from the demonstrations in "
             "every direction [0]."),
    goal_off_decay: str | None = typer.Option(
        None, "--goal-off-decay",
        help="How that label falls with the distance r: gaussian, exp(-(r/R)^2); cauchy, "
             "1/(1+(r/R)^2) [gaussian]."),
    goal_off_context: bool | None = typer.Option(
        None, "--goal-off-context/--no-goal-off-context",
        help="That distance leaves out the dimensions that stay the same along every "
             "demonstration but differ between them (where the reset put a goal) [on]."),
    regions: bool | None = typer.Option(None, "--regions/--no-regions",
                                        help="Fit the safety regions (Eq. 5) and enforce "
                                        "them [on]."),
    region_fit: str | None = typer.Option(
        None, "--region-fit",
        help="heldout: components and thresholds chosen on held-out demonstrations; "
             "bic: BIC and in-sample thresholds (the paper's reading); cv: BIC components, "
             "thresholds widened by leaving demonstrations out [heldout]."),
    region_cv_coverage: float | None = typer.Option(
        None, "--region-cv-coverage", **_bounds("fit.region_cv_coverage"),
        help="cv: share of left-out demonstrations' states a threshold is widened to admit "
             "[0.97]."),
    region_coverage: float | None = typer.Option(
        None, "--region-coverage", **_bounds("fit.region_coverage"),
        help="Share of (held-out) demonstration states of an option inside its region "
             "[0.95]."),
    region_slack: float | None = typer.Option(
        None, "--region-slack", **_bounds("fit.region_slack"),
        help="Nats subtracted from every region threshold [0]."),
    region_components: int | None = typer.Option(
        None, "--region-components", **_bounds("fit.region_components"),
        help="Mixture size per option [chosen by the fit]."),
    region_max_components: int | None = typer.Option(
        None, "--region-max-components", **_bounds("fit.region_max_components"),
        help="Largest mixture the fit may choose [6]."),
    region_folds: int | None = typer.Option(
        None, "--region-folds", **_bounds("fit.region_folds"),
        help="Folds of whole demonstrations of the held-out fit [5]."),
    region_reg_covar: float | None = typer.Option(
        None, "--region-reg-covar", **_bounds("fit.region_reg_covar"),
        help="Covariance floor, in units of each dimension's spread (heldout) [0.01]."),
    region_undemonstrated: str | None = typer.Option(
        None, "--region-undemonstrated",
        help="Region of an option no demonstration shows: runs (from its own exploration "
             "runs), none (never admissible), everywhere (its own initiation set), outcomes "
             "(where its exploration runs made the goal heuristic rise) [none]."),
    outcome_initiation: bool | None = typer.Option(
        None, "--outcome-initiation/--no-outcome-initiation",
        help="Also learn where each option may start from the outcomes of its exploration "
             "runs (did the goal heuristic rise?), intersected with its region [off]."),
    outcome_min_gain: float | None = typer.Option(
        None, "--outcome-min-gain",
        help="A run is good when the goal heuristic rose by more than this [0]."),
    constant_dimensions_still: bool | None = typer.Option(
        None, "--constant-dimensions-still/--no-constant-dimensions-still",
        help="State dimensions that never change in the data are kept still by the "
             "dynamics and not tested by the regions [on]."),
    horizon: int | None = typer.Option(None, "--horizon", **_bounds("control.horizon"),
                                       help="Planning horizon n, in model steps [20]."),
    samples: int | None = typer.Option(None, "--samples", **_bounds("control.samples"),
                                       help="Monte-Carlo rollouts per option [32]."),
    depth: int | None = typer.Option(
        None, "--depth", **_bounds("control.depth"),
        help="Options per imagined sequence (1: Eq. 1; 2: look one option further) [1]."),
    risk: float | None = typer.Option(None, "--risk", **_bounds("control.risk"),
                                      help="k in E[G] - k std[G] of Eq. 1 [0]."),
    replan_every: int | None = typer.Option(
        None, "--replan-every", **_bounds("control.replan_every"),
        help="Plan again after this many steps (0: only when the option stops) [10]."),
    margin: float | None = typer.Option(
        None, "--margin", **_bounds("control.margin"),
        help="Score advantage needed to replace a running option at a replan [0]."),
    commit: float | None = typer.Option(
        None, "--commit", **_bounds("control.commit"),
        help="At a replan, the running option goes on while its own score has not fallen "
             "by more than this since it was chosen, whatever the others score [off]."),
    max_decisions: int | None = typer.Option(
        None, "--max-decisions", **_bounds("control.max_decisions"),
        help="Planning steps before an episode is given up [1000]."),
    max_option_steps: int | None = typer.Option(
        None, "--max-option-steps", **_bounds("control.max_option_steps"),
        help="Environment steps one option may run between decisions [1000]."),
    hold: bool | None = typer.Option(
        None, "--hold/--no-hold",
        help="Where no option is admissible, hold (--hold-action, else the zero action of a "
             "Box action space) until one is; --no-hold: end the episode there [hold]."),
    hold_action: str | None = typer.Option(
        None, "--hold-action", help="The action to hold with, comma-separated numbers "
        "[the zero action of a Box action space]."),
    dynamics_noise: float | None = typer.Option(
        None, "--dynamics-noise", **_bounds("control.dynamics_noise"),
        help="Std of Gaussian noise on every learned prediction of the planner (a fault) "
             "[0]."),
    epistemic: float | None = typer.Option(
        None, "--epistemic", **_bounds("control.epistemic"),
        help="Weight of the dynamics ensemble's disagreement in the planner's score [0]."),
    end_inside: bool | None = typer.Option(
        None, "--end-inside/--no-end-inside",
        help="Rollouts that leave an option's continuation set end at their last state "
             "inside it [off]."),
    no_effect_tolerance: float | None = typer.Option(
        None, "--no-effect-tolerance", **_bounds("control.no_effect_tolerance"),
        help="An option that ends with no state coordinate moved more than this is not "
             "started again there, in state units [off]."),
    no_effect_share: float | None = typer.Option(
        None, "--no-effect-share", **_bounds("control.no_effect_share"),
        help="Without --no-effect-tolerance, each coordinate's tolerance is this share of "
             "its spread over the fitted data (0: no such rule) [0.01]."),
    loop_share: float | None = typer.Option(
        None, "--loop-share", **_bounds("control.loop_share"),
        help="Where the state comes back to where an earlier decision started an option "
             "(each coordinate within this share of its spread over the fitted data), "
             "that option does not start there again (0: no such rule) [0.05]."),
    loop_progress: bool | None = typer.Option(
        None, "--loop-progress/--no-loop-progress",
        help="Judge a loop by the goal heuristic: the options whose runs in it lowered it "
             "do not start anywhere until it passes the loop's highest value [off]."),
    start_where_done: bool | None = typer.Option(
        None, "--start-where-done/--no-start-where-done",
        help="An option may start where its termination is certain (it ends at its first "
             "step) [no]."),
    fallback_own_sets: bool | None = typer.Option(
        None, "--fallback-own-sets/--no-fallback-own-sets",
        help="Where no option may start under its learned initiation set, the options "
             "whose own sets hold may (--no-fallback-own-sets: hold or end there) [on]."),
    fallback_goes_on: bool | None = typer.Option(
        None, "--fallback-goes-on/--no-fallback-goes-on",
        help="An option that leaves its learned set where no option may start under its "
             "learned set goes on while its own set holds [off]."),
    fallback_must_gain: bool | None = typer.Option(
        None, "--fallback-must-gain/--no-fallback-must-gain",
        help="DynoPlan starts an option under its own set only where it scores at least "
             "the goal heuristic at the present state, and holds otherwise [on]."),
    fallback_without_gain: bool | None = typer.Option(
        None, "--fallback-without-gain/--no-fallback-without-gain",
        help="Where the learned sets admit options but none is predicted to gain, the "
             "demonstrated options whose own sets hold are scored too (depth 1) [off]."),
    regions_without_gain: bool | None = typer.Option(
        None, "--regions-without-gain/--no-regions-without-gain",
        help="Where the learned sets admit options but none is predicted to gain, the "
             "admissible option whose learned region holds the state most likely runs "
             "(depth 1) [on]."),
    stall_progress: float | None = typer.Option(
        None, "--stall-progress", **_bounds("control.stall_progress"),
        help="Where a hold changed nothing and DynoPlan would hold again at a state whose "
             "goal heuristic is below this, the best option under its own set starts "
             "(0: no such rule) [0.5]."),
    stall_forgets: bool | None = typer.Option(
        None, "--stall-forgets/--no-stall-forgets",
        help="Where DynoPlan held in place below --stall-progress and no option may start "
             "at all, the options forget where their runs ended without effect and "
             "DynoPlan chooses again [on]."),
    score_failures: bool | None = typer.Option(
        None, "--score-failures/--no-score-failures",
        help="DynoPlan weighs each option's imagined future by its chance not to end the "
             "episode in failure from here, learned from the exploration runs that "
             "failed [on]."),
    workers: str = workers_option(),
    ray_address: str | None = ray_address_option(),
    quiet: bool = typer.Option(False, "--quiet", help="No progress bars."),
) -> None:
    """Collect, fit dynamics/goal/regions, run DynoPlan and compare with each option alone
    and random choice; writes OUT/summary.json, OUT/results.md, OUT/settings.toml,
    datasets and models."""
    from dynoplan.data.dataset import read_dataset
    from dynoplan.io import staged_folder, write_text
    from dynoplan.parallel import parse_workers
    from dynoplan.pipeline import GymTask, call_factory, load_object, run_pipeline
    from dynoplan.pipeline.config import (
        TASK_KEYS,
        pipeline_settings,
        read_config,
        setting_keys,
        settings_toml,
    )

    # every parameter by name: a setting's flag is named as its field (config.setting_keys)
    flags = dict(locals())
    flags["demo_dataset"] = None if demo_dataset is None else str(demo_dataset)
    given = {key: flags[key.rpartition(".")[2]] for key in [*TASK_KEYS, *setting_keys()]
             if flags.get(key.rpartition(".")[2]) is not None}
    values = {**(read_config(config) if config is not None else {}), **given}
    pipeline_settings(given)  # a flag's mistake names the flag
    settings = pipeline_settings(values, str(config) if config is not None else None)
    task_refs = {key: values.get(key) for key in TASK_KEYS}
    for key in ("env", "options"):
        if not isinstance(task_refs[key], str) or not task_refs[key]:
            raise DynoplanError(f"give --{key} (or {key} = \"...\" in the --config file)")
    for key in ("demonstrator", "demo_dataset", "success", "state_fn", "disturbance"):
        if task_refs[key] is not None and not isinstance(task_refs[key], str):
            raise DynoplanError(f"{config}: {key} must be a string, got {task_refs[key]!r}")
    env_id, options_ref = str(task_refs["env"]), str(task_refs["options"])
    pool = parse_workers(workers, ray_address)
    dataset = task_refs["demo_dataset"]
    demo_data = read_dataset(Path(dataset)) if dataset is not None else None
    demo_maker = reference = None
    if demo_data is None:
        module = options_ref.partition(":")[0]
        reference = task_refs["demonstrator"] or f"{module}:make_demonstrator"
        if task_refs["demonstrator"] is None:
            try:
                load_object(reference)
            except DynoplanError:
                raise DynoplanError(
                    f"'{module}' defines no make_demonstrator(); give "
                    "--demonstrator MODULE:FUNCTION or --demo-dataset PATH") from None
        demo_maker = call_factory(reference, "demonstrator")
    task = GymTask(env_id, options_ref, task_refs["success"], task_refs["state_fn"],
                   reference, task_refs["disturbance"])
    made = task.make_options()
    command = "dynoplan " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    with staged_folder(out) as staged, warnings_as_lines():
        # nothing of a failed run, the previous run's kept
        result = run_pipeline(task.make_env(), list(made), demonstrator=demo_maker,
                              demos=demo_data, settings=settings, out=staged,
                              progress=not quiet,
                              status=None if quiet else lambda m: typer.echo(f"-- {m}",
                                                                             err=True),
                              command=command, workers=pool, task=task,
                              disturbed_env=(task.make_env(disturbed=True)
                                             if settings.improve_disturbed
                                             and task.disturbance else None))
        write_text(staged / "settings.toml", settings_toml(task_refs, settings))
    typer.echo(result.table)
    typer.echo(result.admissibility_table)
    stages = ", ".join(f"{k} {v:.1f} s" for k, v in result.summary["stage_seconds"].items())
    typer.echo(f"{result.summary['seconds']:.1f} s ({stages}) -> {out}/summary.json, "
               "settings.toml")
