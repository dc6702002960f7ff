"""Faults injected into gear episodes, to measure recovery by replanning.

- :class:`ObservationNoise`: Gaussian noise on what the controller and the policies
  observe (arm joints, finger openings, object and human positions);
- :class:`GraspSlip`: once per episode, while the gear is being lifted (held, its bottom
  1-6 cm above the table), the gripper is forced open for half a second: the gear drops
  back on the table and the running option (pick) has failed mid-run.

Dynamics-prediction noise is :class:`dynoplan.models.corruption.NoisyDynamics`.
"""

from typing import Any

import gymnasium as gym
import numpy as np

from dynoplan.envs.gear.env import OBS_SLICES, GearAssemblyEnv
from dynoplan.envs.gear.scene import TABLE_TOP_Z
from dynoplan.types import FloatArray

_NOISY = ("arm_qpos", "fingers", "gear_pos", "peg_pos", "human_pos")


class ObservationNoise(gym.Wrapper[Any, Any, Any, Any]):
    """Adds ``N(0, std)`` to the observed positions; seeded by ``reset(seed=...)``."""

    def __init__(self, env: GearAssemblyEnv, std: float = 0.005) -> None:
        super().__init__(env)
        self.std = std
        self.mask = np.zeros(env.observation_space.shape or (50,), dtype=bool)
        for key in _NOISY:
            self.mask[OBS_SLICES[key]] = True
        self._rng = np.random.default_rng(0)

    def _noisy(self, obs: FloatArray) -> FloatArray:
        out = obs.copy()
        out[self.mask] += self._rng.normal(0.0, self.std, size=int(self.mask.sum()))
        return out

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[FloatArray, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        self._rng = np.random.default_rng([0 if seed is None else seed, 1])
        return self._noisy(obs), info

    def step(self, action: FloatArray) -> tuple[FloatArray, Any, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return self._noisy(obs), reward, terminated, truncated, info


class GraspSlip(gym.Wrapper[Any, Any, Any, Any]):
    """Opens the gripper for ``duration`` steps the first time the gear is held low
    (see the module docstring); ``info["slipped"]`` says whether it has happened."""

    def __init__(self, env: GearAssemblyEnv, duration: int = 10) -> None:
        super().__init__(env)
        self.gear_env = env
        self.duration = duration
        self._left = 0
        self._done = False

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[FloatArray, dict[str, Any]]:
        self._left, self._done = 0, False
        obs, info = self.env.reset(seed=seed, options=options)
        info["slipped"] = False
        return obs, info

    def step(self, action: FloatArray) -> tuple[FloatArray, Any, bool, bool, dict[str, Any]]:
        act = np.asarray(action, dtype=np.float64).copy()
        if self._left > 0:
            act[12] = 0.0
            self._left -= 1
        obs, reward, terminated, truncated, info = self.env.step(act)
        height = float(obs[OBS_SLICES["gear_pos"]][2]) - TABLE_TOP_Z
        if not self._done and int(info["pads_on_gear"]) >= 2 and 0.01 < height < 0.06:
            self._done, self._left = True, self.duration
        info["slipped"] = self._done
        return obs, reward, terminated, truncated, info


__all__ = ["GraspSlip", "ObservationNoise"]
