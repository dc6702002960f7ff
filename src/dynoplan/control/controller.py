"""The controller: plan, run the chosen option, monitor it, plan again.

One episode:

1. map the observation to the planner state (``state_fn``);
2. ask the chooser for a plan (Eq. 1 for :class:`~dynoplan.planning.OptionPlanner`);
3. if no option is admissible, hold still with ``hold_action`` (counted), or end the
   episode when there is no safe hold action;
4. run the chosen option step by step until its termination fires, it leaves its
   continuation set (its initiation set unless the option gives another; an option
   started under its fallback set, where no option was admissible, goes on while that
   set holds; with ``fallback_goes_on``, so does one that leaves its continuation set
   where no option may start under its own initiation set), the state
   becomes non-finite, ``replan_every`` steps pass, or ``max_option_steps`` is reached;
5. repeat until the environment terminates or truncates, or ``max_decisions`` is hit.

After an interruption by ``replan_every`` the chooser is told which option runs: that
option competes where it may go on (its continuation set), the others where they may
start; it is kept unless another option's score beats it by more than ``margin`` (keeps
the choice from flapping).

An option that terminates where it started (no coordinate of the state moved more than
``no_effect_tolerance``) is not started again until the state leaves that spot
(:meth:`~dynoplan.options.Option.ended_without_effect`): choosing it there again would
end there again, for as long as the chooser's models promise progress from it.

The same holds for a loop of two or more options (``loop_tolerance``): where the episode
comes back to a state at which it made an earlier decision (every coordinate within the
tolerance), the options chosen there did not get it anywhere, and none of them starts there again
until the state leaves that spot (two options that undo each other: go behind a cube and
retreat, reach and grasp at one spot). Given the goal heuristic (``progress``), the loop is
judged by it instead: the options of the loop whose own runs lost progress (the goal
heuristic lower where the run ended than where it started) undid what the others did, and
they may not start anywhere until the goal heuristic passes the highest value it had in
the loop (or until no option is admissible); where no run of the loop lost progress, the
rule above applies.

Where the controller held and the hold changed nothing, far from the goal
(``stall_progress``), it does not hold again for want of an option that gains: the best
option it may start runs instead.
"""

import itertools
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np

from dynoplan.control.choosers import OptionChooser
from dynoplan.errors import DynoplanError
from dynoplan.options.option import Option, admissible
from dynoplan.planning.option_planner import Plan
from dynoplan.types import FloatArray, Generator


def flat_state(observation: Any) -> FloatArray:
    """The observation flattened to a ``float64`` vector: the default planner state (a
    ``Box`` or a ``Discrete`` observation)."""
    return np.asarray(observation, dtype=np.float64).reshape(-1)


def finite_state(state: FloatArray) -> bool:
    """Whether every entry of ``state`` (``(state_dim,)``) is finite: asked after every
    environment step, so a small state is judged without numpy's cost per call."""
    if state.size <= 64:
        return all(map(math.isfinite, state.tolist()))
    return bool(np.isfinite(state).all())


def default_success(terminated: bool, info: dict[str, Any]) -> bool:
    """``info["is_success"]`` (or ``info["success"]``) if given, else ``terminated``."""
    for key in ("is_success", "success"):
        if key in info:
            return bool(info[key])
    return bool(terminated)


@dataclass
class Decision:
    """One planning step and what running its choice did.

    ``stop_reason`` is one of ``terminated`` (beta fired or the policy finished),
    ``left_region``, ``invalid_state``, ``replan``, ``step_cap``, ``episode_end``,
    ``hold`` (no admissible option). ``env_step`` is the number of environment steps
    taken before the decision's first step, for an option and a hold alike: its steps
    are ``trace.infos[env_step:env_step + steps]``.
    """

    index: int
    env_step: int
    state: FloatArray
    plan: Plan
    option: str | None
    steps: int
    stop_reason: str
    state_after: FloatArray
    latency_s: float
    outside_region: bool = False


@dataclass
class EpisodeTrace:
    """Everything that happened in one episode (for metrics, figures and debugging)."""

    decisions: list[Decision] = field(default_factory=list)
    success: bool = False
    env_steps: int = 0
    total_reward: float = 0.0
    no_admissible: int = 0
    infos: list[dict[str, Any]] = field(default_factory=list)

    @property
    def planning_steps(self) -> int:
        return sum(1 for d in self.decisions if d.option is not None)

    @property
    def switches(self) -> int:
        chosen = [d.option for d in self.decisions if d.option is not None]
        return sum(1 for a, b in itertools.pairwise(chosen) if a != b)

    @property
    def out_of_region_starts(self) -> int:
        return sum(1 for d in self.decisions if d.outside_region)

    @property
    def latencies_s(self) -> list[float]:
        return [d.latency_s for d in self.decisions]


class Controller:
    """Runs options chosen by an ``OptionChooser`` in a Gymnasium environment.

    Args:
        options: the options, in the chooser's order (names must match).
        chooser: the planner or a baseline.
        state_fn: observation -> planner state ``(state_dim,)``.
        max_decisions: planning steps per episode before giving up.
        max_option_steps: environment steps one option may run before the controller
            plans again.
        replan_every: plan again after this many steps even if the option runs on
            (``None``: only when it stops).
        margin: score advantage another option needs to replace a running one.
        commit: at a replan, the running option goes on without a comparison with the
            others while its own score is at least the score it was chosen with minus
            ``commit`` (its prospects have not fallen since); else the margin rule
            decides (``None``: the margin rule always decides).
        hold_action: a safe action to take when no option is admissible, or a callable
            ``observation -> action`` giving one (for example "stay where you are");
            ``None``: end the episode instead.
        success_fn: ``(terminated, info) -> bool``.
        record_infos: keep every step's ``info`` in the trace.
        termination_every: draw the running option's ``beta`` every this many env steps
            (the dynamics models' time step, so the real option stops at the rate its
            imagined rollouts do); a policy that reports it is finished stops at once.
        no_effect_tolerance: an option that terminates with no coordinate of the state
            more than this from where it started may not start again while the state
            stays that close (``None``: it may); a number, or one per coordinate
            ``(state_dim,)``.
        loop_tolerance: where the state comes back within this (every coordinate) of a
            state at which an earlier decision of the episode started an option, that
            option may not start again while the state stays that close (``None``: no
            such rule); a number, or one per coordinate ``(state_dim,)``.
        stall_progress: where the controller held and the hold left the state where it
            was (every coordinate within ``no_effect_tolerance``; exactly, without one),
            and the chooser holds again only because its best option under its own set
            would not gain on a goal heuristic below this value (the chooser's
            ``Plan.gain_floor``), that option starts: a hold that changes nothing, far
            from the goal, waits forever (``None``: no such rule).
        progress: the goal heuristic's mean at states, ``(batch, state_dim) -> (batch,)``:
            with ``loop_tolerance``, a loop bars the options whose runs in it lost progress
            (see above; ``None``: the options started where the loop began are not started
            there again).
        stall_goal: the goal heuristic's mean at states, as ``progress``: given, where the
            controller held, the hold left the state where it was, no option may start
            at all and the goal heuristic there is below ``stall_progress``, the options
            forget where their runs ended without effect (the no-effect and loop rules'
            marks) and the chooser chooses again: those rules keep an option from
            ending where it started again, not the episode from waiting forever
            (``None``: the marks stay while the state does).
    """

    def __init__(
        self,
        options: Sequence[Option],
        chooser: OptionChooser,
        state_fn: Callable[[Any], FloatArray] = flat_state,
        max_decisions: int = 50,
        max_option_steps: int = 1000,
        replan_every: int | None = None,
        margin: float = 0.0,
        commit: float | None = None,
        hold_action: Any = None,
        success_fn: Callable[[bool, dict[str, Any]], bool] = default_success,
        record_infos: bool = False,
        termination_every: int = 1,
        no_effect_tolerance: float | FloatArray | None = None,
        loop_tolerance: float | FloatArray | None = None,
        stall_progress: float | None = None,
        progress: Callable[[FloatArray], FloatArray] | None = None,
        fallback_goes_on: bool = False,
        stall_goal: Callable[[FloatArray], FloatArray] | None = None,
    ) -> None:
        self.options = list(options)
        if tuple(o.name for o in self.options) != tuple(chooser.option_names):
            raise DynoplanError("the controller's options and the chooser's must be the same")
        if max_decisions < 1 or max_option_steps < 1 or termination_every < 1:
            raise DynoplanError("max_decisions, max_option_steps and termination_every "
                                "must be >= 1")
        if no_effect_tolerance is not None and not np.all(
                np.asarray(no_effect_tolerance) >= 0.0):
            raise DynoplanError(f"no_effect_tolerance must be >= 0, got {no_effect_tolerance}")
        if loop_tolerance is not None and not np.all(np.asarray(loop_tolerance) >= 0.0):
            raise DynoplanError(f"loop_tolerance must be >= 0, got {loop_tolerance}")
        self.chooser = chooser
        self._index = {o.name: i for i, o in enumerate(self.options)}
        self.state_fn = state_fn
        self.max_decisions = max_decisions
        self.max_option_steps = max_option_steps
        self.replan_every = replan_every
        self.margin = margin
        self.commit = commit
        self.hold_action = hold_action
        self.success_fn = success_fn
        self.record_infos = record_infos
        self.fallback_goes_on = fallback_goes_on
        self.termination_every = termination_every
        self.no_effect_tolerance = no_effect_tolerance
        self.loop_tolerance = loop_tolerance
        self.stall_progress = stall_progress
        self.progress = progress
        self.stall_goal = stall_goal

    def run(self, env: gym.Env[Any, Any], rng: Generator, seed: int | None = None,
            reset_options: dict[str, Any] | None = None) -> EpisodeTrace:
        """Run one episode; ``seed`` seeds ``env.reset``, ``rng`` every other choice."""
        reset = getattr(self.chooser, "reset", None)
        if callable(reset):
            reset()
        for o in self.options:
            o.forget_runs()
        obs, info = env.reset(seed=seed, options=reset_options)
        trace = EpisodeTrace()
        state = self.state_fn(obs)
        terminated = truncated = False
        running: int | None = None  # an option interrupted by ``replan_every``
        committed = np.nan  # the score the running option was chosen with
        starts = _DecisionStarts()
        bars: dict[int, float] = {}  # barred option -> the progress that lifts its bar
        for k in range(self.max_decisions):
            if bars:
                self._lift_bars(bars, state)
            if self.loop_tolerance is not None:
                self._close_loops(trace, state, starts, bars)
            t0 = time.perf_counter()
            plan = self.chooser.choose(state, rng, running)
            if bars and not plan.admissible.any():
                self._lift_bars(bars, None)
                plan = self.chooser.choose(state, rng, running)
            if not plan.admissible.any() and self._deadlocked(trace, state):
                for o in self.options:  # no bar is left: lifted above where none is admissible
                    o.forget_runs()
                plan = self.chooser.choose(state, rng, running)
            latency = time.perf_counter() - t0
            chosen = self._keep_running(plan, running, committed)
            if chosen is None:
                chosen = self._unstall(plan, trace, state)
            if chosen is None:
                trace.no_admissible += 1
                if self.hold_action is None:
                    trace.decisions.append(Decision(k, trace.env_steps, state, plan, None, 0,
                                                    "hold", state, latency))
                    break
                hold = self.hold_action(obs) if callable(self.hold_action) else self.hold_action
                start_step = trace.env_steps
                obs, reward, terminated, truncated, info = env.step(hold)
                self._count(trace, reward, info)
                trace.decisions.append(Decision(k, start_step, state, plan, None, 1,
                                                "hold", self.state_fn(obs), latency))
                state = self.state_fn(obs)
                if terminated or truncated:
                    break
                continue
            option = self.options[chosen]
            widened = plan.widened is not None and bool(plan.widened[chosen])
            outside = not widened and not bool(admissible(self.options, state, running)[chosen])
            # started under its fallback set: it goes on while that set holds
            fell_back = not outside and not option.may_run(state, chosen == running)
            if chosen != running:
                option.start(obs, rng)
                committed = float(plan.scores[chosen])
            start_step, start_state = trace.env_steps, state
            reason, steps = "step_cap", 0
            for steps in range(1, self.max_option_steps + 1):
                obs, reward, terminated, truncated, info = env.step(option.act(obs))
                self._count(trace, reward, info)
                state = self.state_fn(obs)
                if terminated or truncated:
                    reason = "episode_end"
                    break
                if not finite_state(state):
                    reason = "invalid_state"
                    break
                if not option.can_continue(state) and not (
                        (fell_back or self._falls_back(state)) and option.in_fallback(state)):
                    reason = "left_region"
                    break
                if option.policy.finished() or (steps % self.termination_every == 0
                                                and option.should_stop(state, rng)):
                    reason = "terminated"
                    break
                if self.replan_every is not None and steps >= self.replan_every:
                    reason = "replan"
                    break
            running = chosen if reason == "replan" else None
            if (reason == "terminated" and self.no_effect_tolerance is not None
                    and np.all(np.abs(state - start_state) <= self.no_effect_tolerance)):
                option.ended_without_effect(state, self.no_effect_tolerance)
            trace.decisions.append(Decision(k, start_step, start_state, plan, option.name,
                                            steps, reason, state, latency, outside))
            if terminated or truncated:
                break
        trace.success = self.success_fn(terminated, info)
        return trace

    def _falls_back(self, state: FloatArray) -> bool:
        """Whether a running option that left its continuation set at ``state``
        (``(state_dim,)``) goes on under its fallback set: with ``fallback_goes_on``, where
        no option may start under its own initiation set (where the controller, choosing
        again, would choose under the fallback sets too)."""
        return self.fallback_goes_on and not any(o.may_run(state, False)
                                                 for o in self.options)

    def _close_loops(self, trace: EpisodeTrace, state: FloatArray,
                     starts: "_DecisionStarts", bars: dict[int, float]) -> None:
        """Where ``state`` is back at (within ``loop_tolerance``) the state of an earlier
        decision, the loop since the latest such decision is judged: with ``progress``,
        the loop's options whose runs lost progress are barred (``bars``: until the
        progress passes the loop's highest); without it, or where no run lost progress,
        every option started at those decisions may not start again while the state
        stays there. The last decision is left to the no-effect rule: a loop takes two
        or more."""
        assert self.loop_tolerance is not None
        starts.extend(trace.decisions[:-1])
        near = starts.started_near(state, self.loop_tolerance)
        if not near:
            return
        if self.progress is not None:
            loop = [d for d in trace.decisions[near[-1]:] if d.option is not None]
            g = self.progress(np.stack([d.state for d in loop]
                                       + [d.state_after for d in loop]))
            before, after = g[:len(loop)], g[len(loop):]
            losers = {self._index[str(d.option)]
                      for d, b, a in zip(loop, before, after, strict=True) if a < b}
            if losers:
                top = float(np.max(g))
                for i in losers:
                    bars[i] = max(top, bars.get(i, -np.inf))
                    self.options[i].runs.barred = True
                return
        for j in near:
            self.options[self._index[str(trace.decisions[j].option)]].ended_without_effect(
                state, self.loop_tolerance)

    def _lift_bars(self, bars: dict[int, float], state: FloatArray | None) -> None:
        """Lift the bars ``bars`` whose progress the goal heuristic at ``state`` passes
        (every bar, with ``state`` ``None``)."""
        g = np.inf if state is None or self.progress is None \
            else float(self.progress(state[None])[0])
        for i in [i for i, top in bars.items() if g > top]:
            self.options[i].runs.barred = False
            del bars[i]

    def _held_in_place(self, trace: EpisodeTrace, state: FloatArray) -> bool:
        """Whether the last decision held and the hold left ``state`` where it was
        (every coordinate within ``no_effect_tolerance``; exactly, without one)."""
        if not trace.decisions:
            return False
        last = trace.decisions[-1]
        tolerance = 0.0 if self.no_effect_tolerance is None else self.no_effect_tolerance
        return last.option is None and bool(np.all(np.abs(state - last.state) <= tolerance))

    def _deadlocked(self, trace: EpisodeTrace, state: FloatArray) -> bool:
        """Whether the options' no-effect marks are all that keeps the episode waiting
        at ``state`` (``stall_goal``): it held in place, below ``stall_progress``, and
        some option is marked."""
        if (self.stall_goal is None or self.stall_progress is None
                or not any(o.runs.where is not None for o in self.options)
                or not self._held_in_place(trace, state)):
            return False
        return float(self.stall_goal(state[None])[0]) < self.stall_progress

    def _unstall(self, plan: Plan, trace: EpisodeTrace, state: FloatArray) -> int | None:
        """The best-scoring admissible option where the last decision held without moving
        the state and the chooser holds again below ``stall_progress``; else ``None``."""
        if (self.stall_progress is None or plan.gain_floor is None
                or plan.gain_floor >= self.stall_progress
                or not self._held_in_place(trace, state)):
            return None
        finite = np.flatnonzero(np.isfinite(plan.scores))
        return int(finite[np.argmax(plan.scores[finite])]) if finite.size else None

    def _keep_running(self, plan: Plan, running: int | None, committed: float) -> int | None:
        """The commitment and margin rules: keep an interrupted option while its score
        has not fallen by more than ``commit`` below ``committed`` (the score it was
        chosen with), else unless beaten by ``margin``.

        The chooser judged the running option by its continuation set, so
        ``plan.admissible[running]`` says whether it may go on."""
        if running is None or not plan.admissible[running]:
            return plan.chosen
        current = plan.scores[running]
        if (self.commit is not None and np.isfinite(current) and np.isfinite(committed)
                and current >= committed - self.commit):
            return running
        if plan.chosen is None:
            return plan.chosen
        best = plan.scores[plan.chosen]
        if np.isfinite(current) and best - current <= self.margin:
            return running
        return plan.chosen

    def _count(self, trace: EpisodeTrace, reward: SupportsFloat, info: dict[str, Any]) -> None:
        trace.env_steps += 1
        trace.total_reward += float(reward)
        if self.record_infos:
            trace.infos.append(dict(info))


class _DecisionStarts:
    """The states at which an episode's decisions started an option, stacked as they come:
    the loop rule asks at every decision which of them the state is back at, one array
    comparison instead of a loop over the episode's decisions."""

    def __init__(self) -> None:
        self.states: np.ndarray | None = None  # (capacity, state_dim), rows [0, n) in use
        self.options: list[str] = []
        self.decisions: list[int] = []  # the index of each row's decision in the episode
        self.seen = 0  # decisions taken in so far

    def extend(self, decisions: Sequence[Decision]) -> None:
        """Take in the decisions after those already seen (the ones that ran an option)."""
        for j, d in enumerate(decisions[self.seen:], start=self.seen):
            if d.option is None:
                continue
            row = np.asarray(d.state).reshape(-1)
            n = len(self.options)
            if self.states is None:
                self.states = np.empty((16, row.size), dtype=row.dtype)
            elif n == len(self.states):
                self.states = np.concatenate([self.states, np.empty_like(self.states)])
            self.states[n] = row
            self.options.append(d.option)
            self.decisions.append(j)
        self.seen = max(self.seen, len(decisions))

    def started_near(self, state: FloatArray, tolerance: float | FloatArray) -> list[int]:
        """The decisions (their indices in the episode, in order) that started an option
        at a state within ``tolerance`` of ``state`` (shape ``(state_dim,)``) in every
        coordinate."""
        if self.states is None:
            return []
        near = np.all(np.abs(state - self.states[:len(self.options)]) <= tolerance, axis=1)
        return [self.decisions[i] for i in np.flatnonzero(near)]
