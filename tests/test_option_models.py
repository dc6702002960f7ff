"""Option models (Sutton, Precup and Singh 1999): dynamics that predict where an option
ends, so that an option needing longer than any fixed horizon to show its worth is chosen."""

import numpy as np

from dynoplan.data.episodes import Episode
from dynoplan.options import ConstantTermination, FunctionPolicy, Option, TerminationFromCallable
from dynoplan.pipeline.control_settings import ControllerSettings
from dynoplan.pipeline.evaluate import planning_settings
from dynoplan.pipeline.fit import FittedModels
from dynoplan.pipeline.fit_data import option_end_pairs
from dynoplan.planning import OptionPlanner

WIND = 30
"""Steps the wind-up option backs away before it releases."""


class WindUpStep:
    """One step of a wind-up on ``[x, w]``: back away (x - 0.5, w + 1) for ``WIND`` steps,
    then release (x + 100, w = -1: released)."""

    state_dim = 2

    def sample(self, states, rng):
        x, w = states[..., 0], states[..., 1]
        release = w >= WIND
        return np.stack([np.where(release, x + 100.0, x - 0.5),
                         np.where(release, -1.0, w + 1.0)], axis=-1)


class WindUpEnd:
    """Where the wind-up ends: released, ``100 - 0.5 (WIND - w)`` further on."""

    state_dim = 2

    def sample(self, states, rng):
        x, w = states[..., 0], states[..., 1]
        return np.stack([x + 100.0 - 0.5 * (WIND - w), np.full_like(x, -1.0)], axis=-1)


class Creep:
    """One step of a creep (x + 0.5), or ``steps`` of them (its expected run)."""

    state_dim = 2

    def __init__(self, steps=1):
        self.steps = steps

    def sample(self, states, rng):
        return states + np.array([0.5 * self.steps, 0.0])


class Progress:
    """G = x / 200, clipped to [0, 1]."""

    def sample(self, states, rng):
        return np.clip(states[:, 0] / 200.0, 0.0, 1.0)

    def mean_std(self, states):
        return self.sample(states, None), np.zeros(len(states))


def _options(wind_up, creep):
    released = TerminationFromCallable(lambda s: (s[:, 1] < 0).astype(float))
    return [Option("wind_up", FunctionPolicy(lambda o, r: 0), wind_up, released),
            Option("creep", FunctionPolicy(lambda o, r: 0), creep, ConstantTermination(0.1))]


def test_an_option_that_needs_longer_than_the_horizon_is_chosen_by_its_end():
    start, rng = np.array([0.0, 0.0]), np.random.default_rng(0)
    settings = ControllerSettings(horizon=20)
    # step models over a 20-step horizon: the wind-up only backs away, the creep wins
    steps = OptionPlanner(_options(WindUpStep(), Creep()), Progress(),
                          horizon=settings.horizon, samples=16).plan(start, rng)
    assert steps.chosen_name == "creep" and steps.scores[0] < steps.scores[1]
    # option models: one model step to where each option ends; the wind-up wins
    models = FittedModels(["wind_up", "creep"], {}, Progress(),  # type: ignore[arg-type]
                          report={"settings": {"option_model": "end"}})
    ends = OptionPlanner(_options(WindUpEnd(), Creep(steps=10)), Progress(),
                         horizon=planning_settings(settings, models).horizon,
                         samples=16).plan(start, rng)
    assert planning_settings(settings, models).horizon == 1
    assert ends.chosen_name == "wind_up"
    np.testing.assert_allclose(ends.end_states[0, :, 0], 85.0)


def test_option_end_pairs_pair_every_state_of_a_run_with_where_it_ended():
    states = np.arange(7, dtype=np.float64)[:, None]  # 6 steps: runs 0 0 0 | 1 1 | 0
    episode = Episode(states, np.zeros((6, 1)), np.zeros(6), np.zeros(6, bool),
                      np.zeros(6, bool), {"option": np.array([0, 0, 0, 1, 1, 0])})
    pairs = option_end_pairs([episode], ["a", "b"], lambda o: o)
    np.testing.assert_array_equal(pairs["a"][0][:, 0], [0, 1, 2, 5])
    np.testing.assert_array_equal(pairs["a"][1][:, 0], [3, 3, 3, 6])
    np.testing.assert_array_equal(pairs["b"][0][:, 0], [3, 4])
    np.testing.assert_array_equal(pairs["b"][1][:, 0], [5, 5])


class Shift:
    """s -> s + by, exact."""

    state_dim = 2

    def __init__(self, by):
        self.by = np.array([by, 0.0])

    def sample(self, states, rng):
        return states + self.by


def test_a_fallback_option_is_started_only_where_it_gains_on_the_present_state():
    from dynoplan.options import InitiationFromCallable

    nowhere = InitiationFromCallable(lambda s: np.zeros(len(s), dtype=bool))
    everywhere = InitiationFromCallable(lambda s: np.ones(len(s), dtype=bool))

    def falling_back(by):
        return Option(f"shift{by:+.0f}", FunctionPolicy(lambda o, r: 0), Shift(by),
                      ConstantTermination(1.0), initiation=nowhere, fallback=everywhere)

    state, rng = np.array([100.0, 0.0]), np.random.default_rng(0)
    back = [falling_back(-50.0)]
    assert OptionPlanner(back, Progress(), horizon=1, samples=4).plan(
        state, rng).chosen_name == "shift-50"  # the paper's planner takes any way
    assert OptionPlanner(back, Progress(), horizon=1, samples=4,
                         fallback_must_gain=True).plan(state, rng).chosen is None
    on = [falling_back(-50.0), falling_back(20.0)]
    assert OptionPlanner(on, Progress(), horizon=1, samples=4,
                         fallback_must_gain=True).plan(state, rng).chosen_name == "shift+20"


def test_runs_the_explorer_cut_at_its_step_limit_give_the_option_models_no_end():
    """Two options that never stop on their own (termination 0), explored with a step
    limit of 3 on 10-step episodes: every run ends at the limit or the time limit, so no
    run is an option's end. With terminations that fire at once every run but each
    episode's last (the time limit) is one."""
    import gymnasium as gym
    from gymnasium import spaces

    from dynoplan.adapters import option_spec
    from dynoplan.pipeline.collect import collect_transitions
    from dynoplan.pipeline.fit_data import option_runs

    class Walk(gym.Env):
        observation_space = spaces.Box(-100, 100, (1,), np.float64)
        action_space = spaces.Box(-1, 1, (1,), np.float32)

        def reset(self, *, seed=None, options=None):
            super().reset(seed=seed)
            self.x = 0.0
            return np.array([self.x]), {}

        def step(self, action):
            self.x += float(action[0])
            return np.array([self.x]), 0.0, False, False, {}

    def options(beta):
        return [option_spec("go", lambda obs: np.array([1.0], np.float32), termination=beta),
                option_spec("stay", lambda obs: np.array([0.0], np.float32), termination=beta)]

    env = gym.wrappers.TimeLimit(Walk(), 10)
    names = ["go", "stay"]
    cut = collect_transitions(env, options(0.0), 4, seed=0, max_option_steps=3)
    for episode in cut:
        assert episode.infos["interrupted"][[2, 5, 8, 9]].all()
    assert sum(len(p[0]) for p in option_end_pairs(cut, names, lambda o: o).values()) == 0
    assert sum(len(r[0]) for r in option_runs(cut, names, lambda o: o).values()) == 0
    whole = collect_transitions(env, options(1.0), 4, seed=0, max_option_steps=3)
    last_runs = 0
    for episode in whole:
        assert np.flatnonzero(episode.infos["interrupted"]).tolist() == [9]
        labels = episode.infos["option"]
        last_runs += len(labels) - np.flatnonzero(labels != labels[-1]).max(initial=-1) - 1
    kept = sum(len(p[0]) for p in option_end_pairs(whole, names, lambda o: o).values())
    assert kept == 40 - last_runs > 0
