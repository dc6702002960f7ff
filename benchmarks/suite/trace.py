"""DynoPlan's episodes on a suite run's fitted models, decision by decision.

Usage (from the repository root)::

    python -m benchmarks.suite.trace results/suite panda-stack 1
    python -m benchmarks.suite.trace results/suite panda-stack 1 --decisions 1,11
    python -m benchmarks.suite.trace results/suite cartpole-move 0 --disturbed
    python -m benchmarks.suite.trace results/suite lunar-lander 3 --starts

For one task and seed of the suite run ``RUN`` (the ``--out`` of :mod:`benchmarks.suite`)
this loads ``RUN/<task>/seed<s>/models``, builds DynoPlan as the evaluation does (with
``--set control.*`` settings as :mod:`benchmarks.suite.rerun` takes them, and with the
goal heuristic fitted again for ``--set fit.goal_*`` as it fits it) and runs it on
the run's own seeded evaluation episodes (``--disturbed``: under the task's
disturbance). It prints one line per episode: its index, whether it succeeded, its
steps and the options it ran, each with its number of steps (``hold``: no option ran).
For the episodes named by ``--decisions`` it prints every decision first: the step it
was made at, the goal heuristic there, the option chosen (``-``: a hold), its steps and
why it stopped, and the score of every option the planner judged admissible.
"""

import argparse
import os
import sys
from pathlib import Path

import numpy as np

from benchmarks.suite.__main__ import parse_sets
from benchmarks.suite.rerun import load_run_seed, refit_goal, split_sets
from dynoplan.control.controller import EpisodeTrace
from dynoplan.data import read_dataset
from dynoplan.errors import DynoplanError
from dynoplan.pipeline.config import pipeline_settings
from dynoplan.pipeline.evaluate import (
    DYNOPLAN,
    ControllerRunner,
    learned_regions,
    make_controller,
    planning_settings,
)
from dynoplan.seeding import episode_seeds


def option_runs(trace: EpisodeTrace) -> str:
    """The options ``trace`` ran, consecutive decisions of one option merged:
    ``reach:9 grasp:1 hold:3`` (steps each)."""
    runs: list[tuple[str, int]] = []
    for d in trace.decisions:
        name = d.option or "hold"
        if runs and runs[-1][0] == name:
            runs[-1] = (name, runs[-1][1] + d.steps)
        else:
            runs.append((name, d.steps))
    return " ".join(f"{name}:{steps}" for name, steps in runs)


def decision_lines(trace: EpisodeTrace, goal_means: "np.ndarray") -> list[str]:
    """One line per decision of ``trace``; ``goal_means`` ``(decisions,)`` is the goal
    heuristic at each decision's state."""
    lines = []
    for d, g in zip(trace.decisions, goal_means, strict=True):
        scores = " ".join(f"{n}={v:.3f}" for n, v in zip(d.plan.option_names, d.plan.scores,
                                                          strict=True) if np.isfinite(v))
        lines.append(f"  step {d.env_step:4d}  G {g:.3f}  {d.option or '-':>14s} "
                     f"{d.steps:4d} {d.stop_reason:12s} | {scores}")
    return lines


def _values(state: "np.ndarray") -> str:
    """A state as ``[0.33 -0.12 ...]``, two decimals."""
    return np.array2string(np.asarray(state, dtype=np.float64).ravel(), precision=2,
                           suppress_small=True, max_line_width=10_000)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.suite.trace",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path, help="a suite run's --out folder")
    parser.add_argument("task", help="the task's name")
    parser.add_argument("seed", type=int, help="one of the run's seeds")
    parser.add_argument("--decisions", default="", metavar="I,J",
                        help="episodes (indices) whose every decision is printed")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="a controller setting (control.*), or a goal setting "
                             "(fit.goal_*: the goal heuristic is fitted again)")
    parser.add_argument("--disturbed", action="store_true",
                        help="under the task's disturbance")
    parser.add_argument("--starts", action="store_true",
                        help="print where each demonstration and each episode started "
                             "(the first observation; the episodes': the first decision's "
                             "state)")
    args = parser.parse_args(argv)
    try:
        goal_sets, control = split_sets(parse_sets(args.set))
        settings = pipeline_settings(control)
        wanted = {int(i) for i in args.decisions.split(",") if i.strip()}
        loaded = load_run_seed(args.run, args.task, args.seed, args.disturbed)
        task, summary, rows, fitted = loaded.task, loaded.summary, loaded.rows, loaded.fitted
        if goal_sets:  # the goal heuristic fitted again, as the rerun fits it
            fitted = refit_goal(fitted, loaded.folder, summary, goal_sets, 0)
        options, planner_options = fitted.build(task.module.make_options())
        env = task.make_env(disturbed=args.disturbed)
        controller = make_controller(DYNOPLAN, options, fitted.goal,
                                     planning_settings(settings.control, fitted),
                                     planner_options, env.action_space, fitted.state_scale)
        runner = ControllerRunner(env, controller, regions=learned_regions(fitted))
        seeds = episode_seeds(summary["seeds"]["evaluation"], int(rows[DYNOPLAN]["episodes"]))
        if args.starts:
            for k, demo in enumerate(read_dataset(loaded.folder / "demos")):
                print(f"demonstration {k} starts at {_values(demo.observations[0])}")
        successes = 0
        for seed in seeds:
            trace = runner.run(seed)
            successes += trace.success
            if seed.index in wanted:
                states = np.stack([d.state for d in trace.decisions])
                print("\n".join(decision_lines(trace, fitted.goal.mean_std(states)[0])))
            start = f" from {_values(trace.decisions[0].state)}" \
                if args.starts and trace.decisions else ""
            print(f"{seed.index} {'success' if trace.success else 'failure'} "
                  f"{trace.env_steps}{start} {option_runs(trace)}", flush=True)
        print(f"DynoPlan: {successes} of {len(seeds)} (the run's: "
              f"{rows[DYNOPLAN]['success_rate']:.2f})")
    except (DynoplanError, OSError, ValueError, KeyError) as exc:
        print(f"trace: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    os.environ.setdefault("MUJOCO_GL", "egl")
    sys.exit(main())
