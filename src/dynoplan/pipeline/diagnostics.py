"""What the pipeline sees in a user's task and data, said as warnings (one line each).

- :func:`seeded_reset_warning`: ``reset(seed=s)`` does not reproduce its episode, so the
  rows of the evaluation would not be on the same episodes;
- :func:`episode_history_warning`: a seeded episode goes differently after another one
  ran on the same environment (state kept across ``reset``), so a row's episodes depend
  on the ones before them;
- :func:`constant_dimensions`: state dimensions that never change in the data (padding,
  a fixed goal); the dynamics keep them still and the regions do not test them
  (:class:`~dynoplan.models.neural_dynamics.MLPEnsembleDynamics`,
  :meth:`~dynoplan.models.regions.SafetyRegions.fit_heldout`);
- :func:`weak_dynamics_warnings`: an option's one-step model is no better than
  predicting no change;
- :func:`sole_admissible_warnings`: an option is the only admissible one in a share of
  the demonstration states, so there the planner has no choice to make;
- :func:`no_start_warning`: no option may start at some of the evaluation's start
  states, so those episodes hold (or end) from their first step.
"""

import copy
from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from dynoplan.models.regions import constant_mask
from dynoplan.options.option import Option, admissible, admissible_batch
from dynoplan.types import FloatArray

HISTORY_STEPS = 30
"""Steps of seeded random actions :func:`episode_history_warning` compares."""
SOLE_SHARE = 0.25
"""An option that is the only admissible one at this share of the demonstration states
(or more) is reported."""
SOLE_STATES = 500
"""At most this many demonstration states (evenly spaced) are checked."""


def seeded_reset_warning(env: gym.Env[Any, Any], seed: int) -> str | None:
    """Reset ``env`` twice with ``seed``; a warning when the observations differ.

    The pipeline compares controllers on "the same seeded episodes": every row resets
    with the same seeds. An environment whose ``reset(seed=...)`` ignores the seed (or
    draws from a global generator) breaks that silently.
    """
    a, b = (_flat(env, env.reset(seed=seed)[0]) for _ in range(2))
    if a.shape == b.shape and np.array_equal(a, b, equal_nan=True):
        return None
    return (f"environment '{_name(env)}': two resets with seed {seed} gave different "
            "observations, so the controllers are not compared on the same episodes; make "
            "reset(seed=...) seed everything the episode draws (a wrapper that reseeds "
            "what the environment ignores)")


def episode_history_warning(env: gym.Env[Any, Any], seed: int, other: int,
                            steps: int = HISTORY_STEPS) -> str | None:
    """Run the episode of ``seed`` for ``steps`` seeded random actions, then the episode
    of ``other``, then the first again; a warning when the two runs of it differ.

    An environment that keeps state across ``reset`` (PyBullet keeps its contact
    solver's, as panda-gym's tasks show) makes an episode depend on the episodes run
    before it on the same environment: a row of the evaluation then differs when it runs
    alone, after other rows or on another number of workers. The actions come from a copy
    of the action space seeded with the episode's seed (the environment's own space is
    left alone).
    """
    def run(episode_seed: int) -> list[FloatArray]:
        space = copy.deepcopy(env.action_space)
        space.seed(episode_seed)
        seen = [_flat(env, env.reset(seed=episode_seed)[0])]
        for _ in range(steps):
            observation, _, terminated, truncated, _ = env.step(space.sample())
            seen.append(_flat(env, observation))
            if terminated or truncated:
                break
        return seen

    first = run(seed)
    run(other)
    again = run(seed)
    if len(first) == len(again) and all(np.array_equal(a, b, equal_nan=True)
                                        for a, b in zip(first, again, strict=True)):
        return None
    return (f"environment '{_name(env)}': the episode of seed {seed} went differently after "
            "another episode ran on the same environment (it keeps state across reset): "
            "an episode depends on the episodes before it in its row, so a row may differ "
            "when it runs alone or on another number of workers")


def _flat(env: gym.Env[Any, Any], observation: Any) -> FloatArray:
    """``observation`` flattened by ``env``'s observation space, as float64 ``(n,)``."""
    return np.asarray(gym.spaces.flatten(env.observation_space, observation),
                      dtype=np.float64)


def _name(env: gym.Env[Any, Any]) -> str:
    """The environment's registered id, else its class's name."""
    return env.spec.id if env.spec is not None else type(env.unwrapped).__name__


def constant_dimensions(states: FloatArray) -> list[int]:
    """Indices of the dimensions of ``states`` ``(N, d)`` that never change."""
    x = np.asarray(states, dtype=np.float64)
    if x.ndim != 2 or len(x) == 0:
        return []
    return [int(i) for i in np.flatnonzero(constant_mask(x))]


def constant_dimensions_warning(dims: Sequence[int], state_dim: int,
                                handled: bool = True) -> str | None:
    """The warning for :func:`constant_dimensions` (``None`` when there are none);
    ``handled``: whether the fit keeps them still and untested
    (``FitSettings.constant_dimensions_still``)."""
    if not dims:
        return None
    shown = ", ".join(str(i) for i in dims[:12]) + (", ..." if len(dims) > 12 else "")
    what = ("the dynamics keep them still and the safety regions do not test them" if handled
            else "the dynamics may move them and the safety regions reject any move in them")
    return (f"{len(dims)} of the {state_dim} state dimensions never change in the "
            f"demonstrations and option runs ({shown}): {what}")


def weak_dynamics_warnings(report: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """One warning per option whose one-step error (``rmse``) is no lower than that of
    predicting no change (``no_change_rmse``), from :func:`fit_dynamics`' report."""
    out = []
    for name, row in report.items():
        rmse, still = row.get("rmse"), row.get("no_change_rmse")
        if rmse is not None and still is not None and rmse >= still:
            out.append(f"option '{name}': its dynamics model predicts one step worse than "
                       f"'no change' (RMSE {rmse:.3g} against {still:.3g}): the planner's "
                       "rollouts of it are guesses; collect more of its runs "
                       "(exploration_episodes) or give it a larger stride")
    return out


def sole_admissible_warnings(options: Sequence[Option], states: FloatArray,
                             share: float = SOLE_SHARE) -> list[str]:
    """One warning per option that is the only admissible one at ``share`` or more of
    ``states`` ``(N, d)`` (the demonstration states): there the planner only confirms it."""
    x = np.asarray(states, dtype=np.float64)
    if len(x) == 0 or len(options) < 2:
        return []
    x = x[np.linspace(0, len(x) - 1, min(len(x), SOLE_STATES)).astype(int)]
    may = np.stack([admissible(options, s) for s in x])
    sole = (may.sum(axis=1) == 1)
    out = []
    for k, option in enumerate(options):
        at = float(np.mean(sole & may[:, k]))
        if at >= share:
            out.append(f"option '{option.name}' is the only admissible option at {at:.0%} of "
                       "the demonstration states: there the initiation sets choose, not the "
                       "planner")
    return out


def no_start_warning(options: Sequence[Option], starts: FloatArray) -> str | None:
    """A warning when no option may start (under its own set, its learned set or its
    fallback: :func:`~dynoplan.options.option.admissible_batch`) at some of ``starts``
    ``(N, d)``, the evaluation's start states: those episodes cannot begin. ``None``
    when every start state admits an option."""
    x = np.asarray(starts, dtype=np.float64)
    if len(x) == 0:
        return None
    stuck = int(np.sum(~admissible_batch(options, x).any(axis=0)))
    if not stuck:
        return None
    return (f"no option may start at {stuck} of the {len(x)} evaluation start states "
            f"({stuck / len(x):.0%}): those episodes hold (or end) from their first step; "
            "the learned regions do not reach them (more demonstrations cover more starts)")


__all__ = ["SOLE_SHARE", "constant_dimensions",
           "constant_dimensions_warning", "no_start_warning", "seeded_reset_warning",
           "sole_admissible_warnings", "weak_dynamics_warnings"]
