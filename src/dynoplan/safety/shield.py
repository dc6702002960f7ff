"""A runtime monitor independent of the planner: a protective stop below ``S_p``.

:class:`SeparationShield` wraps an environment whose ``info`` measures, after every step,
the robot-human separation (``min_human_distance``, m), the robot's speed
(``robot_speed``, m/s, its fastest point) and the person's (``human_speed``). Before each
step it checks the last measurement: if the robot moves (at :data:`AT_REST_SPEED` or more)
closer to the person than the protective separation distance ``S_p``
(:func:`~dynoplan.safety.separation.protective_separation`), it replaces the action by the
task's stop action for that step and counts a protective stop. Whatever chose the action
(an option's policy, a planner, a person at a keyboard) is not consulted; the monitor
needs nothing but the measurements.

``info["protective_stop"]`` is True on the steps it stopped, and
``info["protective_stops"]`` counts them since the reset.
"""

from collections.abc import Callable
from typing import Any

import gymnasium as gym

from dynoplan.safety.separation import (
    AT_REST_SPEED,
    SeparationParameters,
    protective_separation,
)

MEASURED = ("min_human_distance", "robot_speed", "human_speed")
"""The ``info`` keys the shield reads after every reset and step."""


class SeparationShield(gym.Wrapper[Any, Any, Any, Any]):
    """Stops the robot for a step whenever it moves closer to the person than ``S_p``.

    Args:
        env: reports :data:`MEASURED` in ``info`` after ``reset`` and ``step``.
        stop_action: ``stop_action(observation) -> action`` that brings the robot to rest
            (for example: hold the joints where they are).
        params: the constants of ``S_p``.
    """

    def __init__(self, env: gym.Env[Any, Any], stop_action: Callable[[Any], Any],
                 params: SeparationParameters = SeparationParameters()) -> None:
        super().__init__(env)
        self.stop_action = stop_action
        self.params = params
        self.stops = 0
        self._observation: Any = None
        self._info: dict[str, Any] = {}

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        self.stops = 0
        return obs, self._record(obs, info, stopped=False)

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        stop = self.must_stop(self._info)
        if stop:
            action = self.stop_action(self._observation)
            self.stops += 1
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, terminated, truncated, self._record(obs, info, stopped=stop)

    def must_stop(self, info: dict[str, Any]) -> bool:
        """The robot moves and is closer to the person than ``S_p`` (by ``info``)."""
        missing = [k for k in MEASURED if k not in info]
        if missing:
            raise KeyError(f"the separation shield needs info keys {', '.join(missing)}")
        speed = float(info["robot_speed"])
        if speed < AT_REST_SPEED:
            return False
        s_p = float(protective_separation(speed, float(info["human_speed"]), self.params))
        return float(info["min_human_distance"]) < s_p

    def _record(self, obs: Any, info: dict[str, Any], stopped: bool) -> dict[str, Any]:
        self._observation, self._info = obs, info
        info = dict(info)
        info["protective_stop"] = stopped
        info["protective_stops"] = self.stops
        return info


__all__ = ["MEASURED", "SeparationShield"]
