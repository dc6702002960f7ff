"""Option runs (``pipeline/collect.py``): one option at a time from a start its task
chooses, until its policy is finished, cut into episodes at the decision rate; outcome
runs label every start."""

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

from dynoplan import DynoplanError
from dynoplan.data import Episode
from dynoplan.options.option import OptionPolicy
from dynoplan.pipeline.collect import (
    OUTCOME_KEY,
    OptionRuns,
    OptionRunsJob,
    Recording,
    RunStart,
    collect_option_runs,
    decision_episodes,
    run_outcomes,
)
from dynoplan.pipeline.fit_data import decision_runs, label_runs


class Line(gym.Env):
    """x on a line, where the task's starts put it; the action is added; ``info["cost"]``
    is 1 on a step that ends below 0."""

    observation_space = spaces.Box(-100, 100, (1,), np.float64)
    action_space = spaces.Box(-1, 1, (1,), np.float64)
    x = 0.0

    def step(self, action):
        self.x += float(action[0])
        return np.array([self.x]), 0.0, False, False, {"cost": int(self.x < 0)}


class Walk(OptionPolicy):
    """One unit per step in ``direction``, finished after ``length`` steps."""

    def __init__(self, direction: float, length: int = 5) -> None:
        self.direction, self.length, self.steps = direction, length, 0

    def reset(self, observation: Any, rng: np.random.Generator) -> None:
        self.steps = 0

    def act(self, observation: Any) -> Any:
        self.steps += 1
        return np.array([self.direction])

    def finished(self) -> bool:
        return self.steps >= self.length


@dataclass(frozen=True)
class LineRuns:
    """The line as an :class:`~dynoplan.pipeline.collect.OptionRunTask`: runs start at a
    random x in 0..9 (recorded as the run's seed), outcome runs end well when no step
    went below 0."""

    @property
    def option_names(self) -> tuple[str, ...]:
        return ("right", "left")

    @property
    def decision_steps(self) -> int:
        return 2

    @property
    def run_info_keys(self) -> tuple[str, ...]:
        return ("cost",)

    def make_env(self) -> gym.Env:
        return Line()

    def policy_makers(self, models: Path | None) -> dict[str, Any]:
        return {"right": lambda env: Walk(1.0), "left": lambda env: Walk(-1.0)}

    def before_run(self, seed: int) -> None:
        pass

    def run_start(self, runs: OptionRuns, option: str, rng: np.random.Generator) -> RunStart:
        start = int(rng.integers(10))
        runs.env.unwrapped.x = float(start)
        return RunStart(np.array([float(start)]), {}, start, {"start": start})

    def run_outcomes(self, policy: OptionPolicy, recording: Recording) -> np.ndarray:
        return run_outcomes(recording.episode.infos["cost"], True, False, self.decision_steps)


def test_a_run_is_one_option_from_its_start_cut_at_the_decision_rate():
    job = OptionRunsJob(LineRuns(), None, ("left",), seed=4, max_steps=100)
    runs = collect_option_runs(job, runs_per_option=3)
    assert len(runs) == 3
    for tags, episodes in runs:
        x0 = tags["start"]
        assert len(episodes) == 2  # two phase offsets of a 5-step run
        first, second = episodes
        np.testing.assert_array_equal(first.observations[:, 0], [x0, x0 - 2, x0 - 4])
        np.testing.assert_array_equal(second.observations[:, 0], [x0 - 1, x0 - 3, x0 - 5])
        for e in episodes:  # labels index every option of the task: "left" is 1
            np.testing.assert_array_equal(e.actions, [1, 1])
            np.testing.assert_array_equal(e.infos["option"], [1, 1])
            assert e.seed == x0
        # the costs of each decision's two env steps, summed
        costs = [int(x < 0) for x in x0 - np.arange(1, 6)]
        np.testing.assert_array_equal(first.infos["cost"], [costs[0] + costs[1],
                                                            costs[2] + costs[3]])
    again = collect_option_runs(job, runs_per_option=3)
    assert [t for t, _ in again] == [t for t, _ in runs]  # seeded from [seed, option, run]


def test_outcome_runs_label_every_start_and_keep_the_last_state():
    job = OptionRunsJob(LineRuns(), None, ("left",), seed=4, max_steps=100, outcomes=True,
                        stream=(17,))
    for tags, episodes in collect_option_runs(job, runs_per_option=4):
        x0 = tags["start"]
        first, second = episodes
        np.testing.assert_array_equal(first.observations[:, 0], [x0, x0 - 2, x0 - 4, x0 - 5])
        np.testing.assert_array_equal(second.observations[:, 0], [x0 - 1, x0 - 3, x0 - 5])
        assert set(first.infos) == {"option", OUTCOME_KEY}
        # from step t the run ends well when no step from t on goes below 0 and more
        # than one decision (2 steps) remains
        ends = x0 - np.arange(1, 6)
        expect = [bool((ends[t:] >= 0).all()) and 5 - t > 2 for t in range(5)]
        np.testing.assert_array_equal(first.infos[OUTCOME_KEY], np.array(expect)[[0, 2, 4]])


def test_decision_episodes_of_a_recorded_episode():
    episode = Episode(observations=np.arange(6.0)[:, None], actions=np.zeros((5, 1)),
                      rewards=np.ones(5), terminations=np.zeros(5, bool),
                      truncations=np.zeros(5, bool),
                      infos={"option": np.array([0, 0, 1, 1, 1]),
                             "cost": np.array([1, 2, 3, 4, 5]),
                             "flag": np.array([True, False, True, False, True])}, seed=9)
    cut = decision_episodes(episode, 3, summed=("cost",), at_start=("flag",))
    assert [e.observations[:, 0].tolist() for e in cut] == [[0, 3], [1, 4], [2, 5]]
    assert [e.actions.tolist() for e in cut] == [[0], [0], [1]]
    assert [e.infos["cost"].tolist() for e in cut] == [[6], [9], [12]]
    assert [e.infos["flag"].tolist() for e in cut] == [[True], [False], [True]]
    assert all(e.rewards.tolist() == [0.0] and e.seed == 9 for e in cut)
    to_end = decision_episodes(episode, 3, to_end=True)
    assert [e.observations[:, 0].tolist() for e in to_end] == [[0, 3, 5], [1, 4, 5], [2, 5]]


def test_decision_runs_cut_every_run_of_one_option_at_the_decision_rate():
    labels = np.array([0, 0, 0, 0, 0, 1, 2, 2, 2])
    episode = Episode(observations=np.arange(10.0)[:, None], actions=np.zeros((9, 1)),
                      rewards=np.ones(9), terminations=np.zeros(9, bool),
                      truncations=np.zeros(9, bool), infos={"option": labels}, seed=3)
    assert label_runs(labels) == [(0, 5), (5, 6), (6, 9)]
    cut = decision_runs([episode], 2)
    # option 0: observations 0..5, offsets 0 and 1; option 1 (1 step): none; option 2:
    # observations 6..9, offsets 0 and 1
    assert [e.observations[:, 0].tolist() for e in cut] == [
        [0, 2, 4], [1, 3, 5], [6, 8], [7, 9]]
    assert [e.actions.tolist() for e in cut] == [[0, 0], [0, 0], [2], [2]]
    assert all(e.truncations[-1] and not e.truncations[:-1].any() and e.seed == 3
               for e in cut)
    unlabelled = Episode(observations=np.zeros((2, 1)), actions=np.zeros((1, 1)),
                         rewards=np.zeros(1), terminations=np.zeros(1, bool),
                         truncations=np.zeros(1, bool))
    with pytest.raises(DynoplanError, match="episode 0 has no option labels"):
        decision_runs([unlabelled], 2)


def test_option_runs_need_a_run_and_a_step():
    with pytest.raises(DynoplanError, match="at least one run"):
        collect_option_runs(OptionRunsJob(LineRuns(), None, ("left",), 0, 10), 0)
