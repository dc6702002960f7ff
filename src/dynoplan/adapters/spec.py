"""Options from user parts: with a dynamics model (:func:`make_option`) or without one yet.

A researcher usually has a policy, a way to tell when it is done and perhaps where it
may start, but no model of its closed-loop dynamics: that is learned by the pipeline
from data. :class:`OptionSpec` is that option-to-be; ``spec.with_dynamics(model)`` makes
the :class:`~dynoplan.options.Option` the planner needs.
"""

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from dynoplan.adapters.initiation import initiation_from
from dynoplan.adapters.policies import policy_from
from dynoplan.adapters.termination import termination_from
from dynoplan.errors import DynoplanError
from dynoplan.models.dynamics import DynamicsModel
from dynoplan.options.initiation import Everywhere, Initiation
from dynoplan.options.option import Option, OptionPolicy
from dynoplan.options.state_map import StateMap
from dynoplan.options.termination import Termination


@dataclass
class OptionSpec:
    """An option without its dynamics model: ``(pi_w, I_w, beta_w)``, and where a running
    option may go on (its continuation set; ``None``: its initiation set).

    Build one with :func:`option_spec`, which accepts callables, Stable-Baselines3
    models, classifiers and regions.
    """

    name: str
    policy: OptionPolicy
    termination: Termination
    initiation: Initiation = field(default_factory=Everywhere)
    continuation: Initiation | None = None
    state_map: StateMap | None = None
    """The option's own state (:mod:`dynoplan.options.state_map`; ``None``: the planner
    state): its dynamics are fitted on, and rolled in, ``state_map.to_option(s)``."""

    @property
    def continuation_set(self) -> Initiation:
        """The set a running option stays in: ``continuation``, else ``initiation``."""
        return self.initiation if self.continuation is None else self.continuation

    def with_dynamics(self, dynamics: DynamicsModel,
                      initiation: Initiation | None = None) -> Option:
        """The full option with ``D_w = dynamics`` (and optionally another ``I_w``)."""
        return Option(self.name, self.policy, dynamics, self.termination,
                      self.initiation if initiation is None else initiation,
                      self.continuation, state_map=self.state_map)


def check_option_name(name: Any) -> str:
    """``name`` if it is a valid option name (non-empty, no spaces); else one clear error."""
    if not isinstance(name, str) or not name or any(c.isspace() for c in name):
        raise DynoplanError(f"an option name must be a non-empty string without spaces, "
                            f"got {name!r}")
    return name


def option_spec(name: str, policy: Any, termination: Any = None,
                initiation: Any = None, continuation: Any = None,
                state_map: StateMap | None = None) -> OptionSpec:
    """An :class:`OptionSpec` from whatever the user has.

    Args:
        name: unique name (used in datasets, traces and on the command line).
        policy: an ``OptionPolicy``, a model with ``predict`` (Stable-Baselines3), or
            ``fn(observation) -> action`` (see :func:`~dynoplan.adapters.policy_from`).
        termination: a number, a ``Termination``, a classifier, ``fn(states) -> (B,)``,
            or ``None`` for never (see :func:`~dynoplan.adapters.termination_from`).
        initiation: ``None`` (everywhere), an ``Initiation``, or ``fn(states) -> (B,)``
            booleans (see :func:`~dynoplan.adapters.initiation_from`).
        continuation: where a running option may go on, in the same forms; ``None``:
            its initiation set (give one when a condition only matters at the start, for
            example "a move may not start at its goal").
        state_map: the option's own state and its map from and to the planner state
            (:class:`~dynoplan.options.state_map.StateMap`, e.g. ``CoordinateMap``);
            ``None``: the planner state.
    """
    return OptionSpec(check_option_name(name), policy_from(policy), termination_from(termination),
                      initiation_from(initiation, name),
                      None if continuation is None else initiation_from(continuation, name),
                      state_map)


def make_option(name: str, policy: Any, dynamics: DynamicsModel, termination: Any = None,
                initiation: Any = None, continuation: Any = None) -> Option:
    """A complete :class:`~dynoplan.options.Option` from whatever the user has.

    Same arguments as :func:`option_spec`, plus ``dynamics``: any object with
    ``sample(states (B, d), rng) -> (B, d)`` and ``state_dim``.
    """
    if not callable(getattr(dynamics, "sample", None)):
        raise DynoplanError(
            f"{type(dynamics).__name__} is not a dynamics model: it needs "
            "sample(states, rng) -> next states")
    return option_spec(name, policy, termination, initiation,
                       continuation).with_dynamics(dynamics)


def as_spec(item: Option | OptionSpec) -> OptionSpec:
    """The spec part of an option (drops its dynamics)."""
    if isinstance(item, OptionSpec):
        return item
    if isinstance(item, Option):
        return OptionSpec(item.name, item.policy, item.termination, item.initiation,
                          item.continuation, item.state_map)
    raise DynoplanError(f"expected an Option or OptionSpec, got {type(item).__name__}")


def check_unique_names(items: Sequence[Option | OptionSpec]) -> list[str]:
    """The names, in order; raises when empty or when a name repeats."""
    if not items:
        raise DynoplanError("no options given")
    names = [check_option_name(item.name) for item in items]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise DynoplanError(f"option names must be unique; repeated: {', '.join(repeated)}")
    return names
