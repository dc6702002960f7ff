"""Safety of the robot around people: ISO/TS 15066 speed and separation monitoring."""

from dynoplan.safety.separation import (
    AT_REST_SPEED,
    SeparationParameters,
    protective_separation,
)

__all__ = ["AT_REST_SPEED", "SeparationParameters", "protective_separation"]
