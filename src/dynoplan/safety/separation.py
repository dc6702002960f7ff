"""The protective separation distance of ISO/TS 15066 (speed and separation monitoring).

While the robot moves it must stay at least

    S_p = v_h (T_r + T_s) + v_r T_r + B + C + Z_d + Z_r

from the person (ISO/TS 15066:2016, 5.5.4, Eq. 1, with constant speeds over the reaction
and stopping time): the person's approach during the robot's reaction and stopping time,
the robot's travel during its reaction time, its stopping distance ``B``, the intrusion
distance ``C`` (how far a body part reaches beyond where it is sensed) and the position
uncertainties of the person ``Z_d`` and of the robot ``Z_r``. A robot at rest may be
touched (it is then a quasi-static contact the standard bounds separately, by force).
"""

from dataclasses import dataclass

import numpy as np

from dynoplan.types import FloatArray

AT_REST_SPEED = 0.01
"""m/s: below this speed of its fastest point the robot counts as at rest."""


def require_non_negative(constants: object) -> None:
    """Raise ``ValueError`` naming the first attribute of ``constants`` (a dataclass of
    SI constants) that is not finite and >= 0."""
    for name, value in vars(constants).items():
        if not (np.isfinite(value) and value >= 0.0):
            raise ValueError(f"{name} must be finite and >= 0, got {value}")


@dataclass(frozen=True)
class SeparationParameters:
    """The constants of :func:`protective_separation` (SI units).

    Attributes:
        reaction_time: ``T_r`` (s), from the person's being sensed to the robot's stop
            command taking effect: one control period of 0.05 s plus 0.05 s of sensing.
        stopping_time: ``T_s`` (s), for the robot to come to rest once braking.
        human_speed_bound: ``v_h`` (m/s) when the person's speed is not measured: ISO
            13855's walking speed of 1.6 m/s.
        intrusion: ``C`` (m), how far a hand reaches beyond its sensed position.
        human_uncertainty: ``Z_d`` (m), the sensed position's error.
        robot_uncertainty: ``Z_r`` (m), the robot's position error.
    """

    reaction_time: float = 0.1
    stopping_time: float = 0.2
    human_speed_bound: float = 1.6
    intrusion: float = 0.05
    human_uncertainty: float = 0.02
    robot_uncertainty: float = 0.01

    def __post_init__(self) -> None:
        require_non_negative(self)

    def stopping_distance(self, robot_speed: FloatArray | float) -> FloatArray:
        """``B`` (m): braking from ``robot_speed`` at constant deceleration in
        ``stopping_time``, ``v_r T_s / 2``."""
        return 0.5 * np.asarray(robot_speed, dtype=np.float64) * self.stopping_time


def protective_separation(robot_speed: FloatArray | float,
                          human_speed: FloatArray | float | None = None,
                          params: SeparationParameters = SeparationParameters()) -> FloatArray:
    """``S_p`` (m) for the robot's speed ``v_r`` and the person's ``v_h`` (m/s; ``None``:
    ``params.human_speed_bound``); arrays broadcast, shape of their broadcast.

    Raises:
        ValueError: a negative or non-finite speed.
    """
    v_r = np.asarray(robot_speed, dtype=np.float64)
    v_h = np.asarray(params.human_speed_bound if human_speed is None else human_speed,
                     dtype=np.float64)
    if not (np.all(np.isfinite(v_r)) and np.all(np.isfinite(v_h))
            and np.all(v_r >= 0) and np.all(v_h >= 0)):
        raise ValueError("speeds must be finite and >= 0")
    out: FloatArray = (v_h * (params.reaction_time + params.stopping_time)
                       + v_r * params.reaction_time + params.stopping_distance(v_r)
                       + params.intrusion + params.human_uncertainty
                       + params.robot_uncertainty)
    return out
