"""A flat end-to-end policy for the gear assembly, trained with Stable-Baselines3 PPO.

The baseline the paper's hierarchy is compared with: one network from observation to
action, no options, no planner. To give it a fair chance:

- actions are normalised: ``a`` in ``[-1, 1]^7`` moves the left arm's joint targets by
  ``a[:6] * JOINT_STEP`` rad from the current angles and sets the gripper to
  ``(a[6] + 1) / 2``; the right arm holds the peg where it is;
- the reward is shaped (the task's own reward is 1 at success only): minus the distance
  from the left tool point to the gear while it is not held, a bonus per step it is held,
  minus the distance from the gear to the peg tip while held, a large bonus when seated,
  and a penalty per physics step of robot-human contact;
- episodes last at most ``MAX_STEPS`` decisions (20 s).

The trained policy is saved without pickle: its ``state_dict`` as safetensors plus JSON
with the architecture and the training budget; loading rebuilds the same PPO policy.
"""

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import numpy.typing as npt
from gymnasium import spaces

from dynoplan.adapters.spec import OptionSpec
from dynoplan.envs.gear.env import OBS_SLICES, GearAssemblyEnv
from dynoplan.envs.gear.metrics import gear_metrics
from dynoplan.errors import DynoplanError
from dynoplan.io import read_json_object, write_json, write_with
from dynoplan.options.option import FunctionPolicy
from dynoplan.options.termination import ConstantTermination
from dynoplan.pipeline.collect import CallableDemonstrator, RunStart, record_episode
from dynoplan.pipeline.evaluate import EpisodeRecord
from dynoplan.seeding import EpisodeSeed
from dynoplan.timing import without_wall_clock
from dynoplan.types import FloatArray, Generator

FLAT_POLICY = "flat_ppo"
"""The flat end-to-end baseline's controller name (it needs ``GearTask.flat_folder``)."""
JOINT_STEP = 0.05  # rad per decision at |a| = 1
MAX_STEPS = 400
FORMAT_VERSION = 1
NET_ARCH = (128, 128)
NET_ARCH_MAX_LAYERS = 8
"""Hidden layers a flat policy's ``net_arch`` may list at most."""
OBS_DIM, ACTION_DIM = 50, 7
META_FILE, WEIGHTS_FILE = "flat_policy.json", "flat_policy.safetensors"
F32 = npt.NDArray[np.float32]


class FlatGearTask(gym.Wrapper[Any, Any, Any, Any]):
    """The gear assembly as a flat RL problem (see the module docstring)."""

    def __init__(self, env: GearAssemblyEnv | None = None) -> None:
        base = env or GearAssemblyEnv(max_episode_steps=MAX_STEPS)
        super().__init__(base)
        self.gear_env = base
        self.action_space = spaces.Box(-1.0, 1.0, shape=(ACTION_DIM,), dtype=np.float32)
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(OBS_DIM,),
                                            dtype=np.float32)
        self._tcp = base.model.site("l_tcp").id

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[F32, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        return obs.astype(np.float32), info

    def step(self, action: F32) -> tuple[F32, float, bool, bool, dict[str, Any]]:
        a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        env = self.gear_env
        q = env.arm_qpos
        target = q.copy()
        target[:6] = q[:6] + JOINT_STEP * a[:6]
        obs, reward, terminated, truncated, info = env.step(
            np.concatenate([target, [(a[6] + 1.0) / 2.0]]))
        return (obs.astype(np.float32), self.shaped_reward(obs, float(reward), info),
                terminated, truncated, info)

    def shaped_reward(self, obs: FloatArray, reward: float, info: dict[str, Any]) -> float:
        """Dense reward of one step (see the module docstring)."""
        gear = obs[OBS_SLICES["gear_pos"]]
        held = int(info["pads_on_gear"]) >= 2
        if held:
            r = 0.5 - 2.0 * float(np.linalg.norm(gear - obs[OBS_SLICES["peg_pos"]]))
        else:
            tcp = self.gear_env.data.site_xpos[self._tcp]
            r = -float(np.linalg.norm(tcp - gear))
        return r + 50.0 * reward - 0.1 * float(info["human_contacts"])


def train_flat_policy(steps: int, seed: int, out: Path, progress: bool = False) -> dict[str, Any]:
    """Train PPO for ``steps`` environment steps; save ``out/flat_policy.safetensors`` and
    ``.json``; return the report (budget, wall seconds, last mean episode reward)."""
    return save_flat_policy(fit_flat_policy(steps, seed, progress), out)


def fit_flat_policy(steps: int, seed: int,
                    progress: bool = False) -> tuple[dict[str, Any], dict[str, Any]]:
    """Train PPO for ``steps`` environment steps, writing nothing: the policy's
    ``state_dict`` (CPU tensors) and the report of :func:`train_flat_policy`. Depends on
    ``steps`` and ``seed`` alone (SB3 seeds its generators, the environment and the
    action space from ``seed``; the training runs inside
    :func:`~dynoplan.models.trainer.deterministic_training`, one thread, restored
    afterwards), so it gives the same weights to the bit in any process on one machine
    (a Ray task, while other work goes on)."""
    from dynoplan.models.trainer import deterministic_training

    with deterministic_training():
        return _fit_flat_policy(steps, seed, progress)


def _fit_flat_policy(steps: int, seed: int,
                     progress: bool) -> tuple[dict[str, Any], dict[str, Any]]:
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.logger import Logger

    if steps < 64:
        raise DynoplanError(f"--flat-steps must be >= 64, got {steps}")
    env = FlatGearTask()
    env.reset(seed=seed)
    n_steps = min(512, steps)
    model = PPO("MlpPolicy", env, n_steps=n_steps, batch_size=min(64, n_steps), seed=seed,
                device="cpu", verbose=0, policy_kwargs={"net_arch": list(NET_ARCH)})
    # a logger that writes nothing: left alone, SB3 makes an SB3-<time> folder in /tmp
    model.set_logger(Logger(folder=None, output_formats=[]))
    t0 = time.perf_counter()
    model.learn(total_timesteps=steps, progress_bar=progress)
    seconds = time.perf_counter() - t0
    rewards = [float(e["r"]) for e in model.ep_info_buffer] if model.ep_info_buffer else []
    state = {k: v.detach().contiguous() for k, v in model.policy.state_dict().items()}
    report = {"format_version": FORMAT_VERSION, "algorithm": "PPO", "env_steps": int(steps),
              "net_arch": list(NET_ARCH), "n_steps": n_steps, "seed": seed,
              "train_seconds": seconds, "torch": torch.__version__,
              "episode_reward_mean_last": float(np.mean(rewards[-20:])) if rewards else None}
    env.close()
    return state, report


def save_flat_policy(fitted: tuple[dict[str, Any], dict[str, Any]], out: Path) -> dict[str, Any]:
    """Write :func:`fit_flat_policy`'s result into ``out`` (``flat_policy.safetensors``
    and ``flat_policy.json``, which :class:`FlatPolicy` reads; the JSON without the
    report's wall-clock ``train_seconds``); return the report, with them."""
    from safetensors.torch import save_file

    state, report = fitted
    out.mkdir(parents=True, exist_ok=True)
    write_with(out / WEIGHTS_FILE, lambda p: save_file(state, str(p)))
    write_json(out / META_FILE, without_wall_clock(report))  # the same bytes for the same fit
    return report


def read_flat_policy(folder: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """The checked metadata and weights (``state_dict``, CPU tensors) of a flat policy
    folder written by :func:`save_flat_policy`; no network is built.

    Raises:
        DynoplanError: one line naming the file and the field: a missing or malformed
            ``flat_policy.json`` (not an object, another ``format_version``, a
            ``net_arch`` that is not a list of 1 to :data:`NET_ARCH_MAX_LAYERS` positive
            integers, or that describes a network larger than the weights file), an
            unreadable weights file, or a weight that is NaN or infinite.
    """
    from safetensors.torch import load_file

    from dynoplan.models.mlp_file import check_parameter_count

    meta_path, weights = folder / META_FILE, folder / WEIGHTS_FILE
    meta = read_json_object(meta_path, "flat policy's metadata")
    if meta.get("format_version") != FORMAT_VERSION:
        raise DynoplanError(f"{meta_path}: format_version {meta.get('format_version')!r}, "
                            f"expected {FORMAT_VERSION}")
    arch = meta.get("net_arch")
    if (not isinstance(arch, list) or not 1 <= len(arch) <= NET_ARCH_MAX_LAYERS
            or not all(isinstance(h, int) and not isinstance(h, bool) and h >= 1
                       for h in arch)):
        raise DynoplanError(f"{meta_path}: field 'net_arch' must be a list of 1 to "
                            f"{NET_ARCH_MAX_LAYERS} positive integers, got {arch!r}")
    if not weights.is_file():
        raise DynoplanError(f"{weights}: flat-policy weights not found")
    try:
        state = load_file(str(weights))
    except Exception as exc:  # safetensors raises several types on corrupt files
        raise DynoplanError(f"{weights}: not a valid flat-policy file "
                            f"({exc.__class__.__name__})") from None
    for name, tensor in state.items():
        if tensor.is_floating_point() and not bool(tensor.isfinite().all()):
            raise DynoplanError(f"{weights}: tensor '{name}' must be finite, it holds NaN "
                                "or infinity")
    check_parameter_count(weights, {k: v.numpy() for k, v in state.items()},
                          [OBS_DIM, *arch, ACTION_DIM])
    return meta, state


class FlatPolicy:
    """A trained flat policy: ``act(observation (50,)) -> env action (13,)`` for the raw
    :class:`GearAssemblyEnv` (it applies the same action mapping as training)."""

    def __init__(self, folder: Path, env: GearAssemblyEnv) -> None:
        """Load the policy in ``folder`` (:func:`read_flat_policy` checks it first).

        Raises:
            DynoplanError: as :func:`read_flat_policy`, or weights of another network.
        """
        from stable_baselines3 import PPO

        meta, state = read_flat_policy(folder)
        self.wrapper = FlatGearTask(env)
        self.model = PPO("MlpPolicy", self.wrapper, device="cpu",
                         policy_kwargs={"net_arch": list(meta["net_arch"])})
        try:
            self.model.policy.load_state_dict(state)
        except RuntimeError as exc:  # missing, unexpected or mis-shaped tensors
            first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise DynoplanError(f"{folder / WEIGHTS_FILE}: weights do not fit the net_arch "
                                f"{meta['net_arch']} of {META_FILE} ({first})") from None
        self.meta = meta
        self.env = env
        # what PPO.predict does per call, done once: evaluation mode (it has no dropout
        # or batch norm, so this only saves predict's per-call module walk)
        self.model.policy.set_training_mode(False)
        space = self.model.policy.action_space
        assert isinstance(space, gym.spaces.Box)
        self._low, self._high = space.low, space.high

    def act(self, observation: FloatArray) -> FloatArray:
        import torch

        # PPO.predict(observation, deterministic=True) without its per-call overhead:
        # the same network, the mean action clipped to the action space
        obs = torch.as_tensor(np.asarray(observation, dtype=np.float32)).reshape(1, -1)
        with torch.no_grad():
            mean = self.model.policy.get_distribution(obs).get_actions(deterministic=True)
        a = np.clip(mean.numpy().reshape(-1), self._low, self._high)
        a = np.clip(np.asarray(a, dtype=np.float64), -1.0, 1.0)
        q = np.asarray(observation, dtype=np.float64)[OBS_SLICES["arm_qpos"]].copy()
        q[:6] += JOINT_STEP * a[:6]
        lim = self.env.joint_limits
        return np.concatenate([np.clip(q, lim[:, 0], lim[:, 1]), [(a[6] + 1.0) / 2.0]])


METRIC_KEYS = ("human_contacts", "min_human_distance", "robot_speed", "human_speed")
"""Step ``info`` entries a flat policy's episode records: what
:func:`~dynoplan.envs.gear.metrics.gear_metrics` reads."""


@dataclass
class FlatPolicyRunner:
    """A flat policy ``act(observation) -> action`` on the gear, as an episode runner of
    the evaluation: the pipeline's recorder runs it as one option that acts until the
    episode ends (no decisions; its "decision latency" is the time of one ``act`` call)."""

    env: GearAssemblyEnv
    act: Callable[[FloatArray], FloatArray]

    def episode(self, seed: EpisodeSeed) -> EpisodeRecord:
        ms: list[float] = []

        def timed(observation: FloatArray, _: Generator) -> FloatArray:
            t0 = time.perf_counter()
            action = self.act(observation)
            ms.append(1e3 * (time.perf_counter() - t0))
            return action

        obs, info = self.env.reset(seed=seed.env_seed)
        spec = OptionSpec(FLAT_POLICY, FunctionPolicy(timed), ConstantTermination(0.0))
        recording = record_episode(self.env, [spec], CallableDemonstrator(lambda _: FLAT_POLICY),
                                   seed.env_seed, seed.rng(),
                                   start=RunStart(obs, info, seed.env_seed),
                                   info_keys=METRIC_KEYS)
        episode = recording.episode
        infos = [{key: episode.infos[key][t] for key in METRIC_KEYS} for t in range(len(episode))]
        metrics = gear_metrics(self.env, infos, float(info["min_human_distance"]))
        return EpisodeRecord(seed.env_seed, recording.success, len(episode),
                             float(sum(episode.rewards.tolist())), 0, 0, 0, 0, tuple(ms), (),
                             (), metrics)


__all__ = ["FLAT_POLICY", "METRIC_KEYS", "FlatGearTask", "FlatPolicy", "FlatPolicyRunner",
           "fit_flat_policy", "read_flat_policy", "save_flat_policy", "train_flat_policy"]
