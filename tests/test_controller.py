"""Controller: runs chosen options, stops them at region exits, holds still, margin rule."""

from dataclasses import replace

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

from dynoplan.control import Controller, FixedChoice
from dynoplan.errors import DynoplanError
from dynoplan.options import (
    AllOf,
    AnyOf,
    ConstantTermination,
    Everywhere,
    FunctionPolicy,
    InitiationFromCallable,
    Option,
    OptionPolicy,
    TerminationFromCallable,
)
from dynoplan.pipeline.control_settings import ControllerSettings
from dynoplan.planning import Plan


class Line(gym.Env):
    """x on a line; the action is added to x; success at x >= 10."""

    def __init__(self):
        self.observation_space = spaces.Box(-100, 100, (1,), np.float64)
        self.action_space = spaces.Box(-5, 5, (1,), np.float64)
        self.x = 0.0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x = 0.0
        return np.array([self.x]), {}

    def step(self, action):
        self.x += float(np.asarray(action).reshape(-1)[0])
        done = self.x >= 10
        return np.array([self.x]), float(done), done, False, {"is_success": done}


class _Identity:
    state_dim = 1

    def sample(self, states, rng):
        return states


def _option(name, step, beta=0.0, initiation=None):
    kwargs = {} if initiation is None else {"initiation": initiation}
    return Option(name, FunctionPolicy(lambda o, r, s=step: np.array([s])), _Identity(),
                  ConstantTermination(beta), **kwargs)


class ScriptedScores:
    """A chooser returning given scores per call (to exercise the margin rule)."""

    def __init__(self, names, scores_per_call):
        self._names = tuple(names)
        self.calls = list(scores_per_call)

    @property
    def option_names(self):
        return self._names

    def choose(self, state, rng, running=None):
        scores = np.array(self.calls.pop(0), dtype=float)
        n = len(scores)
        return Plan(self._names, np.ones(n, bool), scores, np.zeros(n), np.zeros((n, 0, 1)),
                    np.zeros((n, 0), np.int64), int(np.argmax(scores)))


def test_runs_until_success_and_records_the_trace():
    options = [_option("up", 1.0, beta=0.25)]
    trace = Controller(options, FixedChoice(options, "up"), max_decisions=100).run(
        Line(), np.random.default_rng(0), seed=0)
    assert trace.success
    assert trace.env_steps == 10
    assert trace.decisions[-1].stop_reason == "episode_end"
    assert trace.planning_steps == len(trace.decisions)


def test_an_option_leaving_its_region_is_stopped_and_counted_when_started_outside():
    below_3 = InitiationFromCallable(lambda s: s[:, 0] < 3)
    options = [_option("bounded", 1.0, initiation=below_3)]
    controller = Controller(options, FixedChoice(options, "bounded"), max_decisions=2)
    trace = controller.run(Line(), np.random.default_rng(0), seed=0)
    assert trace.decisions[0].stop_reason == "left_region"
    assert trace.decisions[0].state_after[0] == 3.0
    assert trace.decisions[1].outside_region  # the fixed baseline ignores regions
    assert trace.out_of_region_starts == 1


def test_without_an_admissible_option_the_robot_holds_still():
    nowhere = InitiationFromCallable(lambda s: np.zeros(len(s), bool))
    from dynoplan.envs.random_walk import NoisyWalkGoal
    from dynoplan.planning import OptionPlanner

    options = [_option("never", 1.0, initiation=nowhere)]
    planner = OptionPlanner(options, NoisyWalkGoal(0.0))
    trace = Controller(options, planner, max_decisions=4, hold_action=np.array([0.0])).run(
        Line(), np.random.default_rng(0), seed=0)
    assert trace.no_admissible == 4
    assert trace.env_steps == 4
    assert all(d.stop_reason == "hold" for d in trace.decisions)
    assert not trace.success
    ended = Controller(options, planner, max_decisions=4).run(Line(), np.random.default_rng(0))
    assert ended.no_admissible == 1 and ended.env_steps == 0


def test_where_no_option_is_admissible_the_fallback_sets_decide_not_a_hold_for_good():
    # a learned judgement that rules out everything at the start (an over-confident
    # classifier) narrows a region that does hold the start
    from dynoplan.envs.random_walk import NoisyWalkGoal
    from dynoplan.options import admissible
    from dynoplan.planning import OptionPlanner

    nowhere = InitiationFromCallable(lambda s: np.zeros(len(s), bool))
    region = InitiationFromCallable(lambda s: s[:, 0] < 20)
    up = Option("up", FunctionPolicy(lambda o, r: np.array([1.0])), _Identity(),
                ConstantTermination(0.0), initiation=AllOf(region, nowhere), continuation=region,
                fallback=region)
    down = _option("down", -1.0, initiation=nowhere)  # no fallback: stays inadmissible
    options = [up, down]
    assert admissible(options, np.array([0.0])).tolist() == [True, False]
    assert admissible(options, np.array([30.0])).tolist() == [False, False]
    with_other = [up, _option("any", 0.5)]  # another option may start: no fallback
    assert admissible(with_other, np.array([0.0])).tolist() == [False, True]
    trace = Controller(options, OptionPlanner(options, NoisyWalkGoal(0.0)), max_decisions=4,
                       hold_action=np.array([0.0])).run(Line(), np.random.default_rng(0), seed=0)
    assert trace.success and trace.no_admissible == 0
    assert trace.out_of_region_starts == 0  # a fallback start is a start inside the sets


def test_an_option_started_under_its_fallback_goes_on_while_the_fallback_holds():
    # its own set (x < 2) is left after two steps; without a way to go on, the controller
    # would stop it and choose again at every step
    own = InitiationFromCallable(lambda s: s[:, 0] < 2)
    anywhere = InitiationFromCallable(lambda s: s[:, 0] < 100)
    up = Option("up", FunctionPolicy(lambda o, r: np.array([1.0])), _Identity(),
                ConstantTermination(0.0), initiation=AllOf(own, anywhere),
                fallback=anywhere)
    trace = Controller([up], FixedChoice([up], "up"), max_decisions=20,
                       hold_action=np.array([0.0])).run(Line(), np.random.default_rng(0), seed=0)
    assert trace.success
    assert [d.steps for d in trace.decisions] == [2, 8]  # in its own set, then falling back
    assert [d.stop_reason for d in trace.decisions] == ["left_region", "episode_end"]


def test_with_fallback_goes_on_an_option_leaving_its_set_where_none_may_start_goes_on():
    # "up" starts inside its learned set (x < 2) and leaves it after two steps; there no
    # option may start under its learned set ("idle" only at x < -5), so with the rule it
    # goes on under its own set, as an option started there would
    own = InitiationFromCallable(lambda s: s[:, 0] < 2)
    anywhere = InitiationFromCallable(lambda s: s[:, 0] < 100)
    up = Option("up", FunctionPolicy(lambda o, r: np.array([1.0])), _Identity(),
                ConstantTermination(0.0), initiation=AllOf(own, anywhere), fallback=anywhere)
    idle = _option("idle", 0.0, initiation=InitiationFromCallable(lambda s: s[:, 0] < -5))

    def run(goes_on, options):
        controller = Controller(options, FixedChoice(options, "up"), max_decisions=20,
                                hold_action=np.array([0.0]), fallback_goes_on=goes_on)
        return [d.steps for d in controller.run(Line(), np.random.default_rng(0), seed=0)
                .decisions]

    assert run(False, [up, idle]) == [2, 8]  # stopped at the edge, chosen again
    assert run(True, [up, idle]) == [10]  # one run to the goal
    # where another option may start under its learned set, the edge stops it as always
    other = _option("other", 0.0, initiation=InitiationFromCallable(lambda s: s[:, 0] >= 2))
    assert run(True, [up, other])[0] == 2


def _options_run_on_scores(calls, **rules):
    """The options ("a", "b") a controller replanning at every step runs, given the
    chooser's scores at each decision (``calls``) and the controller's ``rules``."""
    options = [_option("a", 0.5), _option("b", 0.5)]
    chooser = ScriptedScores(["a", "b"], [list(c) for c in calls])
    controller = Controller(options, chooser, max_decisions=len(calls), replan_every=1,
                            **rules)
    return [d.option for d in controller.run(Line(), np.random.default_rng(0)).decisions]


def test_margin_keeps_a_running_option_unless_clearly_beaten():
    calls = [[0.5, 0.1], [0.50, 0.55], [0.5, 0.7]]
    assert _options_run_on_scores(calls, margin=0.1) == ["a", "a", "b"]
    assert _options_run_on_scores(calls, margin=0.0) == ["a", "b", "b"]


def test_commitment_keeps_a_running_option_while_its_own_prospects_hold():
    """With ``commit``, another option that promises more does not interrupt the running
    one until the running one's own score falls below what it was chosen with."""
    # "a" chosen at 0.5; "b" promises more and more while "a" holds, then "a" falls
    calls = [[0.5, 0.1], [0.49, 0.8], [0.5, 0.9], [0.3, 0.9], [0.9, 0.2]]
    assert _options_run_on_scores(calls, commit=0.05) == ["a", "a", "a", "b", "a"]
    assert _options_run_on_scores(calls, commit=None) == ["a", "b", "b", "b", "a"]
    with pytest.raises(DynoplanError, match="commit must be >= 0"):
        ControllerSettings(commit=-0.1).validate()


def test_switch_count():
    options = [_option("a", 0.5), _option("b", 0.5)]
    chooser = ScriptedScores(["a", "b"], [[1, 0], [0, 1], [0, 1], [1, 0]])
    trace = Controller(options, chooser, max_decisions=4, replan_every=1).run(
        Line(), np.random.default_rng(0))
    assert trace.switches == 2



def test_initiation_sets_compose_as_intersection_and_union():
    left = InitiationFromCallable(lambda s: s[:, 0] < 0.0)
    small = InitiationFromCallable(lambda s: np.abs(s[:, 0]) < 1.0)
    states = np.array([[-2.0], [-0.5], [0.5], [2.0]])
    assert AllOf(left, small).contains(states).tolist() == [False, True, False, False]
    assert AnyOf(left, small).contains(states).tolist() == [True, True, True, False]
    with pytest.raises(ValueError, match="at least one"):
        AnyOf()




def _starts_below_2_continues_anywhere():
    """Moves +1 per step; may start only at x < 2, may go on anywhere; stops at x >= 6."""
    return Option("up", FunctionPolicy(lambda o, r: np.array([1.0])), _Identity(),
                  TerminationFromCallable(lambda s: (s[:, 0] >= 6).astype(float)),
                  initiation=InitiationFromCallable(lambda s: s[:, 0] < 2),
                  continuation=Everywhere())


@pytest.mark.parametrize("replan_every", [None, 1])
def test_a_running_option_goes_on_in_its_continuation_set_beyond_its_initiation_set(
        replan_every):
    """Started at x = 0 (inside its initiation set x < 2), the option runs to its own end
    at x = 6 whether or not the controller replans on the way: at a replan the running
    option is judged by its continuation set, not by where it may start."""
    from dynoplan.envs.random_walk import NoisyWalkGoal
    from dynoplan.planning import OptionPlanner

    options = [_starts_below_2_continues_anywhere()]
    controller = Controller(options, OptionPlanner(options, NoisyWalkGoal(0.0), horizon=3,
                                                   samples=2),
                            max_decisions=20, replan_every=replan_every)
    trace = controller.run(Line(), np.random.default_rng(0), seed=0)
    ran = [d for d in trace.decisions if d.option is not None]
    assert ran[-1].state_after[0] == 6.0 and ran[-1].stop_reason == "terminated"
    assert all(d.option == "up" and not d.outside_region for d in ran)
    assert trace.env_steps == 6 and trace.out_of_region_starts == 0


def test_the_planner_scores_a_running_option_under_its_continuation_set():
    from dynoplan.envs.random_walk import NoisyWalkGoal
    from dynoplan.planning import OptionPlanner

    planner = OptionPlanner([_starts_below_2_continues_anywhere()], NoisyWalkGoal(0.0))
    state, rng = np.array([3.0]), np.random.default_rng(0)
    assert not planner.choose(state, rng).admissible[0]  # may not start at x = 3
    plan = planner.choose(state, rng, running=0)  # but may go on there
    assert plan.admissible[0] and plan.chosen == 0 and np.isfinite(plan.scores[0])


class RestorableLine(Line):
    """:class:`Line` that can take over another instance's state (for the oracle)."""

    def copy_state_from(self, source):
        self.x = source.x
        return np.array([self.x]), {}


def test_the_simulator_oracle_judges_options_by_the_planners_sets():
    """The oracle simulates a running option on through its continuation set, and may
    start an option only in its initiation set, as the learned planner does."""
    from dynoplan.envs.random_walk import NoisyWalkGoal
    from dynoplan.planning import SimulatorOracle

    option = _starts_below_2_continues_anywhere()
    live = RestorableLine()
    live.reset(seed=0)
    oracle = SimulatorOracle(live, [option], {"up": lambda env: option.policy},
                             NoisyWalkGoal(0.0), RestorableLine(), lambda o: np.asarray(o),
                             horizon=10)
    rng = np.random.default_rng(0)
    live.x = 1.0  # inside its initiation set: simulated to its own end at x = 6
    plan = oracle.choose(np.array([1.0]), rng)
    assert plan.chosen == 0 and plan.end_states[0, 0, 0] == 6.0 and plan.steps[0, 0] == 5
    live.x = 3.0  # may not start at x = 3, but a running option goes on there
    assert not oracle.choose(np.array([3.0]), rng).admissible[0]
    plan = oracle.choose(np.array([3.0]), rng, running=0)
    assert plan.admissible[0] and plan.end_states[0, 0, 0] == 6.0


class _Shift(_Identity):
    """A (wrong) dynamics model: every step moves x by ``by``."""

    def __init__(self, by):
        self.by = by

    def sample(self, states, rng):
        return states + self.by


class _Progress:
    """G(x) = 0.2 + x / 100, exact."""

    def mean_std(self, states):
        mean = 0.2 + np.asarray(states, dtype=float)[:, 0] / 100
        return mean, np.zeros_like(mean)

    def sample(self, states, rng):
        return self.mean_std(states)[0]


def test_a_hold_that_changes_nothing_far_from_the_goal_is_not_held_for_good():
    # no learned set holds anywhere; "up" may start under its own set, but its (wrong)
    # model says it goes down, so the planner would hold rather than lose progress: on a
    # line that does not move under the hold, for good
    from dynoplan.planning import OptionPlanner

    nowhere = InitiationFromCallable(lambda s: np.zeros(len(s), bool))
    anywhere = InitiationFromCallable(lambda s: s[:, 0] < 100)
    up = Option("up", FunctionPolicy(lambda o, r: np.array([1.0])), _Shift(-1.0),
                ConstantTermination(0.0), initiation=AllOf(anywhere, nowhere),
                fallback=anywhere)
    planner = OptionPlanner([up], _Progress(), fallback_must_gain=True)

    def run(stall_progress):
        return Controller([up], planner, max_decisions=20, hold_action=np.array([0.0]),
                          stall_progress=stall_progress).run(
            Line(), np.random.default_rng(0), seed=0)

    assert planner.choose(np.array([0.0]), np.random.default_rng(0)).gain_floor == 0.2
    for held in (run(None), run(0.2)):  # no rule; G(0) = 0.2 is not below 0.2
        assert not held.success and held.no_admissible == 20 and held.env_steps == 20
    moved = run(0.5)  # one hold changed nothing at G = 0.2 < 0.5: "up" starts
    assert moved.success and moved.no_admissible == 1
    assert [d.option for d in moved.decisions] == [None, "up"]


def test_where_no_learned_choice_gains_an_option_under_its_own_set_that_gains_runs():
    # "wait" may start everywhere under its learned set, but its model says it loses
    # progress; "up" has no learned set (its own set, the fallback, holds everywhere)
    # and its model says it gains: the learned sets alone never let the line reach 10
    from dynoplan.planning import OptionPlanner

    nowhere = InitiationFromCallable(lambda s: np.zeros(len(s), bool))
    anywhere = InitiationFromCallable(lambda s: s[:, 0] < 100)
    wait = Option("wait", FunctionPolicy(lambda o, r: np.array([0.0])), _Shift(-1.0),
                  ConstantTermination(1.0), initiation=anywhere, fallback=anywhere)

    def up(model):
        return Option("up", FunctionPolicy(lambda o, r: np.array([1.0])), model,
                      ConstantTermination(0.0), initiation=AllOf(anywhere, nowhere),
                      fallback=anywhere)

    def run(widen, model=_Shift(1.0)):
        options = [wait, up(model)]
        planner = OptionPlanner(options, _Progress(), horizon=3, samples=2,
                                widen_without_gain=widen)
        return planner, Controller(options, planner, max_decisions=30).run(
            Line(), np.random.default_rng(0), seed=0)

    planner, learned_only = run(False)
    assert not learned_only.success
    assert {d.option for d in learned_only.decisions} == {"wait"}
    planner, widened = run(True)
    plan = planner.choose(np.array([0.0]), np.random.default_rng(0))
    assert plan.chosen_name == "up" and plan.widened is not None
    assert plan.widened.tolist() == [False, True] and plan.admissible.all()
    # "up" goes on under its own set: one decision from the start to the goal
    assert widened.success and [d.option for d in widened.decisions] == ["up"]
    assert widened.out_of_region_starts == 0
    # an option no demonstration ran is not looked at
    options = [wait, replace(up(_Shift(1.0)), demonstrated=False)]
    plan = OptionPlanner(options, _Progress(), horizon=3, samples=2,
                         widen_without_gain=True).choose(np.array([0.0]),
                                                         np.random.default_rng(0))
    assert plan.chosen_name == "wait" and plan.widened is None
    # an option that does not gain either is scored, but the learned choice stays
    planner, neither = run(True, _Shift(-2.0))
    plan = planner.choose(np.array([0.0]), np.random.default_rng(0))
    assert plan.chosen_name == "wait" and plan.widened is not None
    assert not neither.success
    # the rule belongs to the depth-1 planner
    with pytest.raises(DynoplanError, match="depth-1 planner"):
        ControllerSettings(depth=2, fallback_without_gain=True).validate()


def test_where_no_option_gains_the_option_the_regions_make_likeliest_runs():
    # both options may start everywhere; the models of both say they lose progress, and
    # "down"'s less; the regions make "up" the demonstrations' choice on the line
    from dynoplan.planning import OptionPlanner

    anywhere = InitiationFromCallable(lambda s: s[:, 0] < 100)

    def option(name, step, model, log_l):
        return Option(name, FunctionPolicy(lambda o, r: np.array([step])), model,
                      ConstantTermination(0.0), initiation=anywhere,
                      likelihood=None if log_l is None
                      else (lambda states: np.full(len(states), log_l)))

    def run(rule, up_log_l=-1.0):
        options = [option("down", -1.0, _Shift(-1.0), -5.0),
                   option("up", 1.0, _Shift(-2.0), up_log_l)]
        planner = OptionPlanner(options, _Progress(), horizon=3, samples=2,
                                regions_without_gain=rule)
        return planner, Controller(options, planner, max_decisions=30).run(
            Line(), np.random.default_rng(0), seed=0)

    planner, scores_only = run(False)
    assert not scores_only.success and {d.option for d in scores_only.decisions} == {"down"}
    planner, followed = run(True)
    plan = planner.choose(np.array([0.0]), np.random.default_rng(0))
    assert plan.chosen_name == "up" and plan.scores[1] < plan.scores[0]
    assert followed.success and {d.option for d in followed.decisions} == {"up"}
    # an option the safety constraint rules out (score -inf) is never the regions' choice
    assert planner._most_likely(np.array([0.0]), (0, 1), 0, np.array([0.0, -np.inf])) == 0
    # an option without a region is left to the scores
    planner, _ = run(True, up_log_l=None)
    assert planner.choose(np.array([0.0]), np.random.default_rng(0)).chosen_name == "down"
    # the default, and the sequence planner has no such rule: depth 2 stays valid with it
    assert ControllerSettings().regions_without_gain
    ControllerSettings(depth=2).validate()
    with pytest.raises(DynoplanError, match="depth-1 planner"):
        ControllerSettings(depth=2, fallback_without_gain=True).validate()


def test_an_option_that_ends_where_it_started_is_not_chosen_there_again():
    # "stay" ends at once without moving, but its model promises +5 a step: Eq. 1 prefers
    # it to "up", whose learned initiation rules it out (only its fallback region holds)
    from dynoplan.envs.random_walk import NoisyWalkGoal
    from dynoplan.planning import OptionPlanner

    nowhere = InitiationFromCallable(lambda s: np.zeros(len(s), bool))
    region = InitiationFromCallable(lambda s: s[:, 0] < 20)
    up = Option("up", FunctionPolicy(lambda o, r: np.array([1.0])), _Identity(),
                ConstantTermination(0.0), initiation=AllOf(region, nowhere),
                continuation=region, fallback=region)
    stay = Option("stay", FunctionPolicy(lambda o, r: np.array([0.0])), _Shift(5.0),
                  ConstantTermination(1.0))
    options = [up, stay]

    def run(tolerance):
        planner = OptionPlanner(options, NoisyWalkGoal(0.0), horizon=2, samples=4)
        return Controller(options, planner, max_decisions=30, replan_every=3,
                          no_effect_tolerance=tolerance).run(Line(), np.random.default_rng(0))

    looping = run(None)
    assert not looping.success
    assert {d.option for d in looping.decisions} == {"stay"}
    assert looping.env_steps == 30  # one step each time, to the decision limit
    trace = run(1e-6)
    assert trace.success
    assert [d.option for d in trace.decisions[:2]] == ["stay", "up"]
    assert trace.out_of_region_starts == 0
    # a new episode forgets the last one's runs
    again = run(1e-6)
    assert [d.option for d in again.decisions[:2]] == ["stay", "up"]


def test_an_option_that_ended_without_effect_may_start_again_once_the_state_moves():
    from dynoplan.options import admissible

    stay = _option("stay", 0.0)
    stay.ended_without_effect(np.array([3.0]), 0.1)
    assert admissible([stay], np.array([3.05])).tolist() == [False]
    assert admissible([stay], np.array([3.2])).tolist() == [True]
    assert admissible([stay], np.array([3.0]), running=0).tolist() == [True]  # going on
    stay.forget_runs()
    assert admissible([stay], np.array([3.0])).tolist() == [True]
    with pytest.raises(DynoplanError, match="no_effect_tolerance"):
        Controller([stay], FixedChoice([stay], "stay"), no_effect_tolerance=-1.0)


def test_two_options_that_undo_each_other_are_not_chosen_again_where_the_loop_closes():
    # "forward" (x < 0.5) and "back" (x > 0.5) each move one step and promise much more;
    # "up" promises nothing but gets there: Eq. 1 alternates forward and back for ever
    from dynoplan.envs.random_walk import NoisyWalkGoal
    from dynoplan.planning import OptionPlanner

    def one_step(name, by, promise, where):
        return Option(name, FunctionPolicy(lambda o, r: np.array([by])), _Shift(promise),
                      ConstantTermination(1.0), initiation=InitiationFromCallable(where))

    options = [one_step("forward", 1.0, 5.0, lambda s: s[:, 0] < 0.5),
               one_step("back", -1.0, 4.0, lambda s: s[:, 0] > 0.5),
               _option("up", 1.0)]

    def run(tolerance):
        planner = OptionPlanner(options, NoisyWalkGoal(0.0), horizon=2, samples=4)
        return Controller(options, planner, max_decisions=30, loop_tolerance=tolerance,
                          no_effect_tolerance=1e-6).run(Line(), np.random.default_rng(0))

    looping = run(None)
    assert not looping.success
    assert [d.option for d in looping.decisions[:4]] == ["forward", "back"] * 2
    trace = run(0.5)
    assert trace.success
    # back at x = 0, where "forward" started the loop: "up" instead
    assert [d.option for d in trace.decisions] == ["forward", "back", "up"]
    with pytest.raises(DynoplanError, match="loop_tolerance"):
        Controller(options, FixedChoice(options, "up"), loop_tolerance=-1.0)


def test_a_loop_judged_by_the_goal_bars_the_option_that_undid_the_progress():
    # "grasp" (x < 0.5) moves to x = 1; "undo" (0.5 < x < 1.5) moves back to 0 and
    # promises more than "carry" (x > 0.5), which alone gets to the goal. The loop closes
    # back at x = 0, where "grasp" started it: the old rule bars "grasp" there and nothing
    # is left; judged by the goal heuristic, "undo" lost the progress "grasp" made
    from dynoplan.envs.random_walk import NoisyWalkGoal
    from dynoplan.pipeline.evaluate import goal_means
    from dynoplan.planning import OptionPlanner

    def one_step(name, by, promise, where):
        return Option(name, FunctionPolicy(lambda o, r: np.array([by])), _Shift(promise),
                      ConstantTermination(1.0), initiation=InitiationFromCallable(where))

    options = [one_step("grasp", 1.0, 5.0, lambda s: s[:, 0] < 0.5),
               one_step("undo", -1.0, 4.0, lambda s: (s[:, 0] > 0.5) & (s[:, 0] < 1.5)),
               Option("carry", FunctionPolicy(lambda o, r: np.array([1.0])), _Shift(1.0),
                      ConstantTermination(0.0),
                      initiation=InitiationFromCallable(lambda s: s[:, 0] > 0.5))]
    goal = NoisyWalkGoal(0.0)

    def run(progress):
        planner = OptionPlanner(options, goal, horizon=2, samples=4)
        return Controller(options, planner, max_decisions=30, loop_tolerance=0.5,
                          progress=progress).run(Line(), np.random.default_rng(0))

    by_state = run(None)  # "grasp" may not start at x = 0 again: nothing is admissible
    assert not by_state.success
    assert [d.option for d in by_state.decisions] == ["grasp", "undo", None]
    for _ in range(2):  # a new episode forgets the bar
        trace = run(goal_means(goal))
        assert trace.success
        assert [d.option for d in trace.decisions] == ["grasp", "undo", "grasp", "carry"]


def test_a_planners_copy_of_an_option_sees_where_its_run_ended_without_effect():
    # the planner may hold copies of the controller's options (noisy dynamics, other
    # feature maps): what the controller records must reach them
    from dataclasses import replace

    from dynoplan.options import admissible

    stay = _option("stay", 0.0)
    copy = replace(stay, dynamics=_Shift(1.0))
    stay.ended_without_effect(np.array([3.0]), 0.1)
    assert admissible([copy], np.array([3.0])).tolist() == [False]
    stay.forget_runs()
    assert admissible([copy], np.array([3.0])).tolist() == [True]


class _DoesNothingFirst(OptionPolicy):
    """Its first run of the episode stands still for one step and stops (a run without
    effect); later runs move x up by 1 per step."""

    def __init__(self):
        self.runs = self.steps = 0

    def reset(self, observation, rng):
        self.runs, self.steps = self.runs + 1, 0

    def act(self, observation):
        self.steps += 1
        return np.array([0.0 if self.runs == 1 else 1.0])

    def finished(self):
        return self.runs == 1 and self.steps >= 1


def test_a_stall_kept_only_by_the_no_effect_marks_forgets_them_with_stall_forgets():
    # "up" ends its first run where it started: the no-effect rule marks the spot, no
    # option may start there, and the hold does not move the line: without stall_forgets
    # the episode waits to its end; with it, one hold in place at G = 0.2 < 0.5 forgets
    # the mark and "up" runs again
    from dynoplan.planning import OptionPlanner

    def run(stall_goal):
        up = Option("up", _DoesNothingFirst(), _Shift(1.0), ConstantTermination(0.0))
        planner = OptionPlanner([up], _Progress())
        return Controller([up], planner, max_decisions=20, hold_action=np.array([0.0]),
                          no_effect_tolerance=0.01, stall_progress=0.5,
                          stall_goal=stall_goal).run(Line(), np.random.default_rng(0),
                                                     seed=0)

    held = run(None)
    assert not held.success and held.no_admissible == 19
    assert [d.option for d in held.decisions[:3]] == ["up", None, None]
    moved = run(lambda states: _Progress().mean_std(states)[0])
    assert moved.success and moved.no_admissible == 1
    assert [d.option for d in moved.decisions[:3]] == ["up", None, "up"]
    # at the goal's side of stall_progress the marks stay: holding there is no stall
    near_goal = run(lambda states: np.full(len(states), 0.9))
    assert not near_goal.success and near_goal.no_admissible == 19
