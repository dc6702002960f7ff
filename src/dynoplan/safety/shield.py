"""A runtime monitor independent of the planner: a protective stop below ``S_p``.

:class:`SeparationShield` wraps an environment whose ``info`` measures, after every step,
the robot-human separation (``min_human_distance``, m), the robot's speed
(``robot_speed``, m/s, its fastest point) and the person's (``human_speed``). Before each
step it anticipates the next measurement (:class:`Anticipation`): if, one control period
from now, the robot could be moving closer to the person than the protective separation
distance ``S_p`` (:func:`~dynoplan.safety.separation.protective_separation`) at the speeds
both could then have, it replaces the action by the task's stop action for that step and
counts a protective stop. Judging the measurement alone (is the robot within ``S_p`` now?)
lets the step in which the separation falls below ``S_p`` through: a monitor acts one
control period after it measures, which is what ISO/TS 15066's reaction time ``T_r`` is
for. Whatever chose the action (an option's policy, a planner, a person at a keyboard) is
not consulted; the monitor needs nothing but the measurements.

``info["protective_stop"]`` is True on the steps it stopped, and
``info["protective_stops"]`` counts them since the reset.
"""

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import gymnasium as gym

from dynoplan.safety.separation import (
    AT_REST_SPEED,
    SeparationParameters,
    protective_separation,
    require_non_negative,
)

MEASURED = ("min_human_distance", "robot_speed", "human_speed")
"""The ``info`` keys the shield reads after every reset and step."""


@dataclass(frozen=True)
class Anticipation:
    """How far the measured speeds can change before the next measurement (SI units).

    Attributes:
        control_period: ``T_c`` (s) between two measurements (two actions).
        robot_acceleration: ``a_r`` (m/s^2) bound on the change of the robot's speed
            (its fastest point) while an action drives it.
        restart_speed: ``v_0`` (m/s) bound on the robot's speed one period after a
            protective stop: the first action after a stop may command a jump (the task
            bounds it: the gear's options resume within 0.1 rad of the stopped arm).
        human_acceleration: ``a_h`` (m/s^2) bound on the change of the person's speed.
    """

    control_period: float = 0.05
    robot_acceleration: float = 10.0
    restart_speed: float = 0.5
    human_acceleration: float = 11.0

    def __post_init__(self) -> None:
        require_non_negative(self)

    def next_speeds(self, robot_speed: float, human_speed: float,
                    after_stop: bool) -> tuple[float, float]:
        """``(v_r', v_h')`` (m/s): the fastest the robot and the person can be at the next
        measurement, from their measured speeds now (``after_stop``: this period's
        action is the first after a protective stop)."""
        v_r = (max(robot_speed, self.restart_speed) if after_stop
               else robot_speed + self.robot_acceleration * self.control_period)
        return v_r, human_speed + self.human_acceleration * self.control_period

    def separation_bound(self, distance: float, robot_speed: float,
                         human_speed: float) -> float:
        """m: the least separation one period from now when it is ``distance`` now and
        the two approach each other at most at these speeds."""
        return distance - (robot_speed + human_speed) * self.control_period


class SeparationShield(gym.Wrapper[Any, Any, Any, Any]):
    """Stops the robot for a step whenever, one control period ahead, it could be moving
    closer to the person than ``S_p``.

    Args:
        env: reports :data:`MEASURED` in ``info`` after ``reset`` and ``step``.
        stop_action: ``stop_action(observation) -> action`` that brings the robot to rest
            (for example: hold the joints where they are).
        params: the constants of ``S_p``.
        anticipation: the bounds on how the speeds change within a control period.
    """

    def __init__(self, env: gym.Env[Any, Any], stop_action: Callable[[Any], Any],
                 params: SeparationParameters = SeparationParameters(),
                 anticipation: Anticipation = Anticipation()) -> None:
        super().__init__(env)
        self.stop_action = stop_action
        self.params = params
        self.anticipation = anticipation
        self.stops = 0
        self._stopped = False
        self._observation: Any = None
        self._info: dict[str, Any] = {}

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        self.stops = 0
        self._stopped = False
        return obs, self._record(obs, info, stopped=False)

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        stop = self.must_stop(self._info, after_stop=self._stopped)
        if stop:
            action = self.stop_action(self._observation)
            self.stops += 1
        self._stopped = stop
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, terminated, truncated, self._record(obs, info, stopped=stop)

    def must_stop(self, info: dict[str, Any], after_stop: bool = False) -> bool:
        """By the measurement ``info``: one control period from now, the robot could
        move (at :data:`AT_REST_SPEED` or more) closer to the person than ``S_p`` at the
        speeds both could then have (:meth:`Anticipation.next_speeds`; ``after_stop``:
        the last step was a protective stop)."""
        missing = [k for k in MEASURED if k not in info]
        if missing:
            raise KeyError(f"the separation shield needs info keys {', '.join(missing)}")
        v_r, v_h = self.anticipation.next_speeds(
            float(info["robot_speed"]), float(info["human_speed"]), after_stop)
        if v_r < AT_REST_SPEED:
            return False
        s_p = float(protective_separation(v_r, v_h, self.params))
        ahead = self.anticipation.separation_bound(float(info["min_human_distance"]), v_r, v_h)
        return ahead < s_p

    def _record(self, obs: Any, info: dict[str, Any], stopped: bool) -> dict[str, Any]:
        self._observation, self._info = obs, info
        info = dict(info)
        info["protective_stop"] = stopped
        info["protective_stops"] = self.stops
        return info


__all__ = ["MEASURED", "Anticipation", "SeparationShield"]
