"""Controllers of the gear assembly on the same seeded episodes, and their metrics.

Controllers (rows of ``results.csv``):

- ``dynoplan``: the option planner (Eq. 1) with the learned dynamics ensembles, the
  learned goal heuristic and the Gaussian-mixture regions as initiation sets;
- ``oracle``: the same controller, but each option's future simulated by MuJoCo itself
  (:class:`~dynoplan.planning.SimulatorOracle`);
- ``fixed_script``: pick, fast move, insert, each run to its end, ignoring the human
  and the regions;
- ``random``: a uniformly random admissible option at every decision;
- ``flat_ppo``: one PPO network from observation to action (:mod:`dynoplan.baselines`).

Every controller runs on the same episodes: episode ``i`` resets the env with the same
seed (gear pose and human schedule: none, crossing or blocking). An episode depends on
its :class:`~dynoplan.seeding.EpisodeSeed` alone, not on the episodes run
before it, so a run split over workers (:mod:`dynoplan.experiments.gear_jobs`) gives the
same metrics.
"""

import time
from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from dynoplan.control import Controller
from dynoplan.control.controller import EpisodeTrace
from dynoplan.envs.gear.env import CONTROL_DT, GearAssemblyEnv
from dynoplan.envs.gear.options.motion import reseed_ompl
from dynoplan.errors import DynoplanError
from dynoplan.options.initiation import RegionModel
from dynoplan.pipeline.evaluate import EpisodeRecord, quantile_or_none
from dynoplan.progress import track
from dynoplan.seeding import EpisodeSeed
from dynoplan.types import FloatArray

RESULT_COLUMNS = (
    "controller", "episodes", "success_rate", "time_to_success_s", "contacts",
    "episodes_with_contact", "min_human_distance", "out_of_region_starts", "switches",
    "holds", "decision_ms_p50", "decision_ms_p99",
)
"""Columns of ``results.csv``, in order."""


def seconds(record: EpisodeRecord) -> float:
    """The episode's simulated duration (s)."""
    return record.env_steps * CONTROL_DT


def human_mode(record: EpisodeRecord) -> str:
    """The human's behaviour in the episode (``away``, ``cross``, ``block``)."""
    return str(record.task_metrics["human_mode"])


def gear_metrics(env: GearAssemblyEnv, infos: Sequence[dict[str, Any]],
                 min_distance: float = np.inf) -> dict[str, Any]:
    """The gear's own measurements of an episode from its steps' ``infos``: the human's
    behaviour, robot-human contacts and the smallest robot-human distance (m; also
    over ``min_distance``, for example the distance at the reset)."""
    return {"human_mode": env.schedule.mode,
            "contacts": int(sum(int(i["human_contacts"]) for i in infos)),
            "min_human_distance": float(min([min_distance, *(
                float(i["min_human_distance"]) for i in infos)]))}


def trace_metrics(trace: EpisodeTrace, env: GearAssemblyEnv, seed: int,
                  regions: RegionModel | None = None) -> EpisodeRecord:
    """The record of a controller's episode (the trace must have ``record_infos``).

    Option starts outside their regions are counted against ``regions`` when given (so a
    controller that ignores the regions, like the fixed script, is measured against the
    same learned regions as the others; an option without a region, not demonstrated,
    never starts outside it), else as the controller saw them."""
    outside = None if regions is None else sum(
        1 for d in trace.decisions
        if d.option is not None and _has_region(regions, d.option)
        and not bool(regions.contains(d.state[None], d.option)[0]))
    return EpisodeRecord.of(trace, seed, gear_metrics(env, trace.infos), outside)


def _has_region(regions: RegionModel, option: str) -> bool:
    try:
        regions.option_index(option)
    except DynoplanError:
        return False
    return True


def controller_episode(env: gym.Env[Any, Any], gear_env: GearAssemblyEnv,
                       controller: Controller, seed: EpisodeSeed,
                       regions: RegionModel | None = None) -> EpisodeRecord:
    """One seeded episode of ``controller`` on ``env`` (``gear_env`` itself or a wrapper
    of it, for example a fault); out-of-region starts are counted against ``regions``
    when given (see :func:`trace_metrics`). OMPL is reseeded from the episode's seed
    first (:func:`run_episode`), so the episode does not depend on what this process
    planned before."""
    return trace_metrics(run_episode(env, controller, seed), gear_env, seed.env_seed, regions)


def run_episode(env: gym.Env[Any, Any], controller: Controller, seed: EpisodeSeed,
                frames: list[Any] | None = None) -> EpisodeTrace:
    """Run ``controller``'s episode ``seed`` on ``env`` as the evaluation does (OMPL
    reseeded from the seed first); with ``frames``, append ``env.render()`` after every
    step (``env`` built with ``render_mode="rgb_array"``)."""
    reseed_ompl(seed.env_seed)
    if frames is not None:
        env = _Recorder(env, frames)
    trace: EpisodeTrace = controller.run(env, seed.rng(), seed=seed.env_seed)
    return trace


class _Recorder(gym.Wrapper[Any, Any, Any, Any]):
    """Appends a rendered frame to ``frames`` after every step."""

    def __init__(self, env: gym.Env[Any, Any], frames: list[Any]) -> None:
        super().__init__(env)
        self.frames = frames

    def step(self, action: Any) -> Any:
        out = self.env.step(action)
        self.frames.append(self.env.render())
        return out


def run_controller(env: gym.Env[Any, Any], gear_env: GearAssemblyEnv, controller: Controller,
                   seeds: Sequence[EpisodeSeed], name: str, progress: bool = True,
                   regions: RegionModel | None = None) -> list[EpisodeRecord]:
    """:func:`controller_episode` on every seed, in order, in this process."""
    return [controller_episode(env, gear_env, controller, s, regions)
            for s in track(seeds, name, total=len(seeds), enabled=progress)]


def policy_episode(env: GearAssemblyEnv, act: Callable[[FloatArray], FloatArray],
                   seed: EpisodeSeed) -> EpisodeRecord:
    """One seeded episode of a flat policy ``act(observation) -> action`` (no options, no
    decisions: its "decision latency" is the time of one ``act`` call)."""
    obs, info = env.reset(seed=seed.env_seed)
    first_distance = float(info["min_human_distance"])
    infos: list[dict[str, Any]] = []
    ms: list[float] = []
    reward, done, success = 0.0, False, False
    while not done:
        t0 = time.perf_counter()
        action = act(obs)
        ms.append(1e3 * (time.perf_counter() - t0))
        obs, r, terminated, truncated, info = env.step(action)
        infos.append(info)
        reward += float(r)
        success = bool(info["is_success"])
        done = terminated or truncated
    return EpisodeRecord(seed.env_seed, success, len(infos), reward, 0, 0, 0, 0, tuple(ms),
                         (), (), gear_metrics(env, infos, first_distance))


def run_policy(env: GearAssemblyEnv, act: Callable[[FloatArray], FloatArray],
               seeds: Sequence[EpisodeSeed], name: str,
               progress: bool = True) -> list[EpisodeRecord]:
    """:func:`policy_episode` on every seed, in order, in this process."""
    return [policy_episode(env, act, s)
            for s in track(seeds, name, total=len(seeds), enabled=progress)]


def summarise(name: str, episodes: Sequence[EpisodeRecord]) -> dict[str, Any]:
    """One row of ``results.csv`` (see :data:`RESULT_COLUMNS`) plus per-mode success."""
    ms = [m for e in episodes for m in e.decision_ms]
    ok = [e for e in episodes if e.success]
    contacts = [int(e.task_metrics["contacts"]) for e in episodes]
    row: dict[str, Any] = {
        "controller": name,
        "episodes": len(episodes),
        "success_rate": float(np.mean([e.success for e in episodes])) if episodes else 0.0,
        "time_to_success_s": float(np.median([seconds(e) for e in ok])) if ok else None,
        "contacts": int(sum(contacts)),
        "episodes_with_contact": int(sum(c > 0 for c in contacts)),
        "min_human_distance": float(min(e.task_metrics["min_human_distance"]
                                        for e in episodes)),
        "out_of_region_starts": int(sum(e.out_of_region_starts for e in episodes)),
        "switches": int(sum(e.switches for e in episodes)),
        "holds": int(sum(e.no_admissible for e in episodes)),
        "decision_ms_p50": quantile_or_none(ms, 0.5),
        "decision_ms_p99": quantile_or_none(ms, 0.99),
    }
    by_mode = {}
    for mode in sorted({human_mode(e) for e in episodes}):
        sub = [e for e in episodes if human_mode(e) == mode]
        by_mode[mode] = {"episodes": len(sub),
                         "success_rate": float(np.mean([e.success for e in sub])),
                         "contacts": int(sum(int(e.task_metrics["contacts"]) for e in sub))}
    row["by_human_mode"] = by_mode
    return row


__all__ = ["RESULT_COLUMNS", "controller_episode", "gear_metrics", "human_mode",
           "policy_episode", "run_controller", "run_episode", "run_policy", "seconds",
           "summarise", "trace_metrics"]
