"""OptionPlanner (Eq. 1): argmax, admissibility, termination, batching, NaN handling."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.stats import ks_2samp

from dynoplan.envs.random_walk import NoisyWalkDynamics, NoisyWalkGoal, make_random_walk_options
from dynoplan.models.dynamics import LoopStackedDynamics, stack_dynamics
from dynoplan.options import (
    ConstantTermination,
    FunctionPolicy,
    InitiationFromCallable,
    Option,
)
from dynoplan.planning import OptionPlanner, SequencePlanner


class Drift:
    """Deterministic s -> s + speed (a known answer), optionally NaN after a point."""

    def __init__(self, speed: float, nan_above: float = np.inf) -> None:
        self.speed = speed
        self.nan_above = nan_above

    @property
    def state_dim(self) -> int:
        return 1

    def sample(self, states, rng):
        nxt = states + self.speed
        return np.where(nxt > self.nan_above, np.nan, nxt)


class Linear:
    """G(s) = s / 100, exact."""

    def sample(self, states, rng):
        return np.clip(states[:, 0] / 100.0, 0, 1)

    def mean_std(self, states):
        return self.sample(states, None), np.zeros(len(states))


def _option(name, dynamics, beta=0.0, initiation=None):
    kwargs = {} if initiation is None else {"initiation": initiation}
    return Option(name, FunctionPolicy(lambda o, r: 0), dynamics, ConstantTermination(beta),
                  **kwargs)


def test_argmax_picks_the_option_whose_future_scores_best():
    options = [_option("slow", Drift(1.0)), _option("fast", Drift(3.0)),
               _option("back", Drift(-1.0))]
    plan = OptionPlanner(options, Linear(), horizon=5, samples=8).plan(
        np.array([10.0]), np.random.default_rng(0))
    assert plan.chosen_name == "fast"
    np.testing.assert_allclose(plan.scores, [0.15, 0.25, 0.05])
    np.testing.assert_allclose(plan.end_states[1, :, 0], 25.0)
    assert (plan.steps == 5).all()


class FailsAbove:
    """P(fail | s): certain above ``limit``, never below."""

    def __init__(self, limit: float) -> None:
        self.limit = limit

    def probability(self, states):
        return (states[:, 0] > self.limit).astype(float)


def test_an_option_whose_runs_fail_from_here_is_scored_as_no_progress():
    # the fast option's imagined end scores best, but a run of it fails from above 5
    fast = _option("fast", Drift(3.0))
    options = [_option("slow", Drift(1.0)), replace(fast, failure=FailsAbove(5.0))]
    planner = OptionPlanner(options, Linear(), horizon=5, samples=8)
    plan = planner.plan(np.array([10.0]), np.random.default_rng(0))
    assert plan.chosen_name == "slow"
    np.testing.assert_allclose(plan.scores, [0.15, 0.0])
    assert planner.plan(np.array([2.0]), np.random.default_rng(0)).chosen_name == "fast"
    # depth 2: a sequence through a failing option is worth nothing either
    deep = SequencePlanner(options, Linear(), horizon=5, samples=8, depth=2)
    plan = deep.plan(np.array([10.0]), np.random.default_rng(0))
    assert plan.chosen_name == "slow" and plan.sequences[0] == ("slow", "slow")


def test_termination_stops_rollouts_and_inadmissible_options_are_skipped():
    never = InitiationFromCallable(lambda s: np.zeros(len(s), bool))
    options = [_option("one-step", Drift(1.0), beta=1.0),
               _option("blocked", Drift(50.0), initiation=never)]
    plan = OptionPlanner(options, Linear(), horizon=10, samples=4).plan(
        np.array([0.0]), np.random.default_rng(0))
    assert (plan.steps[0] == 1).all()
    assert list(plan.admissible) == [True, False]
    assert plan.chosen_name == "one-step"
    assert np.isnan(plan.scores[1])


def test_no_admissible_option_gives_no_choice():
    never = InitiationFromCallable(lambda s: np.zeros(len(s), bool))
    plan = OptionPlanner([_option("x", Drift(1.0), initiation=never)], Linear()).plan(
        np.array([0.0]), np.random.default_rng(0))
    assert plan.chosen is None and plan.chosen_name is None


def test_a_rollout_that_leaves_the_region_stops_there():
    below_5 = InitiationFromCallable(lambda s: s[:, 0] < 5)
    options = [_option("bounded", Drift(1.0), initiation=below_5)]
    plan = OptionPlanner(options, Linear(), horizon=20, samples=3).plan(
        np.array([0.0]), np.random.default_rng(0))
    np.testing.assert_allclose(plan.end_states[0, :, 0], 5.0)


def test_with_end_inside_a_model_carried_past_its_region_cannot_win_there():
    # "over" has data below 20 (its region) but its model carries on to 40, where the goal
    # would rate it best; "steady" stays in its own region and truly gets to 25
    over = _option("over", Drift(30.0), initiation=InitiationFromCallable(lambda s: s[:, 0] < 20))
    steady = _option("steady", Drift(3.0))
    rng = np.random.default_rng(0)
    naive = OptionPlanner([over, steady], Linear(), horizon=5, samples=4).plan(
        np.array([10.0]), rng)
    assert naive.chosen_name == "over"  # scored at 40, a state it had no data for
    inside = OptionPlanner([over, steady], Linear(), horizon=5, samples=4, end_inside=True)
    plan = inside.plan(np.array([10.0]), rng)
    assert plan.chosen_name == "steady"
    np.testing.assert_allclose(plan.end_states[0, :, 0], 10.0)  # its last state inside
    assert (plan.steps[0] == 0).all() and (plan.steps[1] == 5).all()


def test_a_model_that_diverges_to_nan_is_not_chosen():
    options = [_option("explodes", Drift(10.0, nan_above=15.0)), _option("steady", Drift(1.0))]
    plan = OptionPlanner(options, Linear(), horizon=5, samples=4).plan(
        np.array([0.0]), np.random.default_rng(0))
    assert np.isfinite(plan.end_states).all()
    assert plan.chosen_name == "steady"


def test_stacked_rollouts_equal_the_per_option_loop_in_distribution():
    models = [NoisyWalkDynamics(p, 0.2) for p in (1.0, 0.5, 0.0)]
    stacked = stack_dynamics(models)
    assert not isinstance(stacked, LoopStackedDynamics)
    loop = LoopStackedDynamics(models)
    x = np.full((3, 4000, 1), 7.0)
    a = stacked.sample(x, np.random.default_rng(0))
    b = loop.sample(x, np.random.default_rng(1))
    for o in range(3):
        assert ks_2samp(a[o, :, 0], b[o, :, 0]).pvalue > 1e-3


def test_the_planner_is_deterministic_given_the_generator():
    options = make_random_walk_options(0.2)
    planner = OptionPlanner(options, NoisyWalkGoal(0.2), samples=32)
    p1 = planner.plan(np.array([3.0]), np.random.default_rng(7))
    p2 = planner.plan(np.array([3.0]), np.random.default_rng(7))
    np.testing.assert_array_equal(p1.scores, p2.scores)
    np.testing.assert_array_equal(p1.end_states, p2.end_states)


def test_duplicate_option_names_are_rejected():
    from dynoplan.errors import DynoplanError

    with pytest.raises(DynoplanError, match="unique"):
        OptionPlanner([_option("a", Drift(1)), _option("a", Drift(2))], Linear())


class Shift:
    """Moves the robot (state[:3]) by a fixed step; the hand (state[3:]) stays put."""

    def __init__(self, step) -> None:
        self.step = np.concatenate([np.asarray(step, dtype=float), np.zeros(3)])

    @property
    def state_dim(self) -> int:
        return 6

    def sample(self, states, rng):
        return states + self.step


class RobotX:
    """G(s) = robot x / 10: going toward +x is progress."""

    def sample(self, states, rng):
        return states[:, 0] / 10.0

    def mean_std(self, states):
        return self.sample(states, None), np.zeros(len(states))


def _safe_planner(hand_velocity, steps=(0.5, -0.1), names=("toward", "away")):
    """Options moving the robot by ``steps`` along x per 1 s step; the hand predicted at
    constant velocity with a fixed 2 cm spread; checked over the whole horizon."""
    from dynoplan.safety.constraint import ConstantVelocityHuman, SeparationConstraint

    human = ConstantVelocityHuman(position=lambda s: s[3:6],
                                  velocity=lambda: np.asarray(hand_velocity, dtype=float),
                                  spread=(0.02, 0.0))
    constraint = SeparationConstraint(lambda s: s[:, None, :3], human, step_seconds=1.0,
                                      lookahead=10.0)
    options = [_option(n, Shift([dx, 0, 0])) for n, dx in zip(names, steps, strict=True)]
    return OptionPlanner(options, RobotX(), horizon=4, samples=8, constraint=constraint,
                         risk_level=0.05)


def test_the_safety_constraint_rejects_an_option_whose_rollouts_cross_the_predicted_hand():
    state = np.array([0.0, 0, 0, 2.0, 0, 0])  # the hand 2 m ahead of the robot, still
    unconstrained = OptionPlanner(_safe_planner([0, 0, 0]).options, RobotX(), horizon=4,
                                  samples=8).plan(state, np.random.default_rng(0))
    assert unconstrained.chosen_name == "toward"  # Eq. 1 alone runs into the hand
    plan = _safe_planner([0, 0, 0]).plan(state, np.random.default_rng(0))
    assert plan.unsafe_shares.tolist() == [1.0, 0.0]
    assert plan.scores[0] == -np.inf and plan.chosen_name == "away"
    # the hand predicted to leave at 10 m/s: going toward where it was is safe again
    plan = _safe_planner([0, 10.0, 0]).plan(state, np.random.default_rng(0))
    assert plan.unsafe_shares.tolist() == [0.0, 0.0] and plan.chosen_name == "toward"


def test_the_separation_constraint_reuses_the_robot_points_it_has_seen():
    """A rollout's next ``before`` is its last ``after`` but for the rows put back (a
    continuation set's ``end_inside``): only those rows' points are computed again, and
    the answers are those of computing every point from scratch."""
    from dynoplan.safety.constraint import ConstantVelocityHuman, SeparationConstraint
    from dynoplan.safety.separation import AT_REST_SPEED, protective_separation

    rows_asked = []

    def points(s):
        rows_asked.append(len(s))
        return np.stack([s[:, :3], s[:, :3] + 0.1], axis=1)  # two points on the robot

    human = ConstantVelocityHuman(position=lambda s: s[3:6],
                                  velocity=lambda: np.array([0.0, -0.2, 0.0]))
    constraint = SeparationConstraint(points, human, step_seconds=0.5, lookahead=10.0)
    rng = np.random.default_rng(0)
    state = np.array([0.0, 0, 0, 0.4, 0.1, 0])
    constraint.prepare(state)
    before = np.broadcast_to(state, (2, 8, 6)).copy()
    for step in (1, 2, 3):
        after = before.copy()
        after[..., :3] += rng.normal(0.0, 0.05, size=(2, 8, 3))
        unsafe = constraint.unsafe(before, after, step)
        p0, p1 = points(before.reshape(-1, 6)), points(after.reshape(-1, 6))
        rows_asked.pop()
        rows_asked.pop()
        speed = np.linalg.norm(p1 - p0, axis=-1).max(axis=-1) / 0.5
        hand, spread = human.predict(0.5 * step)
        gap = np.linalg.norm(p1 - hand, axis=-1).min(axis=-1)
        s_p = protective_separation(speed, human.speed) + spread
        expected = (speed >= AT_REST_SPEED) & (gap < s_p)
        np.testing.assert_array_equal(unsafe, expected.reshape(2, 8))
        before = after.copy()
        before[1, 3] = state  # one rollout put back where it started
    assert 0 < unsafe.sum() < unsafe.size  # the check is not vacuous
    # prepare: 1 row; each step one call: the 16 ``after`` rows, and from the second
    # step on the one ``before`` row that was put back
    assert rows_asked == [1, 16, 17, 17]


def test_with_every_option_unsafe_the_planner_chooses_none_so_the_controller_holds():
    # S_p(0.5 m/s) + spread = 0.2 m, S_p(0.1 m/s) + spread = 0.12 m; the hand at 0.45 m:
    # the fast option is 5 cm from it after one step, the slow one after four
    state = np.array([0.0, 0, 0, 0.45, 0, 0])
    plan = _safe_planner([0, 0, 0], steps=(0.5, 0.1), names=("fast", "slow")).plan(
        state, np.random.default_rng(0))
    assert plan.unsafe_shares.tolist() == [1.0, 1.0] and plan.chosen is None
