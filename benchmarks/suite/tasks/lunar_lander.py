"""Land Gymnasium's continuous lunar lander on its pad, from a start beside the pad.

The environment is Gymnasium's Box2D ``LunarLander-v3`` with ``continuous=True`` (the
``gymnasium[box2d]`` extra): a lander with a throttled main engine and two side engines
(``action = [main, lateral]`` in ``[-1, 1]``; the main engine is off at ``main <= 0``
and runs at 50-100 % above; the side engines fire at ``|lateral| > 0.5``) must land on
a flat pad between two flags, on the moon's random terrain. The observation is
``[x, y, vx, vy, angle, angular velocity, left leg contact, right leg contact]``, ``x``
and ``y`` relative to the centre of the pad (the pad spans ``|x| <= 0.2``; one unit of
``x`` is 10 m, of ``y`` 6.7 m; one unit of ``vx`` is 5 m/s, of ``vy`` 7.5 m/s).

Two changes, registered as ``LunarLanderPad-v0`` (600 steps, 12 s at 50 Hz):

- **The lander enters beside the pad.** Gymnasium drops it above the pad's centre (with
  a random initial push); here it is moved sideways by 3-6 m (``|x|`` in
  ``[0.3, 0.6]``, a side drawn at random), drawn from the environment's own seeded
  generator, so that reaching the pad takes a flight sideways.
- **Success: landed on the pad and at rest.** Both legs touch the ground, the lander's
  centre is over the pad (``|x| <= 0.2``) and it is still (``|vx|, |vy| < 0.02``,
  ``|angular velocity| < 0.05``) for ``HOLD_STEPS`` consecutive steps; the episode
  then terminates with ``info["is_success"] = True``. Every other termination (a crash,
  leaving the screen, falling asleep off the pad) has ``is_success = False``.

Options (plain functions of the observation; one velocity-tracking flight controller
under all of them, attitude from the side engines, vertical speed from the main engine):

- ``hover``: stabilise; kill the horizontal and vertical speed, level attitude. Done
  when the lander is steady.
- ``translate``: fly over the pad at constant altitude (horizontal speed proportional to
  the distance to the pad, at most 2.5 m/s). Done when over the pad's centre and slow.
- ``descend``: go down without drifting sideways, braking on the way (sink rate
  ``0.9 sqrt(y)``, 0.75-4 m/s). Done below ``y = 0.12`` (about 0.8 m above the pad's
  level).
- ``touchdown``: sink at 0.75 m/s, level; once a leg touches, cut both engines. Done when
  both legs touch and the lander is still.
- ``full_throttle``: the distractor; main engine at full power, no steering.

The demonstrator (:class:`PadLanding`): ``hover`` until steady, ``translate`` until
over the pad, ``descend`` until low, ``touchdown``. It goes back to ``translate``
whenever the lander is (again) more than ``0.15`` from the pad's centre while in the
air, and to ``touchdown`` whenever a leg touches.

Disturbance (:func:`disturb`): a lateral push; once per episode, at a random step
between 40 and 200, an impulse on the lander's body that changes its horizontal speed
by 1.5-2.5 m/s either way (the demonstrator flies back over the pad).
"""

from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium.envs.box2d.lunar_lander import LunarLander

from dynoplan.adapters import OptionSpec, option_spec
from dynoplan.pipeline import Demonstrator

ENV_ID = "LunarLanderPad-v0"
MAX_STEPS = 600
X, Y, VX, VY, ANGLE, SPIN, LEFT_LEG, RIGHT_LEG = range(8)

START_OFFSET = (0.3, 0.6)
"""Range of ``|x|`` the lander is moved to at reset (pad half-width is 0.2)."""
METRES_PER_X = 10.0
"""World metres per unit of the observation's ``x``."""
PAD_HALF_WIDTH = 0.2
HOLD_STEPS = 10
"""Consecutive steps at rest on the pad that make a success (0.2 s)."""
REST_SPEED = 0.02
REST_SPIN = 0.05

MAIN_HOVER = 0.16
"""Main-engine command that about balances the lander's weight (58 % power)."""
VERTICAL_GAIN = 10.0
TILT_GAIN = 1.5
"""Tilt (rad) per unit of horizontal speed error."""
MAX_TILT = 0.4
ATTITUDE_GAIN = 2.0
"""Spin (observation units) commanded per radian of attitude error."""
SIDE_GAIN = 20.0
"""Side-engine command per unit of spin error."""
CRUISE_SPEED = 0.5
"""Largest horizontal speed of ``translate`` (observation units: 2.5 m/s)."""
APPROACH_GAIN = 3.0
"""Horizontal speed commanded by ``translate`` per unit of distance to the pad."""
DESCENT_GAIN = 0.9
"""Sink rate commanded by ``descend`` per square root of the altitude (a constant
deceleration profile)."""
DESCENT_SPEEDS = (0.1, 0.55)
"""Slowest and fastest sink rate of ``descend`` (observation units: 0.75 and 4 m/s)."""
LOW = 0.12
"""Altitude (observation units) where ``descend`` hands over to ``touchdown``."""
TOUCHDOWN_SINK = 0.1
"""Sink rate of ``touchdown`` (observation units: 0.75 m/s)."""
OVER_PAD = 0.04
OFF_PAD = 0.15


class PadLander(LunarLander):
    """``LunarLander`` whose lander starts 3-6 m beside the pad (see the module
    docstring); the offset comes from the environment's seeded generator."""

    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed, options=options)
        side = 1.0 if self.np_random.random() < 0.5 else -1.0
        shift = side * float(self.np_random.uniform(*START_OFFSET)) * METRES_PER_X
        assert self.lander is not None
        for body in [self.lander, *self.legs]:
            body.position = (body.position[0] + shift, body.position[1])
        observation = self.step(np.zeros(2, dtype=np.float32))[0]
        return np.asarray(observation, dtype=np.float32), {}


def landed(observation: Any) -> bool:
    """Both legs on the ground, over the pad, and still (one step of it)."""
    o = np.asarray(observation, dtype=np.float64)
    return bool(o[LEFT_LEG] > 0.5 and o[RIGHT_LEG] > 0.5 and abs(o[X]) <= PAD_HALF_WIDTH
                and abs(o[VX]) < REST_SPEED and abs(o[VY]) < REST_SPEED
                and abs(o[SPIN]) < REST_SPIN)


class LandOnPad(gym.Wrapper[Any, Any, Any, Any]):
    """Success = :func:`landed` for ``HOLD_STEPS`` consecutive steps: terminates with
    ``info["is_success"] = True``; every other step reports ``False``."""

    def __init__(self, env: gym.Env[Any, Any]) -> None:
        super().__init__(env)
        self.held = 0

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        self.held = 0
        return self.env.reset(**kwargs)

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.held = self.held + 1 if landed(obs) else 0
        success = self.held >= HOLD_STEPS
        return obs, float(reward), bool(terminated) or success, truncated, {
            **info, "is_success": success}


def make_env(**kwargs: Any) -> gym.Env[Any, Any]:
    """:class:`PadLander` (continuous) with :class:`LandOnPad`."""
    return LandOnPad(PadLander(continuous=True, **kwargs))


if ENV_ID not in gym.registry:
    gym.register(ENV_ID, entry_point=make_env, max_episode_steps=MAX_STEPS)

success = None
"""The environment reports ``info["is_success"]`` itself (:class:`LandOnPad`)."""
state_fn = None
"""The 8-value ``Box`` observation is the state."""


# --- options -----------------------------------------------------------------------------


def fly(observation: Any, vx_target: float, vy_target: float) -> np.ndarray:
    """Track a horizontal and a vertical speed: tilt towards the horizontal speed error
    (side engines hold the tilt), main engine about the hover throttle."""
    o = np.asarray(observation, dtype=np.float64)
    tilt = float(np.clip(TILT_GAIN * (o[VX] - vx_target), -MAX_TILT, MAX_TILT))
    turn = ATTITUDE_GAIN * (tilt - o[ANGLE]) - o[SPIN]
    main = MAIN_HOVER / max(np.cos(o[ANGLE]), 0.5) + VERTICAL_GAIN * (vy_target - o[VY])
    return np.clip(np.array([main, -SIDE_GAIN * turn]), -1.0, 1.0).astype(np.float32)


def hover(observation: Any) -> np.ndarray:
    """Stabilise: no horizontal or vertical speed, level."""
    return fly(observation, 0.0, 0.0)


def translate(observation: Any) -> np.ndarray:
    """Fly sideways over the pad's centre, holding altitude."""
    x = float(np.asarray(observation)[X])
    return fly(observation, float(np.clip(-APPROACH_GAIN * x, -CRUISE_SPEED, CRUISE_SPEED)), 0.0)


def descend(observation: Any) -> np.ndarray:
    """Go straight down, braking on the way: sink rate ``DESCENT_GAIN * sqrt(altitude)``
    within ``DESCENT_SPEEDS``."""
    y = max(float(np.asarray(observation)[Y]), 0.0)
    return fly(observation, 0.0, -float(np.clip(DESCENT_GAIN * np.sqrt(y), *DESCENT_SPEEDS)))


def touchdown(observation: Any) -> np.ndarray:
    """Sink slowly and level; engines off once a leg touches."""
    o = np.asarray(observation, dtype=np.float64)
    if o[LEFT_LEG] > 0.5 or o[RIGHT_LEG] > 0.5:
        return np.array([-1.0, 0.0], dtype=np.float32)
    return fly(observation, 0.0, -TOUCHDOWN_SINK)


def full_throttle(observation: Any) -> np.ndarray:
    """Main engine at full power, no steering (a distractor)."""
    return np.array([1.0, 0.0], dtype=np.float32)


def _steady(states: np.ndarray) -> np.ndarray:
    return np.asarray((np.abs(states[:, VX]) < 0.05) & (np.abs(states[:, VY]) < 0.05)
                      & (np.abs(states[:, ANGLE]) < 0.15) & (np.abs(states[:, SPIN]) < 0.1))


def hover_done(states: np.ndarray) -> np.ndarray:
    """The lander is steady (slow, level, not spinning)."""
    return _steady(states)


def translate_done(states: np.ndarray) -> np.ndarray:
    """Over the pad's centre and slow sideways."""
    return np.asarray((np.abs(states[:, X]) < OVER_PAD) & (np.abs(states[:, VX]) < 0.04))


def descend_done(states: np.ndarray) -> np.ndarray:
    """Low over the ground (the pad's level)."""
    return np.asarray(states[:, Y] < LOW)


def touchdown_done(states: np.ndarray) -> np.ndarray:
    """Both legs down and still."""
    return np.asarray((states[:, LEFT_LEG] > 0.5) & (states[:, RIGHT_LEG] > 0.5)
                      & (np.abs(states[:, VX]) < REST_SPEED)
                      & (np.abs(states[:, VY]) < REST_SPEED))


def make_options() -> list[OptionSpec]:
    """``hover``, ``translate``, ``descend``, ``touchdown`` (each done when its job is)
    and the distractor ``full_throttle`` (stops with probability 0.1 per step)."""
    return [
        option_spec("hover", hover, termination=hover_done),
        option_spec("translate", translate, termination=translate_done),
        option_spec("descend", descend, termination=descend_done),
        option_spec("touchdown", touchdown, termination=touchdown_done),
        option_spec("full_throttle", full_throttle, termination=0.1),
    ]


NEXT_PHASE = {"hover": "translate", "translate": "descend", "descend": "touchdown"}


class PadLanding(Demonstrator):
    """Hover until steady, translate over the pad, descend, touch down (see the module
    docstring)."""

    def reset(self, observation: Any, rng: np.random.Generator) -> None:
        self.phase = "hover"

    def choose(self, observation: Any) -> str:
        o = np.asarray(observation, dtype=np.float64)
        s = o[None]
        if o[LEFT_LEG] > 0.5 or o[RIGHT_LEG] > 0.5:
            self.phase = "touchdown"
        elif self.phase in ("descend", "touchdown") and abs(o[X]) > OFF_PAD:
            self.phase = "translate"
        else:
            done = {"hover": hover_done, "translate": translate_done,
                    "descend": descend_done}.get(self.phase)
            if done is not None and bool(done(s)[0]):
                self.phase = NEXT_PHASE[self.phase]
        return self.phase


def make_demonstrator() -> Demonstrator:
    """The demonstrator the command line uses for ``--demos N``."""
    return PadLanding()


# --- disturbance -------------------------------------------------------------------------

DISTURBANCE = ("a lateral push: once per episode, at a random step in [40, 200], the lander's "
               "horizontal speed changes by 1.5-2.5 m/s either way")


class LateralPush(gym.Wrapper[Any, Any, Any, Any]):
    """One sideways impulse on the lander per episode, drawn from the seed of ``reset``."""

    def __init__(self, env: gym.Env[Any, Any]) -> None:
        super().__init__(env)
        self.rng = np.random.default_rng()
        self.t = 0
        self.at = 0
        self.dv = 0.0

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        seed = kwargs.get("seed")
        if seed is not None:
            self.rng = np.random.default_rng(seed)
        self.t = 0
        self.at = int(self.rng.integers(40, 201))
        side = 1.0 if self.rng.random() < 0.5 else -1.0
        self.dv = side * float(self.rng.uniform(1.5, 2.5))
        return self.env.reset(**kwargs)

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        if self.t == self.at:
            lander = self.env.unwrapped.lander  # type: ignore[attr-defined]
            lander.ApplyLinearImpulse((lander.mass * self.dv, 0.0), lander.worldCenter, True)
        self.t += 1
        return self.env.step(action)


def disturb(env: gym.Env[Any, Any]) -> gym.Env[Any, Any]:
    """The task's environment with :class:`LateralPush`."""
    return LateralPush(env)
