"""A gear option as one record, and the ordered registry the whole gear pipeline reads.

A :class:`GearOption` says everything the pipeline needs of an option beyond its policy
file: how its policy is built (a factory, or a trained network read from the models
folder), where it may start and go on (conditions on planner states, intersected with its
learned safety region when the demonstrations show it), and where its standalone trials
and its transition collection start (a start sampler). Its termination ``beta_w`` and its
success test are the policy's own (:class:`~dynoplan.envs.gear.options.base.GearOptionPolicy`).

A :class:`GearOptionRegistry` keeps the options in registration order: an option's label
(in datasets, the regions, the models folder) is its index there, so the paper's four,
registered first, keep the labels 0..3. Demonstrations, collection, training, the models
folder, the controllers, the figures and ``dynoplan gear option NAME`` all take the
options from the registry (:mod:`~dynoplan.envs.gear.options.catalog` holds the one the
pipeline uses).
"""

import os
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from dynoplan.adapters.initiation import initiation_from
from dynoplan.adapters.spec import check_option_name
from dynoplan.envs.gear.env import GearAssemblyEnv
from dynoplan.envs.gear.human import HUMAN_MODES
from dynoplan.envs.gear.options.base import GearPolicyFactory
from dynoplan.envs.gear.options.starts import StartConfig, at_reset
from dynoplan.errors import DynoplanError
from dynoplan.imports import import_user_module
from dynoplan.options.initiation import Initiation
from dynoplan.options.state_map import StateMap
from dynoplan.types import BoolArray, FloatArray, Generator

Condition = Initiation | Callable[[FloatArray], BoolArray]
"""A set of planner states: an :class:`~dynoplan.options.Initiation`, or
``fn(states (N, 22)) -> (N,)`` booleans."""
StartSampler = Callable[[GearAssemblyEnv, Generator, StartConfig], bool]
"""``start(env, rng, config) -> reached``: drives an env just reset (human away) to a
start state of the option, drawing any randomness from ``rng``; ``False`` when this
attempt failed (another reset is tried)."""


@dataclass(frozen=True)
class OptionNetwork:
    """The network a neural option reads from the models folder, and how it is trained.

    The data episodes of every network are one parallel map
    (:func:`~dynoplan.envs.gear.options.catalog.train_option_networks`), so each must
    depend on the seed and its index alone.

    Attributes:
        file: the file's name inside the models folder.
        load: ``load(path) -> factory``: the option's policy factory, reading the file.
        data_actor: ``data_actor(env) -> actor``: what acts in the data episodes (built
            once per worker process).
        data_episode: ``data_episode(env, actor, seed, index) -> episode``.
        fit: ``fit(path, episodes, seed, quick) -> report``: train on the episodes, write
            ``path``, return the training report (JSON-serialisable).
        episodes: data episodes with the full settings; quick_episodes: with ``quick``.
    """

    file: str
    load: Callable[[Path], GearPolicyFactory]
    data_actor: Callable[[GearAssemblyEnv], Any]
    data_episode: Callable[[GearAssemblyEnv, Any, int, int], Any]
    fit: Callable[[Path, list[Any], int, bool], dict[str, Any]]
    episodes: int = 80
    quick_episodes: int = 24


@dataclass(frozen=True, eq=False)
class GearOption:
    """One gear option as the pipeline uses it.

    Attributes:
        name: unique, without spaces (datasets, model files and the command line use it).
        policy: ``policy(env) -> GearOptionPolicy`` for an option that needs no trained
            file (a class is such a factory); ``None`` when ``network`` builds it.
        start: where its standalone trials and its transition runs start
            (:data:`StartSampler`; e.g. :func:`~dynoplan.envs.gear.options.starts.at_reset`,
            :func:`~dynoplan.envs.gear.options.starts.after_pick`).
        initiation: where it may start (``None``: anywhere); intersected with its
            learned safety region when the demonstrations show the option.
        continuation: where a running option may go on (``None``: its initiation set),
            intersected with its region likewise.
        network: the trained network a neural option reads (``None``: none).
        human_mode: the human's schedule in its standalone trials (``away``, ``cross``
            or ``block``).
        color: its colour in figures (``None``: one of a fixed palette).
        trial_notes: constants written into its trials' ``summary.json`` (for example
            a stated safety distance).
        start_sets_human: its ``start`` installs the human's schedule itself (an option
            that starts where the hand has come to the arm); otherwise a schedule of
            ``human_mode`` (or the mode a run asks for) is installed after the start.
        state_map: the option's own state (:mod:`dynoplan.options.state_map`), which its
            dynamics are fitted on and rolled in when a run asks for the options' own
            states (``gear run --own-states``); ``None``: the planner state.
    """

    name: str
    policy: GearPolicyFactory | None = None
    start: StartSampler = at_reset
    initiation: Condition | None = None
    continuation: Condition | None = None
    network: OptionNetwork | None = None
    human_mode: str = "away"
    color: str | None = None
    trial_notes: dict[str, Any] = field(default_factory=dict)
    start_sets_human: bool = False
    state_map: StateMap | None = None

    def __post_init__(self) -> None:
        check_option_name(self.name)
        if (self.policy is None) == (self.network is None):
            raise DynoplanError(f"gear option {self.name!r}: give exactly one of policy "
                                "(a factory env -> policy) and network (a trained file)")
        if self.human_mode not in HUMAN_MODES:
            raise DynoplanError(f"gear option {self.name!r}: human_mode must be one of "
                                f"{', '.join(HUMAN_MODES)}, got {self.human_mode!r}")
        if not callable(self.start):
            raise DynoplanError(f"gear option {self.name!r}: start must be a function "
                                "(env, rng, config) -> reached")

    def factory(self, models: Path | None) -> GearPolicyFactory:
        """The policy's factory; a neural option reads its network from ``models``.

        Raises:
            DynoplanError: no models folder, or no network file in it.
        """
        if self.network is None:
            assert self.policy is not None  # checked at construction
            return self.policy
        if models is None:
            raise DynoplanError(f"option {self.name!r} needs a models folder with "
                                f"{self.network.file}")
        path = models / self.network.file
        if not path.is_file():
            raise DynoplanError(f"{path}: no such model file (`dynoplan gear option "
                                f"{self.name} --models {models}` or `dynoplan gear run` "
                                "train the missing networks)")
        return self.network.load(path)

    def sets(self) -> tuple[Initiation, Initiation | None]:
        """Its own initiation set (everywhere when none is given) and continuation set
        (``None``: its initiation set), before any learned region."""
        return (initiation_from(self.initiation, self.name),
                None if self.continuation is None else initiation_from(self.continuation,
                                                                       self.name))


class GearOptionRegistry:
    """Gear options in registration order; an option's label is its index.

    Args:
        options: the options registered first, in order.
        plugins: the name of an environment variable listing modules to import before the
            registry is first read (comma-separated module names or ``.py`` files), so
            that options registered by those modules are known to the command line and to
            worker processes; ``None``: no plugins.
    """

    def __init__(self, options: Iterable[GearOption] = (), plugins: str | None = None) -> None:
        self._options: dict[str, GearOption] = {}
        self._plugins = plugins
        self._plugins_loaded = plugins is None
        for option in options:
            self.register(option)

    def register(self, option: GearOption) -> GearOption:
        """Add ``option`` after the others (its label is the next index); returns it.

        Raises:
            DynoplanError: not a :class:`GearOption`, or another option has its name.
        """
        if not isinstance(option, GearOption):
            raise DynoplanError(f"expected a GearOption, got {type(option).__name__}")
        known = self._options.get(option.name)
        if known is option:
            return option  # registering the same record twice changes nothing
        if known is not None:
            raise DynoplanError(f"a gear option named {option.name!r} is already registered")
        self._options[option.name] = option
        return option

    def _read(self) -> dict[str, GearOption]:
        if not self._plugins_loaded:
            self._plugins_loaded = True
            assert self._plugins is not None
            for entry in os.environ.get(self._plugins, "").split(","):
                if entry.strip():
                    import_user_module(entry.strip(), self._plugins)
        return self._options

    def __iter__(self) -> Iterator[GearOption]:
        return iter(tuple(self._read().values()))

    def names(self) -> tuple[str, ...]:
        """The options' names in label order."""
        return tuple(self._read())

    def get(self, name: str) -> GearOption:
        """The option called ``name``.

        Raises:
            DynoplanError: no option has that name.
        """
        options = self._read()
        if name not in options:
            raise DynoplanError(f"unknown option {name!r}; expected one of "
                                f"{', '.join(options)}{self._hint()}")
        return options[name]

    def index(self, name: str) -> int:
        """The label of option ``name`` (its index in registration order)."""
        self.get(name)
        return list(self._options).index(name)

    def _hint(self) -> str:
        if self._plugins is None:
            return ""
        return (f" (an option registered in a script is unknown to other processes: name "
                f"its module in {self._plugins})")

    @contextmanager
    def temporary(self, *options: GearOption) -> Iterator["GearOptionRegistry"]:
        """Register ``options`` for the ``with`` block only: on exit the registry is as
        before, whatever was registered inside (tests, examples)."""
        saved = dict(self._read())
        try:
            for option in options:
                self.register(option)
            yield self
        finally:
            self._options = saved


__all__ = ["Condition", "GearOption", "GearOptionRegistry", "OptionNetwork", "StartSampler"]
