"""Many episodes in lockstep: every episode's decision of one step in one planner call.

Episodes are independent and a decision of a small task is tiny, so most of a
sequential run is the planner's fixed cost per call. :func:`run_batched` runs ``E``
episodes side by side: at each decision step it asks the chooser for the plans of all
episodes still running in one call (:meth:`~dynoplan.planning.SequencePlanner.plan_many`,
one stacked model call per horizon step for every episode's branches), then runs each
episode's chosen option in its own environment until it stops, as
:class:`~dynoplan.control.Controller` does.

What it supports is the controller of an option that runs until it stops: options are
chosen again only when the running one stops (no ``replan_every``), there is no hold
(an episode with no admissible option ends), and no no-effect rule (an option's memory
of where it ended without effect would be shared by the episodes). The planner draws
from one generator for all episodes, so an episode's result depends on the batch it ran
in; its distribution over episodes is that of :class:`~dynoplan.control.Controller`'s.
"""

import time
from collections.abc import Callable, Sequence
from typing import Any, Protocol, runtime_checkable

import gymnasium as gym
import numpy as np

from dynoplan.control.choosers import OptionChooser
from dynoplan.control.controller import (
    Decision,
    EpisodeTrace,
    default_success,
    finite_state,
    flat_state,
)
from dynoplan.errors import DynoplanError
from dynoplan.options.option import Option
from dynoplan.planning.option_planner import Plan
from dynoplan.seeding import EpisodeSeed
from dynoplan.types import FloatArray, Generator


@runtime_checkable
class BatchChooser(Protocol):
    """``plan_many(states (episodes, state_dim), rng) -> one Plan per state``."""

    @property
    def option_names(self) -> tuple[str, ...]: ...

    def plan_many(self, states: FloatArray, rng: Generator,
                  running: Sequence[int | None] | None = None) -> list[Plan]: ...


def run_batched(envs: Sequence[gym.Env[Any, Any]], options: Sequence[Option],
                chooser: BatchChooser | OptionChooser, seeds: Sequence[EpisodeSeed],
                planner_rng: Generator,
                max_decisions: int = 50, max_option_steps: int = 1000,
                state_fn: Callable[[Any], FloatArray] = flat_state,
                success_fn: Callable[[bool, dict[str, Any]], bool] = default_success
                ) -> list[EpisodeTrace]:
    """One trace per seed, in order; episode ``i`` runs in ``envs[i]``.

    Args:
        envs: one environment per episode (``len(envs) == len(seeds)``).
        options: the options, in the chooser's order.
        chooser: plans for many states at once (``plan_many``); a chooser without
            ``plan_many`` (a baseline) is asked for one state after another.
        seeds: per episode, ``env_seed`` for ``env.reset`` and ``rng()`` for the option
            runs (starts, termination draws).
        planner_rng: the generator of every planner call.
        max_decisions, max_option_steps, state_fn, success_fn: as
            :class:`~dynoplan.control.Controller`.

    A decision's ``latency_s`` is its batched call's time over the episodes in it.
    """
    if len(envs) != len(seeds):
        raise DynoplanError(f"{len(envs)} environments for {len(seeds)} episodes")
    if tuple(o.name for o in options) != tuple(chooser.option_names):
        raise DynoplanError("the options and the chooser's must be the same")
    if max_decisions < 1 or max_option_steps < 1:
        raise DynoplanError("max_decisions and max_option_steps must be >= 1")
    rngs = [s.rng() for s in seeds]
    traces = [EpisodeTrace() for _ in seeds]
    observations: list[Any] = []
    infos: list[dict[str, Any]] = []
    for env, s in zip(envs, seeds, strict=True):
        obs, info = env.reset(seed=s.env_seed)
        observations.append(obs)
        infos.append(info)
    states = [state_fn(o) for o in observations]
    ended = [False] * len(envs)
    terminated = [False] * len(envs)
    for k in range(max_decisions):
        active = [i for i in range(len(envs)) if not ended[i]]
        if not active:
            break
        t0 = time.perf_counter()
        plans = _plans(chooser, np.stack([states[i] for i in active]), planner_rng)
        latency = (time.perf_counter() - t0) / len(active)
        for i, plan in zip(active, plans, strict=True):
            trace, env, rng = traces[i], envs[i], rngs[i]
            start_state = states[i]
            if plan.chosen is None:
                trace.no_admissible += 1
                trace.decisions.append(Decision(k, trace.env_steps, start_state, plan, None, 0,
                                                "hold", start_state, latency))
                ended[i] = True
                continue
            option = options[plan.chosen]
            option.start(observations[i], rng)
            start_step, reason = trace.env_steps, "step_cap"
            obs, state = observations[i], start_state
            for _ in range(max_option_steps):
                obs, reward, term, trunc, infos[i] = env.step(option.act(obs))
                trace.env_steps += 1
                trace.total_reward += float(reward)
                state = state_fn(obs)
                if term or trunc:
                    reason, ended[i], terminated[i] = "episode_end", True, bool(term)
                    break
                if not finite_state(state):
                    reason = "invalid_state"
                    break
                if not option.can_continue(state):
                    reason = "left_region"
                    break
                if option.should_stop(state, rng):
                    reason = "terminated"
                    break
            observations[i], states[i] = obs, state
            trace.decisions.append(Decision(k, start_step, start_state, plan, option.name,
                                            trace.env_steps - start_step, reason, state,
                                            latency))
    for i, trace in enumerate(traces):
        trace.success = success_fn(terminated[i], infos[i])
    return traces


def _plans(chooser: BatchChooser | OptionChooser, states: FloatArray,
           rng: Generator) -> list[Plan]:
    """One plan per row of ``states`` (``(episodes, state_dim)``)."""
    if isinstance(chooser, BatchChooser):
        return chooser.plan_many(states, rng)
    return [chooser.choose(s, rng) for s in states]
