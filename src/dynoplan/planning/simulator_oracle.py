"""Eq. 1 with the simulator itself as every option's dynamics model (the oracle).

:class:`SimulatorOracle` is an option chooser like
:class:`~dynoplan.planning.OptionPlanner`, but instead of sampling learned models it
copies the live simulator state into a scratch environment and runs each admissible
option's own policy there for up to ``horizon`` decisions of ``steps_per_decision``
environment steps (drawing the option's termination after each decision, as the learned
planner does), then scores the end state with the same goal heuristic. Whatever the
environment copies (for the gear assembly, the human's schedule too) the oracle knows
exactly: an upper bound on what a perfect model could give.

Any Task whose environment can copy another instance's state
(:class:`RestorableEnv`) can use it.
"""

from collections.abc import Callable, Mapping, Sequence
from typing import Any, Protocol

import numpy as np

from dynoplan.models.goal import GoalHeuristic
from dynoplan.options.option import Option, OptionPolicy, PolicyFactory, admissible
from dynoplan.planning.option_planner import Plan
from dynoplan.types import FloatArray, Generator


class RestorableEnv(Protocol):
    """A Gymnasium environment that can take over another instance's full state.

    ``copy_state_from(source)`` makes this environment's simulation (and whatever else
    decides its future, such as a scripted bystander) identical to ``source``'s, and
    returns the observation and info there, as ``reset`` would.
    """

    def copy_state_from(self, source: Any) -> tuple[Any, dict[str, Any]]: ...

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]: ...

    def close(self) -> None: ...


class SimulatorOracle:
    """Chooses options by simulating them (see the module docstring).

    Args:
        env: the live environment whose state is copied at every decision.
        options: the options (their initiation sets and terminations are used).
        factories: option name -> a policy factory; each builds a private policy bound to
            the scratch environment.
        goal: the goal heuristic ``G``.
        scratch: the environment the rollouts run in (never ``env`` itself; it must not
            truncate within ``horizon`` decisions).
        state_fn: observation -> planner state ``(state_dim,)``.
        steps_per_decision: environment steps of one decision (the learned models' step).
        horizon: decisions simulated per rollout.
        samples: rollouts per option (a deterministic simulator's samples differ only
            through termination draws and the policies' own randomness).
    """

    def __init__(self, env: Any, options: Sequence[Option],
                 factories: Mapping[str, PolicyFactory[Any, OptionPolicy]],
                 goal: GoalHeuristic, scratch: RestorableEnv,
                 state_fn: Callable[[Any], FloatArray], steps_per_decision: int = 1,
                 horizon: int = 20, samples: int = 1) -> None:
        self.env = env
        self.options = list(options)
        self.goal = goal
        self.horizon = horizon
        self.samples = samples
        self.scratch = scratch
        self.policies = {o.name: factories[o.name](self.scratch) for o in self.options}
        self.state_fn = state_fn
        self.steps_per_decision = steps_per_decision
        self.simulated_steps = 0

    @property
    def option_names(self) -> tuple[str, ...]:
        return tuple(o.name for o in self.options)

    def choose(self, state: FloatArray, rng: Generator, running: int | None = None) -> Plan:
        """Eq. 1 by simulation; options may run as for the learned planner
        (:func:`~dynoplan.options.option.admissible`: the running one under its
        continuation set, the others under their initiation sets)."""
        n, s, d = len(self.options), self.samples, len(state)
        may_run = admissible(self.options, state, running)
        scores = np.full(n, np.nan)
        spreads = np.full(n, np.nan)
        end_states = np.full((n, s, d), np.nan)
        steps = np.zeros((n, s), dtype=np.int64)
        for k, option in enumerate(self.options):
            if not may_run[k]:
                continue
            values = np.empty(s)
            for j in range(s):
                end, taken = self._rollout(option, rng)
                end_states[k, j], steps[k, j] = end, taken
                values[j] = float(self.goal.sample(end[None], rng)[0])
            scores[k], spreads[k] = values.mean(), values.std()
        chosen = int(np.nanargmax(scores)) if may_run.any() else None
        return Plan(self.option_names, may_run, scores, spreads, end_states, steps, chosen)

    def _rollout(self, option: Option, rng: Generator) -> tuple[FloatArray, int]:
        """Simulate ``option`` from the live state; its end state and decisions taken."""
        obs, _ = self.scratch.copy_state_from(self.env)
        policy = self.policies[option.name]
        policy.reset(obs, rng)
        state = self.state_fn(obs)
        for decision in range(1, self.horizon + 1):
            for _ in range(self.steps_per_decision):
                obs, _, terminated, truncated, _ = self.scratch.step(policy.act(obs))
                self.simulated_steps += 1
                if policy.finished() or terminated or truncated:
                    return self.state_fn(obs), decision
            state = self.state_fn(obs)
            if not option.can_continue(state):  # as the controller stops it
                return state, decision
            beta = float(option.termination.probability(state[None])[0])
            if rng.random() < beta:
                return state, decision
        return state, self.horizon

    def close(self) -> None:
        self.scratch.close()


__all__ = ["RestorableEnv", "SimulatorOracle"]
