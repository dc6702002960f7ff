"""Collecting labelled data in any Gymnasium environment with a ``Box`` observation space.

Two kinds of episodes are recorded, both as :class:`~dynoplan.data.Episode` with the
option that chose every action in ``infos["option"]``:

- **option transitions** (:func:`collect_transitions`): options chosen at random and
  run until their termination fires, to train each option's dynamics ``D_w`` on a
  broad spread of states;
- **demonstrations** (:func:`record_demonstrations`): a scripted
  :class:`Demonstrator` picks the option at every step; only successful episodes are
  kept, and ``infos["progress"]`` is the fraction of the episode done after each step
  (the goal heuristic's training target).
"""

from collections.abc import Callable, Sequence
from typing import Any, cast

import gymnasium as gym
import numpy as np

from dynoplan.adapters.spec import OptionSpec, as_spec, check_unique_names
from dynoplan.control.controller import default_success
from dynoplan.data.episodes import OPTION_KEY, PROGRESS_KEY, Episode
from dynoplan.errors import DynoplanError
from dynoplan.options.option import Option
from dynoplan.progress import track
from dynoplan.seeding import episode_seeds
from dynoplan.types import FloatArray, Generator

ObservationFn = Callable[[Any], FloatArray]
"""Maps one observation to the planner state ``(state_dim,)``."""


def flat_state(observation: Any) -> FloatArray:
    """The observation flattened to a ``float64`` vector: the default planner state."""
    return np.asarray(observation, dtype=np.float64).reshape(-1)


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
            model_dim = getattr(item.dynamics, "state_dim", d)
            if model_dim != d:
                raise DynoplanError(
                    f"{where}: dynamics model has state_dim {model_dim}, the environment's "
                    f"states have {d}")
            nxt = np.asarray(_call(where, "dynamics", states, item.dynamics.sample, states, rng))
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


class Demonstrator:
    """A scripted policy over options: picks the option that acts at every step.

    ``reset(observation, rng)`` starts an episode (draw any randomness of the script
    from ``rng``); ``choose(observation) -> option name`` is called before every step.
    When the name differs from the previous step's, that option is started.
    """

    def reset(self, observation: Any, rng: Generator) -> None:
        """Called once per episode, after ``env.reset``."""

    def choose(self, observation: Any) -> str:
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
    """

    def __init__(self, specs: Sequence[OptionSpec], state_fn: ObservationFn = flat_state,
                 max_option_steps: int = 100) -> None:
        self.specs = list(specs)
        self.state_fn = state_fn
        self.max_option_steps = max_option_steps
        self._rng: Generator = np.random.default_rng(0)
        self._current: int | None = None
        self._steps = 0

    def reset(self, observation: Any, rng: Generator) -> None:
        self._rng = rng
        self._current = None
        self._steps = 0

    def choose(self, observation: Any) -> str:
        s = self.state_fn(observation)[None]
        if self._current is not None:
            spec = self.specs[self._current]
            stop = (self._steps >= self.max_option_steps
                    or not bool(spec.continuation_set.contains(s)[0])
                    or self._rng.random() < float(spec.termination.probability(s)[0]))
            if stop:
                self._current = None
        if self._current is None:
            admissible = [i for i, sp in enumerate(self.specs) if sp.initiation.contains(s)[0]]
            pool = admissible or list(range(len(self.specs)))
            self._current = int(self._rng.choice(pool))
            self._steps = 0
        self._steps += 1
        return self.specs[self._current].name


# --- recording ---------------------------------------------------------------------------


def record_episode(env: gym.Env[Any, Any], specs: Sequence[OptionSpec],
                   demonstrator: Any, env_seed: int | None, rng: Generator,
                   max_steps: int | None = None) -> tuple[Episode, bool]:
    """Run one episode with the option the demonstrator picks at each step.

    Returns:
        The episode (``infos["option"]`` labels, reset seed) and whether it succeeded
        (``info["is_success"]`` if the environment reports it, else ``terminated``).
    """
    names = [s.name for s in specs]
    obs, info = env.reset(seed=env_seed)
    demonstrator.reset(obs, rng)
    observations: list[Any] = [obs]
    actions: list[np.ndarray] = []
    rewards: list[float] = []
    terms: list[bool] = []
    truncs: list[bool] = []
    labels: list[int] = []
    current: int | None = None
    terminated = truncated = False
    while not (terminated or truncated) and (max_steps is None or len(actions) < max_steps):
        name = demonstrator.choose(obs)
        try:
            k = names.index(name)
        except ValueError:
            raise DynoplanError(
                f"the demonstrator chose '{name}', which is not an option "
                f"(options: {', '.join(names)})") from None
        if k != current:
            specs[k].policy.reset(obs, rng)
            current = k
        action = specs[k].policy.act(obs)
        obs, reward, terminated, truncated, info = env.step(action)
        observations.append(obs)
        actions.append(np.asarray(action))
        rewards.append(float(reward))
        terms.append(bool(terminated))
        truncs.append(bool(truncated))
        labels.append(k)
    if not actions:
        raise DynoplanError("max_steps must allow at least one step")
    episode = Episode(
        observations=np.asarray(observations, dtype=_float_dtype(observations)),
        actions=np.asarray(actions), rewards=np.asarray(rewards),
        terminations=np.asarray(terms), truncations=np.asarray(truncs),
        infos={OPTION_KEY: np.asarray(labels, dtype=np.int64)},
        seed=env_seed)
    return episode, default_success(terminated, info)


def _float_dtype(observations: list[Any]) -> Any:
    dtype = np.asarray(observations[0]).dtype
    return dtype if np.issubdtype(dtype, np.floating) else np.float64


def record_demonstrations(env: gym.Env[Any, Any], specs: Sequence[OptionSpec],
                          demonstrator: Any, episodes: int, seed: int,
                          max_attempts: int | None = None, max_steps: int | None = None,
                          progress: bool = False) -> list[Episode]:
    """``episodes`` successful demonstrations, with option and progress labels.

    Episodes that fail are dropped (their progress would be meaningless); attempts stop
    after ``max_attempts`` (default ``5 * episodes``). ``infos["progress"]`` after step
    ``t`` of a ``T``-step demonstration is ``(t + 1) / T``.

    Raises:
        DynoplanError: fewer than ``episodes`` demonstrations succeeded.
    """
    if episodes < 1:
        raise DynoplanError(f"the number of demonstrations must be >= 1, got {episodes}")
    demo = demonstrator_from(demonstrator)
    attempts = max_attempts if max_attempts is not None else 5 * episodes
    kept: list[Episode] = []
    tried = 0
    for s in track(episode_seeds(seed, attempts), "demonstrations", total=attempts,
                   enabled=progress):
        if len(kept) == episodes:
            break
        tried += 1
        episode, success = record_episode(env, specs, demo, s.env_seed, s.rng(), max_steps)
        if success:
            t = len(episode)
            episode.infos[PROGRESS_KEY] = np.arange(1, t + 1, dtype=np.float64) / t
            kept.append(episode)
    if len(kept) < episodes:
        raise DynoplanError(
            f"only {len(kept)} of {tried} demonstrations reached the goal; {episodes} were "
            "asked for: check the demonstrator, and how success is judged (info['is_success'] "
            "at the last step, else terminated; a task that never terminates needs a success "
            "function, --success MODULE:FUNCTION)")
    return kept


def collect_transitions(env: gym.Env[Any, Any], specs: Sequence[OptionSpec], episodes: int,
                        seed: int, state_fn: ObservationFn = flat_state,
                        max_option_steps: int = 100, max_steps: int | None = None,
                        progress: bool = False) -> list[Episode]:
    """Episodes of randomly chosen options (see :class:`RandomOptions`), labelled."""
    if episodes < 1:
        raise DynoplanError(f"the number of exploration episodes must be >= 1, got {episodes}")
    explorer = RandomOptions(specs, state_fn, max_option_steps)
    return [record_episode(env, specs, explorer, s.env_seed, s.rng(), max_steps)[0]
            for s in track(episode_seeds(seed, episodes), "option transitions",
                           total=episodes, enabled=progress)]
