"""The gear's downstream task on the first task's option dynamics (issue 32).

The first task (``dynoplan gear run``) learns the four options' dynamics with the peg
always at one pose. The downstream task (:mod:`dynoplan.envs.gear.peg_pose`,
``dynoplan/GearPegPose-v0``) holds the peg module at another pose every episode (its tip
within +-5 cm in ``x`` and ``y``, +-3 cm in ``z``); same scene, same options, same
operator. Here it is solved through the library's task-fit path
(:func:`dynoplan.pipeline.task_fit.run_task`, the gear's
:class:`~dynoplan.envs.gear.pipeline_task.GearTask` with ``peg``, as
:mod:`dynoplan.envs.gear.task_fit` and ``dynoplan gear task-fit`` fit it):

1. ``demos/``: the task's own demonstrations, the first task's operator chaining the
   options in the new environment (:func:`~dynoplan.envs.gear.demonstrations.record_demos`);
2. ``shared/``: the first task's options folder (``--options-models``, a ``gear run``
   folder), its dynamics unchanged, only the task's goal heuristic (on the features
   ``peg_objects``) and regions fitted from those demonstrations; DynoPlan on
   ``--episodes`` seeded episodes, learned parts only;
3. ``shared-frame/``: the same, the planner rolling each option's (unchanged) dynamics
   in the first task's frame (:class:`~dynoplan.envs.gear.peg_pose.PegFrame`: the
   options' own state space, the scene moved by the peg's offset);
4. ``retrain/``: the options' dynamics fitted again on the new task's own data (its option
   runs, collected as ``gear run`` collects them, and its demonstrations; the first
   task's fit settings), then ``retrained/``: the same task fit (the same demonstrations,
   the same option runs for the goal and regions, the same seeds, hence the same goal
   heuristic and evaluation episodes) on those dynamics;
5. ``results.md``, ``results.json``: every row, the demonstrations and seconds the task
   needed.

``--rows`` chooses among ``shared``, ``shared-frame`` and ``retrained`` (default: all),
and ``first-task``: the reference, the first task itself through the same task fit (its
environment, its own demonstrations from the options folder's ``demos/``, its own
dynamics; the same settings and seeds).
``--one-step-errors`` prints, from a finished ``--out``, how well each option's dynamics
predict one decision ahead on the task's demonstrations (:func:`one_step_errors`): the
first task's plain and in its frame, the retrained ones (in-sample: they were fitted on
those demonstrations too), and the first task's on its own held-out trials.
``--script`` measures the options themselves in both tasks, from a finished ``--out``
with the ``shared`` and ``first-task`` rows (:func:`script_success`): the fixed script
(pick, fast move, insert, each until its policy is finished, no learned part) on the
rows' evaluation episodes. ``--demonstrator`` measures the bar
(:func:`demonstrator_success`): the operator that records the demonstrations, on the
rows' evaluation episodes in both tasks. ``--task-initiation`` (every row reuses the
options' initiation learned from outcome runs) and ``--region-features`` (the feature map
of every row's regions) are the named variants ``docs/transfer.md`` measures.

A stage whose output is already in ``--out`` is kept (a rerun resumes); ``--quick`` runs
every stage on small settings (a smoke test, not a measurement)::

    python -m benchmarks.transfer.gear_peg_task --options-models results/gear-run \\
        --seed 0 --episodes 100 --out results/gear-peg-task
"""

import argparse
import json
import shlex
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from dynoplan.envs.gear.features import FEATURE_MAPS, feature_map
from dynoplan.envs.gear.learning.data import HELDOUT_SEED_OFFSET
from dynoplan.envs.gear.learning.settings import (
    DEFAULT_METRICS,
    DEFAULT_SETTINGS,
    QUICK_METRICS,
    QUICK_SETTINGS,
)
from dynoplan.envs.gear.peg_pose import PEG_WORKSPACE
from dynoplan.envs.gear.pipeline_task import GearTask
from dynoplan.envs.gear.state import PlannerState
from dynoplan.envs.gear.task_fit import (
    DEMOS,
    check_options_folder,
    fit_and_evaluate,
    task_settings,
)
from dynoplan.errors import DynoplanError
from dynoplan.io import write_json
from dynoplan.parallel import SERIAL, Workers, parse_workers
from dynoplan.pipeline.collect import OptionRunSettings
from dynoplan.pipeline.run_settings import run_seeds
from dynoplan.pipeline.task_fit import RUNS_FOLDER

RUNS = OptionRunSettings(runs=40, max_decisions=30, lead_decisions=0)
"""The retrained dynamics' option runs: ``gear run``'s collect stage
(:data:`~dynoplan.envs.gear.pipeline_stages.TRANSITION_RUNS`)."""
QUICK_RUNS = OptionRunSettings(runs=4, max_decisions=15, lead_decisions=0)
"""The retrained dynamics' option runs under ``--quick``."""
ROWS = ("shared", "shared-frame", "retrained")
"""The downstream task's rows, in the table's order (the default)."""
REFERENCE = "first-task"
"""The first task through the same task fit (a reference row, on request)."""


def run(options_models: Path, out: Path, seed: int, episodes: int, demos: int = DEMOS,
        rows: tuple[str, ...] = ROWS, quick: bool = False, workers: Workers = SERIAL,
        command: str = "", progress: bool = True,
        task_improve: int | None = None, task_initiation: bool = False,
        region_features: str | None = None) -> dict[str, Any]:
    """Every stage (module docstring) into ``out``; the content of ``results.json``.
    ``task_improve``: the improvement rounds of every row's task fit (``None``: the
    library's default); ``task_initiation``: every row reuses the options folder's
    initiation learned from outcome runs (the library's default does not);
    ``region_features``: the feature map every row's regions read (``None``: the task's,
    :func:`~dynoplan.envs.gear.task_fit.task_settings`)."""
    from dynoplan.envs.gear.demonstrations import record_demos
    from dynoplan.envs.gear.learning.training import train_gear_models
    from dynoplan.envs.gear.option_runs import collect_gear_transitions

    unknown = [r for r in rows if r not in (*ROWS, REFERENCE)]
    if unknown or not rows:
        raise DynoplanError(f"unknown rows {', '.join(unknown) or '(none)'}; expected some of "
                            f"{', '.join((*ROWS, REFERENCE))}")
    settings = task_settings(seed, episodes, demos, quick)
    if task_improve is not None:
        settings = replace(settings, improve=task_improve)
    if region_features is not None:
        settings = replace(settings, fit=replace(
            settings.fit, region_features=feature_map(region_features).name))
    settings.validate()
    networks = check_options_folder(options_models)
    out.mkdir(parents=True, exist_ok=True)
    seeds = run_seeds(seed)
    peg_task = GearTask(peg=PEG_WORKSPACE)
    seconds: dict[str, float] = {}

    def stage(name: str, done: Path, fn: Any) -> None:
        if done.exists():
            print(f"-- {name}: kept {done}", file=sys.stderr)
            return
        print(f"-- {name}", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        fn()
        seconds[name] = time.perf_counter() - t0

    stage("demonstrations", out / "demos" / "data", lambda: record_demos(
        demos, seeds["demos"], out / "demos", progress, demonstrator="options",
        models=networks, workers=workers, peg=PEG_WORKSPACE))
    for row, frame in (("shared", False), ("shared-frame", True)):
        if row in rows:
            stage(row, out / row / "summary.json", lambda f=frame, r=row: fit_and_evaluate(
                options_models, networks, out / "demos", out / r, settings, workers, command,
                progress=progress, peg_frame=f, reuse_initiation=task_initiation))
    if "retrained" in rows:
        own = out / "retrain"
        collect = QUICK_RUNS if quick else RUNS
        stage("retrain: option runs", own / RUNS_FOLDER / "data",
              lambda: collect_gear_transitions(networks, collect.runs, seed, own / RUNS_FOLDER,
                                               collect.max_decisions, progress, workers,
                                               task=peg_task))
        stage("retrain: held-out trials", own / "heldout" / "data", lambda: record_demos(
            QUICK_METRICS.heldout_episodes if quick else demos,
            seeds["demos"] + HELDOUT_SEED_OFFSET, own / "heldout", progress,
            demonstrator="options", models=networks, workers=workers, peg=PEG_WORKSPACE))
        stage("retrain: dynamics", own / "models" / "models.json", lambda: train_gear_models(
            out / "demos", own / RUNS_FOLDER, own / "models", seed, own / "heldout", quick,
            progress, settings=QUICK_SETTINGS if quick else DEFAULT_SETTINGS,
            measures=QUICK_METRICS if quick else DEFAULT_METRICS))
        first_runs = options_models / RUNS_FOLDER
        stage("retrained", out / "retrained" / "summary.json", lambda: fit_and_evaluate(
            own, networks, out / "demos", out / "retrained", settings, workers, command,
            runs=first_runs if first_runs.is_dir() else None, progress=progress,
            reuse_initiation=task_initiation))
    if REFERENCE in rows:
        stage(REFERENCE, out / REFERENCE / "summary.json", lambda: fit_and_evaluate(
            options_models, networks, options_models / "demos", out / REFERENCE, settings,
            workers, command, progress=progress, first_task=True,
            reuse_initiation=task_initiation))
    summaries = {row: json.loads((out / row / "summary.json").read_text())
                 for row in (*ROWS, REFERENCE) if (out / row / "summary.json").is_file()}
    results = {"command": command, "seed": seed, "episodes": episodes, "demos": demos,
               "quick": quick, "options_models": str(options_models.resolve()),
               "task_improve": settings.improve, "task_initiation": task_initiation,
               "region_features": settings.fit.region_features,
               "stage_seconds": seconds,
               "rows": {name: _row(summary, out / name) for name, summary in summaries.items()}}
    (out / "results.json").write_text(json.dumps(results, indent=2) + "\n")
    (out / "results.md").write_text(_table(results))
    return results


def one_step_errors(models: Path, demos: Path, frame: bool = False
                    ) -> dict[str, dict[str, float]]:
    """Per option, over the decisions of ``demos`` (a gear dataset) that it ran whole: the
    median error (cm) of the dynamics of ``models`` (the ensemble's mean, one decision
    ahead) in the gear's bottom and the tool point, how far the gear really moved (cm),
    and the median of each input's largest distance from the dynamics' training mean in
    training standard deviations (``frame``: through
    :class:`~dynoplan.envs.gear.peg_pose.PegFrame`)."""
    import numpy as np

    from dynoplan.data import read_dataset
    from dynoplan.envs.gear.options.catalog import gear_option_names
    from dynoplan.envs.gear.peg_pose import PegFrame
    from dynoplan.envs.gear.state import DECISION_STEPS
    from dynoplan.pipeline.fit import FittedModels

    folder = models / "models" if (models / "models").is_dir() else models
    dynamics = FittedModels.load(folder, FEATURE_MAPS).dynamics
    planner, names = PlannerState(), list(gear_option_names())
    pairs: dict[str, list[tuple[Any, Any]]] = {n: [] for n in names}
    for episode in read_dataset(demos):
        states, labels = planner(episode.observations), np.asarray(episode.infos["option"])
        for t in range(0, len(labels) - DECISION_STEPS + 1, DECISION_STEPS):
            if (labels[t:t + DECISION_STEPS] == labels[t]).all():
                pairs[names[labels[t]]].append((states[t], states[t + DECISION_STEPS]))
    out: dict[str, dict[str, float]] = {}
    peg = PegFrame() if frame else None
    for name, found in pairs.items():
        if not found or name not in dynamics:
            continue
        x, y = (np.array(a) for a in zip(*found, strict=True))
        model = dynamics[name]
        seen = x if peg is None else peg.to_option(x)
        mean = model.predict(seen)[0].mean(axis=0)  # type: ignore[attr-defined]
        predicted = mean if peg is None else peg.to_planner(x, mean)
        z = np.abs((seen - model.input_mean) / model.input_std).max(axis=1)  # type: ignore[attr-defined]
        out[name] = {
            "decisions": len(x),
            "gear_cm": float(np.median(np.linalg.norm(predicted[:, 16:19] - y[:, 16:19],
                                                      axis=1)) * 100),
            "tool_cm": float(np.median(np.linalg.norm(predicted[:, 13:16] - y[:, 13:16],
                                                      axis=1)) * 100),
            "gear_moved_cm": float(np.median(np.linalg.norm(y[:, 16:19] - x[:, 16:19],
                                                            axis=1)) * 100),
            "input_max_z": float(np.median(z))}
    return out


def print_one_step_errors(options_models: Path, out: Path) -> None:
    """The table of :func:`one_step_errors` for a finished ``out``."""
    cases = [("the first task's, on its own held-out trials", options_models,
              options_models / "heldout", False),
             ("the first task's, plain", options_models, out / "demos", False),
             ("the first task's, in its frame", options_models, out / "demos", True),
             ("retrained (in-sample)", out / "retrain", out / "demos", False)]
    print("| dynamics | option | decisions | gear error (cm) | tool error (cm) | gear moved "
          "(cm) | inputs' largest z (median) |")
    print("|---|---|---|---|---|---|---|")
    for label, models, demos, frame in cases:
        if not (demos / "data").is_dir() or not models.is_dir():
            continue
        for name, e in one_step_errors(models, demos, frame).items():
            print(f"| {label} | {name} | {e['decisions']:.0f} | {e['gear_cm']:.2f} | "
                  f"{e['tool_cm']:.2f} | {e['gear_moved_cm']:.2f} | {e['input_max_z']:.3g} |")


def script_success(options_models: Path, out: Path, seed: int, episodes: int,
                   workers: Workers = SERIAL) -> dict[str, dict[str, Any]]:
    """The fixed script's summary in the first task and in the downstream task, on the
    evaluation episodes of the rows (seed ``seed``, ``episodes`` of them): how well the
    options themselves do the two tasks (the models folders are the rows', for the
    out-of-region count; the script ignores them)."""
    from dynoplan.pipeline.evaluate import ControllerJob, summarize
    from dynoplan.pipeline.jobs import evaluate_many
    from dynoplan.seeding import episode_seeds

    networks = check_options_folder(options_models).resolve()
    seeds = episode_seeds(run_seeds(seed)["evaluation"], episodes)
    control = task_settings(seed, episodes, DEMOS, False).control
    jobs = {"first task": ControllerJob(GearTask(networks=networks),
                                        out / REFERENCE / "models", "fixed_script", control),
            "downstream task": ControllerJob(GearTask(peg=PEG_WORKSPACE, networks=networks),
                                             out / "shared" / "models", "fixed_script",
                                             control)}
    for job in jobs.values():
        if not (job.models / "models.json").is_file():
            raise DynoplanError(f"{job.models}: run the shared and {REFERENCE} rows first")
    done = evaluate_many([(job, seeds) for job in jobs.values()], workers, "fixed script",
                         True)
    return {name: summarize(records) for name, records in zip(jobs, done, strict=True)}


def demonstrator_success(options_models: Path, seed: int, episodes: int,
                         workers: Workers = SERIAL) -> dict[str, dict[str, Any]]:
    """The demonstrator's success in the first task and in the downstream task, on the
    evaluation episodes of the rows (seed ``seed``, ``episodes`` of them; each episode's
    own human mode): the operator that records the task's demonstrations
    (:class:`~dynoplan.envs.gear.operator.OptionOperator`, chaining the option policies of
    ``options_models`` by hand-written rules), every episode kept, failed or not. The
    round's principle: the demonstrator, not the best single option, is the bar."""
    import numpy as np

    from dynoplan.envs.gear.demonstrations import (
        DemoJob,
        build_demonstrator,
        demonstrated_episode,
        episode_seeds,
        succeeded,
    )
    from dynoplan.parallel import parallel_map

    networks = check_options_folder(options_models).resolve()
    seeds = episode_seeds(run_seeds(seed)["evaluation"], episodes)
    found: dict[str, dict[str, Any]] = {}
    for name, peg in (("first task", None), ("downstream task", PEG_WORKSPACE)):
        raw = parallel_map(build_demonstrator, demonstrated_episode,
                           DemoJob("options", networks, peg), [(s, None) for s in seeds],
                           workers, f"demonstrator, {name}", True)
        ok = [bool(succeeded(r)) for r in raw]
        found[name] = {"episodes": len(ok), "success_rate": float(np.mean(ok)),
                       "steps_mean": float(np.mean([len(r["actions"]) for r in raw]))}
    return found


def _row(summary: dict[str, Any], folder: Path) -> dict[str, Any]:
    fit = summary["task_fit"]
    manifest = json.loads((folder / "models" / "models.json").read_text())
    dynoplan = summary["controllers"]["dynoplan"]
    return {"success_rate": dynoplan["success_rate"], "episodes": dynoplan["episodes"],
            "dynamics": fit["options_models"], "demonstrations": fit["demonstrations"],
            "demonstration_steps": fit["demonstration_steps"],
            "goal_fit_seconds": fit["goal_fit_seconds"], "fit_seconds": fit["fit_seconds"],
            "improvement": fit.get("improvement"),
            "reused_initiation": bool(fit.get("reused_initiation")),
            "option_runs": fit["option_runs"], "goal_sha256": manifest["goal"]["sha256"],
            "regions_sha256": (manifest.get("regions") or {}).get("sha256"),
            "dynamics_sha256": {n: d["sha256"] for n, d in manifest["dynamics"].items()}}


def _table(results: dict[str, Any]) -> str:
    lines = [f"Produced by `{results['command']}`.", "",
             "| dynamics | DynoPlan success | episodes | the task's demonstrations (steps) "
             "| the goal fit of the models kept (s) | the first fit: goal and regions (s) "
             "| the improvement round (s) | the options' learned initiation |",
             "|---|---|---|---|---|---|---|---|"]
    names = {"shared": "the first task's, unchanged",
             "shared-frame": "the first task's, unchanged, in the first task's frame",
             "retrained": "retrained on the task",
             REFERENCE: "the first task itself, its own dynamics (reference)"}
    for name, row in results["rows"].items():
        lines.append(f"| {names[name]} | {row['success_rate']:.2f} | {row['episodes']} | "
                     f"{row['demonstrations']} ({row['demonstration_steps']}) | "
                     f"{row['goal_fit_seconds']:.1f} | {row['fit_seconds']:.1f} | "
                     + ("-" if row.get("improvement") is None else
                        f"{row['improvement']['seconds']:.1f}")
                     + (" | reused |" if row.get("reused_initiation") else " | - |"))
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.transfer.gear_peg_task",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--options-models", type=Path, required=True,
                        help="the first task's options folder (a dynoplan gear run --out)")
    parser.add_argument("--out", type=Path, default=Path("results/gear-peg-task"))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--demos", type=int, default=DEMOS)
    parser.add_argument("--rows", default=",".join(ROWS),
                        help=f"comma-separated rows among {', '.join(ROWS)} [all], and "
                             f"{REFERENCE}")
    parser.add_argument("--quick", action="store_true", help="small settings (a smoke test)")
    parser.add_argument("--task-improve", type=int, default=None,
                        help="improvement rounds of every row's task fit (0: its "
                             "demonstrations alone) [the library's default, 1]")
    parser.add_argument("--region-features", default=None,
                        help="the feature map every row's regions read [the task's: "
                             "relative]")
    parser.add_argument("--demonstrator", action="store_true",
                        help="the demonstrator (the operator) in both tasks on the rows' "
                             "episodes")
    parser.add_argument("--task-initiation", action="store_true",
                        help="every row reuses the options folder's initiation learned "
                             "from outcome runs [off, the library's default]")
    parser.add_argument("--workers", default="1", help="1, N (Ray) [1]")
    parser.add_argument("--quiet", action="store_true")
    parser.add_argument("--one-step-errors", action="store_true",
                        help="print the options' one-step errors of a finished --out")
    parser.add_argument("--script", action="store_true",
                        help="the fixed script in both tasks on the rows' episodes")
    args = parser.parse_args(argv)
    command = "python -m benchmarks.transfer.gear_peg_task " + " ".join(
        shlex.quote(a) for a in (argv if argv is not None else sys.argv[1:]))
    try:
        if args.episodes < 1 or args.demos < 1:
            raise DynoplanError("--episodes and --demos must be >= 1")
        if args.one_step_errors:
            print_one_step_errors(args.options_models, args.out)
            return 0
        if args.script:
            found = script_success(args.options_models, args.out, args.seed, args.episodes,
                                   parse_workers(args.workers, None))
            write_json(args.out / "script.json", found)
            for name, summary in found.items():
                print(f"{name}: fixed script success {summary['success_rate']:.2f} of "
                      f"{summary['episodes']} episodes")
            return 0
        if args.demonstrator:
            found = demonstrator_success(args.options_models, args.seed, args.episodes,
                                         parse_workers(args.workers, None))
            args.out.mkdir(parents=True, exist_ok=True)
            write_json(args.out / "demonstrator.json", found)
            for name, summary in found.items():
                print(f"{name}: demonstrator success {summary['success_rate']:.2f} of "
                      f"{summary['episodes']} episodes")
            return 0
        rows = tuple(r for r in args.rows.split(",") if r)
        results = run(args.options_models, args.out, args.seed, args.episodes, args.demos,
                      rows, args.quick, parse_workers(args.workers, None),
                      command, progress=not args.quiet, task_improve=args.task_improve,
                      task_initiation=args.task_initiation,
                      region_features=args.region_features)
    except DynoplanError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(_table(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
