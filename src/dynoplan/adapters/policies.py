"""Policies ``pi_w`` from what a researcher already has: a function, an SB3 model, a planner.

Each class is an :class:`~dynoplan.options.OptionPolicy` and follows its lifecycle:
``reset(observation, rng)`` once when the option starts, ``act(observation)`` once per
environment step, ``finished()`` after each step.
"""

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from dynoplan.errors import DynoplanError
from dynoplan.options.option import FunctionPolicy, OptionPolicy
from dynoplan.types import FloatArray, Generator


class CallablePolicy(OptionPolicy):
    """A policy from ``fn(observation) -> action`` (no state, no randomness).

    For a policy that draws random numbers use
    :class:`~dynoplan.options.FunctionPolicy`, whose ``fn(observation, rng)`` gets the
    option's generator.
    """

    def __init__(self, fn: Callable[[Any], Any]) -> None:
        if not callable(fn):
            raise DynoplanError(f"a policy must be callable, got {type(fn).__name__}")
        self.fn = fn

    def act(self, observation: Any) -> Any:
        return self.fn(observation)


class SB3Policy(OptionPolicy):
    """A Stable-Baselines3 model (or any object with the same ``predict``) as ``pi_w``.

    Calls ``model.predict(obs, deterministic=deterministic)`` and returns the action
    (the first element of the returned pair). Duck-typed: Stable-Baselines3 itself is
    never imported.

    Args:
        model: a trained ``PPO``/``SAC``/... model, or any object with ``predict``.
        deterministic: passed to ``predict`` (the mode of the policy, no sampling).
        recurrent: also pass and keep ``state`` and ``episode_start``, as recurrent
            policies (``sb3_contrib.RecurrentPPO``) need; the state is cleared on ``reset``.
        obs_fn: maps the environment's observation to the model's input (for example
            the normalisation of a ``VecNormalize`` the model was trained under).
    """

    def __init__(self, model: Any, deterministic: bool = True, recurrent: bool = False,
                 obs_fn: Callable[[Any], Any] | None = None) -> None:
        if not callable(getattr(model, "predict", None)):
            raise DynoplanError(
                f"{type(model).__name__} has no predict(observation, deterministic=...) "
                "method; expected a Stable-Baselines3 model")
        self.model = model
        self.deterministic = deterministic
        self.recurrent = recurrent
        self.obs_fn = obs_fn
        self._state: Any = None
        self._episode_start = True

    def reset(self, observation: Any, rng: Generator) -> None:
        self._state = None
        self._episode_start = True

    def act(self, observation: Any) -> Any:
        obs = observation if self.obs_fn is None else self.obs_fn(observation)
        if self.recurrent:
            out = self.model.predict(obs, state=self._state,
                                     episode_start=np.array([self._episode_start]),
                                     deterministic=self.deterministic)
            self._episode_start = False
        else:
            out = self.model.predict(obs, deterministic=self.deterministic)
        if isinstance(out, tuple):
            action, self._state = out[0], out[1] if len(out) > 1 else None
        else:
            action = out
        return action


def _flat(observation: Any) -> FloatArray:
    return np.asarray(observation, dtype=np.float64).reshape(-1)


class MotionPlannerPolicy(OptionPolicy):
    """Plan a path when the option starts, then follow it waypoint by waypoint.

    On ``reset`` it calls ``plan(start_observation) -> waypoints`` (a sequence, empty or
    ``None`` when planning failed). Each ``act`` first skips every waypoint already
    ``reached(observation, waypoint)``, then returns ``track(observation, waypoint)``
    for the next one. The policy is ``finished()`` when the last waypoint has been
    reached, when a waypoint took more than ``max_steps_per_waypoint`` steps (stuck), or
    at once when planning failed; the option then stops after that step.

    Args:
        plan: the motion planner, ``plan(start_observation) -> Sequence[waypoint]``.
        track: a tracking controller, ``track(observation, waypoint) -> action``.
        reached: ``reached(observation, waypoint) -> bool``; default: the Euclidean
            distance between ``state_fn(observation)`` and the waypoint is at most
            ``tolerance``.
        tolerance: see ``reached``.
        state_fn: observation -> state ``(d,)`` for the default ``reached``.
        max_steps_per_waypoint: give up (finish) after this many steps on one waypoint.
        hold_action: the action when there is no path (planning failed); ``None``:
            ``track(observation, state_fn(start_observation))``, i.e. stay where it started.
        reseed: ``reseed(seed)`` seeds the planner's own random generator (for example
            ``ompl.util.RNG.setSeed``) with a seed drawn from the option's ``rng``
            before each ``plan``, so plans are repeatable.
    """

    def __init__(
        self,
        plan: Callable[[Any], Sequence[Any] | None],
        track: Callable[[Any, Any], Any],
        reached: Callable[[Any, Any], bool] | None = None,
        tolerance: float = 1e-2,
        state_fn: Callable[[Any], FloatArray] = _flat,
        max_steps_per_waypoint: int | None = None,
        hold_action: Any = None,
        reseed: Callable[[int], None] | None = None,
    ) -> None:
        if not callable(plan) or not callable(track):
            raise DynoplanError("plan and track must be callables")
        self.plan = plan
        self.track = track
        self.tolerance = float(tolerance)
        self.state_fn = state_fn
        self.reached = reached if reached is not None else self._close
        self.max_steps_per_waypoint = max_steps_per_waypoint
        self.hold_action = hold_action
        self.reseed = reseed
        self.waypoints: list[Any] = []
        self._next = 0
        self._steps_on_waypoint = 0
        self._stuck = False
        self._hold: Any = None

    def _close(self, observation: Any, waypoint: Any) -> bool:
        state = self.state_fn(observation)
        target = np.asarray(waypoint, dtype=np.float64).reshape(-1)
        if target.shape != state.shape:
            raise DynoplanError(
                f"waypoint of shape {target.shape} does not match the state {state.shape}; "
                "pass reached=... for waypoints in another space")
        return bool(np.linalg.norm(state - target) <= self.tolerance)

    def reset(self, observation: Any, rng: Generator) -> None:
        if self.reseed is not None:
            self.reseed(int(rng.integers(2**31 - 1)))
        path = self.plan(observation)
        self.waypoints = [] if path is None else list(path)
        self._next = 0
        self._steps_on_waypoint = 0
        self._stuck = False
        self._hold = self.state_fn(observation)

    def act(self, observation: Any) -> Any:
        while self._next < len(self.waypoints) and self.reached(observation,
                                                                self.waypoints[self._next]):
            self._next += 1
            self._steps_on_waypoint = 0
        if not self.waypoints:
            return self.hold_action if self.hold_action is not None else self.track(
                observation, self._hold)
        self._steps_on_waypoint += 1
        if (self.max_steps_per_waypoint is not None
                and self._steps_on_waypoint > self.max_steps_per_waypoint):
            self._stuck = True
        target = self.waypoints[min(self._next, len(self.waypoints) - 1)]
        return self.track(observation, target)

    def finished(self) -> bool:
        return self._stuck or self._next >= len(self.waypoints)

    @property
    def progress(self) -> tuple[int, int]:
        """``(waypoints reached, waypoints in the path)``."""
        return self._next, len(self.waypoints)


def policy_from(policy: Any) -> OptionPolicy:
    """Turn what the user has into an :class:`~dynoplan.options.OptionPolicy`.

    - an ``OptionPolicy`` is used as it is;
    - an object with ``predict`` (a Stable-Baselines3 model) becomes an :class:`SB3Policy`;
    - a callable ``fn(observation) -> action`` becomes a :class:`CallablePolicy`.

    Raises:
        DynoplanError: anything else.
    """
    if isinstance(policy, OptionPolicy):
        return policy
    if callable(getattr(policy, "predict", None)):
        return SB3Policy(policy)
    if callable(policy):
        return CallablePolicy(policy)
    raise DynoplanError(
        f"cannot make a policy from {type(policy).__name__}: expected an OptionPolicy, a "
        "model with predict(obs, deterministic=True), or a callable fn(observation) -> action")


__all__ = [
    "CallablePolicy",
    "FunctionPolicy",
    "MotionPlannerPolicy",
    "SB3Policy",
    "policy_from",
]
