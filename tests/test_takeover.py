"""The demonstrator taking over DynoPlan's failed episodes (``improve_takeover``): where it
takes over, the replay of DynoPlan's own actions up to there, and the rounds asking it."""

from dataclasses import replace

import numpy as np
import pytest

from dynoplan.adapters import as_spec
from dynoplan.data.episodes import DETOUR_KEY, INTERRUPTED_KEY, OPTION_KEY, PROGRESS_KEY
from dynoplan.errors import DynoplanError
from dynoplan.pipeline import run_pipeline
from dynoplan.pipeline.improve import ImprovementSettings, OwnEpisode, improvement_rounds
from dynoplan.pipeline.takeover import Takeover, demonstrations_after, takeover_point
from dynoplan.seeding import episode_seeds
from test_improve import _trace
from test_pipeline import SMALL, line_env, line_options


class _Position:
    """A goal heuristic that rates a state by its first coordinate."""

    def mean_std(self, states):
        states = np.asarray(states, dtype=np.float64)
        return states[:, 0], np.zeros(len(states))


def test_the_demonstrator_takes_over_at_the_best_rated_decision_before_the_first_hold():
    trace = _trace([("left", 2), ("right", 2), ("left", 2), (None, 1), ("right", 1)],
                   success=False)
    for d, x in zip(trace.decisions, [0.0, 2.0, 2.0, 1.0, 9.0], strict=True):
        d.state[:] = x
    # 2.0 twice (the later one wins); the 9.0 after the hold is not a candidate
    assert takeover_point(trace, _Position()) == 2
    # a hold rated highest is where it takes over: nothing DynoPlan did after counts
    trace.decisions[3].state[:] = 5.0
    assert takeover_point(trace, _Position()) == 3


def _left_for(steps, seed):
    """The observations and actions of ``steps`` steps left on the line from ``seed``."""
    env = line_env()
    observations = [env.reset(seed=seed.env_seed)[0]]
    actions = []
    for _ in range(steps):
        actions.append(np.array([-1.0], np.float32))
        observations.append(env.step(actions[-1])[0])
    return np.asarray(observations), np.asarray(actions)


def test_a_takeover_replays_dynoplans_steps_then_the_demonstrator_reaches_the_goal():
    seed = episode_seeds(4, 1)[0]
    observations, actions = _left_for(3, seed)
    over = Takeover(3, actions, np.array([1, 1, 1]), np.array([False, False, True]),
                    observations[3])
    specs = [as_spec(o) for o in line_options()]
    shown, unreplayed = demonstrations_after(lambda s: line_env(), specs, lambda obs: "right",
                                             [seed], [over])
    assert unreplayed == 0 and len(shown) == 1
    demo = shown[0]
    np.testing.assert_array_equal(demo.observations[:4], observations)  # the same steps
    labels = demo.infos[OPTION_KEY].tolist()
    assert labels[:3] == [1, 1, 1] and set(labels[3:]) == {0}  # then the demonstrator's
    # DynoPlan's steps are no one's choice, and where it was cut is no option's end
    assert demo.infos[DETOUR_KEY].tolist() == [True] * 3 + [False] * (len(demo) - 3)
    assert demo.infos[INTERRUPTED_KEY].tolist() == [False, False, True] + \
        [False] * (len(demo) - 3)
    assert demo.infos[PROGRESS_KEY][-1] == 1.0 and demo.seed == seed.env_seed


def test_an_environment_that_does_not_replay_gives_no_demonstration():
    seed = episode_seeds(4, 1)[0]
    observations, actions = _left_for(3, seed)
    elsewhere = Takeover(3, actions, np.array([1, 1, 1]), np.zeros(3, bool),
                         observations[3] + 0.5)
    specs = [as_spec(o) for o in line_options()]
    assert demonstrations_after(lambda s: line_env(), specs, lambda obs: "right", [seed],
                                [elsewhere]) == ([], 1)


def test_the_rounds_hand_the_failed_episodes_to_the_task_to_take_over():
    settings = ImprovementSettings(rounds=1, episodes=3, keep="last", explore=0.0, demos=2,
                                   takeover=True)
    over = Takeover(0, np.zeros((0, 1)), np.zeros(0, np.int64), np.zeros(0, bool),
                    np.zeros(1))
    own = [OwnEpisode(s, (), None, None if s else over) for s in (True, False, False)]
    handed = []

    def take_over(seeds, episodes):
        handed.append((list(seeds), list(episodes)))
        return [], 1

    _, curve = improvement_rounds(0, settings, list(range(settings.seeds)),
                                  lambda m, b, e: own, lambda r, o: r + 1, lambda _: None,
                                  lambda seeds: pytest.fail("asked from the start"),
                                  take_over)
    assert handed == [([1, 2], own[1:])]
    assert curve[0]["demonstrator_episodes"] == 2 and curve[0]["not_replayed"] == 1
    # a task that cannot take over says so, rather than asking from the start
    with pytest.raises(DynoplanError, match="improve_takeover"):
        improvement_rounds(0, settings, list(range(settings.seeds)),
                           lambda m, b, e: own, lambda r, o: r + 1, lambda _: None,
                           lambda seeds: [])


def test_a_pipeline_run_takes_over_the_episodes_its_round_failed(monkeypatch):
    import dynoplan.pipeline.generic_stages as stages

    steps = []

    def spy(env_of, specs, demonstrator, seeds, takeovers, max_steps=None):
        steps.extend(t.step for t in takeovers)
        return demonstrations_after(env_of, specs, demonstrator, seeds, takeovers, max_steps)

    monkeypatch.setattr(stages, "demonstrations_after", spy)
    # two decisions of two steps: every own episode fails short of the goal
    run = replace(SMALL, improve_episodes=6, improve_takeover=True, improve_demos=6,
                  control=replace(SMALL.control, max_decisions=2, replan_every=2))
    res = run_pipeline(line_env(), line_options(), demonstrator=lambda obs: "right",
                       settings=run)
    first = res.summary["improvement"][0]
    assert first["success_rate"] == 0.0 and first["demonstrator_episodes"] == 6
    # taken over after DynoPlan's first decision at least once, and each one replayed
    # and reached the goal
    assert len(steps) == 6 and max(steps) == 2
    assert first["demonstrations_added"] == 6 and "not_replayed" not in first
    assert res.summary["settings"]["improve_takeover"] is True
