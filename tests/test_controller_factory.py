"""The one controller factory (``make_controller``): a task's variants and what the task
adds (its hold, termination rate, safety constraint, oracle and script), checked on toy
options without an environment."""

import numpy as np
import pytest

from dynoplan.adapters import make_option
from dynoplan.control.choosers import FixedChoice, RandomChoice, ScriptedSequence
from dynoplan.errors import DynoplanError
from dynoplan.options.option import admissible
from dynoplan.options.termination import ConstantTermination
from dynoplan.pipeline import ControllerSettings, ControllerVariant, TaskControl, make_controller
from dynoplan.planning import OptionPlanner

SETTINGS = ControllerSettings(replan_every=5)


class Still:
    state_dim = 1

    def sample(self, states, rng):
        return states.copy()


def options():
    return [make_option(name, lambda s: 0.0, Still(), termination=0.2)
            for name in ("left", "right")]


def goal(states):
    return -np.abs(states[..., 0])


def test_the_generic_names_are_variants_of_the_one_factory():
    planner = make_controller("dynoplan", options(), goal, SETTINGS)
    same = make_controller(ControllerVariant("planner"), options(), goal, SETTINGS)
    assert isinstance(planner.chooser, OptionPlanner) and isinstance(same.chooser, OptionPlanner)
    assert planner.replan_every == same.replan_every == 5
    alone = make_controller("option:right", options(), goal, SETTINGS)
    assert isinstance(alone.chooser, FixedChoice) and alone.replan_every is None
    random = make_controller("random", options(), goal, SETTINGS)
    assert isinstance(random.chooser, RandomChoice) and random.replan_every is None
    with pytest.raises(DynoplanError, match="unknown controller 'best'"):
        make_controller("best", options(), goal, SETTINGS)


def test_what_the_task_adds_reaches_the_controller():
    hold = np.array([0.5])
    task = TaskControl(hold_action=hold, termination_every=4, record_infos=True,
                       script=("right", "left"))
    replanning = make_controller(ControllerVariant("random"), options(), goal, SETTINGS,
                                 task=task)
    assert replanning.hold_action is hold and replanning.record_infos
    assert replanning.replan_every == 5 and replanning.termination_every == 4
    script = make_controller(ControllerVariant("script", replans=False), options(), goal,
                             SETTINGS, task=task)
    assert isinstance(script.chooser, ScriptedSequence)
    assert script.replan_every is None and script.termination_every == 1
    # a script runs each option until its policy says it is finished
    assert all(isinstance(o.termination, ConstantTermination) and o.termination.beta == 0.0
               for o in script.options)
    # the settings' own hold action comes first
    own = make_controller("random", options(), goal,
                          ControllerSettings(hold_action=(0.0,)), task=task)
    assert own.hold_action.tolist() == [0.0]


def test_an_option_never_admissible_in_a_variant():
    controller = make_controller(ControllerVariant("planner", never=("left",)), options(),
                                 goal, SETTINGS)
    assert admissible(controller.options, np.array([0.0])).tolist() == [False, True]


def test_a_variant_needing_what_the_task_lacks_is_one_clear_error():
    for variant, what in ((ControllerVariant("planner", safe=True), "safety constraint"),
                          (ControllerVariant("oracle"), "oracle"),
                          (ControllerVariant("script", replans=False), "script")):
        with pytest.raises(DynoplanError, match=what):
            make_controller(variant, options(), goal, SETTINGS)
    with pytest.raises(DynoplanError, match="does not replan"):
        ControllerVariant("script")
    with pytest.raises(DynoplanError, match="unknown chooser"):
        ControllerVariant("best")
