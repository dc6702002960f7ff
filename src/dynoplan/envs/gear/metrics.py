"""The gear's own measurements of an episode: the human's behaviour, robot-human contacts
(moving or at rest), protective-separation violations, protective stops and the smallest
robot-human distance; and what an episode's record says in the gear's terms (its
simulated duration, the human's behaviour)."""

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from dynoplan.control.controller import EpisodeTrace
from dynoplan.envs.gear.env import CONTROL_DT, GearAssemblyEnv
from dynoplan.pipeline.evaluate import EpisodeRecord
from dynoplan.safety import AT_REST_SPEED, protective_separation
from dynoplan.types import FloatArray


def gear_metrics(env: GearAssemblyEnv, infos: list[dict[str, Any]],
                 min_distance: float = np.inf, held: FloatArray | None = None) -> dict[str, Any]:
    """The gear's own measurements of an episode from its steps' ``infos``:

    - ``human_mode``: the human's behaviour;
    - ``contacts``: env steps' physics steps with a robot-human contact, split into
      ``contacts_moving`` (the robot's fastest point at :data:`AT_REST_SPEED` or more after
      the step, and the step neither a protective stop nor, ``held`` (bool per step), a
      step in which the controller held the arm because no option was admissible: a
      stopped arm that the hand pushes moves, but is not driven) and ``contacts_at_rest``;
    - ``sp_violations_moving``: steps after which the robot moves closer to the hand than
      the protective separation distance ``S_p`` of ISO/TS 15066 for the robot's and the
      hand's measured speeds (:func:`~dynoplan.safety.protective_separation`);
    - ``protective_stops``: steps the runtime monitor stopped
      (:attr:`~dynoplan.envs.gear.pipeline_task.GearTask.shield`);
    - ``min_human_distance``: the smallest robot-human distance (m; also over
      ``min_distance``, for example the distance at the reset).
    """
    contacts = np.array([int(i["human_contacts"]) for i in infos], dtype=np.int64)
    stopped = np.array([bool(i.get("protective_stop", False)) for i in infos], dtype=bool)
    at_rest = stopped if held is None else stopped | np.asarray(held, dtype=bool)
    moving = np.array([float(i["robot_speed"]) >= AT_REST_SPEED for i in infos],
                      dtype=bool) & ~at_rest
    distance = np.array([float(i["min_human_distance"]) for i in infos])
    s_p = protective_separation(np.array([float(i["robot_speed"]) for i in infos]),
                                np.array([float(i["human_speed"]) for i in infos]))
    return {"human_mode": env.schedule.mode,
            "contacts": int(contacts.sum()),
            "contacts_moving": int(contacts[moving].sum()),
            "contacts_at_rest": int(contacts[~moving].sum()),
            "sp_violations_moving": int(np.sum(moving & (distance < s_p))),
            "protective_stops": int(stopped.sum()),
            "min_human_distance": float(min([min_distance, *distance.tolist()]))}


def episode_metrics(env: gym.Env[Any, Any], trace: EpisodeTrace) -> dict[str, Any]:
    """:func:`gear_metrics` of a controller's episode (recorded with ``record_infos``)."""
    gear_env = env.unwrapped
    assert isinstance(gear_env, GearAssemblyEnv)
    held = np.zeros(len(trace.infos), dtype=bool)
    for decision in trace.decisions:
        if decision.option is None:  # the controller's hold
            held[decision.env_step:decision.env_step + decision.steps] = True
    return gear_metrics(gear_env, trace.infos, held=held)



def seconds(record: EpisodeRecord) -> float:
    """The episode's simulated duration (s)."""
    return record.env_steps * CONTROL_DT


def human_mode(record: EpisodeRecord) -> str:
    """The human's behaviour in the episode (``away``, ``cross``, ``block``)."""
    return str(record.task_metrics["human_mode"])


CONTACTS_UNIT = "physics steps (2 ms) with a robot-human contact, summed"
"""What a summary's ``contacts`` count."""


def contact_summary(contacts: Sequence[int], min_distances: Sequence[float],
                    unit: str = "episodes") -> dict[str, Any]:
    """Robot-human contacts and distances over some runs, one value of each per run
    (``unit``: what the runs are called, ``episodes`` or ``trials``): ``contacts``
    (summed, in :data:`CONTACTS_UNIT`), ``contacts_unit``, ``<unit>_with_contact``,
    ``min_human_distance`` (the smallest, m) and ``min_human_distance_median``: the
    columns every gear summary shares (the demonstrator's and the options' trials)."""
    return {"contacts": int(np.sum(contacts)), "contacts_unit": CONTACTS_UNIT,
            f"{unit}_with_contact": int(np.sum(np.asarray(contacts) > 0)),
            "min_human_distance": float(np.min(min_distances)),
            "min_human_distance_median": float(np.median(min_distances))}


__all__ = ["CONTACTS_UNIT", "contact_summary", "episode_metrics", "gear_metrics",
           "human_mode", "seconds"]
