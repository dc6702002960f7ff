"""Learning from DynoPlan's own episodes (``PipelineSettings.improve``): how its episodes
are cut for the fit, and the improvement rounds of a pipeline run."""

from dataclasses import replace

import gymnasium as gym
import numpy as np
import pytest

from dynoplan.control.choosers import Exploring, RandomChoice
from dynoplan.control.controller import Controller, Decision, EpisodeTrace
from dynoplan.data.episodes import (
    FAILURE_KEY,
    INTERRUPTED_KEY,
    OPTION_KEY,
    PROGRESS_KEY,
    Episode,
)
from dynoplan.errors import DynoplanError
from dynoplan.pipeline import run_pipeline
from dynoplan.pipeline.evaluate import ControllerRunner
from dynoplan.pipeline.fit_data import option_end_pairs
from dynoplan.pipeline.improve import (
    HOLD,
    ImprovementSettings,
    OwnEpisode,
    OwnEpisodeRunner,
    StepRecorder,
    improvement_rounds,
    own_episode,
    step_labels,
)
from dynoplan.planning import Plan
from dynoplan.seeding import episode_seeds
from test_pipeline import SMALL, line_env, line_options

PAPER = replace(SMALL, improve=0)
"""The paper's pipeline: no improvement rounds."""


_PLAN = Plan(("a",), np.ones(1, dtype=bool), np.zeros(1), np.zeros(1), np.zeros((1, 1, 1)),
             np.zeros((1, 1), dtype=np.int64), 0)
"""A decision's plan (what was chosen does not matter to the cutting)."""


def _trace(steps, success):
    """A trace of decisions ``(option or None, steps[, stop reason])`` run one after the
    other (an option's run ends ``terminated`` unless a reason is given)."""
    trace, at = EpisodeTrace(success=success), 0
    for k, (option, n, *why) in enumerate(steps):
        reason = why[0] if why else "terminated" if option else "hold"
        trace.decisions.append(Decision(k, at, np.zeros(1), _PLAN, option, n, reason,
                                        np.zeros(1), 0.0))
        at += n
    trace.env_steps = at
    return trace


def _recorder(steps):
    """A recorder that holds an episode of ``steps`` steps along a line."""
    env = line_env()
    recorder = StepRecorder(env)
    recorder.reset(seed=0)
    for _ in range(steps):
        recorder.step(np.array([0.5], np.float32))
    return recorder


def test_steps_are_labelled_with_the_option_that_ran_them_and_holds_apart():
    trace = _trace([("right", 2), (None, 1), ("left", 3)], success=False)
    assert step_labels(trace, ["right", "left"]).tolist() == [0, 0, HOLD, 1, 1, 1]


def test_a_failed_episode_is_cut_at_its_holds_and_its_end_is_a_failure():
    trace = _trace([("right", 2), (None, 1), ("left", 3)], success=False)
    own = own_episode(_recorder(6), trace, ["right", "left"], env_seed=0)
    assert own.demonstration is None  # it failed
    assert [len(p) for p in own.pieces] == [2, 3]
    assert [p.infos[OPTION_KEY].tolist() for p in own.pieces] == [[0, 0], [1, 1, 1]]
    # only the state the episode ended in is a failure
    assert [p.infos[FAILURE_KEY].tolist() for p in own.pieces] == [
        [False, False], [False, False, True]]
    # the pieces keep the states as they were: the second starts where the hold ended
    recorded = np.asarray(_recorder(6).observations)
    np.testing.assert_array_equal(own.pieces[1].observations, recorded[3:7])


def test_a_success_without_holds_becomes_a_demonstration_and_one_with_holds_does_not():
    names = ["right", "left"]
    clean = own_episode(_recorder(4), _trace([("right", 3), ("left", 1)], True), names, 0)
    assert clean.demonstration is not None
    assert clean.demonstration.infos[PROGRESS_KEY].tolist() == [0.25, 0.5, 0.75, 1.0]
    assert not any(p.infos[FAILURE_KEY].any() for p in clean.pieces)
    held = own_episode(_recorder(4), _trace([("right", 3), (None, 1)], True), names, 0)
    assert held.demonstration is None
    assert [len(p) for p in held.pieces] == [3]
    # a success in which a choice was an exploring chooser's random one: runs, no
    # demonstration
    trace = _trace([("right", 3), ("left", 1)], True)
    trace.decisions[1] = replace(trace.decisions[1],
                                 plan=replace(trace.decisions[1].plan, explored=True))
    explored = own_episode(_recorder(4), trace, names, 0)
    assert explored.demonstration is None and [len(p) for p in explored.pieces] == [4]


def test_a_run_cut_short_by_a_replan_teaches_the_option_models_no_end():
    # right replanned into right again (one run), then cut by a replan into left; left's
    # run ends where left terminated
    trace = _trace([("right", 2, "replan"), ("right", 2, "replan"), ("left", 2)], False)
    own = own_episode(_recorder(6), trace, ["right", "left"], env_seed=0)
    (piece,) = own.pieces
    assert piece.infos[INTERRUPTED_KEY].tolist() == [False, False, False, True, False, False]
    pairs = option_end_pairs([piece], ["right", "left"], lambda o: np.asarray(o).reshape(-1))
    assert len(pairs["right"][0]) == 0  # where right stopped is not where it ends
    recorded = np.asarray(_recorder(6).observations)
    np.testing.assert_array_equal(pairs["left"][1], recorded[[6, 6]])


@pytest.fixture(scope="module")
def improved(tmp_path_factory):
    out = tmp_path_factory.mktemp("improve")
    settings = replace(SMALL, improve=2, improve_episodes=3, improve_keep="last")
    return out, run_pipeline(line_env(), line_options(), demonstrator=lambda obs: "right",
                             settings=settings, out=out)


def test_improvement_rounds_report_a_learning_curve_and_refit_on_more_data(improved):
    out, res = improved
    curve = res.summary["improvement"]
    assert [c["round"] for c in curve] == [1, 2]
    assert all(c["episodes"] == 3 and 0.0 <= c["success_rate"] <= 1.0 for c in curve)
    added = sum(c["demonstrations_added"] for c in curve)
    assert added >= 1  # DynoPlan reaches the goal on the line
    # the goal was refitted on the demonstrator's 4 and DynoPlan's successes
    without = run_pipeline(line_env(), line_options(), demonstrator=lambda obs: "right",
                           settings=PAPER)
    assert res.models.report["goal"]["states"] > without.models.report["goal"]["states"]
    assert res.summary["demonstrations"]["episodes"] == 4  # the demonstrator's, as before
    # the other seed streams do not move: the same demonstrations and exploration
    assert {k: v for k, v in res.summary["seeds"].items() if k != "improve"} == \
        without.summary["seeds"]
    assert "improvement round" in (out / "results.md").read_text()


def test_without_rounds_the_run_is_the_papers_pipeline():
    without = run_pipeline(line_env(), line_options(), demonstrator=lambda obs: "right",
                           settings=PAPER)
    assert "improvement" not in without.summary
    assert "improve" not in without.summary["seeds"]


def test_by_default_one_round_runs_and_the_best_models_are_kept():
    res = run_pipeline(line_env(), line_options(), demonstrator=lambda obs: "right",
                       settings=replace(SMALL, improve_episodes=3))
    curve = res.summary["improvement"]
    assert [c["round"] for c in curve] == [1, 2] and curve[1]["check"]
    assert [c["kept"] for c in curve].count(True) == 1


def test_improvement_may_refit_the_goal_alone_and_keep_the_demonstrators_regions(tmp_path):
    settings = replace(SMALL, improve=2, improve_episodes=3, improve_regions=False,
                       improve_keep="last")
    res = run_pipeline(line_env(), line_options(), demonstrator=lambda obs: "right",
                       settings=settings)
    without = run_pipeline(line_env(), line_options(), demonstrator=lambda obs: "right",
                           settings=PAPER)
    assert sum(c["demonstrations_added"] for c in res.summary["improvement"]) >= 1
    assert res.models.report["goal"]["states"] > without.models.report["goal"]["states"]
    mine, theirs = res.models.regions, without.models.regions
    assert mine.option_names == theirs.option_names
    np.testing.assert_array_equal(mine.means, theirs.means)
    np.testing.assert_array_equal(mine.log_thresholds, theirs.log_thresholds)


def test_improvement_keeps_the_models_whose_own_episodes_succeeded_most_often():
    settings = replace(SMALL, improve=2, improve_episodes=3, improve_keep="best")
    res = run_pipeline(line_env(), line_options(), demonstrator=lambda obs: "right",
                       settings=settings)
    curve = res.summary["improvement"]
    assert len(curve) == 3 and curve[-1]["check"]  # one more batch measures the last refit
    rates = [c["success_rate"] for c in curve]
    kept = [c["kept"] for c in curve]
    assert kept.count(True) == 1 and kept.index(True) == rates.index(max(rates))
    without = run_pipeline(line_env(), line_options(), demonstrator=lambda obs: "right",
                           settings=PAPER)
    grew = res.models.report["goal"]["states"] > without.models.report["goal"]["states"]
    assert grew == (kept.index(True) > 0)  # the demonstrator's models when round 1 won


def test_an_unknown_improve_keep_is_one_error():
    with pytest.raises(DynoplanError, match="improve_keep must be one of last, best"):
        replace(SMALL, improve_keep="first").validate()


def _fake_own(successes):
    return [OwnEpisode(bool(s), (), None) for s in successes]


@pytest.mark.parametrize(("keep", "rates", "kept"), [
    ("best", [0.5, 1.0, 0.5], 1),   # the refit of round 1 did best
    ("best", [1.0, 0.5, 1.0], 0),   # a tie: the earliest
    ("last", [1.0, 0.0], 2),        # the last refit, however it did
])
def test_the_rounds_keep_the_models_the_settings_say(keep, rates, kept):
    """Any task's models (here: their round number) go through the one loop: each batch
    runs on the models of its round, a refit follows every round, and the models kept
    are the best batch's (the earliest of equals) or the last refit's."""
    settings = ImprovementSettings(rounds=2, episodes=2, keep=keep, explore=0.0)
    seeds = list(range(settings.batches * settings.episodes))
    played: list[tuple[int, list[int]]] = []

    def play(models, batch, explore):
        assert explore == 0.0
        played.append((models, list(batch)))
        rate = rates[models]
        return _fake_own([1, 1] if rate == 1.0 else [1, 0] if rate == 0.5 else [0, 0])

    models, curve = improvement_rounds(0, settings, seeds, play, lambda r, own: r + 1,
                                       lambda _: None)
    assert models == kept
    assert [m for m, _ in played] == list(range(len(rates)))
    assert [b for _, b in played] == [seeds[i * 2:i * 2 + 2] for i in range(len(rates))]
    assert [c["success_rate"] for c in curve] == rates
    if keep == "best":
        assert curve[-1]["check"] and [c["kept"] for c in curve].index(True) == kept
    else:
        assert all("kept" not in c and "check" not in c for c in curve)


def test_without_rounds_the_first_models_are_kept_and_nothing_runs():
    models, curve = improvement_rounds("first", ImprovementSettings(rounds=0), [],
                                       lambda m, s, e: pytest.fail("no episode runs"),
                                       lambda r, own: pytest.fail("no refit"), lambda _: None)
    assert models == "first" and curve == []


class _Fixed:
    """A chooser that always chooses option 0 where ``admissible`` says what may run."""

    option_names = ("a", "b", "c")

    def __init__(self, admissible):
        self.admissible = np.asarray(admissible, dtype=bool)

    def choose(self, state, rng, running=None):
        n = len(self.option_names)
        chosen = 0 if self.admissible[0] else None
        return Plan(self.option_names, self.admissible, np.zeros(n), np.zeros(n),
                    np.zeros((n, 1, 1)), np.zeros((n, 1), dtype=np.int64), chosen)


def test_exploring_chooses_uniformly_among_the_admissible_options_at_its_rate():
    rng = np.random.default_rng(0)
    chosen = [Exploring(_Fixed([True, False, True]), 0.5).choose(np.zeros(1), rng).chosen
              for _ in range(4000)]
    counts = np.bincount(chosen, minlength=3)
    assert counts[1] == 0  # never an option that may not run
    # half the decisions explore, half of those pick option 2: about a quarter
    assert 0.22 < counts[2] / 4000 < 0.28
    # nothing admissible: it holds, as the chooser does
    assert Exploring(_Fixed([False, False, False]), 1.0).choose(np.zeros(1), rng).chosen is None


def test_exploring_at_zero_is_the_chooser_itself_and_draws_nothing():
    a, b = np.random.default_rng(5), np.random.default_rng(5)
    plan = Exploring(_Fixed([True, True, True]), 0.0).choose(np.zeros(1), a)
    assert plan.chosen == 0
    assert a.random() == b.random()  # the stream is where it was
    with pytest.raises(DynoplanError, match=r"in \[0, 1\]"):
        Exploring(_Fixed([True, True, True]), 1.5)
    with pytest.raises(DynoplanError, match=r"improve_explore must be in \[0, 1\]"):
        replace(SMALL, improve_explore=-0.1).validate()


def test_the_improvement_rounds_explore_and_leave_the_evaluated_controller_alone():
    no_regions = replace(SMALL.fit, regions=False)  # both options may run everywhere
    runs = {}
    for explore in (0.0, 1.0):
        settings = replace(SMALL, improve_episodes=3, improve_keep="last",
                           improve_explore=explore, fit=no_regions)
        res = run_pipeline(line_env(), line_options(), demonstrator=lambda obs: "right",
                           settings=settings)
        runs[explore] = res
    # exploring, the round also ran 3 episodes of random choices: more option runs for
    # the refit, none of them a demonstration; the success is the greedy episodes'
    explored, greedy = runs[1.0].models.report["dynamics"], runs[0.0].models.report["dynamics"]
    assert sum(explored[o]["transitions"] for o in ("right", "left")) > \
        sum(greedy[o]["transitions"] for o in ("right", "left"))
    curve, plain = runs[1.0].summary["improvement"], runs[0.0].summary["improvement"]
    assert curve[0]["explored_episodes"] == 3 and "explored_episodes" not in plain[0]
    assert curve[0]["success_rate"] == plain[0]["success_rate"]
    assert curve[0]["demonstrations_added"] == plain[0]["demonstrations_added"]
    assert runs[1.0].summary["seeds"] == runs[0.0].summary["seeds"]
    # the runner explores on a copy: the controller it was given keeps its own chooser
    options = runs[0.0].options
    controller = Controller(options, RandomChoice(options))
    chooser = controller.chooser
    runner = OwnEpisodeRunner(ControllerRunner(line_env(), controller), explore=0.5)
    assert controller.chooser is chooser
    assert isinstance(runner.runner.controller.chooser, Exploring)


def test_a_round_explores_after_measuring_its_models_on_seeds_of_its_own():
    settings = ImprovementSettings(rounds=2, episodes=2, keep="best", explore=0.3)
    assert settings.seeds == (3 + 2) * 2  # three measured batches, two exploring ones
    seeds = list(range(settings.seeds))
    played: list[tuple[int, list[int], float]] = []

    def play(models, batch, explore):
        played.append((models, list(batch), explore))
        return _fake_own([1, 0])

    improvement_rounds(0, settings, seeds, play, lambda r, own: r + 1, lambda _: None)
    assert played == [(0, [0, 1], 0.0), (0, [6, 7], 0.3), (1, [2, 3], 0.0), (1, [8, 9], 0.3),
                      (2, [4, 5], 0.0)]


def test_the_demonstrator_is_asked_where_a_round_failed_and_its_episodes_are_demonstrations():
    settings = ImprovementSettings(rounds=2, episodes=3, keep="last", explore=0.0, demos=1)
    seeds = list(range(settings.seeds))
    asked: list[list[int]] = []
    refits: list[list[OwnEpisode]] = []
    shown = Episode(np.zeros((3, 1)), np.zeros((2, 1)), np.zeros(2), np.zeros(2, bool),
                    np.zeros(2, bool), {PROGRESS_KEY: np.array([0.5, 1.0])}, 7)

    def demonstrate(starts):
        asked.append(list(starts))
        return [shown]

    def refit(r, own):
        refits.append(own)
        return r + 1

    _, curve = improvement_rounds(0, settings, seeds, lambda m, b, e: _fake_own([1, 0, 0]),
                                  refit, lambda _: None, demonstrate)
    # the first failed start of each round's batch, one each (demos=1)
    assert asked == [[1], [4]]
    assert [own[-1].demonstration for own in refits] == [shown, shown]
    assert [c["demonstrator_episodes"] for c in curve] == [1, 1]
    # recorded demonstrations alone: no demonstrator to ask, and none is asked
    _, curve = improvement_rounds(0, settings, seeds, lambda m, b, e: _fake_own([0, 0, 0]),
                                  refit, lambda _: None)
    assert all("demonstrator_episodes" not in c for c in curve)
    with pytest.raises(DynoplanError, match="improve_demos must be >= 0"):
        replace(settings, demos=-1).validate()


def test_demonstrations_at_the_given_starts_keep_the_successes_with_their_seeds():
    from dynoplan.adapters import as_spec
    from dynoplan.pipeline.collect import demonstrations_at

    starts = episode_seeds(5, 3)
    specs = [as_spec(o) for o in line_options()]
    shown = demonstrations_at(line_env(), specs, lambda obs: "right", starts)
    assert [e.seed for e in shown] == [s.env_seed for s in starts]
    assert all(e.infos[PROGRESS_KEY][-1] == 1.0 for e in shown)
    # a demonstrator that never reaches the goal shows nothing
    assert demonstrations_at(line_env(), specs, lambda obs: "left", starts) == []


class _Counting(gym.Wrapper):
    """The line, counting the episodes run on it (the 'disturbed' one of the test)."""

    def __init__(self, env):
        super().__init__(env)
        self.resets = 0

    def reset(self, **kwargs):
        self.resets += 1
        return self.env.reset(**kwargs)


def test_a_share_of_the_rounds_own_episodes_rehearse_under_the_tasks_disturbance():
    settings = ImprovementSettings(disturbed=0.5)
    assert [settings.rehearses(s) for s in episode_seeds(0, 6)] == [False, True] * 3
    assert not any(ImprovementSettings().rehearses(s) for s in episode_seeds(0, 6))
    disturbed = _Counting(line_env())
    run = replace(SMALL, improve_episodes=4, improve_explore=0.5, improve_disturbed=0.5)
    res = run_pipeline(line_env(), line_options(), demonstrator=lambda obs: "right",
                       settings=run, disturbed_env=disturbed)
    curve = res.summary["improvement"]
    # half of the round's 4 measured and 4 exploring episodes, half of the check's 4
    assert [c["disturbed_episodes"] for c in curve] == [4, 2]
    assert disturbed.resets >= 6  # those episodes ran there (and the demonstrator, asked)
    # off (the default), the rounds never touch it
    untouched = _Counting(line_env())
    plain = run_pipeline(line_env(), line_options(), demonstrator=lambda obs: "right",
                         settings=replace(run, improve_disturbed=0.0), disturbed_env=untouched)
    assert untouched.resets == 0
    assert all("disturbed_episodes" not in c for c in plain.summary["improvement"])
    with pytest.raises(DynoplanError, match="give the disturbed environment"):
        run_pipeline(line_env(), line_options(), demonstrator=lambda obs: "right",
                     settings=run)
    with pytest.raises(DynoplanError, match=r"improve_disturbed must be in \[0, 1\]"):
        replace(settings, disturbed=1.5).validate()
