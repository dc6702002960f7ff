"""SequencePlanner: depth 1 is Eq. 1, a level is the loop over its branches, the trap's
known answer, and many episodes in lockstep."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from scipy.stats import ks_2samp

from dynoplan.control.batched import run_batched
from dynoplan.control.controller import Controller
from dynoplan.envs import RANDOM_WALK_ID, TRAP_WALK_ID
from dynoplan.envs.random_walk import NoisyWalkGoal, make_random_walk_options
from dynoplan.envs.trap import CorridorProgress, TrapWalkEnv, make_trap_options
from dynoplan.errors import DynoplanError
from dynoplan.options import Option
from dynoplan.options.initiation import InitiationFromCallable
from dynoplan.options.option import admissible, admissible_batch
from dynoplan.pipeline.evaluate import planning_steps_summary
from dynoplan.planning import OptionPlanner, SequencePlanner
from dynoplan.seeding import episode_seeds


def _walk(depth, samples=64, **kwargs):
    options = make_random_walk_options(0.2)
    return SequencePlanner(options, NoisyWalkGoal(0.2), horizon=20, samples=samples,
                           depth=depth, **kwargs)


@pytest.mark.parametrize("state", [0.0, 7.0, 18.0])
def test_depth_one_makes_the_option_planners_decision_from_the_same_generator(state):
    options = make_random_walk_options(0.2)
    one = OptionPlanner(options, NoisyWalkGoal(0.2), samples=64)
    seq = SequencePlanner(options, NoisyWalkGoal(0.2), samples=64, depth=1)
    a = one.plan(np.array([state]), np.random.default_rng(5))
    b = seq.plan(np.array([state]), np.random.default_rng(5))
    np.testing.assert_array_equal(a.scores, b.scores)
    np.testing.assert_array_equal(a.end_states, b.end_states)
    assert a.chosen == b.chosen
    assert b.sequences == tuple((name,) for name in a.option_names)


def test_depth_one_equals_the_option_planner_in_distribution():
    options = make_random_walk_options(0.2)
    one = OptionPlanner(options, NoisyWalkGoal(0.2), samples=32)
    seq = SequencePlanner(options, NoisyWalkGoal(0.2), samples=32, depth=1)
    rng_a, rng_b = np.random.default_rng(0), np.random.default_rng(1)
    a = np.array([one.plan(np.array([4.0]), rng_a).scores for _ in range(300)])
    b = np.array([seq.plan(np.array([4.0]), rng_b).scores for _ in range(300)])
    for o in range(len(options)):
        assert ks_2samp(a[:, o], b[:, o]).pvalue > 1e-3
    assert not np.array_equal(a, b)  # different generators: a test that can fail


def _loop_depth_two(planner, state, rng):
    """Depth 2 by a Python loop over branches: every (first, second) pair rolled alone."""
    n = len(planner.options)
    scores = np.full(n, -np.inf)
    for first in range(n):
        end = planner.rollout((first,), state, rng).end_states  # (1, samples, 1)
        for second in range(n):
            leaf = planner.rollout((second,), end, rng).end_states[0]
            scores[first] = max(scores[first], planner.goal.sample(leaf, rng).mean())
    return scores


def test_a_batched_level_equals_the_loop_over_its_branches_in_distribution():
    planner = _walk(depth=2, samples=32)
    state = np.array([10.0])
    rng_a, rng_b = np.random.default_rng(0), np.random.default_rng(1)
    batched = np.array([planner.plan(state, rng_a).scores for _ in range(200)])
    loop = np.array([_loop_depth_two(planner, state, rng_b) for _ in range(200)])
    for o in range(len(planner.options)):
        assert ks_2samp(batched[:, o], loop[:, o]).pvalue > 1e-3, o


def test_plans_for_many_states_equal_plans_one_at_a_time_in_distribution():
    planner = _walk(depth=2, samples=32)
    states = np.array([[0.0], [9.0], [19.0]])
    rng_a, rng_b = np.random.default_rng(0), np.random.default_rng(1)
    many = np.array([[p.scores for p in planner.plan_many(states, rng_a)]
                     for _ in range(150)])
    alone = np.array([[planner.plan(s, rng_b).scores for s in states] for _ in range(150)])
    for r in range(len(states)):
        for o in range(len(planner.options)):
            assert ks_2samp(many[:, r, o], alone[:, r, o]).pvalue > 1e-3


def test_at_the_wall_depth_one_pushes_on_and_depth_two_backs_away_to_go_around():
    wall = np.array([8.0, 0.0])  # the main lane's dead end
    options, goal = make_trap_options(), CorridorProgress()
    one = SequencePlanner(options, goal, samples=64, depth=1).plan(
        wall, np.random.default_rng(0))
    two = SequencePlanner(options, goal, samples=64, depth=2).plan(
        wall, np.random.default_rng(0))
    assert one.chosen_name == "forward"
    assert one.scores[0] == pytest.approx(0.4)  # forward cannot pass the wall
    assert two.chosen_name == "detour"
    assert two.sequences is not None and two.sequences[2] == ("detour", "forward")
    assert two.scores[2] > 0.5 > two.scores[0]


def _trap_run(depth, episodes, seed=0):
    options = make_trap_options()
    planner = SequencePlanner(options, CorridorProgress(), horizon=20, samples=32, depth=depth)
    seeds = episode_seeds(seed, episodes)
    envs = [gym.make(TRAP_WALK_ID) for _ in seeds]
    return run_batched(envs, options, planner, seeds, np.random.default_rng(seed),
                       max_decisions=30)


def test_the_traps_known_answer_hill_climbing_stalls_and_depth_two_gets_around():
    two = planning_steps_summary(_trap_run(2, 40))
    one = _trap_run(1, 20)
    assert two["success_rate"] == 1.0
    assert not any(t.success for t in one)
    # depth 1 stalls at the wall: every episode ends on the main lane at position 8
    assert all(tuple(t.decisions[-1].state_after) == (8.0, 0.0) for t in one)


def test_beam_expands_only_the_best_branches():
    plan = _walk(depth=2, samples=64, beam=2).plan(np.array([5.0]), np.random.default_rng(0))
    assert int(np.isfinite(plan.scores).sum()) == 2
    assert plan.chosen is not None and np.isfinite(plan.scores[plan.chosen])
    assert sum(len(s) == 2 for s in plan.sequences or ()) == 2


def test_bad_depth_and_beam_are_rejected():
    with pytest.raises(DynoplanError, match="depth"):
        _walk(depth=0)
    with pytest.raises(DynoplanError, match="beam"):
        _walk(depth=2, beam=0)


def test_admissible_batch_judges_every_state_as_admissible_judges_it_alone():
    low = InitiationFromCallable(lambda s: s[:, 0] < 5)
    options = [Option(o.name, o.policy, o.dynamics, o.termination, initiation=low,
                      fallback=InitiationFromCallable(lambda s: s[:, 0] < 15) if k == 1 else None)
               for k, o in enumerate(make_random_walk_options(0.2))]
    options[3].ended_without_effect(np.array([2.0]), 0.5)
    states = np.arange(20.0)[:, None]
    running = np.array([k % 6 - 1 for k in range(20)])
    batch = admissible_batch(options, states, running)
    alone = np.stack([admissible(options, s, None if r < 0 else int(r))
                      for s, r in zip(states, running, strict=True)], axis=1)
    np.testing.assert_array_equal(batch, alone)
    assert batch[:, 12].any() and not batch[:, 17].any()  # the fallback, then nothing


def test_episodes_in_lockstep_reach_the_goal_as_often_and_as_fast_as_one_at_a_time():
    options = make_random_walk_options(0.2)
    planner = SequencePlanner(options, NoisyWalkGoal(0.2), samples=64, depth=1)
    seeds = episode_seeds(0, 200)
    envs = [gym.make(RANDOM_WALK_ID) for _ in seeds]
    batched = run_batched(envs, options, planner, seeds, np.random.default_rng(0))
    alone = OptionPlanner(options, NoisyWalkGoal(0.2), samples=64)
    controller = Controller(options, alone, max_decisions=50)
    env = gym.make(RANDOM_WALK_ID)
    sequential = [controller.run(env, s.rng(), seed=s.env_seed) for s in episode_seeds(1, 200)]
    assert all(t.success for t in batched) and all(t.success for t in sequential)
    steps_b = [t.planning_steps for t in batched]
    steps_s = [t.planning_steps for t in sequential]
    assert ks_2samp(steps_b, steps_s).pvalue > 1e-3
    assert abs(np.median(steps_b) - np.median(steps_s)) <= 1


def test_the_trap_walk_follows_the_gymnasium_api_and_its_rules():
    check_env(TrapWalkEnv(), skip_render_check=True)
    env = TrapWalkEnv(slip=0.0)
    env.reset(seed=0)
    for _ in range(12):
        obs, *_ = env.step(1)
    assert tuple(obs) == (8, 0)  # the wall
    obs, *_ = env.step(2)
    assert tuple(obs) == (8, 0)  # no switch past the gate
    for _ in range(4):
        env.step(0)
    obs, *_ = env.step(2)
    assert tuple(obs) == (4, 1)
    for _ in range(16):
        obs, reward, terminated, _, info = env.step(1)
    assert terminated and reward == 1.0 and info["is_success"]


@pytest.mark.parametrize("walk", ["random", "trap"])
def test_rollouts_of_the_running_rows_only_equal_the_full_arrays_in_distribution(walk):
    if walk == "random":
        options, goal, state = make_random_walk_options(0.2), NoisyWalkGoal(0.2), [3.0]
    else:
        options, goal, state = make_trap_options(), CorridorProgress(), [6.0, 0.0]
    full = SequencePlanner(options, goal, samples=2000, depth=1)
    rows = SequencePlanner(options, goal, samples=2000, depth=1, compact=True)
    idx = tuple(range(len(options)))
    a = full.rollout(idx, np.array(state), np.random.default_rng(0))
    b = rows.rollout(idx, np.array(state), np.random.default_rng(1))
    for o in idx:
        assert ks_2samp(a.end_states[o, :, 0], b.end_states[o, :, 0]).pvalue > 1e-3
        assert ks_2samp(a.steps[o], b.steps[o]).pvalue > 1e-3
    assert not np.array_equal(a.steps, b.steps)


@pytest.mark.parametrize("end_inside", [False, True])
def test_rollouts_of_the_running_rows_stop_at_a_region_as_the_full_arrays_do(end_inside):
    """Deterministic models (no misprediction, no termination): the rows and the full
    arrays must end every rollout at the same state after the same steps, where an
    option leaves its continuation set (``end_inside``: at its last state inside)."""
    from dynoplan.envs.random_walk import NoisyWalkDynamics
    from dynoplan.options.termination import ConstantTermination

    below_six = InitiationFromCallable(lambda s: s[..., 0] <= 5)
    right, left, stay = (Option(name, None, NoisyWalkDynamics(p, 0.0),  # type: ignore[arg-type]
                                ConstantTermination(0.0), initiation=region)
                         for name, p, region in [("right", 1.0, below_six),
                                                 ("left", 0.0, below_six),
                                                 ("wide", 1.0, InitiationFromCallable(
                                                     lambda s: s[..., 0] <= 8))])
    options = [right, left, stay]
    plans = [SequencePlanner(options, NoisyWalkGoal(0.0), horizon=8, samples=3, depth=1,
                             end_inside=end_inside, compact=compact)
             for compact in (False, True)]
    idx = (0, 1, 2, 0)
    full, rows = (p.rollout(idx, np.array([2.0]), np.random.default_rng(0)) for p in plans)
    np.testing.assert_array_equal(rows.end_states, full.end_states)
    np.testing.assert_array_equal(rows.steps, full.steps)
    assert rows.end_states[0, 0, 0] == (5.0 if end_inside else 6.0)
    assert rows.end_states[1, 0, 0] == 0.0 and rows.steps[1, 0] == 8
    assert rows.end_states[2, 0, 0] == (8.0 if end_inside else 9.0)


def test_member_disagreements_equal_the_loop_over_options():
    from dynoplan.planning.option_planner import member_disagreement
    from dynoplan.planning.sequence_planner import member_disagreements

    rng = np.random.default_rng(0)
    g = rng.random((6, 40))
    members = rng.integers(0, 4, size=(6, 40))
    members[2] = 1  # one member only: no disagreement
    np.testing.assert_allclose(member_disagreements(g, members),
                               member_disagreement(g, members), atol=1e-12)
    assert member_disagreements(g, members)[2] == 0.0
    assert (member_disagreements(g, None) == 0).all()


class _Drift:
    """Deterministic s -> s + speed (a known answer)."""

    def __init__(self, speed):
        self.speed = speed

    @property
    def state_dim(self):
        return 1

    def sample(self, states, rng):
        return states + self.speed


class _Linear:
    """G(s) = s / 100, exact."""

    def sample(self, states, rng):
        return states[:, 0] / 100.0

    def mean_std(self, states):
        return states[:, 0] / 100.0, np.zeros(len(states))


class _Beyond:
    """A step that ends beyond ``limit`` is unsafe."""

    def __init__(self, limit):
        self.limit = limit

    def prepare(self, state):
        pass

    def unsafe(self, before, after, step):
        return after[..., 0] > self.limit


def _drift_options():
    from dynoplan.options import ConstantTermination, FunctionPolicy
    from dynoplan.options.initiation import Everywhere

    low = InitiationFromCallable(lambda s: s[:, 0] < 3.0)  # may start low, then runs on
    return [Option("slow", FunctionPolicy(lambda o, r: 0), _Drift(1.0), ConstantTermination(0.0)),
            Option("fast", FunctionPolicy(lambda o, r: 0), _Drift(3.0), ConstantTermination(0.0)),
            Option("only_low", FunctionPolicy(lambda o, r: 0), _Drift(10.0),
                   ConstantTermination(0.0), initiation=low, continuation=Everywhere())]


def test_an_unsafe_step_anywhere_along_a_sequence_rules_the_sequence_out():
    options = _drift_options()
    free = SequencePlanner(options, _Linear(), horizon=5, samples=4, depth=2).plan(
        np.array([0.0]), np.random.default_rng(0))
    # only_low runs first (0 -> 50), then fast (-> 65); after slow or fast it may not start
    assert free.chosen_name == "only_low"
    assert free.sequences == (("slow", "fast"), ("fast", "fast"), ("only_low", "fast"))
    np.testing.assert_allclose(free.scores, [0.20, 0.30, 0.65])
    safe = SequencePlanner(options, _Linear(), horizon=5, samples=4, depth=2,
                           constraint=_Beyond(12.0)).plan(np.array([0.0]),
                                                          np.random.default_rng(0))
    # slow then slow reaches 10 safely; every sequence through a step beyond 12 is out
    assert safe.chosen_name == "slow"
    assert safe.sequences is not None and safe.sequences[0] == ("slow", "slow")
    np.testing.assert_allclose(safe.scores, [0.10, -np.inf, -np.inf])
    np.testing.assert_allclose(safe.unsafe_shares, [0.0, 1.0, 1.0])


def test_a_second_option_that_may_not_start_leaves_the_sequence_where_it_is():
    options = _drift_options()
    planner = SequencePlanner(options, _Linear(), horizon=5, samples=4, depth=2)
    plan = planner.plan(np.array([0.0]), np.random.default_rng(0))
    assert plan.chosen_name == "only_low"
    # 'slow' then 'only_low' cannot start at 5: it scores 5 / 100, below slow-then-fast
    level = planner.rollout((2,), np.full((1, 4, 1), 5.0), np.random.default_rng(0),
                            start_alive=np.zeros((1, 4), dtype=bool))
    assert (level.end_states == 5.0).all() and (level.steps == 0).all()
