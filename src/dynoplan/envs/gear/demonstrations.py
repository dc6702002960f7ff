"""Run the gear's demonstrators: demonstrations, a summary, a picture and a video.

Both demonstrators are pipeline :class:`~dynoplan.pipeline.collect.Demonstrator` s,
recorded by the pipeline's :func:`~dynoplan.pipeline.collect.record_episode`: the
:class:`~dynoplan.envs.gear.operator.OptionOperator` chains the options' policies, and
:class:`ExpertDemonstrator` lets the scripted :class:`GearExpert` act itself, labelling
its actions with options.

- :func:`record_expert_episodes`: per-episode arrays (observations, actions, option
  labels, progress, ...) ready to be written as a dataset;
- :func:`run_expert`: many seeded episodes, ``summary.json`` (success, contacts, speed);
- :func:`render_scene`: ``scene.png`` and ``episode.mp4`` of one seeded episode;
- :func:`record_demos`: seeded demonstrations (the human schedule drawn per episode:
  away, crossing or blocking) written with option labels and progress as a
  Minari-layout dataset (``docs/dataset-format.md``), what ``gear run`` and ``gear
  demos`` record (:func:`dynoplan.envs.gear.stages.demonstrations`).
"""

import platform
import time
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import numpy.typing as npt

from dynoplan.adapters.spec import OptionSpec
from dynoplan.data import DatasetMetadata, Episode, write_dataset
from dynoplan.envs import GEAR_ASSEMBLY_ID, GEAR_PEG_POSE_ID
from dynoplan.envs.gear.env import CONTROL_DT, GearAssemblyEnv
from dynoplan.envs.gear.expert import GearExpert
from dynoplan.envs.gear.human import HUMAN_MODES
from dynoplan.envs.gear.metrics import contact_summary
from dynoplan.envs.gear.options.catalog import gear_option_names
from dynoplan.envs.gear.peg_pose import GearPegPoseEnv, PegWorkspace
from dynoplan.errors import DynoplanError
from dynoplan.io import ensure_writable_dir, write_json, write_with
from dynoplan.parallel import SERIAL, Workers, parallel_map
from dynoplan.pipeline.collect import (
    Decision,
    Demonstrator,
    RunStart,
    record_episode,
    successful_attempts,
)
from dynoplan.reports.video import write_mp4
from dynoplan.seeding import episode_seeds as derive_episode_seeds
from dynoplan.types import Generator

RawEpisode = dict[str, Any]
"""One episode: ``observations`` (T+1, 50), ``actions`` (T, 13), ``rewards`` (T,),
``terminations`` (T,), ``truncations`` (T,), ``infos`` (dict of (T,) arrays: ``option``,
``progress``, ``stage``, ``min_human_distance``, ``success``, ``human_contacts``,
``pads_on_gear``, ``insertion_depth``), ``seed`` and ``human_mode``."""


def succeeded(episode: RawEpisode) -> bool:
    """Whether ``episode`` ended in success (its last step's ``infos["success"]``)."""
    return bool(np.asarray(episode["infos"]["success"])[-1])

_INFO_KEYS = ("stage", "min_human_distance", "is_success", "human_contacts", "pads_on_gear",
              "insertion_depth")


def episode_seeds(seed: int, episodes: int) -> list[int]:
    """Independent ``env.reset`` seeds for ``episodes`` episodes, derived from ``seed``."""
    return [s.env_seed for s in derive_episode_seeds(seed, episodes)]


def check_request(episodes: int, human_mode: str | None, demonstrator: str = "expert",
                  count_flag: str = "--episodes") -> None:
    """One error line for a request that cannot run (before any work is done): fewer than
    one episode (the command's flag ``count_flag``), an unknown human mode or an unknown
    demonstrator (:data:`DEMONSTRATORS`)."""
    if episodes < 1:
        raise DynoplanError(f"{count_flag} must be >= 1, got {episodes}")
    if human_mode is not None and human_mode not in HUMAN_MODES:
        raise DynoplanError(f"--human must be one of {', '.join(HUMAN_MODES)}, got {human_mode!r}")
    if demonstrator not in DEMONSTRATORS:
        raise DynoplanError(f"unknown demonstrator {demonstrator!r}; expected one of "
                            f"{', '.join(DEMONSTRATORS)}")


DEMO_MODE_CYCLE = ("block", "cross", "away")
"""Human modes of successive option demonstrations (when no mode is forced)."""

DEMONSTRATORS = ("options", "expert")
"""``options``: the operator chaining the four option policies (the paper's way);
``expert``: the scripted expert with privileged state."""


class ExpertDemonstrator(Demonstrator):
    """The scripted :class:`GearExpert` as a pipeline demonstrator: it acts itself (its
    privileged script, read from the simulator and the step's ``info``), each action a
    :class:`~dynoplan.pipeline.collect.Decision` labelled with the option it belongs to
    (the paper's four: ``gear_option_names()[:4]``); it needs no option's policy. It
    draws nothing at random."""

    def __init__(self, expert: GearExpert) -> None:
        from dynoplan.envs.gear.options.catalog import gear_option_names

        self.expert = expert
        self.names = gear_option_names()
        self.info: dict[str, Any] = {}

    def reset(self, observation: Any, rng: Generator) -> None:
        self.expert.reset()

    def observe(self, info: dict[str, Any]) -> None:
        self.info = info

    def choose(self, observation: Any) -> Decision:
        decision = self.expert.act(observation, self.info)
        return Decision(self.names[decision.option], action=decision.action)


def make_demonstrator(kind: str, env: GearAssemblyEnv, models: Path | None = None
                      ) -> tuple[Demonstrator, list[OptionSpec]]:
    """The demonstrator ``kind`` (see :data:`DEMONSTRATORS`) on ``env`` and the options
    whose policies it chains (the recorder runs them; none for the expert, which acts
    itself); the options' neural parts are read from ``models``."""
    if kind == "expert":
        return ExpertDemonstrator(GearExpert(env)), []
    if kind == "options":
        from dynoplan.envs.gear.operator import OptionOperator
        from dynoplan.envs.gear.options.catalog import policy_factories

        operator = OptionOperator(env, policy_factories(models))
        return operator, operator.specs
    raise DynoplanError(f"unknown demonstrator {kind!r}; expected one of "
                        f"{', '.join(DEMONSTRATORS)}")


def run_expert_episode(env: GearAssemblyEnv, demonstrator: Demonstrator, seed: int,
                       human_mode: str | None = None,
                       frames: list[npt.NDArray[np.uint8]] | None = None,
                       specs: Sequence[OptionSpec] = ()) -> RawEpisode:
    """One episode of ``demonstrator`` (running the options ``specs``; see
    :func:`make_demonstrator`) in ``env`` from ``env.reset(seed=seed)`` with the human
    mode ``human_mode`` (None: the seed's own), recorded by the pipeline's recorder
    (:func:`~dynoplan.pipeline.collect.record_episode`) with the generator
    ``default_rng(seed)``; labels index ``gear_option_names()``.

    ``progress`` is normalised time: ``progress[t] = (t + 1) / T``, the progress of
    ``observations[t + 1]`` (``observations[0]`` has progress 0). With ``frames``, a
    rendered frame is appended after the reset and after every step.
    Adds ``step_seconds`` (wall time spent in ``env.step``) to the episode.
    """
    from dynoplan.envs.gear.options.catalog import gear_option_names

    recorded = _Recorded(env, frames)
    obs, info = recorded.reset(seed=seed, options={"human_mode": human_mode}
                               if human_mode is not None else None)
    recording = record_episode(recorded, specs, demonstrator, seed,
                               np.random.default_rng(seed), start=RunStart(obs, info, seed),
                               info_keys=_INFO_KEYS, option_names=gear_option_names())
    episode = recording.episode
    infos = episode.infos
    steps = len(episode)
    return {
        "observations": np.asarray(episode.observations, dtype=np.float64),
        "actions": np.asarray(episode.actions, dtype=np.float64),
        "rewards": np.asarray(episode.rewards, dtype=np.float64),
        "terminations": np.asarray(episode.terminations, dtype=bool),
        "truncations": np.asarray(episode.truncations, dtype=bool),
        "infos": {
            "option": np.asarray(infos["option"], dtype=np.int64),
            "progress": np.arange(1, steps + 1, dtype=np.float64) / steps,
            "stage": np.asarray(infos["stage"], dtype=np.int64),
            "min_human_distance": np.asarray(infos["min_human_distance"], dtype=np.float64),
            "success": np.asarray(infos["is_success"], dtype=bool),
            "human_contacts": np.asarray(infos["human_contacts"], dtype=np.int64),
            "pads_on_gear": np.asarray(infos["pads_on_gear"], dtype=np.int64),
            "insertion_depth": np.asarray(infos["insertion_depth"], dtype=np.float64),
        },
        "seed": seed,
        "human_mode": env.schedule.mode,
        "step_seconds": recorded.step_seconds,
    }


class _Recorded(gym.Wrapper[Any, Any, Any, Any]):
    """The gear env as a demonstration records it: the wall time spent in ``env.step``
    and, with ``frames``, a rendered frame after the reset and after every step."""

    def __init__(self, env: GearAssemblyEnv, frames: list[npt.NDArray[np.uint8]] | None
                 ) -> None:
        super().__init__(env)
        self.gear_env = env
        self.frames = frames
        self.step_seconds = 0.0

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        if self.frames is not None:
            self.frames.append(_frame(self.gear_env))
        return obs, info

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        t0 = time.perf_counter()
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.step_seconds += time.perf_counter() - t0
        if self.frames is not None:
            self.frames.append(_frame(self.gear_env))
        return obs, reward, terminated, truncated, info


def _frame(env: GearAssemblyEnv) -> npt.NDArray[np.uint8]:
    frame = env.render()
    if frame is None:
        raise RuntimeError("the env was not made with render_mode='rgb_array'")
    return frame


@dataclass(frozen=True)
class DemoJob:
    """Demonstrated episodes as a worker rebuilds them (:mod:`dynoplan.parallel`): the
    demonstrator ``kind`` (:data:`DEMONSTRATORS`), the options' networks read from
    ``models``, in the first task's environment or, with ``peg``, the downstream task's
    (:class:`~dynoplan.envs.gear.peg_pose.GearPegPoseEnv` on that workspace)."""

    kind: str
    models: Path | None = None
    peg: PegWorkspace | None = None


@dataclass
class DemoWorker:
    """What a worker holds for a :class:`DemoJob`: the environment, the demonstrator on
    it and the options whose policies it chains (:func:`make_demonstrator`)."""

    job: DemoJob
    env: GearAssemblyEnv
    demonstrator: Demonstrator
    specs: list[OptionSpec]


def build_demonstrator(job: DemoJob) -> DemoWorker:
    """The environment and the demonstrator on it (once per process)."""
    import torch

    torch.set_num_threads(1)  # as in the command line: identical predictions everywhere
    env = GearAssemblyEnv() if job.peg is None else GearPegPoseEnv(job.peg)
    return DemoWorker(job, env, *make_demonstrator(job.kind, env, job.models))


def demonstrated_episode(worker: DemoWorker, item: tuple[int, str | None]) -> RawEpisode:
    """The episode of env seed ``item[0]`` with the human mode ``item[1]`` (None: the
    seed's own). It depends on them alone (the options draw from ``default_rng(seed)``,
    and the operator's planners are reseeded from it first:
    :func:`~dynoplan.envs.gear.options.motion.reseed_ompl`), so it is the same on any
    worker, after any other episode."""
    seed, mode = item
    if worker.job.kind == "options":
        from dynoplan.envs.gear.options.motion import reseed_ompl

        reseed_ompl(seed)
    return run_expert_episode(worker.env, worker.demonstrator, seed, mode,
                              specs=worker.specs)


def record_expert_episodes(n: int, seed: int, progress: bool = False,
                           human_mode: str | None = None, demonstrator: str = "expert",
                           models: Path | None = None,
                           workers: Workers = SERIAL,
                           peg: PegWorkspace | None = None) -> list[RawEpisode]:
    """``n`` demonstrated episodes with seeds derived from ``seed`` (see :data:`RawEpisode`);
    ``demonstrator`` is one of :data:`DEMONSTRATORS`; ``peg``: in the downstream task's
    environment (:class:`DemoJob`). The episodes run on ``workers``;
    each depends on its own seed and mode alone (:func:`demonstrated_episode`), so the
    list is the same on one worker or many."""
    check_request(n, human_mode, demonstrator)
    job = DemoJob(demonstrator, models, peg)
    if demonstrator == "expert":
        return parallel_map(build_demonstrator, demonstrated_episode, job,
                            [(s, human_mode) for s in episode_seeds(seed, n)], workers,
                            "gear expert", progress)
    if models is not None:
        from dynoplan.envs.gear.options.catalog import policy_factories

        policy_factories(models)  # a missing or broken network: one error here
    return _successful_episodes(job, n, seed, human_mode, progress, workers)


def _successful_episodes(job: DemoJob, n: int, seed: int, human_mode: str | None,
                         progress: bool, workers: Workers) -> list[RawEpisode]:
    """``n`` successful episodes (a demonstration shows the task done). Demonstration
    ``j`` has the human mode ``human_mode``, or without one ``DEMO_MODE_CYCLE[j % 3]``,
    so that ten demonstrations show every situation (block 4, cross 3, away 3). The
    seeds derived from ``seed`` are tried in the pipeline's rounds
    (:func:`~dynoplan.pipeline.collect.successful_attempts`: each round gives the next
    seeds in order to the demonstrations still without a success, in order), at most
    ``3 n`` seeds in all; the rounds' episodes run on ``workers``. Demonstration ``j``
    comes ``j``-th."""
    seeds = episode_seeds(seed, 3 * n)
    modes = [human_mode or DEMO_MODE_CYCLE[j % len(DEMO_MODE_CYCLE)] for j in range(n)]

    def run(pairs: list[tuple[int, int]]) -> list[RawEpisode]:
        return parallel_map(build_demonstrator, demonstrated_episode, job,
                            [(seeds[i], modes[j]) for j, i in pairs], workers,
                            f"gear demos (options, {len(pairs)} tries)", progress)

    found, _ = successful_attempts(n, len(seeds), run, succeeded)
    done = [e for _, e in (f for f in found if f is not None)]
    if len(done) < n:
        raise DynoplanError(f"only {len(done)} of {3 * n} option demonstrations succeeded; "
                            f"{n} were asked for")
    return done


def summarise(episodes: list[RawEpisode], seed: int, wall_seconds: float) -> dict[str, Any]:
    """Success, safety and speed over ``episodes`` (the ``summary.json`` content)."""
    n = len(episodes)
    success = [succeeded(ep) for ep in episodes]
    steps = np.array([len(ep["actions"]) for ep in episodes])
    sim_seconds = float(steps.sum() * CONTROL_DT)
    step_seconds = float(sum(ep["step_seconds"] for ep in episodes))
    contacts = [int(ep["infos"]["human_contacts"].sum()) for ep in episodes]
    min_dist = [float(ep["infos"]["min_human_distance"].min()) for ep in episodes]
    from dynoplan.envs.gear.options.catalog import gear_option_names

    names = gear_option_names()
    option_counts: Counter[str] = Counter()
    for ep in episodes:
        for k, c in zip(*np.unique(ep["infos"]["option"], return_counts=True), strict=True):
            option_counts[names[int(k)]] += int(c)
    by_mode: dict[str, dict[str, float]] = {}
    for mode in HUMAN_MODES:
        idx = [i for i, ep in enumerate(episodes) if ep["human_mode"] == mode]
        if idx:
            by_mode[mode] = {"episodes": len(idx),
                             "success_rate": float(np.mean([success[i] for i in idx]))}
    success_steps = steps[np.array(success)] if any(success) else np.array([])
    return {
        "episodes": n,
        "seed": seed,
        "success_rate": float(np.mean(success)),
        "successes": int(np.sum(success)),
        "failed_seeds": [ep["seed"] for ep, ok in zip(episodes, success, strict=True) if not ok],
        **contact_summary(contacts, min_dist),
        "time_to_success_mean": (float(success_steps.mean() * CONTROL_DT)
                                 if len(success_steps) else None),
        "time_to_success_max": (float(success_steps.max() * CONTROL_DT)
                                if len(success_steps) else None),
        "by_human_mode": by_mode,
        "option_steps": dict(option_counts),
        "env_steps": int(steps.sum()),
        "simulated_seconds": sim_seconds,
        "env_step_seconds": step_seconds,
        "realtime_factor": sim_seconds / step_seconds if step_seconds > 0 else None,
        "realtime_factor_with_expert": sim_seconds / wall_seconds if wall_seconds > 0 else None,
        "wall_seconds": wall_seconds,
        "machine": {"python": platform.python_version(), "processor": platform.processor(),
                    "system": platform.system()},
    }


def run_expert(episodes: int, seed: int, out: Path, progress: bool = True,
               human_mode: str | None = None) -> dict[str, Any]:
    """Run the expert for ``episodes`` seeded episodes; write ``out/summary.json``."""
    check_request(episodes, human_mode)
    folder = ensure_writable_dir(out)
    t0 = time.perf_counter()
    eps = record_expert_episodes(episodes, seed, progress=progress, human_mode=human_mode)
    summary = summarise(eps, seed, time.perf_counter() - t0)
    write_json(folder / "summary.json", summary)
    return summary


def render_scene(out: Path, seed: int = 0, video: bool = True, human_mode: str | None = None,
                 width: int = 640, height: int = 480) -> dict[str, Path]:
    """Write ``out/scene.png`` (the scene after reset) and, with ``video``,
    ``out/episode.mp4`` (the expert's episode at 20 frames per second)."""
    import imageio.v2 as imageio

    check_request(1, human_mode)
    folder = ensure_writable_dir(out)
    env = GearAssemblyEnv(render_mode="rgb_array", width=width, height=height)
    written: dict[str, Path] = {}
    try:
        frames: list[npt.NDArray[np.uint8]] = []
        if video:
            run_expert_episode(env, ExpertDemonstrator(GearExpert(env)), seed, human_mode,
                               frames=frames)
        else:
            env.reset(seed=seed, options={"human_mode": human_mode} if human_mode else None)
            frames.append(_frame(env))
        first = frames[0]
        write_with(folder / "scene.png", lambda p: imageio.imwrite(p, first))
        written["scene"] = folder / "scene.png"
        if video:
            written["video"] = write_mp4(folder / "episode.mp4", frames,
                                         fps=int(env.metadata["render_fps"]))
    finally:
        env.close()
    return written


DATASET_ID = "dynoplan/gear-assembly/expert-v0"
"""Dataset id of demonstrations by either demonstrator (``metadata.extra`` names it)."""


def to_dataset_episode(raw: dict[str, Any]) -> Episode:
    """The expert's per-episode arrays as a validated :class:`~dynoplan.data.Episode`."""
    return Episode(
        observations=raw["observations"],
        actions=raw["actions"],
        rewards=raw["rewards"],
        terminations=raw["terminations"],
        truncations=raw["truncations"],
        infos=dict(raw["infos"]),
        seed=int(raw["seed"]),
    )


def record_demos(n: int, seed: int, out: Path, progress: bool = True,
                 human_mode: str | None = None, demonstrator: str = "expert",
                 models: Path | None = None, workers: Workers = SERIAL,
                 peg: PegWorkspace | None = None) -> dict[str, Any]:
    """Record ``n`` demonstrations into the dataset folder ``out``; return a summary.

    ``demonstrator``: ``expert`` (the scripted expert) or ``options`` (an operator
    chaining the option policies, whose networks are read from ``models``). ``peg``: in
    the downstream task's environment (``dynoplan/GearPegPose-v0`` on that workspace,
    :mod:`~dynoplan.envs.gear.peg_pose`). The episodes run on ``workers``; the dataset is
    the same on one worker or many."""
    ensure_writable_dir(out.parent if out.parent != Path("") else Path("."))
    raw = record_expert_episodes(n, seed, progress=progress, human_mode=human_mode,
                                 demonstrator=demonstrator, models=models, workers=workers,
                                 peg=peg)
    episodes = [to_dataset_episode(r) for r in raw]
    modes = [str(r["human_mode"]) for r in raw]
    env_id = GEAR_ASSEMBLY_ID if peg is None else GEAR_PEG_POSE_ID
    env = gym.make(env_id)
    try:
        spec = env.spec.to_json() if env.spec is not None else None
        obs_space, act_space = env.observation_space, env.action_space
        assert isinstance(obs_space, gym.spaces.Box) and isinstance(act_space, gym.spaces.Box)
        metadata = DatasetMetadata(
            dataset_id=DATASET_ID,
            env_id=env_id,
            env_spec=spec,
            option_names=list(gear_option_names()),
            seed=seed,
            extra={"human_modes": modes, "demonstrator": demonstrator,
                   "state": "observations[:, 0:12] (arm joint angles)",
                   "progress": "progress[t] = (t + 1) / T describes observations[t + 1]"},
            observation_space=obs_space,
            action_space=act_space,
        )
    finally:
        env.close()
    write_dataset(out, episodes, metadata)
    successes = [succeeded(r) for r in raw]
    return {
        "dataset": str(out),
        "episodes": n,
        "steps": int(sum(len(e) for e in episodes)),
        "success_rate": float(np.mean(successes)),
        "human_modes": dict(Counter(modes)),
        "option_steps": {gear_option_names()[k]: int(v) for k, v in sorted(Counter(
            int(o) for e in episodes for o in e.infos["option"]).items())},
    }
