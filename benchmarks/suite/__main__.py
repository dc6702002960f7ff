"""The composition suite: every task over several seeds on one set of settings.

Usage (from the repository root)::

    python -m benchmarks.suite --seeds 0,1,2 --episodes 30 --out results/suite
    python -m benchmarks.suite --tasks lunar-lander --set control.horizon=40 --out ...

For every task (:mod:`benchmarks.suite.registry`) and seed it runs the generic pipeline
(:func:`dynoplan.pipeline.run_pipeline`) on the library's default settings, with only the
task's environment, options, demonstrator, success and state functions given, into
``OUT/<task>/seed<s>/``; then it evaluates the demonstrator and DynoPlan again on the same
seeded episodes under the task's disturbance. ``--set KEY=VALUE`` changes a setting for
every task alike (a key of ``dynoplan pipeline --config``: ``demos``, ``fit.stride``,
``control.horizon``, ...): the ablations. A task whose package is missing is skipped with
one line.

Writes ``OUT/suite.json`` (every number) and ``OUT/suite.md``: per task, the
demonstrator, DynoPlan, the best option alone and random choice on every seed, the
composition ratio (DynoPlan's mean success over the demonstrator's), the decision latency
(p50 over all DynoPlan decisions), decisions per episode, both rows under the disturbance,
the task's elapsed time (from the start of its first seed's run to the end of its last:
what the task takes on the machine at ``--jobs``), and its wall time and CPU time (each
summed over its seeds; a seed runs in one process, so on a quiet machine with ``--jobs 1``
the two agree, and the CPU time stays what the task costs when other work shares the
cores). ``suite.json`` also holds the whole command's elapsed time.
"""

import argparse
import os
import sys
import time
import tomllib
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.suite.registry import SuiteEntry, select
from dynoplan.errors import DynoplanError, DynoplanWarning
from dynoplan.io import ensure_writable_dir, write_json, write_text
from dynoplan.pipeline import evaluate_controllers, run_pipeline
from dynoplan.pipeline.config import pipeline_settings
from dynoplan.pipeline.evaluate import (
    DEMONSTRATOR,
    DYNOPLAN,
    RANDOM,
    learned_regions,
    planning_settings,
)
from dynoplan.reports.tables import markdown_table


def parse_sets(items: list[str], flag: str = "--set") -> dict[str, Any]:
    """``KEY=VALUE`` pairs, each value read as a TOML value (a bare word as a string);
    ``flag`` names the option in errors."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        if not sep or not key:
            raise DynoplanError(f"{flag} {item!r}: expected KEY=VALUE")
        try:
            out[key] = tomllib.loads(f"v = {text}")["v"]
        except tomllib.TOMLDecodeError:
            out[key] = text
    return out


def run_one(entry: SuiteEntry, seed: int, episodes: int, sets: dict[str, Any],
            out: Path) -> dict[str, Any]:
    """One task on one seed: the pipeline's summary, the disturbed rows, the wall time
    (``wall_s``), this process's CPU time (``cpu_s``: what the run costs whatever else
    shares the machine) and when the run started and ended (``span``: seconds since the
    epoch), as written to ``out/suite-run.json``."""
    import torch

    torch.set_num_threads(1)
    task = entry.load()
    settings = pipeline_settings({**sets, "episodes": episodes, "seed": seed})
    began = time.time()
    started, cpu_started = time.perf_counter(), time.process_time()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DynoplanWarning)
        result = run_pipeline(task.make_env(), task.module.make_options(),
                              demonstrator=task.module.make_demonstrator(),
                              settings=settings, out=out, task=task.gym_task,
                              disturbed_env=(task.make_env(disturbed=True)
                                             if settings.improve_disturbed else None),
                              command=f"python -m benchmarks.suite ({entry.name}, seed {seed})")
        disturbed = evaluate_controllers(
            task.make_env(disturbed=True), result.options, result.models.goal,
            planning_settings(settings.control, result.models), settings.episodes,
            result.summary["seeds"]["evaluation"],
            result.planner_options, [DEMONSTRATOR, DYNOPLAN],
            regions=learned_regions(result.models),
            demonstrator=task.module.make_demonstrator(),
            state_scale=result.models.state_scale,
            fresh_env=lambda: task.make_env(disturbed=True))
    run = {"task": entry.name, "seed": seed, "wall_s": time.perf_counter() - started,
           "cpu_s": time.process_time() - cpu_started, "span": [began, time.time()],
           "controllers": result.summary["controllers"],
           "composition_ratio": result.summary["composition_ratio"],
           "disturbed": disturbed, "disturbance": task.module.DISTURBANCE,
           "warnings": sorted({str(w.message) for w in caught
                               if issubclass(w.category, DynoplanWarning)}),
           "stage_seconds": result.summary["stage_seconds"]}
    write_json(out / "suite-run.json", run)
    return run


def _job(args: tuple[SuiteEntry, int, int, dict[str, Any], Path]) -> dict[str, Any]:
    return run_one(*args)


def task_row(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """One task's line of the suite table from its runs (one per seed)."""
    def rates(name: str, rows: str = "controllers") -> list[float]:
        return [float(r[rows][name]["success_rate"]) for r in runs]

    options = [n for n in runs[0]["controllers"] if n.startswith("option:")]

    def best_option(run: dict[str, Any]) -> str:
        return max(options, key=lambda n: float(run["controllers"][n]["success_rate"]))

    best = [float(r["controllers"][best_option(r)]["success_rate"]) for r in runs]
    demo, plan = rates(DEMONSTRATOR), rates(DYNOPLAN)
    latencies = [r["controllers"][DYNOPLAN]["latency_ms_p50"] for r in runs]
    return {
        "task": runs[0]["task"], "seeds": [r["seed"] for r in runs],
        "demonstrator": demo, "dynoplan": plan, "best_option": best,
        "best_option_names": [best_option(r) for r in runs],
        "random": rates(RANDOM),
        "composition_ratio": float(np.mean(plan) / np.mean(demo)) if np.mean(demo) else None,
        "latency_ms_p50": float(np.median([x for x in latencies if x is not None]))
        if any(x is not None for x in latencies) else None,
        "decisions_mean": float(np.mean([r["controllers"][DYNOPLAN]["decisions_mean"]
                                         for r in runs])),
        "disturbed_demonstrator": rates(DEMONSTRATOR, "disturbed"),
        "disturbed_dynoplan": rates(DYNOPLAN, "disturbed"),
        "elapsed_s": float(max(r["span"][1] for r in runs) - min(r["span"][0] for r in runs)),
        "wall_s": float(sum(r["wall_s"] for r in runs)),
        "cpu_s": float(sum(r["cpu_s"] for r in runs)),
        "dynoplan_option_share": [r["controllers"][DYNOPLAN]["option_share"] for r in runs],
    }


def _seeds(values: list[float]) -> str:
    return " / ".join(f"{v:.2f}" for v in values)


def suite_table(rows: list[dict[str, Any]]) -> str:
    """The suite as a markdown table: success per seed (``s0 / s1 / s2``)."""
    return markdown_table(
        [{**r, **{k: _seeds(r[k]) for k in ("demonstrator", "dynoplan", "best_option",
                                            "random", "disturbed_demonstrator",
                                            "disturbed_dynoplan")},
          "best_option": _seeds(r["best_option"]) + f" ({r['best_option_names'][0]})",
          **{k: f"{r[k]:.0f}" for k in ("elapsed_s", "wall_s", "cpu_s")}} for r in rows],
        ["task", "demonstrator", "dynoplan", "composition_ratio", "best_option", "random",
         "disturbed_demonstrator", "disturbed_dynoplan", "latency_ms_p50",
         "decisions_mean", "elapsed_s", "wall_s", "cpu_s"],
        ["task", "demonstrator", "DynoPlan", "composition ratio", "best option alone",
         "random", "demonstrator, disturbed", "DynoPlan, disturbed",
         "decision p50 (ms)", "decisions / episode", "elapsed (s)", "wall, seeds' sum (s)",
         "CPU (s)"])


def _commit() -> str | None:
    """The commit of the checkout the ``dynoplan`` library was imported from (which
    ``PYTHONPATH`` may point at a snapshot other than this script's), with ``+`` when its
    work tree has changes (``None`` outside a git checkout)."""
    import subprocess

    import dynoplan

    root = Path(dynoplan.__file__).resolve().parents[2]
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root,
                              capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=root, capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return None
    return head + ("+" if dirty.strip() else "")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.suite",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", help="comma-separated task names [all]")
    parser.add_argument("--seeds", default="0,1,2", help="comma-separated seeds [0,1,2]")
    parser.add_argument("--episodes", type=int, default=30,
                        help="evaluation episodes per controller and seed [30]")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="a pipeline setting for every task (repeatable)")
    parser.add_argument("--jobs", type=int, default=1,
                        help="runs side by side (processes) [1]; latencies are measured "
                             "with 1")
    parser.add_argument("--out", type=Path, default=Path("results/suite"))
    args = parser.parse_args(argv)
    began = time.perf_counter()
    try:
        entries = select(args.tasks)
        seeds = [int(s) for s in args.seeds.split(",")]
        sets = parse_sets(args.set)
        pipeline_settings({**sets, "episodes": args.episodes})  # a mistake before any work
        out = ensure_writable_dir(args.out)
        available = []
        for entry in entries:
            reason = entry.missing()
            if reason is not None:
                print(reason, file=sys.stderr)
            else:
                available.append(entry)
        jobs = [(e, s, args.episodes, sets, out / e.name / f"seed{s}")
                for e in available for s in seeds]
        if args.jobs > 1:
            with ProcessPoolExecutor(args.jobs) as pool:
                runs = list(pool.map(_job, jobs))
        else:
            runs = [_job(j) for j in jobs]
    except DynoplanError as exc:
        print(f"suite: error: {exc}", file=sys.stderr)
        return 2
    rows = [task_row([r for r in runs if r["task"] == e.name]) for e in available]
    command = "python -m benchmarks.suite " + " ".join(sys.argv[1:] if argv is None else argv)
    write_json(out / "suite.json", {"command": command, "commit": _commit(), "settings": sets,
                                    "episodes": args.episodes, "seeds": seeds,
                                    "jobs": args.jobs,
                                    "elapsed_s": time.perf_counter() - began,
                                    "tasks": rows, "runs": runs})
    table = suite_table(rows) if rows else "no task ran\n"
    write_text(out / "suite.md", f"Produced by `{command}` at {_commit()}.\n\n{table}")
    print(table)
    return 0


if __name__ == "__main__":
    os.environ.setdefault("MUJOCO_GL", "egl")
    sys.exit(main())
