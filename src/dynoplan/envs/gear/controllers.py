"""The gear options as library :class:`~dynoplan.options.Option` objects, and the
controllers compared in the evaluation table.

Every controller drives the same four option policies (bound to one environment); they
differ only in how an option is chosen and what may stop it:

==============  ====================================  ============  ==================
controller      chooser                               initiation    termination
==============  ====================================  ============  ==================
dynoplan        :class:`OptionPlanner` (Eq. 1),       learned       ``beta_w``
                learned dynamics and goal
oracle          :class:`SimulatorOracle` (MuJoCo      learned       ``beta_w``
                simulates each option)
random          uniform among admissible options      learned       ``beta_w``
fixed_script    pick, fast move, insert               everywhere    policy finished
dynoplan+rules  :class:`OptionPlanner`                rules         ``beta_w``
==============  ====================================  ============  ==================

The controllers without a suffix use learned parts only (:data:`INITIATION_SETS`,
``learned``): each option's Eq. 5 region intersected with where it was seen to do well
(its initiation learned from outcomes), and no hand-written condition. :data:`VARIANTS`
names the same choosers on other sets: ``+rules`` adds each option's hand-written
conditions (its registry record, :mod:`~dynoplan.envs.gear.options.catalog`; the paper's
four are described in :mod:`~dynoplan.envs.gear.options.preconditions`) to its region,
``_regions`` keeps the Eq. 5 regions alone (the paper's method), ``_everywhere`` has no
initiation set. Each option keeps its own policy and termination ``beta_w`` in every
variant.

The choosers that replan (all but the fixed script) plan again every decision period
(:data:`~dynoplan.envs.gear.state.DECISION_STEPS` env steps), and draw ``beta`` at that
rate too: the learned models step at the decision rate.

Every controller is built by the pipeline's one factory,
:func:`~dynoplan.pipeline.evaluate.make_controller`, from a variant of :data:`VARIANTS`, the
options on its sets (:func:`gear_options`), :data:`GEAR_CONTROL` and what the gear adds
(:func:`gear_control`); :meth:`~dynoplan.envs.gear.pipeline_task.GearTask.make_runner`
puts them together.
"""

from collections.abc import Mapping, Sequence
from dataclasses import fields, replace
from typing import Any

import numpy as np

from dynoplan.adapters.spec import OptionSpec
from dynoplan.envs.gear.arm_points import arm_points
from dynoplan.envs.gear.env import CONTROL_DT, OBS_SLICES, GearAssemblyEnv
from dynoplan.envs.gear.options.base import GearPolicyFactory, gripper_as_it_is
from dynoplan.envs.gear.options.catalog import FAST_MOVE, INSERT, PICK, gear_option
from dynoplan.envs.gear.options.give_way import GIVE_WAY_NAME
from dynoplan.envs.gear.options.preconditions import (
    CARRIED_GEAR_HEIGHT,
    HELD_GEAR_HEIGHT,
    INSERT_KEEP_CLEARANCE,
    INSERT_START_CLEARANCE,
    MOVE_START_DISTANCE,
    PICK_CLEARANCE,
    FarFromGoal,
    hand_clear_of_tool,
    hand_near_tool,
    holding_gear,
    not_carried,
)
from dynoplan.envs.gear.state import DECISION_STEPS, STATE_SLICES, PlannerState
from dynoplan.errors import DynoplanError
from dynoplan.models.goal import GoalHeuristic
from dynoplan.options.initiation import Everywhere, Initiation, Nowhere
from dynoplan.options.option import Option
from dynoplan.options.state_map import StateMap
from dynoplan.pipeline.control_settings import ControllerSettings
from dynoplan.pipeline.evaluate import ControllerVariant, TaskControl
from dynoplan.pipeline.fit import FittedModels
from dynoplan.planning import SimulatorOracle
from dynoplan.safety.constraint import ConstantVelocityHuman, SeparationConstraint
from dynoplan.types import FloatArray

CONTROLLERS = ("dynoplan", "random", "oracle", "fixed_script")
"""Option-level controllers of ``gear run``'s table, in table order, each with learned
parts only (the flat PPO policy and the variant rows are run beside them)."""

INITIATION_SETS = ("rules", "learned", "regions", "everywhere")
"""Where the options may start and go on (:func:`gear_options`):

- ``rules``: each option's own hand-written conditions (its registry record) intersected
  with its learned Eq. 5 region (:func:`preconditions`);
- ``learned``: what was learned alone, no hand-written condition: the option's Eq. 5
  region intersected with its initiation learned from outcomes
  (:mod:`dynoplan.models.outcome_initiation`, when the models folder holds one), and the
  region as the continuation set; an option with neither is not admissible;
- ``regions``: the paper's method, the Eq. 5 regions alone (an option without a region
  is admissible everywhere, as the paper's ``I = R^12``);
- ``everywhere``: no initiation set at all (the paper: "the initiation set of all
  policies is R^12").

Where no option may start under its sets, each may start under its own set
(:func:`own_sets`), the options' fallback of every task
(:meth:`~dynoplan.pipeline.fit.FittedModels.build`)."""


VARIANTS: dict[str, ControllerVariant] = {
    "dynoplan": ControllerVariant("planner", "learned", end_inside=True),
    "random": ControllerVariant("random", "learned"),
    "oracle": ControllerVariant("oracle", "learned"),
    "fixed_script": ControllerVariant("script", "everywhere", replans=False),
    "dynoplan+rules": ControllerVariant("planner", "rules"),
    "random+rules": ControllerVariant("random", "rules"),
    "oracle+rules": ControllerVariant("oracle", "rules"),
    "dynoplan_regions": ControllerVariant("planner", "regions"),
    "random_regions": ControllerVariant("random", "regions"),
    "dynoplan_everywhere": ControllerVariant("planner", "everywhere"),
    "random_everywhere": ControllerVariant("random", "everywhere"),
    "dynoplan_safe": ControllerVariant("planner", "learned", end_inside=True, safe=True),
    "dynoplan+rules_safe": ControllerVariant("planner", "rules", safe=True),
    "dynoplan_no_give_way": ControllerVariant("planner", "learned", end_inside=True,
                                              never=(GIVE_WAY_NAME,)),
    "dynoplan_safe_no_give_way": ControllerVariant("planner", "learned", end_inside=True,
                                                   safe=True, never=(GIVE_WAY_NAME,)),
}
"""Every controller ``gear evaluate --controllers`` and ``gear episode --controller``
accept: :data:`CONTROLLERS`, the variants on other initiation sets and the safe ones, as
:class:`~dynoplan.pipeline.evaluate.ControllerVariant` s of the one controller factory
(:func:`~dynoplan.pipeline.evaluate.make_controller`; ``sets`` is one of
:data:`INITIATION_SETS`, :func:`gear_options`).

``dynoplan`` scores its rollouts at their last state inside the continuation set
(``end_inside``): on the learned sets nothing else stops a rollout where the option's
dynamics run out of data (measured in ``docs/gear-options.md``, ablation: 93 % against
80 % on the same 30 episodes, with the regions as the fallback of that time)."""

FIXED_SCRIPT = (PICK.name, FAST_MOVE.name, INSERT.name)
"""The fixed script's options, each run until its policy reports it is finished."""

MAX_EPISODE_SECONDS = 40.0
"""Simulated seconds an episode may last (the env's own limit)."""


MAX_EPISODE_STEPS = round(MAX_EPISODE_SECONDS / CONTROL_DT)

GEAR_CONTROL = ControllerSettings(
    replan_every=DECISION_STEPS, max_decisions=MAX_EPISODE_STEPS,
    max_option_steps=MAX_EPISODE_STEPS, oracle_horizon=10, oracle_samples=1)
"""How the gear's controllers plan and run (``gear run``'s defaults): the library's
defaults (:class:`~dynoplan.pipeline.control_settings.ControllerSettings`, the same on
every Task), in the gear's units:

- ``replan_every``: the choosers that replan (all but the fixed script) plan again every
  decision period (:data:`~dynoplan.envs.gear.state.DECISION_STEPS` env steps);
- an episode and an option may run as long as the environment's limit;
- ``oracle_horizon``, ``oracle_samples``: the simulator oracle's (it pays real simulation
  time).

Measured on the models of ``gear run --seed 0, 1, 2`` (``docs/suite.md``, "The eighth
round: the gear on the same defaults"): on the same 100 episodes per seed these defaults succeed
as often as the gear's former settings (:data:`GEAR_TUNED`), within one episode per
seed."""

GEAR_TUNED = ControllerSettings(
    horizon=10, samples=64, margin=0.1, replan_every=DECISION_STEPS,
    max_decisions=MAX_EPISODE_STEPS, max_option_steps=MAX_EPISODE_STEPS, oracle_horizon=10,
    oracle_samples=1, epistemic=0.0, no_effect_tolerance=1e-3, no_effect_share=None,
    loop_share=None, start_where_done=True, fallback_must_gain=False, stall_progress=None)
"""The gear's own controller settings before the library's defaults served it (until
``aadcbbc``), a named variant (``gear run``'s row ``dynoplan gear-tuned``): where they
differ from :data:`GEAR_CONTROL`,

- ``horizon`` 10, ``samples`` 64: Eq. 1's ``n`` (decisions of 0.5 s) and ``S``;
- ``margin`` 0.1: near the peg the goal heuristic's estimates of the moves and the
  insertion differ by less than their noise, and a smaller margin lets them take turns;
- ``no_effect_tolerance`` 1e-3 (1 mm, 1 mrad) in place of ``no_effect_share`` (1 % of
  each coordinate's spread): an option that ends where it started is not started there
  again (:class:`~dynoplan.control.Controller`). Without either, a move already at its
  goal (done after two steps) was chosen again and again, while the insertion it should
  give way to was ruled out by its learned initiation (measured in ``docs/safety.md``);
- the generic pipeline's other rules off: an option may start where its termination is
  certain (``start_where_done``), no rule against coming back to an earlier decision's
  state (``loop_share``), and where only an option's fallback set holds, the planner
  starts the best-scoring option rather than holding (``fallback_must_gain``,
  ``stall_progress``)."""

TUNED_CHANGES: dict[str, Any] = {
    f.name: getattr(GEAR_TUNED, f.name) for f in fields(ControllerSettings)
    if getattr(GEAR_TUNED, f.name) != getattr(GEAR_CONTROL, f.name)}
""":data:`GEAR_TUNED` as changes of :data:`GEAR_CONTROL` (``dataclasses.replace``)."""


def gear_options(env: GearAssemblyEnv, models: FittedModels,
                 factories: Mapping[str, GearPolicyFactory], sets: str = "rules"
                 ) -> list[Option]:
    """The options in ``models.option_names`` order, their policies bound to ``env``, each
    with its own termination ``beta_w`` and its own sets under ``sets`` (one of
    :data:`INITIATION_SETS`, :func:`own_sets`), built as every task's fitted options are
    (:meth:`~dynoplan.pipeline.fit.FittedModels.build`): their sets with what was learned
    (:func:`fitted_for` says what ``sets`` uses), their own sets as the fallback, whether
    the demonstrations ran them, their region's likelihood and their own state
    (:func:`option_state_map`). Under ``learned`` an option without a region (the
    demonstrations do not show it) starts only where its outcomes say, and nowhere
    without them (the generic pipeline gives such an option a region that holds nowhere,
    ``region_undemonstrated="none"``)."""
    missing = [n for n in models.option_names if n not in factories]
    if missing:
        raise DynoplanError(f"no policy for option(s) {', '.join(missing)}")
    specs = []
    for name in models.option_names:
        policy = factories[name](env)
        own, own_continuation = own_sets(name, sets)
        specs.append(OptionSpec(name, policy, policy.termination(), own, own_continuation,
                                state_map=option_state_map(name, models)))
    fitted = fitted_for(models, sets)
    options, _ = fitted.build(specs)
    return [replace(o, initiation=Nowhere(), continuation=None)
            if sets == "learned" and fitted.region(o.name) is None
            and fitted.outcome(o.name) is None else o for o in options]


def fitted_for(models: FittedModels, sets: str) -> FittedModels:
    """What of ``models`` the options' sets use under ``sets`` (one of
    :data:`INITIATION_SETS`): everything under ``learned``; the regions without the
    initiation learned from outcomes under ``rules`` and ``regions``; nothing learned
    under ``everywhere``.

    Raises:
        DynoplanError: unknown ``sets``, or learned sets without regions.
    """
    check_sets(sets)
    if sets == "everywhere":
        return replace(models, use_regions=False, learned_initiation=None)
    if models.regions is None:
        raise DynoplanError("the gear's options need the learned safety regions")
    return models if sets == "learned" else replace(models, learned_initiation=None)


def option_state_map(name: str, models: FittedModels) -> StateMap | None:
    """The state option ``name``'s dynamics in ``models`` read: its registry record's own
    state (:attr:`~dynoplan.envs.gear.options.registry.GearOption.state_map`) when the
    models folder says they were fitted on it, else ``None`` (the planner state).

    Raises:
        DynoplanError: the folder's own state has another size than the record's map, or
            the record declares none.
    """
    own = models.option_state_dims.get(name)
    if own is None:
        return None
    state_map = gear_option(name).state_map
    if state_map is None or state_map.option_dim != own:
        raise DynoplanError(
            f"option '{name}': its dynamics read its own state of {own} values; the "
            "registered option " + ("declares none" if state_map is None
                                    else f"maps {state_map.option_dim}"))
    return state_map


def check_sets(sets: str) -> None:
    """Raises :class:`~dynoplan.errors.DynoplanError` unless ``sets`` is one of
    :data:`INITIATION_SETS`."""
    if sets not in INITIATION_SETS:
        raise DynoplanError(f"unknown initiation sets {sets!r}; expected one of "
                            f"{', '.join(INITIATION_SETS)}")


def own_sets(name: str, sets: str) -> tuple[Initiation, Initiation | None]:
    """Option ``name``'s own initiation and continuation sets under ``sets`` (one of
    :data:`INITIATION_SETS`), without anything learned: its hand-written conditions (its
    registry record) under ``rules``; everywhere under the other sets, which use no
    hand-written condition."""
    check_sets(sets)
    return gear_option(name).sets() if sets == "rules" else (Everywhere(), None)


def gear_control(env: GearAssemblyEnv, factories: Mapping[str, GearPolicyFactory]
                 ) -> TaskControl:
    """What the gear gives the one controller factory
    (:func:`~dynoplan.pipeline.evaluate.make_controller`) for controllers on ``env``: the
    planner state (:class:`~dynoplan.envs.gear.state.PlannerState`), :class:`HoldStill`,
    terminations drawn every decision period (the learned models step at that rate),
    every step's ``info`` kept (for :func:`~dynoplan.envs.gear.metrics.episode_metrics`),
    the safety constraint (:func:`gear_safety_constraint`), the simulator oracle
    (:func:`gear_oracle`, its policies from ``factories``) and :data:`FIXED_SCRIPT`."""

    def oracle(options: Sequence[Option], goal: GoalHeuristic,
               settings: ControllerSettings) -> SimulatorOracle:
        return gear_oracle(env, list(options), factories, goal, settings.oracle_horizon,
                           settings.oracle_samples)

    return TaskControl(state_fn=PlannerState(), hold_action=HoldStill(env),
                       termination_every=DECISION_STEPS, record_infos=True,
                       constraint=gear_safety_constraint(env), oracle=oracle,
                       script=FIXED_SCRIPT)


SAFETY_LOOKAHEAD = 2.5
"""Seconds of each imagined future the gear's safety constraint checks (5 decisions)."""


def gear_safety_constraint(env: GearAssemblyEnv) -> SeparationConstraint:
    """ISO/TS 15066 separation between both arms (:func:`arm_points`) and the hand, whose
    motion is predicted at constant velocity from its measured velocity in ``env`` (the
    observation's ``human_vel``), one model step per decision period."""
    human = ConstantVelocityHuman(
        position=lambda state: state[STATE_SLICES["human_pos"]],
        velocity=lambda: env.schedule.velocity(float(env.data.time)))
    return SeparationConstraint(arm_points, human, step_seconds=DECISION_STEPS * CONTROL_DT,
                                lookahead=SAFETY_LOOKAHEAD)


def gear_oracle(env: GearAssemblyEnv, options: list[Option],
                factories: Mapping[str, GearPolicyFactory], goal: GoalHeuristic, horizon: int,
                samples: int) -> SimulatorOracle:
    """The simulator oracle on the gear: MuJoCo (and the human's schedule) copied into a
    scratch environment that never truncates, one decision = :data:`DECISION_STEPS`."""
    return SimulatorOracle(env, options, factories, goal,
                           scratch=GearAssemblyEnv(max_episode_steps=10**9),
                           state_fn=PlannerState(), steps_per_decision=DECISION_STEPS,
                           horizon=horizon, samples=samples)


class HoldStill:
    """The safe action when no option is admissible: both arms held at their last
    commanded joint targets and the gripper as it is (observation (50,) -> action (13,)).

    Holding the *measured* angles instead lets the arms sag under gravity, every step a
    little more (the peg module dropped 9 cm onto the table in a 5 s hold)."""

    def __init__(self, env: GearAssemblyEnv) -> None:
        self.env = env

    def __call__(self, observation: FloatArray) -> FloatArray:
        return np.concatenate([self.env.arm_targets, [gripper_as_it_is(observation)]])


class StopWhereItIs:
    """The gear's protective stop (the runtime monitor's stop action; observation (50,)
    -> action (13,)): the left arm commanded to the joint angles it has now while it
    moves, and held at its last targets once it is still (commanding the measured angles
    step after step lets it sag under gravity); the right arm, which holds the peg and
    never moves in the task, held at its targets; the gripper as it is."""

    STILL = 0.05
    """rad/s: the left arm is still when no joint turns faster."""

    def __init__(self, env: GearAssemblyEnv) -> None:
        self.env = env

    def __call__(self, observation: FloatArray) -> FloatArray:
        targets = self.env.arm_targets
        still = float(np.max(np.abs(observation[OBS_SLICES["arm_qvel"]][:6]))) < self.STILL
        left = targets[:6] if still else self.env.arm_qpos[:6]
        return np.concatenate([left, targets[6:], [gripper_as_it_is(observation)]])


__all__ = [
    "CARRIED_GEAR_HEIGHT",
    "CONTROLLERS",
    "FIXED_SCRIPT",
    "GEAR_CONTROL",
    "GEAR_TUNED",
    "HELD_GEAR_HEIGHT",
    "INITIATION_SETS",
    "INSERT_KEEP_CLEARANCE",
    "INSERT_START_CLEARANCE",
    "MAX_EPISODE_SECONDS",
    "MAX_EPISODE_STEPS",
    "MOVE_START_DISTANCE",
    "PICK_CLEARANCE",
    "TUNED_CHANGES",
    "VARIANTS",
    "FarFromGoal",
    "HoldStill",
    "StopWhereItIs",
    "check_sets",
    "fitted_for",
    "gear_control",
    "gear_options",
    "gear_oracle",
    "gripper_as_it_is",
    "hand_clear_of_tool",
    "hand_near_tool",
    "holding_gear",
    "not_carried",
    "option_state_map",
    "own_sets",
]

