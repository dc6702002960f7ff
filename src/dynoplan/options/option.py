"""The option ``o_w = (pi_w, I_w, beta_w, D_w)`` and the lifecycle a controller drives.

Lifecycle (like a behaviour tree's ``initialise / update / terminate``):

1. ``can_start(state)`` -- the controller only starts an option inside ``I_w``; once
   running, it stops the option when ``can_continue(state)`` turns false (the
   continuation set, ``I_w`` unless given: a precondition that only matters at the start
   -- a move may not start at its goal -- is left out of it). When the controller
   interrupts a running option to plan again, the option competes under its
   continuation set (:func:`admissible`).
2. ``start(observation, rng)`` -- once, when the option is chosen (a motion-planned
   option plans here; a neural one may reset a recurrent state).
3. ``act(observation) -> action`` -- once per environment step; must not block for long.
4. ``should_stop(state, rng) -> bool`` -- after each step: draws ``beta_w(state)``, and
   also stops when the policy says its own work is finished.
"""

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, TypeVar

import numpy as np

from dynoplan.models.dynamics import DynamicsModel
from dynoplan.options.initiation import Everywhere, Initiation
from dynoplan.options.state_map import StateMap, planner_dynamics
from dynoplan.options.termination import ConstantTermination, Termination
from dynoplan.types import BoolArray, FloatArray, Generator


class OptionPolicy:
    """Base class of an option's policy ``pi_w``: override ``act`` (and maybe ``reset``)."""

    def reset(self, observation: Any, rng: Generator) -> None:
        """Called by ``Option.start``; plan or clear internal state here."""

    def act(self, observation: Any) -> Any:
        raise NotImplementedError

    def finished(self) -> bool:
        """True when the policy has nothing left to do (for example a plan ran out)."""
        return False


class FunctionPolicy(OptionPolicy):
    """A policy from a plain callable ``fn(observation, rng) -> action``."""

    def __init__(self, fn: Callable[[Any, Generator], Any]) -> None:
        self.fn = fn
        self._rng: Generator = np.random.default_rng(0)

    def reset(self, observation: Any, rng: Generator) -> None:
        self._rng = rng

    def act(self, observation: Any) -> Any:
        return self.fn(observation, self._rng)


EnvT = TypeVar("EnvT")
PolicyT = TypeVar("PolicyT", bound=OptionPolicy)
PolicyFactory = Callable[[EnvT], PolicyT]
"""``factory(env) -> policy``: builds an option's policy bound to one environment (a
policy may keep per-environment state, so every environment gets its own). Generic in
the environment and policy types: ``PolicyFactory[GearAssemblyEnv, GearOptionPolicy]``."""


class FailureModel(Protocol):
    """``P(fail | s)``: the chance that a run of an option started at each state ends
    its episode in failure (terminated without success), ``(batch, state_dim)`` ->
    ``(batch,)`` in ``[0, 1]``."""

    def probability(self, states: np.ndarray) -> np.ndarray: ...


@dataclass
class RunMemory:
    """What a controller told an option about its runs: where the last one ended without
    effect (``where``, ``(state_dim,)``, or ``None``) and the tolerance it was judged by,
    and whether the option is barred (``barred``: a run of it undid a loop's progress,
    and it may not start anywhere until the controller lifts the bar)."""

    where: np.ndarray | None = None
    tolerance: float | np.ndarray = 0.0
    barred: bool = False


@dataclass
class Option:
    """An option with a forward dynamics model (the paper's extension of options).

    Attributes:
        name: unique, used in traces, reports and on the command line.
        policy: ``pi_w``, acts on raw environment observations.
        dynamics: ``D_w``, predicts the next planner state under ``pi_w`` (the next
            option state with a ``state_map``).
        termination: ``beta_w`` on planner states.
        initiation: ``I_w`` on planner states (default: everywhere).
        continuation: where a running option may go on (default: ``initiation``); the
            controller and the planner's rollouts stop the option when it leaves it.
        fallback: where the option may start when *no* option may run at the state
            under its own sets (``None``: nowhere). A fitted task gives every option
            its own initiation set, without what was learned
            (:meth:`~dynoplan.pipeline.fit.FittedModels.build`): where the learned sets
            rule out every option, the options' own sets decide rather than the robot
            holding still for good (:func:`admissible`).

    With ``start_where_done`` off, the option does not start where its termination is
    certain (:meth:`done_at`). A controller may tell the option that its last run ended
    without effect
    (:meth:`ended_without_effect`): the option then does not start again, under its
    initiation set or its fallback, while the state stays where that run ended. Started
    again there, it would end there again (a move already at its goal, a pick that
    gives up on a gear it cannot grasp), and a chooser whose models promise progress from
    it would choose it for good.
    """

    name: str
    policy: OptionPolicy
    dynamics: DynamicsModel
    termination: Termination
    initiation: Initiation = field(default_factory=Everywhere)
    continuation: Initiation | None = None
    fallback: Initiation | None = None
    start_where_done: bool = True
    """``False``: the option does not start where its termination is certain
    (``beta_w(s) >= 1``): it would end there at its first step, having achieved nothing."""
    runs: RunMemory = field(default_factory=RunMemory, repr=False, compare=False)
    """Where the option's last run ended without effect; a copy made with
    ``dataclasses.replace`` (a planner's option with other dynamics) shares it."""
    state_map: StateMap | None = None
    """The option's own state (:mod:`dynoplan.options.state_map`): ``None``, the planner
    state; else ``dynamics`` model the option's state ``state_map.to_option(s)`` and the
    planner rolls the option in that space (:attr:`planner_dynamics`)."""
    failure: FailureModel | None = None
    """``P(fail | s)`` on planner states, learned from the option's runs that ended their
    episode in failure (``None``: it is not known to fail). A run that fails leaves no
    progress, so the planner weighs each rollout's goal score by ``1 - P(fail | s)`` at
    the state the option starts from."""
    demonstrated: bool = True
    """Whether the demonstrations ran the option (a fitted task's options say;
    :meth:`~dynoplan.pipeline.fit.FittedModels.build`). A planner that looks beyond the
    learned sets where none of their options gains (``widen_without_gain``) looks at
    demonstrated options only: an option no demonstration used has shown no use there."""
    likelihood: Callable[[FloatArray], FloatArray] | None = field(default=None,
                                                                    compare=False)
    """``log L(s | w)`` of Eq. 5 at planner states, ``(batch, state_dim) -> (batch,)``: how
    likely the demonstrations make it that the option runs at each state (its learned
    region's density; a fitted task's options with a region have it,
    :meth:`~dynoplan.pipeline.fit.FittedModels.build`; ``None``: no region). A planner
    with ``regions_without_gain`` follows it where no option gains."""

    @property
    def planner_dynamics(self) -> DynamicsModel:
        """``D_w`` on planner states ``(batch, state_dim)``: ``dynamics`` itself, or, with a
        ``state_map``, each step taken in the option's own state
        (:class:`~dynoplan.options.state_map.MappedDynamics`)."""
        return planner_dynamics(self.dynamics, self.state_map)

    @property
    def continuation_set(self) -> Initiation:
        """The set a running option stays in: ``continuation``, else ``initiation``."""
        return self.initiation if self.continuation is None else self.continuation

    def can_start(self, state: np.ndarray) -> bool:
        """Whether ``state`` (shape ``(state_dim,)``) lies in ``I_w``."""
        return bool(self.initiation.contains(np.asarray(state, dtype=np.float64)[None])[0])

    def can_continue(self, state: np.ndarray) -> bool:
        """Whether a running option may go on in ``state`` (shape ``(state_dim,)``)."""
        region = self.continuation_set
        if isinstance(region, Everywhere):  # called after every step: no array for it
            return True
        return bool(region.contains(np.asarray(state, dtype=np.float64)[None])[0])

    def start(self, observation: Any, rng: Generator) -> None:
        self.policy.reset(observation, rng)

    def act(self, observation: Any) -> Any:
        return self.policy.act(observation)

    def may_run(self, state: np.ndarray, running: bool) -> bool:
        """Whether the option may run at ``state``: start there (``running=False``: its
        initiation set, not where its last run ended without effect) or go on there
        (``running=True``: its continuation set)."""
        if running:
            return self.can_continue(state)
        return (not self.without_effect_at(state) and not self.done_at(state)
                and self.can_start(state))

    def may_fall_back(self, state: np.ndarray) -> bool:
        """Whether the option may start at ``state`` (shape ``(state_dim,)``) when no
        option may under its own sets: its ``fallback`` holds there, and its last run
        did not end there without effect."""
        if self.fallback is None or self.without_effect_at(state) or self.done_at(state):
            return False
        return bool(self.fallback.contains(np.asarray(state, dtype=np.float64)[None])[0])

    def done_at(self, state: np.ndarray) -> bool:
        """Whether the option may not start at ``state`` because its termination is
        certain there (only when ``start_where_done`` is off)."""
        if self.start_where_done:
            return False
        s = np.asarray(state, dtype=np.float64).reshape(1, -1)
        return bool(float(self.termination.probability(s)[0]) >= 1.0)

    def in_fallback(self, state: np.ndarray) -> bool:
        """Whether ``state`` (shape ``(state_dim,)``) lies in the option's fallback set
        (``False`` without one)."""
        return self.fallback is not None and bool(
            self.fallback.contains(np.asarray(state, dtype=np.float64)[None])[0])

    def ended_without_effect(self, state: np.ndarray, tolerance: float | np.ndarray) -> None:
        """Record that a run of this option ended at ``state`` (shape ``(state_dim,)``)
        where it started, within ``tolerance`` in every coordinate: the option may not
        start again while the state stays that close to ``state``."""
        self.runs.where = np.array(state, dtype=np.float64).reshape(-1)
        self.runs.tolerance = np.array(tolerance, dtype=np.float64)

    def forget_runs(self) -> None:
        """Forget :meth:`ended_without_effect` and any bar (a controller calls it at every
        reset)."""
        self.runs.where = None
        self.runs.barred = False

    def without_effect_at(self, state: np.ndarray) -> bool:
        """Whether the option is barred (:attr:`RunMemory.barred`), or ``state`` is within
        the tolerance of where the option's last run ended without effect."""
        if self.runs.barred:
            return True
        where = self.runs.where
        if where is None:
            return False
        s = np.asarray(state, dtype=np.float64).reshape(-1)
        return bool(s.shape == where.shape
                    and np.all(np.abs(s - where) <= self.runs.tolerance))

    def should_stop(self, state: np.ndarray, rng: Generator) -> bool:
        """Draw termination after a step: ``beta_w(state)``, or the policy is finished."""
        if self.policy.finished():
            return True
        if type(self.termination) is ConstantTermination:  # no array for a constant
            return bool(rng.random() < self.termination.beta)
        beta = float(self.termination.probability(np.asarray(state, dtype=np.float64)[None])[0])
        return bool(rng.random() < beta)


def admissible(options: Sequence[Option], state: np.ndarray,
               running: int | None = None) -> BoolArray:
    """``1_{I_w}(s)`` for every option, ``(options,)``: each option may start where its
    initiation set holds, and the running one (index ``running``: an option the
    controller interrupted to plan again) may go on where its continuation set holds.

    Where that leaves no option, each option with a ``fallback`` set may start where the
    fallback holds (the learned judgement is advice; the safety regions still bound every
    start)."""
    may_run = np.array([o.may_run(state, k == running) for k, o in enumerate(options)],
                       dtype=bool)
    if may_run.any() or all(o.fallback is None for o in options):
        return may_run
    return np.array([o.may_fall_back(state) for o in options], dtype=bool)


def admissible_batch(options: Sequence[Option], states: np.ndarray,
                     running: np.ndarray | None = None) -> BoolArray:
    """:func:`admissible` for many states at once: ``(options, batch)`` booleans.

    Args:
        options: the options, in order.
        states: ``(batch, state_dim)`` planner states.
        running: ``(batch,)`` the index of the option running at each state, ``-1`` where
            none runs (default: none anywhere).

    Each state is judged exactly as :func:`admissible` judges it alone: the running
    option by its continuation set, the others by their initiation sets (not where
    their last run ended without effect, nor where their termination is certain unless
    they may start there); where that leaves no option, the options' fallback sets.
    """
    s = np.asarray(states, dtype=np.float64)
    n = s.shape[0]
    run = np.full(n, -1, dtype=np.int64) if running is None else np.asarray(running)
    blocked = np.stack([_blocked(o, s) for o in options])  # (options, batch)
    may = np.empty((len(options), n), dtype=bool)
    for k, o in enumerate(options):
        may[k] = np.asarray(o.initiation.contains(s), dtype=bool) & ~blocked[k]
        goes_on = run == k
        if goes_on.any():
            may[k, goes_on] = np.asarray(o.continuation_set.contains(s[goes_on]), dtype=bool)
    stuck = ~may.any(axis=0)
    if stuck.any() and any(o.fallback is not None for o in options):
        for k, o in enumerate(options):
            if o.fallback is None:
                may[k, stuck] = False
            else:
                may[k, stuck] = np.asarray(o.fallback.contains(s[stuck]), dtype=bool) \
                    & ~blocked[k, stuck]
    return may


def _blocked(option: Option, states: np.ndarray) -> BoolArray:
    """``(batch,)`` where ``option`` may not start whatever its sets say: it is barred,
    its last run ended there without effect, or its termination is certain there (when
    it may not start where done)."""
    out = np.full(states.shape[0], option.runs.barred, dtype=bool)
    where = option.runs.where
    if where is not None and where.shape == states.shape[1:]:
        out |= np.all(np.abs(states - where) <= option.runs.tolerance, axis=-1)
    if not option.start_where_done:
        out |= np.asarray(option.termination.probability(states), dtype=np.float64) >= 1.0
    return out
