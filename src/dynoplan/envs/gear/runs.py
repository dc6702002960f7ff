"""Where the gear's option runs start, and how an outcome run is judged: the gear's hooks
of :class:`~dynoplan.pipeline.collect.OptionRunTask` (through
:class:`~dynoplan.envs.gear.pipeline_task.GearTask`).

- :func:`own_start` (option transitions): the human's behaviour drawn among
  :data:`~dynoplan.envs.gear.human.HUMAN_MODES`, the env driven to a start of the option
  itself (:func:`~dynoplan.envs.gear.options.catalog.reach_start`) and, in
  :data:`PERTURBED_FRACTION` of the runs, the arm held at a random joint offset first;
- :func:`beyond_start` (outcome runs): with probability ``own_fraction`` a start of the
  option itself, else a start of another registered option, the *source*, which then
  runs for a random number of decisions (0 to ``lead_decisions``), so that the starts
  cover the states the other options visit, not only where they begin;
- :func:`ended_well`: from each decision state of an outcome run, the option ended well
  when it reached its own end (``status == "done"`` and its own ``succeeded(info)``)
  without touching the human, and did not finish at once
  (:func:`~dynoplan.pipeline.collect.run_outcomes`).
"""

from typing import Any

import numpy as np

from dynoplan.envs.gear.env import GRIPPER_CLOSED, GRIPPER_OPEN, GearAssemblyEnv
from dynoplan.envs.gear.human import HUMAN_MODES
from dynoplan.envs.gear.options.catalog import reach_start
from dynoplan.envs.gear.state import DECISION_STEPS
from dynoplan.pipeline.collect import (
    OptionRun,
    OptionRuns,
    Recording,
    RunStart,
    record_episode,
    run_outcomes,
)
from dynoplan.types import BoolArray, FloatArray, Generator

PERTURBED_FRACTION = 0.3
PERTURBATION_STD = 0.05  # rad, left-arm joint offset of perturbed starts
OWN_FRACTION = 0.5
"""Share of the outcome runs started in the option's own start region (no lead), so that
where it works is as well sampled as where it does not."""
RUN_INFO_KEYS = ("human_contacts",)
"""What an option run records of every step: robot-human contacts."""


def _gear_env(runs: OptionRuns) -> GearAssemblyEnv:
    env = runs.env.unwrapped
    assert isinstance(env, GearAssemblyEnv)
    return env


def own_start(runs: OptionRuns, option: str, rng: Generator) -> RunStart:
    """A start of ``option`` itself, the human in a random mode, perturbed in
    :data:`PERTURBED_FRACTION` of the runs (module docstring)."""
    env = _gear_env(runs)
    mode = HUMAN_MODES[int(rng.integers(len(HUMAN_MODES)))]
    perturb = bool(rng.random() < PERTURBED_FRACTION)
    start = reach_start(env, option, rng, human_mode=mode)
    obs, info = start.observation, start.info
    if perturb:
        obs, info = _perturb(env, rng, held=int(info["pads_on_gear"]) >= 2)
    return RunStart(obs, info, start.env_seed, {"human_mode": start.human_mode})


def beyond_start(runs: OptionRuns, option: str, rng: Generator) -> RunStart:
    """A start of ``option`` or beyond it: another option's start, after that option ran
    for up to ``runs.job.lead_decisions`` decisions (module docstring). ``over`` when the task
    ended there (the gear seated or dropped)."""
    env = _gear_env(runs)
    names = list(runs.job.task.option_names)
    own = bool(rng.random() < OWN_FRACTION)
    others = [n for n in names if n != option] or [option]
    source = option if own else others[int(rng.integers(len(others)))]
    mode = HUMAN_MODES[int(rng.integers(len(HUMAN_MODES)))]
    start = reach_start(env, source, rng, human_mode=mode)
    obs, info = start.observation, start.info
    lead = 0 if own else int(rng.integers(runs.job.lead_decisions + 1)) * DECISION_STEPS
    if lead:
        led = record_episode(env, list(runs.specs.values()), OptionRun(runs.specs[source]),
                             None, rng, lead, start=RunStart(obs, info, start.env_seed),
                             option_names=names)
        obs, info = led.episode.observations[-1], led.info
    over = bool(info.get("is_success")) or bool(info.get("gear_dropped"))
    return RunStart(obs, info, start.env_seed, {"source": source, "human_mode": start.human_mode},
                    over=over)


def ended_well(policy: Any, recording: Recording) -> BoolArray:
    """``(T,)``: the outcome of starting the option at each env step of its recorded run
    (module docstring; the task's success ends the episode before the policy can say it
    is done)."""
    info = recording.info
    success = bool(info.get("is_success"))
    reached_end = (policy.status == "done" or success) and bool(policy.succeeded(info))
    out: BoolArray = run_outcomes(recording.episode.infos["human_contacts"], reached_end,
                                  success, DECISION_STEPS)
    return out


def _perturb(env: GearAssemblyEnv, rng: Generator,
             held: bool) -> tuple[FloatArray, dict[str, Any]]:
    """Hold the left arm at a random joint offset for half a decision."""
    q = env.arm_qpos
    q[:6] += rng.normal(0.0, PERTURBATION_STD, size=6)
    lim = env.joint_limits
    action = np.concatenate([np.clip(q, lim[:, 0], lim[:, 1]),
                             [GRIPPER_CLOSED if held else GRIPPER_OPEN]])
    obs, info = env.set_human_schedule(env.schedule)
    for _ in range(DECISION_STEPS // 2):
        obs, _, _, _, info = env.step(action)
    return obs, info


__all__ = ["OWN_FRACTION", "PERTURBATION_STD", "PERTURBED_FRACTION", "RUN_INFO_KEYS",
           "beyond_start", "ended_well", "own_start"]
