"""Collecting labelled data in any Gymnasium environment with a ``Box`` observation space.

Two kinds of episodes are recorded, both as :class:`~dynoplan.data.Episode` with the
option that chose every action in ``infos["option"]``:

- **option transitions** (:func:`collect_transitions`): options chosen at random and
  run until their termination fires, to train each option's dynamics ``D_w`` on a
  broad spread of states;
- **demonstrations** (:func:`record_demonstrations`): a scripted
  :class:`Demonstrator` picks the option at every step; only successful episodes are
  kept, and ``infos["progress"]`` is the fraction of the episode done after each step
  (the goal heuristic's training target);
- **option runs** (:class:`OptionRun`, :func:`collect_option_runs`): one option at a
  time from a start the task chooses (:class:`OptionRunTask`), run until its policy says
  it is finished, and cut into episodes at the decision rate (:func:`decision_episodes`):
  the transitions of a task whose options start from states a reset does not reach, and
  the outcome runs that initiation sets are learned from.
"""

from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, TypeVar, cast

import gymnasium as gym
import numpy as np

from dynoplan.adapters.spec import OptionSpec, as_spec, check_unique_names
from dynoplan.control.controller import default_success, flat_state
from dynoplan.data.episodes import (
    DETOUR_KEY,
    FAILURE_KEY,
    INTERRUPTED_KEY,
    OPTION_KEY,
    PROGRESS_KEY,
    Episode,
)
from dynoplan.errors import DynoplanError
from dynoplan.options.option import Option, OptionPolicy
from dynoplan.options.termination import ConstantTermination
from dynoplan.parallel import SERIAL, Workers, parallel_map
from dynoplan.progress import track
from dynoplan.seeding import EpisodeSeed, episode_seeds
from dynoplan.types import FloatArray, Generator

ObservationFn = Callable[[Any], FloatArray]
"""Maps one observation to the planner state ``(state_dim,)``."""


def make_env(env_id: str, **kwargs: Any) -> gym.Env[Any, Any]:
    """``gymnasium.make(env_id)`` with a one-line error for an unknown id."""
    try:
        return gym.make(env_id, **kwargs)
    except gym.error.Error as exc:
        raise DynoplanError(f"environment '{env_id}': {exc}") from None


def box_state_dim(env: gym.Env[Any, Any], state_fn: ObservationFn = flat_state) -> int:
    """The planner state dimension of ``env``, whose observation space must be a ``Box``.

    Raises:
        DynoplanError: the observation space is not a ``Box`` (the generic pipeline
            models states as real vectors), or ``state_fn`` gives a non-vector.
    """
    space = env.observation_space
    name = env.spec.id if env.spec is not None else type(env.unwrapped).__name__
    if not isinstance(space, gym.spaces.Box):
        raise DynoplanError(
            f"environment '{name}': observation space is {space}, but the pipeline needs a "
            "Box (real-valued vector) observation space; wrap the environment (for example "
            "gymnasium.wrappers.FlattenObservation) or write a state_fn")
    state = np.asarray(state_fn(space.sample()))
    if state.ndim != 1 or state.shape[0] < 1:
        raise DynoplanError(
            f"environment '{name}': state_fn must return a vector (state_dim,), got shape "
            f"{state.shape}")
    return int(state.shape[0])


def probe_options(env: gym.Env[Any, Any], items: Sequence[Option | OptionSpec],
                  state_fn: ObservationFn = flat_state, seed: int = 0) -> int:
    """Check every option against the environment before any data is collected.

    Each option's policy is started on a reset observation and asked for one action
    (not executed); its termination and initiation are evaluated on a batch of two
    states; a given dynamics model must map ``(2, d)`` to ``(2, d)``.

    Returns:
        The planner state dimension ``d``.

    Raises:
        DynoplanError: names repeat; an action does not fit the action space; a
            termination, initiation or dynamics model disagrees with ``d`` (each message
            names the option and the part).
    """
    d = box_state_dim(env, state_fn)
    check_unique_names(items)
    obs, _ = env.reset(seed=seed)
    states = np.stack([state_fn(obs), state_fn(obs)]).astype(np.float64)
    rng = np.random.default_rng(seed)
    for item in items:
        spec = as_spec(item)
        where = f"option '{spec.name}'"
        _call(where, "policy", states, spec.policy.reset, obs, rng)
        _check_action(env.action_space, _call(where, "policy", states, spec.policy.act, obs),
                      spec.name)
        parts = [("termination", spec.termination.probability),
                 ("initiation", spec.initiation.contains)]
        if spec.continuation is not None:
            parts.append(("continuation", spec.continuation.contains))
        for what, fn in parts:
            out = np.asarray(_call(where, what, states, fn, states))
            if out.shape != (2,):
                raise DynoplanError(
                    f"{where}: {what} returned shape {out.shape} for states (2, {d}); "
                    f"expected (2,): its state dimension disagrees with the environment's "
                    f"({d})")
        if isinstance(item, Option):
            model = item.planner_dynamics
            model_dim = getattr(model, "state_dim", d)
            if model_dim != d:
                raise DynoplanError(
                    f"{where}: dynamics model has state_dim {model_dim}, the environment's "
                    f"states have {d}")
            nxt = np.asarray(_call(where, "dynamics", states, model.sample, states, rng))
            if nxt.shape != states.shape:
                raise DynoplanError(
                    f"{where}: dynamics returned shape {nxt.shape} for states {states.shape}")
    return d


def _call(where: str, what: str, states: FloatArray, fn: Callable[..., Any],
          *args: Any) -> Any:
    """Run user code; turn its exception into one line naming the option and the part."""
    try:
        return fn(*args)
    except DynoplanError:
        raise
    except Exception as exc:
        raise DynoplanError(
            f"{where}: {what} failed on states of shape {states.shape}: "
            f"{type(exc).__name__}: {exc}") from None


def _check_action(space: gym.Space[Any], action: Any, name: str) -> None:
    a = np.asarray(action)
    if isinstance(space, gym.spaces.Box):
        if a.shape != space.shape:
            raise DynoplanError(
                f"option '{name}': policy returned an action of shape {a.shape}, the "
                f"environment's action space is {space} (shape {space.shape})")
    elif isinstance(space, gym.spaces.Discrete) and (
            a.shape != () or not np.issubdtype(a.dtype, np.integer)
            or not space.contains(np.int64(a))):
        raise DynoplanError(
            f"option '{name}': policy returned {action!r}, the environment's action "
            f"space is {space}")


# --- who picks the option while recording ------------------------------------------------


@dataclass(frozen=True)
class Decision:
    """What a demonstrator's ``choose`` returns instead of an option name when it needs
    more than choosing (:class:`Demonstrator`).

    Attributes:
        option: the option's name, the step's label.
        restart: start the option again (its policy's ``reset``) although it acted on
            the step before, for example a failed grasp tried once more.
        action: the step's action, given by the demonstrator itself (a script that acts
            and labels its own actions with options); ``None``: the option's policy
            acts. After a step the demonstrator acted on, no option is running: the
            next step that chooses an option starts it.
    """

    option: str
    restart: bool = False
    action: Any = None


class Demonstrator:
    """A scripted policy over options: picks the option that acts at every step.

    ``reset(observation, rng)`` starts an episode (draw any randomness of the script
    from ``rng``); ``choose(observation)`` is called before every step and returns the
    option's name, ``None`` (the recording ends there) or a :class:`Decision`. When the
    name differs from the previous step's, that option is started (its policy's
    ``reset(observation, rng)`` with the episode's ``rng``); a ``Decision`` may start it
    again, or act itself. ``observe(info)`` is given the environment's ``info`` of the
    reset and of every step, before the next ``choose`` (a script that reads success or
    privileged state from it; optional for a duck-typed demonstrator).
    """

    def reset(self, observation: Any, rng: Generator) -> None:
        """Called once per episode, after ``env.reset`` (and after ``observe`` of its
        ``info``)."""

    def observe(self, info: dict[str, Any]) -> None:
        """Called with the ``info`` of ``env.reset`` and then of every step."""

    def choose(self, observation: Any) -> "str | Decision | None":
        raise NotImplementedError


class CallableDemonstrator(Demonstrator):
    """A stateless demonstrator from ``fn(observation) -> option name``."""

    def __init__(self, fn: Callable[[Any], str]) -> None:
        self.fn = fn

    def choose(self, observation: Any) -> str:
        return self.fn(observation)


def demonstrator_from(demonstrator: Any) -> Demonstrator:
    """A :class:`Demonstrator` as it is, or one from ``fn(observation) -> option name``."""
    if isinstance(demonstrator, Demonstrator):
        return demonstrator
    if callable(getattr(demonstrator, "choose", None)) and callable(
            getattr(demonstrator, "reset", None)):
        return cast(Demonstrator, demonstrator)  # duck-typed: has reset and choose
    if callable(demonstrator):
        return CallableDemonstrator(demonstrator)
    raise DynoplanError(
        f"cannot use {type(demonstrator).__name__} as a demonstrator: expected a "
        "Demonstrator (reset, choose) or fn(observation) -> option name")


class RandomOptions(Demonstrator):
    """Exploration: a uniformly random admissible option, run until its ``beta`` fires.

    A new option is drawn when the running one's termination fires (drawn from the
    episode's ``rng``, as the controller does), when it leaves its continuation set, or
    after ``max_option_steps``. With no admissible option, any option is drawn.

    Attributes:
        cut: the steps of this episode (0-based) at which a run stopped only because it
            had run ``max_option_steps``: where it stopped is not where its option ends.
    """

    def __init__(self, specs: Sequence[OptionSpec], state_fn: ObservationFn = flat_state,
                 max_option_steps: int = 100) -> None:
        self.specs = list(specs)
        self.state_fn = state_fn
        self.max_option_steps = max_option_steps
        self._rng: Generator = np.random.default_rng(0)
        self._current: int | None = None
        self._steps = 0
        self._t = 0
        self.cut: list[int] = []

    def reset(self, observation: Any, rng: Generator) -> None:
        self._rng = rng
        self._current = None
        self._steps = 0
        self._t = 0
        self.cut = []

    def choose(self, observation: Any) -> str:
        s = self.state_fn(observation)[None]
        if self._current is not None:
            stop, capped = run_stops(self.specs[self._current], s, self._rng, self._steps,
                                     self.max_option_steps)
            if stop:
                if capped:
                    self.cut.append(self._t - 1)
                self._current = None
        self._t += 1
        if self._current is None:
            self._current = random_admissible(self.specs, s, self._rng)
            self._steps = 0
        self._steps += 1
        return self.specs[self._current].name


def label_runs(labels: np.ndarray) -> list[tuple[int, int]]:
    """The runs of option labels ``(T,)``: every maximal stretch ``start:end`` of steps
    with one label, in order (``T >= 1``)."""
    cuts = np.flatnonzero(np.diff(labels)) + 1
    return [(int(a), int(b)) for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(labels)],
                                             strict=True)]


def run_stops(spec: OptionSpec, state: FloatArray, rng: Generator, steps: int,
              max_steps: int) -> tuple[bool, bool]:
    """Whether a run of ``spec`` that has acted ``steps`` times stops at ``state``
    ``(1, d)`` (it has run ``max_steps``, left its continuation set, or its termination
    fired: one draw from ``rng``, made only when the first two do not hold), and whether
    the cap alone stopped it."""
    capped = steps >= max_steps
    stop = (capped or not bool(spec.continuation_set.contains(state)[0])
            or rng.random() < float(spec.termination.probability(state)[0]))
    return stop, capped


def random_admissible(specs: Sequence[OptionSpec], state: FloatArray, rng: Generator) -> int:
    """The index of an option drawn uniformly from those whose own initiation set holds
    at ``state`` ``(1, d)`` (from all of them where none does)."""
    admissible = [i for i, sp in enumerate(specs) if sp.initiation.contains(state)[0]]
    return int(rng.choice(admissible or list(range(len(specs)))))


class Steering(Demonstrator):
    """A demonstrator that may act instead of the one it wraps (:meth:`instead`). The one
    it wraps is asked at every step all the same, and told every ``observe``, so that a
    script that keeps track of the episode keeps track of it."""

    def __init__(self, demonstrator: Any) -> None:
        self.demonstrator = demonstrator_from(demonstrator)
        self._t = 0

    def reset(self, observation: Any, rng: Generator) -> None:
        self.demonstrator.reset(observation, rng)
        self._t = 0

    def observe(self, info: dict[str, Any]) -> None:
        observe = getattr(self.demonstrator, "observe", None)
        if observe is not None:
            observe(info)

    def choose(self, observation: Any) -> "str | Decision | None":
        choice = self.demonstrator.choose(observation)
        t, self._t = self._t, self._t + 1
        return self.instead(t, observation, choice)

    def instead(self, t: int, observation: Any, choice: "str | Decision | None"
                ) -> "str | Decision | None":
        """What acts at step ``t`` (0-based) of the episode, where the wrapped
        demonstrator chose ``choice`` (default: that choice)."""
        return choice


class Detour(Steering):
    """A demonstrator with one detour per episode: DART's idea (Laskey et al., CoRL
    2017: disturb the supervisor while it demonstrates, so that the data show it
    recovering) at the level of options.

    From a step drawn uniformly from ``[1, within)`` at ``reset``, an option drawn at
    random (:func:`random_admissible`, the distractors too) acts instead of the
    demonstrator's choice until it stops as an exploring run stops (:func:`run_stops`,
    at most ``max_steps``). Then the demonstrator goes on from wherever the detour left
    the task (asked at every step, the detour's too: :class:`Steering`).

    Attributes:
        steps: the detour's steps (0-based) in this episode.
        cut: the cap alone ended the detour (where it stopped is not its option's end).
    """

    def __init__(self, demonstrator: Any, specs: Sequence[OptionSpec],
                 state_fn: ObservationFn = flat_state, within: int = 2,
                 max_steps: int = 1) -> None:
        if within < 2 or max_steps < 1:
            raise DynoplanError(f"a detour needs within >= 2 and max_steps >= 1, got "
                                f"{within} and {max_steps}")
        super().__init__(demonstrator)
        self.specs = list(specs)
        self.state_fn = state_fn
        self.within = within
        self.max_steps = max_steps
        self._rng: Generator = np.random.default_rng(0)
        self._at = 1
        self._current: int | None = None
        self._over = False
        self.steps: list[int] = []
        self.cut = False

    @classmethod
    def around(cls, demonstrator: Any, specs: Sequence[OptionSpec], demos: Sequence[Episode],
               state_fn: ObservationFn = flat_state) -> "Detour":
        """Detours sized from the demonstrations ``demos``: they start within their
        median length and last at most the median length of their option runs."""
        lengths = [len(d) for d in demos]
        runs = [end - start for d in demos for start, end in label_runs(d.infos[OPTION_KEY])]
        return cls(demonstrator, specs, state_fn, max(2, int(np.median(lengths))),
                   max(1, int(np.median(runs))))

    def reset(self, observation: Any, rng: Generator) -> None:
        super().reset(observation, rng)
        self._rng = rng
        self._at = int(rng.integers(1, self.within))
        self._current = None
        self._over = False
        self.steps = []
        self.cut = False

    def instead(self, t: int, observation: Any, choice: "str | Decision | None"
                ) -> "str | Decision | None":
        if self._over or t < self._at:
            return choice
        s = self.state_fn(observation)[None]
        if self._current is None:
            self._current = random_admissible(self.specs, s, self._rng)
        else:
            stop, self.cut = run_stops(self.specs[self._current], s, self._rng,
                                       len(self.steps), self.max_steps)
            if stop:
                self._over = True
                return choice
        self.steps.append(t)
        return self.specs[self._current].name


class OptionRun(Demonstrator):
    """One option, from the episode's start until its policy says it is finished
    (``policy.finished()``; the recording ends there): an *option run*."""

    def __init__(self, spec: OptionSpec) -> None:
        self.spec = spec
        self._started = False

    def reset(self, observation: Any, rng: Generator) -> None:
        self._started = False

    def choose(self, observation: Any) -> str | None:
        if self._started and self.spec.policy.finished():
            return None
        self._started = True
        return self.spec.name


# --- recording ---------------------------------------------------------------------------


@dataclass(frozen=True)
class RunStart:
    """Where a recording starts when it does not start at ``env.reset``: the env has been
    driven there already.

    Attributes:
        observation, info: what the env returned last.
        env_seed: the seed of the reset it started from (recorded in the episode).
        tags: what the task drew to get there (for example the human's behaviour), kept
            with the run's episodes.
        over: the env's episode ended before the run could start (nothing to record).
    """

    observation: Any
    info: dict[str, Any]
    env_seed: int | None
    tags: dict[str, Any] = field(default_factory=dict)
    over: bool = False


@dataclass(frozen=True)
class Recording:
    """One recorded episode, whether it succeeded (``info["is_success"]`` if the
    environment reports it, else ``terminated``) and the last step's ``info``."""

    episode: Episode
    success: bool
    info: dict[str, Any]


def record_episode(env: gym.Env[Any, Any], specs: Sequence[OptionSpec],
                   demonstrator: Any, env_seed: int | None, rng: Generator,
                   max_steps: int | None = None, start: RunStart | None = None,
                   info_keys: Sequence[str] = (),
                   option_names: Sequence[str] | None = None) -> Recording:
    """Run one episode with the option the demonstrator picks at each step.

    Args:
        specs: the options whose policies act; a :class:`Decision` with an action needs
            no spec.
        demonstrator: a :class:`Demonstrator` (or duck-typed: ``reset`` and ``choose``,
            ``observe`` optional).
        start: where the episode starts (the env is there already) instead of
            ``env.reset(seed=env_seed)``.
        info_keys: step ``info`` entries recorded as ``infos[key]`` ``(T,)``.
        option_names: what the labels index (default: the names of ``specs``, which
            may then be a subset of them).

    Returns:
        The recording: the episode (``infos["option"]`` labels, reset seed), its success
        and the last ``info``.
    """
    by_name = {s.name: s for s in specs}
    names = [s.name for s in specs] if option_names is None else list(option_names)
    if start is None:
        obs, info = env.reset(seed=env_seed)
    else:
        obs, info, env_seed = start.observation, start.info, start.env_seed
    observe = getattr(demonstrator, "observe", None)
    if observe is not None:
        observe(info)
    demonstrator.reset(obs, rng)
    observations: list[Any] = [obs]
    actions: list[np.ndarray] = []
    rewards: list[float] = []
    terms: list[bool] = []
    truncs: list[bool] = []
    labels: list[int] = []
    recorded: dict[str, list[Any]] = {key: [] for key in info_keys}
    current: str | None = None
    terminated = truncated = False
    while not (terminated or truncated) and (max_steps is None or len(actions) < max_steps):
        choice = demonstrator.choose(obs)
        if choice is None:
            break
        decision = choice if isinstance(choice, Decision) else Decision(choice)
        name = decision.option
        acts = decision.action is not None
        if name not in names or not (acts or name in by_name):
            raise DynoplanError(
                f"the demonstrator chose '{name}', which is not an option "
                f"(options: {', '.join(n for n in names if n in by_name)})")
        if acts:
            action, current = decision.action, None
        else:
            spec = by_name[name]
            if name != current or decision.restart:
                spec.policy.reset(obs, rng)
                current = name
            action = spec.policy.act(obs)
        obs, reward, terminated, truncated, info = env.step(action)
        if observe is not None:
            observe(info)
        observations.append(obs)
        actions.append(np.asarray(action))
        rewards.append(float(reward))
        terms.append(bool(terminated))
        truncs.append(bool(truncated))
        labels.append(names.index(name))
        for key, values in recorded.items():
            values.append(info[key])
    if not actions:
        raise DynoplanError("max_steps must allow at least one step")
    episode = Episode(
        observations=np.asarray(observations, dtype=_float_dtype(observations)),
        actions=np.asarray(actions), rewards=np.asarray(rewards),
        terminations=np.asarray(terms), truncations=np.asarray(truncs),
        infos={OPTION_KEY: np.asarray(labels, dtype=np.int64),
               **{key: np.asarray(values) for key, values in recorded.items()}},
        seed=env_seed)
    return Recording(episode, default_success(terminated, info), info)


def _float_dtype(observations: list[Any]) -> Any:
    dtype = np.asarray(observations[0]).dtype
    return dtype if np.issubdtype(dtype, np.floating) else np.float64


R = TypeVar("R")


def successful_attempts(wanted: int, attempts: int,
                        run: Callable[[list[tuple[int, int]]], Sequence[R]],
                        succeeded: Callable[[R], bool]) -> tuple[list[tuple[int, R] | None], int]:
    """Attempts ``0, 1, ...`` (at most ``attempts``) until ``wanted`` requests ``0 ..
    wanted - 1`` each have one that succeeded, in rounds: each round gives the next
    attempts, in order, to the requests still without a success, in order, and runs them
    together (``run``, for example on several workers). The attempts run are always the
    first ones, up to the ``wanted``-th success: the same as trying them one by one and
    stopping there.

    Args:
        run: the round's ``(request, attempt)`` pairs to their results, in that order.
        succeeded: whether a result is a success.

    Returns:
        Per request, ``(attempt, result)`` of its success or ``None`` (the attempts ran
        out), and the number of attempts run.
    """
    found: list[tuple[int, R] | None] = [None] * wanted
    tried = 0
    while tried < attempts:
        todo = [j for j in range(wanted) if found[j] is None][:attempts - tried]
        if not todo:
            break
        pairs = [(j, tried + k) for k, j in enumerate(todo)]
        results = run(pairs)
        tried += len(pairs)
        for (j, attempt), result in zip(pairs, results, strict=True):
            if succeeded(result):
                found[j] = (attempt, result)
    return found, tried


def record_demonstrations(env: gym.Env[Any, Any], specs: Sequence[OptionSpec],
                          demonstrator: Any, episodes: int, seed: int,
                          max_attempts: int | None = None, max_steps: int | None = None,
                          progress: bool = False) -> list[Episode]:
    """``episodes`` successful demonstrations, with option and progress labels.

    Episodes that fail are dropped (their progress would be meaningless); the seeds
    derived from ``seed`` are tried in order (:func:`successful_attempts`) and attempts
    stop after ``max_attempts`` (default ``5 * episodes``). The demonstrations come in
    the order of their seeds. ``infos["progress"]`` after step ``t`` of a ``T``-step
    demonstration is ``(t + 1) / T``. A :class:`Detour` as the demonstrator marks each
    episode's detour (``infos["detour"]``, and ``infos["interrupted"]`` at its last step
    where the cap cut it).

    Raises:
        DynoplanError: fewer than ``episodes`` demonstrations succeeded.
    """
    if episodes < 1:
        raise DynoplanError(f"the number of demonstrations must be >= 1, got {episodes}")
    demo = demonstrator_from(demonstrator)
    attempts = max_attempts if max_attempts is not None else 5 * episodes
    seeds = episode_seeds(seed, attempts)

    def one(i: int) -> Recording:
        recording = record_episode(env, specs, demo, seeds[i].env_seed, seeds[i].rng(),
                                   max_steps)
        if isinstance(demo, Detour):
            _mark_detour(recording.episode, demo)
        return recording

    def run(pairs: list[tuple[int, int]]) -> list[Recording]:
        return [one(i) for _, i in track(pairs, "demonstrations", total=len(pairs),
                                         enabled=progress)]

    found, tried = successful_attempts(episodes, attempts, run, lambda r: r.success)
    kept = [with_progress(recording.episode)
            for _, recording in sorted((f for f in found if f is not None), key=lambda f: f[0])]
    if len(kept) < episodes:
        raise DynoplanError(
            f"only {len(kept)} of {tried} demonstrations reached the goal; {episodes} were "
            "asked for: check the demonstrator, and how success is judged (info['is_success'] "
            "at the last step, else terminated; a task that never terminates needs a success "
            "function, --success MODULE:FUNCTION)")
    return kept


def _mark_detour(episode: Episode, detour: Detour) -> None:
    """``infos["detour"]`` (and ``infos["interrupted"]``) of ``episode`` from ``detour``."""
    steps = np.asarray(detour.steps, dtype=np.int64)  # each one acted: all < len(episode)
    marked = np.zeros(len(episode), dtype=bool)
    marked[steps] = True
    episode.infos[DETOUR_KEY] = marked
    cut = np.zeros(len(episode), dtype=bool)
    if detour.cut and len(steps):
        cut[steps[-1]] = True
    episode.infos[INTERRUPTED_KEY] = cut


def without_detour(episode: Episode) -> Episode:
    """``episode`` (a demonstration with no detour) marked as such, with the fields of a
    :class:`Detour`'s demonstrations (one dataset holds episodes of one layout)."""
    for key in (DETOUR_KEY, INTERRUPTED_KEY):
        episode.infos.setdefault(key, np.zeros(len(episode), dtype=bool))
    return episode


def with_progress(episode: Episode) -> Episode:
    """``episode`` (a successful demonstration) with its progress labels:
    ``infos["progress"]`` after step ``t`` of ``T`` steps is ``(t + 1) / T``."""
    t = len(episode)
    episode.infos[PROGRESS_KEY] = np.arange(1, t + 1, dtype=np.float64) / t
    return episode


def demonstrations_at(env: gym.Env[Any, Any], specs: Sequence[OptionSpec], demonstrator: Any,
                      seeds: Sequence[EpisodeSeed],
                      max_steps: int | None = None) -> list[Episode]:
    """The demonstrator's episodes from the starts of ``seeds`` (each episode's
    ``env_seed`` and ``rng``), its successes only, in order, with progress labels
    (:func:`with_progress`): demonstrations where a learner asks for them (the
    improvement rounds' ``improve_demos``) rather than where a seed stream falls."""
    demo = demonstrator_from(demonstrator)
    return [with_progress(r.episode) for r in
            (record_episode(env, specs, demo, s.env_seed, s.rng(), max_steps) for s in seeds)
            if r.success]


def collect_transitions(env: gym.Env[Any, Any], specs: Sequence[OptionSpec], episodes: int,
                        seed: int, state_fn: ObservationFn = flat_state,
                        max_option_steps: int = 100, max_steps: int | None = None,
                        progress: bool = False, demos: Sequence[Episode] = (),
                        branches: int = 0) -> list[Episode]:
    """Episodes of randomly chosen options (see :class:`RandomOptions`), labelled with
    their options, ``infos["failure"]`` (True at the last step of an episode that
    terminated without success) and ``infos["interrupted"]`` (True at the last step of a
    run the explorer cut at ``max_option_steps``, and at the last step of an episode that
    did not terminate: where those runs stopped is not where their options end):
    ``episodes`` from ``env.reset``, then ``branches`` that branch off the demonstrations
    ``demos``.

    A branching episode starts where a demonstration drawn at random (of those with a
    reset seed) was after a step drawn at random (:func:`branch_start`), so that the
    options are also tried along the way the demonstrations went, in their episodes: the
    goal heuristic then sees states off a demonstration next to the demonstration, and
    the option models the states where the demonstrated chain hands over. Without a
    seeded demonstration they start at a reset too. The first ``episodes`` are the same
    whatever ``branches`` is.
    """
    if episodes < 1:
        raise DynoplanError(f"the number of exploration episodes must be >= 1, got {episodes}")
    if branches < 0:
        raise DynoplanError(f"the number of exploration episodes that branch off the "
                            f"demonstrations must be >= 0, got {branches}")
    explorer = RandomOptions(specs, state_fn, max_option_steps)
    seeded = [d for d in demos if d.seed is not None]
    out = []
    total = episodes + branches
    for i, s in enumerate(track(episode_seeds(seed, total), "option transitions",
                                total=total, enabled=progress)):
        rng = s.rng()
        start = None
        if i >= episodes and seeded:
            demo = seeded[int(rng.integers(len(seeded)))]
            start = branch_start(env, demo, int(rng.integers(len(demo))))
        recording = record_episode(env, specs, explorer, s.env_seed, rng, max_steps,
                                   start=start)
        episode = recording.episode
        failure = np.zeros(len(episode), dtype=bool)
        failure[-1] = bool(episode.terminations[-1]) and not recording.success
        episode.infos[FAILURE_KEY] = failure
        cut = np.zeros(len(episode), dtype=bool)
        cut[explorer.cut] = True
        cut[-1] = not episode.terminations[-1]  # the time limit, not the option, ended it
        episode.infos[INTERRUPTED_KEY] = cut
        out.append(episode)
    return out


def branch_start(env: gym.Env[Any, Any], demo: Episode, step: int) -> RunStart:
    """Where an exploration episode branches off the demonstration ``demo``: the env
    reset with the demonstration's seed and driven by its first ``step`` actions
    (``0 <= step < len(demo)``), which reproduces its state after ``step`` steps where
    ``reset(seed=s)`` reproduces its episode (the pipeline checks this once per run)."""
    if demo.seed is None or not 0 <= step < len(demo):
        raise DynoplanError(f"cannot branch off a demonstration of {len(demo)} steps "
                            f"with seed {demo.seed} after {step} steps")
    obs, info = env.reset(seed=demo.seed)
    discrete = isinstance(env.action_space, gym.spaces.Discrete)
    for action in demo.actions[:step]:
        obs, _, terminated, truncated, info = env.step(
            int(action.reshape(-1)[0]) if discrete else action)
        if terminated or truncated:  # the env did not follow the demonstration
            obs, info = env.reset(seed=demo.seed)
            break
    return RunStart(obs, info, demo.seed)


# --- option runs -------------------------------------------------------------------------

OUTCOME_KEY = "outcome"
"""``infos["outcome"]`` ``(T,)`` of an outcome run: whether the option, started at that
observation, ended well (:func:`run_outcomes`)."""


def decision_rows(last: int, steps: int, to_end: bool = False) -> Iterator[np.ndarray]:
    """The decision-rate slices of observations ``0..last`` (``steps`` env steps per
    decision): per phase offset ``o`` of the decision period, the indices ``o, o + steps,
    o + 2 steps, ...`` up to ``last``, and with ``to_end`` ``last`` too when the offset
    misses it (a shorter last decision). Offsets that give no decision (fewer than two
    indices) are left out."""
    for offset in range(min(steps, last)):
        rows = np.arange(offset, last + 1, steps)
        if to_end and rows[-1] != last:
            rows = np.r_[rows, last]
        if len(rows) > 1:
            yield rows


def decision_episodes(episode: Episode, steps: int, to_end: bool = False,
                      summed: Sequence[str] = (), at_start: Sequence[str] = (),
                      span: tuple[int, int] | None = None, truncated: bool = False,
                      ) -> list[Episode]:
    """An episode recorded every env step as episodes at the decision rate (``steps``
    env steps per decision), one per phase offset ``o`` of the decision period: the
    observations at env steps ``o, o + steps, o + 2 steps, ...``, and with ``to_end`` the
    episode's last observation too when the offset misses it (a shorter last decision).
    Offsets that give no decision are left out. With ``span = (a, b)`` only the env steps
    ``a:b`` are cut (observations ``a..b``, offsets counted from ``a``): one option's run
    inside a longer episode.

    Each step of a new episode is one decision: ``actions`` and ``infos["option"]`` are
    the label of the option acting at its start, rewards 0, no termination (an option's
    decisions, not a task's episode) and no truncation, unless ``truncated``: then the
    last decision of each is truncated (the run was cut out of a longer episode);
    ``infos[key]`` is, for ``key`` in ``summed``, the sum of the decision's env steps'
    values and, for ``key`` in ``at_start``, the value at its first env step. ``seed`` is
    kept.
    """
    labels = episode.infos[OPTION_KEY]
    first, last = (0, len(episode.observations) - 1) if span is None else span
    sums = {key: np.r_[0, np.cumsum(episode.infos[key])] for key in summed}
    out = []
    for rows in decision_rows(last - first, steps, to_end):
        rows = first + rows
        n = len(rows) - 1
        label = labels[rows[:-1]]
        infos = {OPTION_KEY: label,
                 **{key: np.diff(c[rows]).astype(episode.infos[key].dtype)
                    for key, c in sums.items()},
                 **{key: np.asarray(episode.infos[key])[rows[:-1]] for key in at_start}}
        ends = np.zeros(n, dtype=bool)
        ends[-1] = truncated
        out.append(Episode(observations=episode.observations[rows], actions=label.copy(),
                           rewards=np.zeros(n), terminations=np.zeros(n, dtype=bool),
                           truncations=ends, infos=infos, seed=episode.seed))
    return out


def run_outcomes(costs: np.ndarray, reached_end: bool, task_success: bool,
                 decision_steps: int) -> np.ndarray:
    """Outcomes of starting an option at each env step of one of its runs: ``(T,)``
    booleans for a run of ``T`` env steps with ``costs`` ``(T,)`` (for example contacts)
    per step.

    From step ``t`` the option ended well when the run reached the option's own end
    (``reached_end``), no cost was paid from ``t`` on, and from there it took more than
    one decision (``decision_steps`` env steps), unless its last step was the task's
    success: an option that would finish at once where it starts is not admissible
    there."""
    c = np.asarray(costs, dtype=np.int64)
    steps = len(c)
    later = np.cumsum(c[::-1])[::-1]  # costs from step t on
    remaining = steps - np.arange(steps)
    out: np.ndarray = reached_end & (later == 0) & ((remaining > decision_steps)
                                                    | task_success)
    return out


PolicyMaker = Callable[[Any], OptionPolicy]
"""Builds one option's policy bound to an environment."""


class OptionRunTask(Protocol):
    """What a task provides to run its options one at a time from starts it chooses
    (:func:`collect_option_runs`). Like a :class:`~dynoplan.pipeline.task.Task`, it is
    small, frozen, hashable and picklable: workers rebuild from it."""

    @property
    def option_names(self) -> tuple[str, ...]:
        """Every option of the task, in label order (what the labels index)."""
        ...

    @property
    def decision_steps(self) -> int:
        """Env steps per decision (the rate of the episodes written)."""
        ...

    @property
    def run_info_keys(self) -> tuple[str, ...]:
        """Step ``info`` entries an option run records (summed per decision)."""
        ...

    def make_env(self) -> gym.Env[Any, Any]:
        """A new instance of the task's environment."""
        ...

    def policy_makers(self, models: Path | None) -> Mapping[str, PolicyMaker]:
        """Per option name, what builds its policy bound to an environment, any networks
        read from the models folder ``models``."""
        ...

    def before_run(self, seed: int) -> None:
        """Called with a seed of the run before it starts (to seed global generators, so
        that a run does not depend on the runs before it in the process)."""
        ...

    def run_start(self, runs: "OptionRuns", option: str, rng: Generator) -> RunStart:
        """Drive ``runs.env`` to a start of ``option``, drawing from ``rng``: one of its
        own (for its transitions) or, for outcome runs (``runs.job.outcomes``), one
        beyond where it is meant to start, possibly after another option ran for up to
        ``runs.job.lead_decisions`` decisions (the options' policies are in
        ``runs.specs``)."""
        ...

    def run_outcomes(self, policy: OptionPolicy, recording: Recording) -> np.ndarray:
        """``(T,)``: whether the option, started at each of the recorded run's
        observations, ended well (see :func:`run_outcomes`)."""
        ...


@dataclass(frozen=True)
class OptionRunSettings:
    """Sizes of a task's option runs (:func:`collect_option_runs`).

    Attributes:
        runs: runs per option.
        max_decisions: decisions an option may run.
        lead_decisions: outcome runs: decisions another option may run before it, at most
            (drawn uniformly in ``0..lead_decisions``; a transition run has none).
    """

    runs: int = 30
    max_decisions: int = 30
    lead_decisions: int = 12


@dataclass(frozen=True)
class OptionRunsJob:
    """Option runs as a worker rebuilds them.

    Attributes:
        task: the task (:class:`OptionRunTask`).
        models: the models folder the policies' networks are read from.
        options: the options run.
        seed: run ``r`` of option ``o`` draws everything from ``[seed, *stream, label of
            o, r]``, so a run gives the same episodes on any worker, after any other run.
        max_steps: env steps a run may last.
        outcomes: outcome runs (starts beyond the option's own, ``infos["outcome"]``)
            instead of transitions.
        lead_decisions: outcome runs: decisions another option may run before the
            option starts, at most.
        stream: keeps the seeds of different kinds of runs apart.
        factories: the policies given in this process (then ``models`` is not read; not
            for workers in other processes).
    """

    task: OptionRunTask
    models: Path | None
    options: tuple[str, ...]
    seed: int
    max_steps: int
    outcomes: bool = False
    lead_decisions: int = 0
    stream: tuple[int, ...] = ()
    factories: Mapping[str, PolicyMaker] | None = field(default=None, hash=False,
                                                       compare=False)


@dataclass
class OptionRuns:
    """What a worker holds for an :class:`OptionRunsJob`: the env and every run option's
    spec, its policy bound to that env."""

    job: OptionRunsJob
    env: gym.Env[Any, Any]
    specs: dict[str, OptionSpec]


def build_option_runs(job: OptionRunsJob) -> OptionRuns:
    """The environment and the options' policies (once per process)."""
    env = job.task.make_env()
    makers = job.factories if job.factories is not None else job.task.policy_makers(job.models)
    return OptionRuns(job, env, {name: OptionSpec(name, makers[name](env),
                                                  ConstantTermination(0.0))
                                 for name in job.options})


def option_run(runs: OptionRuns, item: tuple[str, int]) -> tuple[dict[str, Any], list[Episode]]:
    """Run ``index`` of option ``name`` (``item = (name, index)``): what its start drew
    (:attr:`RunStart.tags`) and its episodes at the decision rate
    (:func:`decision_episodes`; none when the task was over at the start)."""
    name, index = item
    job, task = runs.job, runs.job.task
    key = [job.seed, *job.stream, task.option_names.index(name), index]
    task.before_run(int(np.random.SeedSequence(key).generate_state(1)[0]))
    rng = np.random.default_rng(key)
    start = task.run_start(runs, name, rng)
    if start.over:
        return start.tags, []
    spec = runs.specs[name]
    recording = record_episode(runs.env, list(runs.specs.values()), OptionRun(spec), None,
                               rng, job.max_steps, start=start,
                               info_keys=task.run_info_keys, option_names=task.option_names)
    if not job.outcomes:
        return start.tags, decision_episodes(recording.episode, task.decision_steps,
                                             summed=task.run_info_keys)
    episode = recording.episode
    episode.infos[OUTCOME_KEY] = np.asarray(task.run_outcomes(spec.policy, recording),
                                            dtype=bool)
    return start.tags, decision_episodes(episode, task.decision_steps, to_end=True,
                                         at_start=(OUTCOME_KEY,))


def collect_option_runs(job: OptionRunsJob, runs_per_option: int, workers: Workers = SERIAL,
                        description: str = "option runs", progress: bool = False,
                        ) -> list[tuple[dict[str, Any], list[Episode]]]:
    """``runs_per_option`` runs of every option of ``job`` (:func:`option_run`), option
    by option, on ``workers``: per run, its start's tags and its episodes, in that order
    whatever the workers (the same on one worker or many)."""
    if runs_per_option < 1 or job.max_steps < 1:
        raise DynoplanError("option runs need at least one run per option and one step")
    items = [(name, run) for name in job.options for run in range(runs_per_option)]
    return parallel_map(build_option_runs, option_run, job, items, workers, description,
                        progress)


def start_choices(env: gym.Env[Any, Any], demonstrator: "Demonstrator",
                  option_names: Sequence[str], seed: int, episodes: int) -> Episode | None:
    """The demonstrator's first choice at ``episodes`` start states of ``env`` (its resets
    with the seeds of :func:`~dynoplan.seeding.episode_seeds` ``(seed, episodes)``), as one
    episode of labelled states for the safety regions: ``observations`` ``(n + 1, ...)``
    (the last repeated: no step is taken), zero actions and ``infos["option"]`` ``(n,)``,
    the index in ``option_names`` of the option the demonstrator starts with there.

    The demonstrations show where the task starts only at their own few resets; the
    regions fitted on them can miss the rest of the start states, where then no option
    may start. Starts where the demonstrator chooses nothing (or acts itself) are left
    out; ``None`` when that leaves none."""
    names = list(option_names)
    observations: list[Any] = []
    labels: list[int] = []
    observe = getattr(demonstrator, "observe", None)
    for s in episode_seeds(seed, episodes):
        obs, info = env.reset(seed=s.env_seed)
        if observe is not None:
            observe(info)
        demonstrator.reset(obs, s.rng())
        choice = demonstrator.choose(obs)
        decision = Decision(choice) if isinstance(choice, str) else choice
        if decision is None or decision.action is not None or decision.option not in names:
            continue
        observations.append(obs)
        labels.append(names.index(decision.option))
    if not labels:
        return None
    n = len(labels)
    shape = env.action_space.shape or ()
    return Episode(
        observations=np.asarray([*observations, observations[-1]],
                                dtype=_float_dtype(observations)),
        actions=np.zeros((n, *shape)), rewards=np.zeros(n),
        terminations=np.zeros(n, dtype=bool), truncations=np.zeros(n, dtype=bool),
        infos={OPTION_KEY: np.asarray(labels, dtype=np.int64)}, seed=seed)
