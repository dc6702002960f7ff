"""``dynoplan/RandomWalk19-v0``: the chain of Harutyunyan et al. (2018) as the paper uses it.

Our reading of the paper (its Figure 2 plots states 0..20 and starts at state 0):
non-terminal states ``0..19``, terminal state ``20``; the episode starts at ``start_state``
(default 0); action 0 steps left, 1 steps right; a left step at state 0 stays at 0;
stepping right from state 19 enters state 20, which ends the episode with reward +1.
Every other step gives reward 0.
"""

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

LEFT, RIGHT = 0, 1


class RandomWalkEnv(gym.Env[np.int64, np.int64]):
    """The random walk. Observation: the state index in ``0..n_states`` (``Discrete``).

    Args:
        n_states: non-terminal states (19 in the paper's name, numbered 0..19 here, so
            the default chain has 20 non-terminal states and the goal at 20: the paper's
            Figure 2 reading).
        start_state: where episodes start; ``reset(options={"start_state": k})``
            overrides it for one episode.
    """

    metadata = {"render_modes": ["ansi"], "render_fps": 4}  # noqa: RUF012 (Gymnasium API)

    def __init__(self, goal_state: int = 20, start_state: int = 0,
                 render_mode: str | None = None) -> None:
        if goal_state < 1:
            raise ValueError(f"goal_state must be >= 1, got {goal_state}")
        if not 0 <= start_state < goal_state:
            raise ValueError(f"start_state must be in [0, {goal_state}), got {start_state}")
        self.goal_state = goal_state
        self.start_state = start_state
        self.render_mode = render_mode
        self.observation_space = spaces.Discrete(goal_state + 1)
        self.action_space = spaces.Discrete(2)
        self._state = start_state

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.int64, dict[str, Any]]:
        super().reset(seed=seed)
        start = int((options or {}).get("start_state", self.start_state))
        if not 0 <= start < self.goal_state:
            raise ValueError(f"start_state must be in [0, {self.goal_state}), got {start}")
        self._state = start
        return np.int64(self._state), {"is_success": False}

    def step(self, action: np.int64 | int) -> tuple[np.int64, float, bool, bool, dict[str, Any]]:
        # the action space's own check, without its per-call cost (the step is hot)
        if (not isinstance(action, int) and np.ndim(action) != 0) \
                or int(action) not in (LEFT, RIGHT):
            raise ValueError(f"invalid action {action!r}; expected 0 (left) or 1 (right)")
        if int(action) == RIGHT:
            self._state += 1
        else:
            self._state = max(self._state - 1, 0)
        terminated = self._state == self.goal_state
        reward = 1.0 if terminated else 0.0
        return np.int64(self._state), reward, terminated, False, {"is_success": terminated}

    def render(self) -> str | None:
        if self.render_mode != "ansi":
            return None
        cells = ["." for _ in range(self.goal_state + 1)]
        cells[-1] = "G"
        cells[self._state] = "@"
        return "".join(cells)
