"""Meta-World tasks over one option set whose dynamics are learned once (issue 32).

The paper: "The dynamics can be learned independently of the task, and can be used to
solve a downstream task." Here one Sawyer arm, one planner state and one option set
serve four Meta-World v3 tasks:

================  ==========================================  ==============
task              what succeeds (Meta-World's ``info``)         dynamics
================  ==========================================  ==============
``reach-v3``      the hand within 5 cm of a goal in the air     seen
``pick-place-v3`` the puck within 7 cm of a goal in the air     seen
``push-v3``       the puck within 5 cm of a goal on the table   unseen
``push-back-v3``  the same, the goal towards the robot          unseen
================  ==========================================  ==============

The option dynamics are fitted once, on exploration runs and demonstrations of the two
*seen* tasks only (:data:`TRAIN`, pooled in :data:`TRAIN_ENV_ID`, an environment that
draws the task of each episode from its seed); each task then brings only its own goal
heuristic (and regions), fitted from its own demonstrations by
:func:`dynoplan.pipeline.task_fit.run_task` (``dynoplan task fit``).

The environments are made as the suite's
:mod:`benchmarks.suite.tasks.metaworld_pick_place` makes them (``metaworld.MT1`` and its
:class:`~benchmarks.suite.tasks.metaworld_pick_place.SeededTask`, so ``reset(seed=s)``
is reproducible), with a limit of :data:`MAX_STEPS` steps; success is Meta-World's own
``info["success"]`` of each task (:func:`success`).

The planner state (:func:`state`, the same for every task) is 10 values of the
39-value observation:

========  =====================================================
0:3       hand position (m)
3         gripper opening (1 open, about 0.45 closed on the puck)
4:7       the object's position (m): the puck in all four tasks
7:10      goal position (m)
========  =====================================================

Options (:func:`make_options`): ``reach`` (open the gripper, take the hand to the goal)
and the suite's pick-place chain ``hover``, ``descend``, ``grasp``, and ``carry`` (keep
the gripper closed, bring the puck to the goal), each done when its job is done (else
with probability 2 % per step). In every task some of them are distractors: the chain in
``reach-v3``, ``reach`` in the others. The demonstrators (:func:`make_demonstrator`)
are ``reach`` alone, and the suite's pick-place script for the three puck tasks.

Run everything (shared dynamics, each task on them, each task refitted on its own data,
the table) with ``python -m benchmarks.transfer.metaworld_tasks --out DIR``; without the
``metaworld`` package it prints one line and exits.
"""

import argparse
import importlib.util
import json
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from benchmarks.suite.tasks.metaworld_pick_place import CLOSE, OPEN, move_hand
from dynoplan.adapters import OptionSpec, option_spec
from dynoplan.pipeline import Demonstrator

TASKS = ("reach-v3", "pick-place-v3", "push-v3", "push-back-v3")
"""Every task solved, in the table's order."""
TRAIN = ("reach-v3", "pick-place-v3")
"""The tasks whose runs the option dynamics are fitted on."""
ENV_IDS = {"reach-v3": "MWSharedReach-v3", "pick-place-v3": "MWSharedPickPlace-v3",
           "push-v3": "MWSharedPush-v3", "push-back-v3": "MWSharedPushBack-v3"}
TRAIN_ENV_ID = "MWSharedTrain-v3"
"""The seen tasks pooled: each episode's task drawn from the seed of ``reset``."""
MAX_STEPS = 150
"""Steps per episode (Meta-World allows 500; the demonstrators need at most about 70)."""

HAND = slice(0, 3)  # where the observation has it too: the suite's move_hand reads it there
GRIPPER = 3
OBJECT = slice(4, 7)
GOAL = slice(7, 10)
REACHED = 0.02
"""m: distance from hand to goal at which ``reach`` is done."""
DELIVERED = 0.03
"""m: distance from puck to goal at which ``carry`` is done."""
BETA_RUNNING = 0.02
"""Termination probability per step of an option whose job is not done yet."""


# --- the environments --------------------------------------------------------------------


def make_task_env(task: str) -> gym.Env[Any, Any]:
    """One Meta-World task, reproducibly seeded (the suite's ``make_metaworld_env``)."""
    from benchmarks.suite.tasks.metaworld_pick_place import make_metaworld_env

    return make_metaworld_env(task)


def _union(spaces: Sequence[gym.Space[Any]]) -> gym.spaces.Box:
    boxes = [s for s in spaces if isinstance(s, gym.spaces.Box)]
    low = np.min([s.low for s in boxes], axis=0)
    high = np.max([s.high for s in boxes], axis=0)
    return gym.spaces.Box(low, high, dtype=np.float64)


class TaskPerEpisode(gym.Env[Any, Any]):
    """Several Meta-World tasks of one arm as one environment: ``reset(seed=s)`` draws the
    episode's task from ``default_rng([s, 1])`` (then that task's own seeded reset), so a
    seed gives the same task and the same first observation; ``info["task"]`` names it."""

    def __init__(self, tasks: Sequence[str]) -> None:
        self.tasks = list(tasks)
        self.envs = [make_task_env(t) for t in self.tasks]
        self.observation_space = _union([e.observation_space for e in self.envs])
        self.action_space = self.envs[0].action_space
        self._rng = np.random.default_rng()
        self._current = 0

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        if seed is not None:
            self._rng = np.random.default_rng([seed, 1])
        self._current = int(self._rng.integers(len(self.envs)))
        observation, info = self.envs[self._current].reset(seed=seed, options=options)
        return observation, {**info, "task": self.tasks[self._current]}

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = self.envs[self._current].step(action)
        return observation, reward, terminated, truncated, {**info,
                                                            "task": self.tasks[self._current]}

    def close(self) -> None:
        for env in self.envs:
            env.close()


def make_train_env(**kwargs: Any) -> gym.Env[Any, Any]:
    """The seen tasks (:data:`TRAIN`) pooled in one environment (:class:`TaskPerEpisode`)."""
    return TaskPerEpisode(TRAIN)


def _maker(task: str) -> Callable[..., gym.Env[Any, Any]]:
    def make(**kwargs: Any) -> gym.Env[Any, Any]:
        return make_task_env(task)

    return make


def register() -> None:
    """Register :data:`ENV_IDS` and :data:`TRAIN_ENV_ID` (each :data:`MAX_STEPS` steps)."""
    for task, env_id in ENV_IDS.items():
        if env_id not in gym.registry:
            gym.register(env_id, entry_point=_maker(task), max_episode_steps=MAX_STEPS)
    if TRAIN_ENV_ID not in gym.registry:
        gym.register(TRAIN_ENV_ID, entry_point=make_train_env, max_episode_steps=MAX_STEPS)


register()


def success(observation: Any, info: dict[str, Any]) -> bool:
    """Meta-World's own success of whichever task runs: ``info["success"]`` (1.0)."""
    return bool(info.get("success", 0.0) >= 1.0)


def state(observation: Any) -> np.ndarray:
    """The planner state of every task: hand, gripper, object and goal (10 values)."""
    o = np.asarray(observation, dtype=np.float64)
    return np.concatenate([o[0:7], o[36:39]])


# --- the options -------------------------------------------------------------------------


def reach(s: Any) -> np.ndarray:
    """Open the gripper and take the hand to the goal."""
    return move_hand(s, np.asarray(s[GOAL]), OPEN)


def carry(s: Any) -> np.ndarray:
    """Keep the gripper closed and move the hand so that the puck goes to the goal."""
    hand, puck = np.asarray(s[HAND]), np.asarray(s[OBJECT])
    return move_hand(s, np.asarray(s[GOAL]) + (hand - puck), CLOSE)


def reached(states: np.ndarray) -> np.ndarray:
    """The hand is within ``REACHED`` of the goal, states ``(B, 10)``."""
    return np.asarray(np.linalg.norm(states[:, HAND] - states[:, GOAL], axis=1) < REACHED)


def delivered(states: np.ndarray) -> np.ndarray:
    """The puck is within ``DELIVERED`` of the goal."""
    return np.asarray(np.linalg.norm(states[:, OBJECT] - states[:, GOAL], axis=1) < DELIVERED)


def make_options() -> list[OptionSpec]:
    """The one option set of every task: ``reach`` (done :func:`reached`), and the suite's
    ``hover``, ``descend``, ``grasp`` (done above the puck, at it, holding it: its
    functions read the same first seven values) and ``carry`` (done :func:`delivered`)."""
    from benchmarks.suite.tasks import metaworld_pick_place as pp

    return [
        option_spec("reach", reach, termination=pp.done_when(reached, BETA_RUNNING)),
        option_spec("hover", pp.hover, termination=pp.done_when(pp.above, BETA_RUNNING)),
        option_spec("descend", pp.descend, termination=pp.done_when(pp.at_puck, BETA_RUNNING)),
        option_spec("grasp", pp.grasp, termination=pp.done_when(pp.held, BETA_RUNNING)),
        option_spec("carry", carry, termination=pp.done_when(delivered, BETA_RUNNING)),
    ]


class ReachScript(Demonstrator):
    """The expert of ``reach-v3``: ``reach``."""

    def choose(self, observation: Any) -> str:
        return "reach"


def make_reach_demonstrator() -> Demonstrator:
    return ReachScript()


def make_puck_demonstrator() -> Demonstrator:
    """The expert of the puck tasks: the suite's pick-place script (carry while held,
    else grasp at the puck, descend above it, hover)."""
    from benchmarks.suite.tasks.metaworld_pick_place import PickPlaceScript

    return PickPlaceScript()


def make_demonstrator(task: str) -> Demonstrator:
    """The scripted expert of ``task``."""
    return make_reach_demonstrator() if task == "reach-v3" else make_puck_demonstrator()


# --- the experiment ----------------------------------------------------------------------


def _settings(values: dict[str, Any]) -> Any:
    from dynoplan.pipeline.config import pipeline_settings

    return pipeline_settings(values)


def fit_shared(out: Path, seed: int, demos: int, exploration: int,
               train: Sequence[str] = TRAIN) -> dict[str, Any]:
    """The options folder: ``demos`` demonstrations of every seen task of ``train``
    (recorded on its own environment) and ``exploration`` episodes of random options on
    those tasks pooled (:class:`TaskPerEpisode`), one pipeline run (its evaluation: one
    episode of random choice, unused)."""
    from dynoplan.pipeline import run_pipeline, task_env
    from dynoplan.pipeline.collect import record_demonstrations
    from dynoplan.pipeline.run_settings import run_seeds

    specs = make_options()
    started = time.perf_counter()
    pooled = []
    for task in train:
        env = task_env(gym.make(ENV_IDS[task]), success, state)
        pooled += record_demonstrations(env, specs, make_demonstrator(task), demos,
                                        run_seeds(seed)["demos"])
    settings = _settings({"seed": seed, "exploration_episodes": exploration, "episodes": 1,
                          "controllers": "random"})
    pooled_env = (gym.make(TRAIN_ENV_ID) if tuple(train) == TRAIN else
                  gym.wrappers.TimeLimit(TaskPerEpisode(train), MAX_STEPS))
    result = run_pipeline(pooled_env, specs, demos=pooled, settings=settings,
                          out=out, state_fn=state, success=success,
                          command="python -m benchmarks.transfer.metaworld_tasks (options)")
    stages = result.summary["stage_seconds"]
    return {"demonstrations": len(pooled), "exploration_episodes": exploration,
            "dynamics_seconds": stages.get("dynamics", 0.0),
            "seconds": time.perf_counter() - started}


def _row(evaluation: dict[str, Any], name: str) -> float | None:
    entry = evaluation.get(name)
    return None if entry is None else float(entry["success_rate"])


def solve_shared(task: str, options_folder: Path, out: Path, seed: int, demos: int,
                 episodes: int, runs: Path | None = None,
                 controllers: str = "demonstrator,dynoplan,random",
                 improve: int | None = None) -> dict[str, Any]:
    """``task`` on the shared dynamics: only its goal heuristic and regions are fitted
    (``dynoplan task fit``; with ``runs``, a transitions dataset, on those option runs
    in place of the options folder's: ``--runs``; ``improve``: its improvement rounds,
    ``None`` the library's default), then ``controllers``."""
    from dynoplan.pipeline.task_fit import run_task

    settings = _settings({"seed": seed, "demos": demos, "episodes": episodes,
                          "controllers": controllers,
                          **({} if improve is None else {"improve": improve})})
    what = task if runs is None else f"{task}, own runs"
    result = run_task(gym.make(ENV_IDS[task]), options_folder, make_options(),
                      demonstrator=make_demonstrator(task), settings=settings, out=out,
                      state_fn=state, success=success, runs=runs,
                      command=f"python -m benchmarks.transfer.metaworld_tasks ({what})")
    fitted = result.summary["task_fit"]
    return {"expert": _row(result.evaluation, "demonstrator"),
            "shared": _row(result.evaluation, "dynoplan"),
            "random": _row(result.evaluation, "random"),
            "demonstrations": fitted["demonstrations"], "fit_seconds": fitted["fit_seconds"],
            "improvement": fitted.get("improvement")}


def improvement_of(folder: Path) -> dict[str, Any] | None:
    """What the improvement rounds of the task fit in ``folder`` needed (its
    ``summary.json``'s ``task_fit.improvement``), ``None`` without rounds or folder."""
    summary = folder / "summary.json"
    if not summary.is_file():
        return None
    found: dict[str, Any] | None = json.loads(summary.read_text())["task_fit"].get(
        "improvement")
    return found


def solve_refit(task: str, out: Path, seed: int, demos: int, exploration: int,
                episodes: int) -> dict[str, Any]:
    """``task`` with everything fitted on its own data (``dynoplan pipeline``), DynoPlan
    on the same seeded episodes."""
    from dynoplan.pipeline import run_pipeline

    settings = _settings({"seed": seed, "demos": demos, "episodes": episodes,
                          "exploration_episodes": exploration, "controllers": "dynoplan"})
    result = run_pipeline(gym.make(ENV_IDS[task]), make_options(),
                          demonstrator=make_demonstrator(task), settings=settings, out=out,
                          state_fn=state, success=success,
                          command=f"python -m benchmarks.transfer.metaworld_tasks ({task}, "
                                  "refit)")
    stages = result.summary["stage_seconds"]
    fit_seconds = sum(stages.get(k, 0.0) for k in ("dynamics", "goal heuristic",
                                                   "safety regions"))
    return {"refit": _row(result.evaluation, "dynoplan"), "refit_demonstrations": demos,
            "refit_exploration": exploration, "refit_fit_seconds": fit_seconds}


def solve_own_runs(task: str, root: Path, seed: int, demos: int,
                   episodes: int, improve: int | None = None) -> dict[str, Any]:
    """A diagnostic: ``task`` on the shared dynamics (``root/options``), with the option
    runs of its own refit (``root/refit-TASK/transitions``: its exploration episodes) in
    place of the options folder's for its goal heuristic's off-demonstration states and
    its regions (:func:`solve_shared` with ``runs``: ``dynoplan task fit --runs``).
    Writes ``root/ownruns-TASK``."""
    row = solve_shared(task, root / "options", root / f"ownruns-{task}", seed, demos,
                       episodes, runs=root / f"refit-{task}" / "transitions",
                       controllers="dynoplan", improve=improve)
    return {"shared_own_runs": row["shared"]}


def _mean(values: Sequence[float | None]) -> str:
    real = [v for v in values if v is not None]
    return "-" if not real else f"{np.mean(real):.2f}"


def _cell(rows: list[dict[str, Any]], key: str) -> str:
    values = [r.get(key) for r in rows]
    each = " / ".join("-" if v is None else f"{v:.2f}" for v in values)
    return each if len(values) == 1 else f"{each} (mean {_mean(values)})"


def table(results: dict[str, Any]) -> str:
    """The markdown table of ``results`` (as written to ``results.json``)."""
    head = ("| task | dynamics | expert | DynoPlan, shared dynamics | DynoPlan, refitted | "
            "random | shared: task's demos, goal fit (s) | refit: demos + exploration, "
            "fit (s) | DynoPlan, shared dynamics, the task's own runs | shared: its "
            "improvement round's own episodes, demonstrator's, seconds |\n"
            "|---|---|---|---|---|---|---|---|---|---|\n")
    lines = []
    done = [s for s in results["seed_list"] if str(s) in results["seeds"]]
    train = results.get("train", TRAIN)
    for task in results["tasks"]:
        rows = [results["seeds"][str(s)][task] for s in done]
        lines.append(
            f"| {task} | {'seen' if task in train else 'unseen'} | {_cell(rows, 'expert')} | "
            f"{_cell(rows, 'shared')} | {_cell(rows, 'refit')} | {_cell(rows, 'random')} | "
            f"{rows[0]['demonstrations']}, {np.mean([r['fit_seconds'] for r in rows]):.1f} | "
            + ("- |" if rows[0]["refit_demonstrations"] is None else
               f"{rows[0]['refit_demonstrations']} + {rows[0]['refit_exploration']}, "
               f"{np.mean([r['refit_fit_seconds'] for r in rows]):.1f} |")
            + f" {_cell(rows, 'shared_own_runs')} | {_improvement_cell(rows)} |")
    shared = [results["seeds"][str(s)]["options"] for s in done]
    foot = (f"\nShared dynamics: {shared[0]['demonstrations']} demonstrations "
            f"({', '.join(train)}) + {shared[0]['exploration_episodes']} exploration "
            f"episodes, dynamics fitted in "
            f"{np.mean([s['dynamics_seconds'] for s in shared]):.1f} s (mean over seeds).\n")
    return head + "\n".join(lines) + "\n" + foot


def _improvement_cell(rows: list[dict[str, Any]]) -> str:
    """The shared task fit's improvement rounds: own episodes, the demonstrator's
    episodes (means over the seeds) and seconds (mean), ``-`` without rounds."""
    found = [r["improvement"] for r in rows if r.get("improvement")]
    if not found:
        return "-"
    return (f"{np.mean([f['own_episodes'] for f in found]):.0f}, "
            f"{np.mean([f['demonstrator_episodes'] for f in found]):.1f}, "
            f"{np.mean([f['seconds'] for f in found]):.1f}")


def end_errors(out: Path, seeds: Sequence[int], tasks: Sequence[str]) -> str:
    """Per seed, task and option: the mean distance (cm) between the puck's real and
    predicted (ensemble mean) position where the option's run ended, over the runs of the
    task's refit exploration (``OUT/seed*/refit-TASK/transitions``), for the shared
    dynamics (never fitted on them) and the task's own (fitted on them: in-sample)."""
    from dynoplan.data.dataset import read_dataset
    from dynoplan.pipeline.collect import flat_state
    from dynoplan.pipeline.fit import FittedModels
    from dynoplan.pipeline.fit_data import option_runs
    from dynoplan.pipeline.generic_stages import demos_from_dataset
    from dynoplan.pipeline.task_fit import load_option_models

    names = [s.name for s in make_options() if s.name != "reach"]
    lines = ["| seed | task | " + " | ".join(f"{n}: runs, shared, own" for n in names) + " |",
             "|---|---|" + "---|" * len(names)]
    for seed in seeds:
        shared = load_option_models(out / f"seed{seed}" / "options").models
        for task in tasks:
            folder = out / f"seed{seed}" / f"refit-{task}"
            if task == "reach-v3" or not (folder / "transitions").is_dir():
                continue
            own = FittedModels.load(folder / "models")
            runs = option_runs(demos_from_dataset(read_dataset(folder / "transitions"),
                                                  shared.option_names),
                               shared.option_names, flat_state, 1)
            cells = []
            for name in names:
                starts, ends, _ = runs[name]
                models: list[Any] = [shared.dynamics[name], own.dynamics[name]]  # ensembles
                errors = [100 * float(np.linalg.norm(
                    m.predict(starts)[0].mean(0)[:, OBJECT] - ends[:, OBJECT],
                    axis=1).mean()) for m in models] if len(starts) else [np.nan] * 2
                cells.append(f"{len(starts)}, {errors[0]:.1f}, {errors[1]:.1f}")
            lines.append(f"| {seed} | {task} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.transfer.metaworld_tasks",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("results/metaworld-transfer"))
    parser.add_argument("--seeds", default="0", help="comma-separated seeds [0]")
    parser.add_argument("--episodes", type=int, default=20,
                        help="evaluation episodes per controller [20]")
    parser.add_argument("--demos", type=int, default=10,
                        help="demonstrations per task (its goal; per seen task for the "
                             "dynamics) [10]")
    parser.add_argument("--exploration", type=int, default=20,
                        help="exploration episodes per task fitted on [20]")
    parser.add_argument("--tasks", default=",".join(TASKS))
    parser.add_argument("--train", default=",".join(TRAIN),
                        help="the tasks whose runs the shared dynamics are fitted on "
                             f"[{','.join(TRAIN)}]")
    parser.add_argument("--no-refit", action="store_true",
                        help="skip the per-task refitting (its column stays empty)")
    parser.add_argument("--own-runs", action="store_true",
                        help="also run the diagnostic of solve_own_runs for every task "
                             "with a refit (its exploration runs for goal and regions)")
    parser.add_argument("--task-improve", type=int, default=None,
                        help="improvement rounds of each task fit on the shared dynamics "
                             "(0: its demonstrations alone) [the library's default, 1]")
    parser.add_argument("--end-errors", action="store_true",
                        help="only print the puck's end errors of the options' dynamics "
                             "(shared and own) on each task's refit runs, from --out")
    args = parser.parse_args(argv)
    if importlib.util.find_spec("metaworld") is None:
        print("skipped Meta-World transfer: needs the 'metaworld' package "
              "(pip install 'dynoplan[metaworld]')")
        return 0
    import torch

    torch.set_num_threads(1)
    seeds = [int(s) for s in args.seeds.split(",")]
    tasks = [t for t in args.tasks.split(",") if t]
    train = [t for t in args.train.split(",") if t]
    unknown = [t for t in [*tasks, *train] if t not in ENV_IDS]
    if unknown:
        parser.error(f"unknown task(s) {unknown}; known: {', '.join(TASKS)}")
    if args.end_errors:
        print(end_errors(args.out, seeds, tasks), end="")
        return 0
    results: dict[str, Any] = {"tasks": tasks, "seed_list": seeds, "seeds": {},
                               "episodes": args.episodes, "demos": args.demos,
                               "exploration": args.exploration, "train": train,
                               "task_improve": args.task_improve,
                               "command": " ".join(sys.argv)}
    earlier = args.out / "results.json"
    if earlier.is_file():  # a resume: the seeds finished with the same settings are kept
        old = json.loads(earlier.read_text())
        if all(old.get(k, d) == results[k] for k, d in (
                ("tasks", None), ("episodes", None), ("demos", None), ("exploration", None),
                ("train", list(TRAIN)), ("task_improve", None))):
            results["seeds"] = {s: v for s, v in old["seeds"].items()
                                if int(s) in seeds}
            for s, kept in results["seeds"].items():  # recorded by the seed's task fits
                for task in tasks:
                    if "improvement" not in kept[task]:
                        kept[task]["improvement"] = improvement_of(
                            args.out / f"seed{s}" / f"shared-{task}")
    for seed in seeds:
        if str(seed) in results["seeds"]:
            print(f"seed {seed}: kept from {earlier}", flush=True)
            continue
        root = args.out / f"seed{seed}"
        per: dict[str, Any] = {"options": fit_shared(root / "options", seed, args.demos,
                                                     args.exploration * len(train), train)}
        for task in tasks:
            refit = ({"refit": None, "refit_demonstrations": None,
                      "refit_exploration": None, "refit_fit_seconds": None}
                     if args.no_refit else
                     solve_refit(task, root / f"refit-{task}", seed, args.demos,
                                 args.exploration, args.episodes))
            per[task] = {**solve_shared(task, root / "options", root / f"shared-{task}", seed,
                                        args.demos, args.episodes,
                                        improve=args.task_improve), **refit}
            print(task, json.dumps(per[task]), flush=True)
        results["seeds"][str(seed)] = per
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "results.json").write_text(json.dumps(results, indent=1))
        (args.out / "results.md").write_text(table(results))
    if args.own_runs:
        for seed in seeds:
            root = args.out / f"seed{seed}"
            for task in tasks:
                row = results["seeds"][str(seed)][task]
                if row.get("shared_own_runs") is None and row.get("refit") is not None:
                    row.update(solve_own_runs(task, root, seed, args.demos, args.episodes,
                                              args.task_improve))
                    print(task, seed, row["shared_own_runs"], flush=True)
            (args.out / "results.json").write_text(json.dumps(results, indent=1))
            (args.out / "results.md").write_text(table(results))
    print(table(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
