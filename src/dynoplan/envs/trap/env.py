"""``dynoplan/TrapWalk-v0``: a walk with a dead end that only a detour gets around.

A corridor of positions ``0..length`` with two lanes. The main lane (0) is blocked by a
wall just past position ``wall``: a right step there does nothing. The bypass lane (1)
has no wall, and the lanes meet only at the gate, positions ``0..gate`` (``gate <
wall``): a lane switch works there and nowhere else. Reaching position ``length`` on
either lane ends the episode with reward +1 (success).

Actions: 0 steps left (not below 0), 1 steps right (it slips, leaving the position
unchanged, with probability ``slip``), 2 switches lanes (at the gate only).

Progress along the corridor, ``x / length``, is a goal heuristic that is right about
the goal and wrong about the way: at the wall, every way on first goes back to the
gate. One-step hill climbing over options (Eq. 1) stalls at the wall; a look-ahead of
two options (back to the gate and across, then on along the bypass) does not
(``docs/trap.md``).
"""

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

LEFT, RIGHT, SWITCH = 0, 1, 2


class TrapWalkEnv(gym.Env[np.ndarray, np.int64]):
    """The trap walk. Observation: ``[position, lane]`` (``MultiDiscrete``, int64).

    Args:
        length: the goal position.
        wall: the last position of the main lane that a right step can reach.
        gate: the last position where the lanes meet.
        slip: probability that a right step leaves the position unchanged.
    """

    metadata = {"render_modes": ["ansi"], "render_fps": 4}  # noqa: RUF012 (Gymnasium API)

    def __init__(self, length: int = 20, wall: int = 8, gate: int = 4, slip: float = 0.1,
                 render_mode: str | None = None) -> None:
        if not 0 <= gate < wall < length:
            raise ValueError(f"need 0 <= gate < wall < length, got {gate}, {wall}, {length}")
        if not 0.0 <= slip < 1.0:
            raise ValueError(f"slip must be in [0, 1), got {slip}")
        self.length, self.wall, self.gate, self.slip = length, wall, gate, float(slip)
        self.render_mode = render_mode
        self.observation_space = spaces.MultiDiscrete([length + 1, 2])
        self.action_space = spaces.Discrete(3)
        self._x, self._lane = 0, 0

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        self._x, self._lane = 0, 0
        return self._obs(), {"is_success": False}

    def step(self, action: np.int64 | int) -> tuple[np.ndarray, float, bool, bool,
                                                     dict[str, Any]]:
        if not self.action_space.contains(np.int64(action)):
            raise ValueError(f"invalid action {action!r}; expected 0 (left), 1 (right) "
                             f"or 2 (switch lanes)")
        a = int(action)
        if a == LEFT:
            self._x = max(self._x - 1, 0)
        elif a == RIGHT:
            blocked = self._lane == 0 and self._x >= self.wall
            if not blocked and self.np_random.random() >= self.slip:
                self._x += 1
        elif self._x <= self.gate:
            self._lane = 1 - self._lane
        terminated = self._x >= self.length
        return self._obs(), float(terminated), terminated, False, {"is_success": terminated}

    def _obs(self) -> np.ndarray:
        return np.array([self._x, self._lane], dtype=np.int64)

    def render(self) -> str | None:
        if self.render_mode != "ansi":
            return None
        lanes = []
        for lane in (1, 0):
            cells = ["." if lane == 1 or x <= self.wall else "#"
                     for x in range(self.length + 1)]
            cells[-1] = "G"
            if lane == self._lane:
                cells[self._x] = "@"
            lanes.append("".join(cells))
        return "\n".join(lanes)
