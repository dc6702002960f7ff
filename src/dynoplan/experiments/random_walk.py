"""The paper's Simulated MDP experiment: DynoPlan on the 19-state random walk.

Writes ``summary.json`` (DynoPlan's success rate and planning steps, each option alone,
random choice, one robustness row per misprediction probability), ``results.md`` (both
tables), ``figure_mdp_solution.png`` (Figure 2(b), first episode), ``robustness.png``
and ``robustness.csv`` (success and planning steps against noise).
"""

import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from dynoplan import __version__
from dynoplan.control.batched import run_batched
from dynoplan.control.controller import Controller, EpisodeTrace
from dynoplan.envs import RANDOM_WALK_ID
from dynoplan.envs.random_walk.models import NoisyWalkGoal
from dynoplan.envs.random_walk.options import make_random_walk_options
from dynoplan.errors import DynoplanError
from dynoplan.io import ensure_writable_dir, write_csv, write_json, write_text
from dynoplan.limits import DEPTH_MAX
from dynoplan.pipeline.control_settings import ControllerSettings
from dynoplan.pipeline.evaluate import (
    controller_names,
    make_controller,
    planning_steps_summary,
    run_episodes,
)
from dynoplan.planning import OptionPlanner, SequencePlanner
from dynoplan.reports.random_walk_figures import plot_mdp_solution, plot_robustness
from dynoplan.reports.random_walk_results import random_walk_markdown, trace_rows
from dynoplan.seeding import EpisodeSeed, batch_planner_seed, episode_seeds

ROBUSTNESS_NOISES = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5)
LOCKSTEP_EPISODES = 1000
"""Most episodes that run side by side (:func:`run_lockstep`); more run in batches of
this many, one after another, so that memory stays bounded."""


@dataclass(frozen=True)
class RandomWalkSettings:
    """Everything that defines a random-walk run (recorded in ``summary.json``).

    ``depth``: options per imagined sequence of DynoPlan's planner (1: Eq. 1).
    ``lockstep``: run each controller's episodes side by side, every episode's decision
    of one step in one planner call (:func:`~dynoplan.control.batched.run_batched`; the
    same distribution of results as one after another, not the same episodes); the
    default, since the walk's decisions are tiny and a call's fixed cost dominates.
    """

    episodes: int = 1000
    noise: float = 0.2
    seed: int = 0
    horizon: int = 20
    samples: int = 128
    max_decisions: int = 50
    depth: int = 1
    lockstep: bool = True
    start_state: int = 0
    goal_state: int = 20
    robustness_noises: tuple[float, ...] = field(default=ROBUSTNESS_NOISES)

    def validate(self) -> None:
        if self.episodes < 1:
            raise DynoplanError(f"--episodes must be >= 1, got {self.episodes}")
        for name, p in [("--noise", self.noise), *[("robustness noise", q)
                                                   for q in self.robustness_noises]]:
            if not 0.0 <= p <= 1.0:
                raise DynoplanError(f"{name} must be a probability in [0, 1], got {p}")
        if self.horizon < 1 or self.samples < 1 or self.max_decisions < 1:
            raise DynoplanError("--horizon, --samples and --max-decisions must be >= 1")
        if not 1 <= self.depth <= DEPTH_MAX:
            raise DynoplanError(f"--depth must be in [1, {DEPTH_MAX}], got {self.depth}")
        if not 0 <= self.start_state < self.goal_state:
            raise DynoplanError(
                f"--start-state must be in [0, {self.goal_state - 1}], got {self.start_state}")


def make_walk_controller(kind: str, noise: float, settings: RandomWalkSettings) -> Controller:
    """``dynoplan`` (the planner), ``random``, or ``option:<name>`` (that option alone), as
    the pipeline makes them (:func:`~dynoplan.pipeline.evaluate.make_controller`): the
    random walk's options and goal at misprediction probability ``noise``, replanning only
    when an option stops, no hold."""
    control = ControllerSettings(horizon=settings.horizon, samples=settings.samples,
                                 depth=settings.depth, replan_every=None,
                                 max_decisions=settings.max_decisions, hold=False)
    return make_controller(kind, make_random_walk_options(noise, settings.goal_state),
                           NoisyWalkGoal(noise, settings.goal_state), control)


def run_lockstep(controller: Controller, noise: float, settings: RandomWalkSettings,
                 seeds: list[EpisodeSeed]) -> list[EpisodeTrace]:
    """``controller``'s episodes side by side, one environment each: DynoPlan's
    decisions of one step for every episode in one planner call (the planner of
    ``controller``, as a :class:`~dynoplan.planning.SequencePlanner` of the same
    settings: at depth 1 the same Eq. 1, advancing only the rollouts still running),
    a baseline's one after another; at most :data:`LOCKSTEP_EPISODES` at a time."""
    chooser: Any = controller.chooser
    if isinstance(chooser, OptionPlanner):
        chooser = SequencePlanner(chooser.options, NoisyWalkGoal(noise, settings.goal_state),
                                  horizon=settings.horizon, samples=settings.samples,
                                  depth=settings.depth, compact=True)
    # without gymnasium's passive checker (it checks only, and a checked environment's
    # every reset and step pass through it): the time limit and the order stay
    envs = [gym.make(RANDOM_WALK_ID, goal_state=settings.goal_state,
                     start_state=settings.start_state, disable_env_checker=True)
            for _ in seeds[:LOCKSTEP_EPISODES]]
    planner_rng = np.random.default_rng(batch_planner_seed(settings.seed))
    traces: list[EpisodeTrace] = []
    for first in range(0, len(seeds), LOCKSTEP_EPISODES):
        batch = seeds[first:first + LOCKSTEP_EPISODES]
        traces += run_batched(envs[:len(batch)], controller.options, chooser, batch,
                              planner_rng, max_decisions=settings.max_decisions)
    return traces


def run_random_walk(settings: RandomWalkSettings, out: Path, progress: bool = True) -> dict[
        str, Any]:
    """Run the experiment, write every output into ``out`` and return the summary."""
    settings.validate()
    out = ensure_writable_dir(out)
    env = gym.make(RANDOM_WALK_ID, goal_state=settings.goal_state,
                   start_state=settings.start_state)
    seeds = episode_seeds(settings.seed, settings.episodes)

    def evaluate(kind: str, noise: float) -> tuple[dict[str, Any], list[Any]]:
        controller = make_walk_controller(kind, noise, settings)
        t0, cpu0 = time.perf_counter(), time.process_time()
        if settings.lockstep:
            traces = run_lockstep(controller, noise, settings, seeds)
        else:
            traces = run_episodes(env, controller, seeds, f"{kind} (noise {noise:g})",
                                  progress)
        summary = planning_steps_summary(traces)
        summary["seconds"] = time.perf_counter() - t0
        # this process's CPU time: on a shared machine, closer to a quiet machine's wall
        summary["cpu_seconds"] = time.process_time() - cpu0
        return summary, traces

    main, traces = evaluate("dynoplan", settings.noise)
    options = make_random_walk_options(settings.noise, settings.goal_state)
    baselines = {kind: evaluate(kind, settings.noise)[0]
                 for kind in controller_names(options) if kind != "dynoplan"}
    robustness = []
    for noise in settings.robustness_noises:
        row = main if noise == settings.noise else evaluate("dynoplan", noise)[0]
        robustness.append({"noise": noise, **row})

    plot_mdp_solution(traces[0], out / "figure_mdp_solution.png", settings.goal_state,
                      title=f"DynoPlan on the random walk (noise {settings.noise:g}, "
                            f"episode 0 of seed {settings.seed})")
    plot_robustness(robustness, out / "robustness.png")
    write_csv(out / "robustness.csv", robustness)
    recorded = {**asdict(settings), "robustness_noises": list(settings.robustness_noises)}
    write_text(out / "results.md", random_walk_markdown(recorded, main, baselines, robustness))
    summary = {
        "experiment": "random_walk",
        "dynoplan_version": __version__,
        "settings": recorded,
        **main,
        "noise": settings.noise,
        "baselines": baselines,
        "robustness": robustness,
        "figure_episode": trace_rows(traces[0]),
    }
    write_json(out / "summary.json", summary)
    return summary
