"""Where each option may start: the admissibility diagnostic of every pipeline run.

The share of the evaluation episodes' start states (:func:`start_states`) and of the
demonstration states inside each option's initiation set (the user's own, intersected with
its learned region), with a warning when that is almost nowhere or everywhere
(:func:`admissibility`).
"""

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from dynoplan.control.controller import flat_state
from dynoplan.data.episodes import OPTION_KEY, Episode
from dynoplan.options.option import Option
from dynoplan.pipeline.collect import (
    ObservationFn,
)
from dynoplan.pipeline.fit import (
    episode_states,
)
from dynoplan.reports.tables import markdown_table
from dynoplan.seeding import episode_seeds
from dynoplan.types import FloatArray

NOWHERE = 0.02
"""An option admissible at fewer than this share of both the evaluation start states and
the demonstration states is reported as admissible almost nowhere."""
EVERYWHERE = 0.99
"""... and at least this share of both as admissible everywhere."""


def start_states(env: gym.Env[Any, Any], seed: int, episodes: int,
                 state_fn: ObservationFn = flat_state) -> FloatArray:
    """The planner states the evaluation episodes start from: ``(episodes, d)``.

    The same resets as :func:`~dynoplan.pipeline.evaluate_controllers` with the same
    ``seed`` and ``episodes`` (each episode's ``env_seed``).
    """
    return np.stack([np.asarray(state_fn(env.reset(seed=s.env_seed)[0]),
                                dtype=np.float64).reshape(-1)
                     for s in episode_seeds(seed, episodes)])


def admissibility(options: Sequence[Option], starts: FloatArray,
                  demos: Sequence[Episode], state_fn: ObservationFn = flat_state,
                  ) -> tuple[dict[str, dict[str, float | None]], list[str]]:
    """Where each option may start: the admissibility diagnostic.

    Args:
        options: the options as the controller runs them (learned initiation sets).
        starts: ``(episodes, d)`` start states of the evaluation (:func:`start_states`).
        demos: the demonstrations (option labels).

    Returns:
        Per option ``{"start_states", "demo_states", "own_demo_states"}``: the share of
        the start states, of all demonstration states and of the demonstration states
        where that option acted (``None`` if none) inside its initiation set; and one
        warning per option admissible almost nowhere (< :data:`NOWHERE` of both start
        and demonstration states) or everywhere (>= :data:`EVERYWHERE` of both).
    """
    demo_states = [episode_states(e, state_fn)[:-1] for e in demos]
    states = np.concatenate(demo_states) if demo_states else np.zeros((0, starts.shape[1]))
    labels = (np.concatenate([np.asarray(e.infos[OPTION_KEY]) for e in demos]) if demos
              else np.zeros(0, np.int64))
    rows: dict[str, dict[str, float | None]] = {}
    notes: list[str] = []
    for k, option in enumerate(options):
        at_start = float(np.mean(option.initiation.contains(starts))) if len(starts) else 0.0
        inside = np.asarray(option.initiation.contains(states), dtype=bool)
        at_demo = float(np.mean(inside)) if len(states) else 0.0
        own = labels == k
        rows[option.name] = {"start_states": at_start, "demo_states": at_demo,
                             "own_demo_states": float(np.mean(inside[own])) if own.any()
                             else None}
        shares = (f"{at_start:.0%} of the evaluation start states and {at_demo:.0%} of the "
                  "demonstration states")
        if at_start < NOWHERE and at_demo < NOWHERE:
            notes.append(f"option '{option.name}' is admissible almost nowhere ({shares}): "
                         "the planner will hardly ever start it")
        elif at_start >= EVERYWHERE and at_demo >= EVERYWHERE:
            notes.append(f"option '{option.name}' is admissible everywhere ({shares}): its "
                         "initiation set does not restrict where the planner starts it")
    return rows, notes


def admissibility_table(rows: dict[str, dict[str, float | None]]) -> str:
    """The admissibility diagnostic as a markdown table, one row per option."""
    return markdown_table(
        [{"option": name, **row} for name, row in rows.items()],
        ["option", "start_states", "demo_states", "own_demo_states"],
        ["option", "admissible at evaluation start states", "at demonstration states",
         "at its own demonstration states"])


__all__ = ["EVERYWHERE", "NOWHERE", "admissibility", "admissibility_table",
           "start_states"]
