"""One recorded trajectory with per-step labels.

An :class:`Episode` holds what a Gymnasium environment produced over ``T`` steps,
laid out like Minari's ``EpisodeData``:

- ``observations`` ``(T+1, *obs_shape)``: the reset observation, then one per step;
- ``actions`` ``(T, *act_shape)`` or ``(T,)`` for discrete actions;
- ``rewards``, ``terminations``, ``truncations`` ``(T,)``;
- ``infos``: named per-step arrays ``(T, ...)``, row ``t`` describing step ``t``
  (the info returned by the ``t``-th ``env.step``). The reserved keys are
  ``"option"`` (``int64``, index into the dataset's ``option_names``: the option that
  chose action ``t``) and ``"progress"`` (``float64`` in ``[0, 1]``: task progress after
  step ``t``).

Construction validates shapes and values and raises :class:`EpisodeFieldError`, a
:class:`~dynoplan.errors.DynoplanError` naming the field. The arrays the fit learns from
(labelled states, per-option transitions and runs) are cut from episodes by
:mod:`dynoplan.pipeline.fit_data`, the goal's states and progress by
:func:`dynoplan.models.goal_network.goal_training_set`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from dynoplan.errors import DynoplanError

OPTION_KEY = "option"
"""``infos`` key of the option labels, ``(T,)`` ``int64``."""
PROGRESS_KEY = "progress"
"""``infos`` key of the task progress, ``(T,)`` ``float64`` in ``[0, 1]``."""
FAILURE_KEY = "failure"
"""``infos`` key, ``(T,)`` ``bool``: True at the last step of an episode that terminated
without success (the state it reached is a failure: a fallen pole, a crash)."""
INTERRUPTED_KEY = "interrupted"
"""``infos`` key, ``(T,)`` ``bool``: True at the last step of an option run that a
controller cut short to run another option (a replan), so that where the run stopped is
not where its option ends."""
DETOUR_KEY = "detour"
"""``infos`` key, ``(T,)`` ``bool``: True at the steps of a demonstration on which an option
the demonstrator did not choose acted (a detour, :class:`~dynoplan.pipeline.collect.Detour`):
they are runs of that option and states with a progress, not the demonstrator's choice."""

StateFn = Callable[[np.ndarray], np.ndarray]
"""Maps observations ``(M, *obs_shape)`` to planner states ``(M, state_dim)``."""


class EpisodeFieldError(DynoplanError):
    """An episode field has the wrong shape, type or values.

    ``field`` is the field's path as stored on disk (``"observations"``,
    ``"infos/option"``), ``detail`` what was expected and found.
    """

    def __init__(self, field: str, detail: str) -> None:
        self.field = field
        self.detail = detail
        super().__init__(f"Episode {field}: {detail}")


@dataclass(eq=False)
class Episode:
    """One trajectory of ``T >= 1`` steps (see the module docstring for the layout).

    Arrays are converted with ``np.asarray``; ``rewards`` become ``float64``,
    ``terminations``/``truncations`` ``bool``, ``infos["option"]`` ``int64`` and
    ``infos["progress"]`` ``float64``. Every other dtype is kept as given, so a round
    trip through :func:`~dynoplan.data.write_dataset` is bit-exact.

    Raises:
        EpisodeFieldError: a field has the wrong shape or dtype, observations, actions
            or rewards are not finite, or progress lies outside ``[0, 1]``.
    """

    observations: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    terminations: np.ndarray
    truncations: np.ndarray
    infos: dict[str, np.ndarray] = field(default_factory=dict)
    seed: int | None = None

    def __post_init__(self) -> None:
        self.actions = _actions(self.actions)
        steps = self.actions.shape[0]
        self.observations = _observations(self.observations, steps)
        self.rewards = _per_step("rewards", self.rewards, steps, np.float64)
        _check_finite("rewards", self.rewards)
        self.terminations = _flags("terminations", self.terminations, steps)
        self.truncations = _flags("truncations", self.truncations, steps)
        self.infos = _infos(self.infos, steps)
        if self.seed is not None:
            if isinstance(self.seed, bool) or not isinstance(self.seed, int | np.integer):
                raise EpisodeFieldError("seed", f"expected an int or None, got {self.seed!r}")
            self.seed = int(self.seed)

    def __len__(self) -> int:
        """Number of steps ``T`` (actions taken)."""
        return int(self.actions.shape[0])

    @property
    def options(self) -> np.ndarray | None:
        """Option labels ``(T,)`` ``int64``, or ``None`` when the episode is unlabelled."""
        return self.infos.get(OPTION_KEY)


def check_option_labels(episode: Episode, num_options: int) -> None:
    """Check that ``infos["option"]``, when present, indexes ``num_options`` names.

    Raises:
        EpisodeFieldError: a label lies outside ``0 .. num_options - 1``.
    """
    labels = episode.options
    if labels is None:
        return
    bad = np.flatnonzero((labels < 0) | (labels >= num_options))
    if bad.size:
        step = int(bad[0])
        expected = (
            f"0..{num_options - 1} ({num_options} option_names)"
            if num_options
            else "none (option_names is empty)"
        )
        raise EpisodeFieldError(
            f"infos/{OPTION_KEY}",
            f"label {int(labels[step])} at step {step} is outside {expected}",
        )


def _actions(value: npt.ArrayLike) -> np.ndarray:
    """Actions ``(T, ...)`` set the episode's length ``T``."""
    actions = np.asarray(value)
    if actions.ndim < 1 or actions.shape[0] < 1:
        raise EpisodeFieldError(
            "actions", f"expected an array (T, ...) with T >= 1 steps, got shape {actions.shape}"
        )
    if np.issubdtype(actions.dtype, np.floating):
        _check_finite("actions", actions)
    elif not np.issubdtype(actions.dtype, np.integer):
        raise EpisodeFieldError("actions", f"expected a float or int dtype, got {actions.dtype}")
    return actions


def _observations(value: npt.ArrayLike, steps: int) -> np.ndarray:
    obs = np.asarray(value)
    if obs.ndim < 2 or obs.shape[0] != steps + 1:
        raise EpisodeFieldError(
            "observations",
            f"expected T+1 = {steps + 1} rows (reset, then one per action) of shape "
            f"(T+1, obs_dim), got shape {obs.shape}",
        )
    if not np.issubdtype(obs.dtype, np.floating):
        raise EpisodeFieldError("observations", f"expected a float dtype, got {obs.dtype}")
    _check_finite("observations", obs)
    return obs


def _per_step(name: str, value: npt.ArrayLike, steps: int, dtype: type) -> np.ndarray:
    array = np.asarray(value)
    if array.shape != (steps,):
        raise EpisodeFieldError(
            name,
            f"expected shape (T,) = ({steps},), one per action, got {array.shape}",
        )
    if not _is_real(array.dtype):
        raise EpisodeFieldError(name, f"expected numbers, got dtype {array.dtype}")
    if (
        dtype is np.int64
        and not np.issubdtype(array.dtype, np.integer)
        and not (np.all(np.isfinite(array)) and np.all(array == np.round(array)))
    ):
        raise EpisodeFieldError(name, "expected integer values")
    return array.astype(dtype, copy=False)


def _flags(name: str, value: npt.ArrayLike, steps: int) -> np.ndarray:
    array = np.asarray(value)
    if array.dtype != np.bool_:
        array = _per_step(name, array, steps, np.float64)
        if not np.all((array == 0) | (array == 1)):
            raise EpisodeFieldError(name, "expected booleans (or 0/1)")
    return _per_step(name, array, steps, np.bool_)


def _is_real(dtype: np.dtype) -> bool:
    return bool(
        np.issubdtype(dtype, np.integer) or np.issubdtype(dtype, np.floating) or dtype == np.bool_
    )


def _check_finite(name: str, array: np.ndarray) -> None:
    bad = ~np.isfinite(array)
    if bad.any():
        step = int(np.argwhere(bad)[0][0])
        raise EpisodeFieldError(name, f"NaN or inf at row {step}")


def _infos(value: Mapping[str, npt.ArrayLike], steps: int) -> dict[str, np.ndarray]:
    if not isinstance(value, Mapping):
        raise EpisodeFieldError("infos", f"expected a dict of arrays, got {type(value).__name__}")
    infos: dict[str, np.ndarray] = {}
    for key, raw in value.items():
        name = f"infos/{key}"
        if not isinstance(key, str) or not key or any(not p for p in key.split("/")):
            raise EpisodeFieldError(
                "infos", f"key {key!r} must be a non-empty string ('/' nests groups)"
            )
        if key == OPTION_KEY:
            array = _per_step(name, raw, steps, np.int64)
        elif key == PROGRESS_KEY:
            array = _per_step(name, raw, steps, np.float64)
            outside = ~((array >= 0.0) & (array <= 1.0))
            if outside.any():
                step = int(np.flatnonzero(outside)[0])
                raise EpisodeFieldError(
                    name, f"expected values in [0, 1], got {array[step]} at step {step}"
                )
        else:
            array = np.asarray(raw)
            if array.ndim < 1 or array.shape[0] != steps:
                raise EpisodeFieldError(
                    name, f"expected T = {steps} rows, one per action, got shape {array.shape}"
                )
            if not _is_real(array.dtype):
                raise EpisodeFieldError(
                    name, f"expected numbers or booleans, got dtype {array.dtype}"
                )
        infos[key] = array
    for key in infos:
        for other in infos:
            if other.startswith(key + "/"):
                raise EpisodeFieldError(
                    f"infos/{key}", f"is both an array and the group of infos/{other}"
                )
    return infos
