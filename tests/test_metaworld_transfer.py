"""Meta-World tasks over one option set (benchmarks/transfer/metaworld_tasks.py): the
shared state and options work on plain arrays; without ``metaworld`` the experiment is
one line; with it, every task's demonstrator succeeds and the pooled environment's seeded
reset is reproducible."""

import importlib.util

import numpy as np
import pytest

from benchmarks.transfer import metaworld_tasks as mw

HAS_METAWORLD = importlib.util.find_spec("metaworld") is not None


def _observation(hand, puck, goal, gripper=1.0):
    o = np.zeros(39)
    o[0:3], o[3], o[4:7], o[36:39] = hand, gripper, puck, goal
    return o


def test_the_shared_state_and_options_read_hand_gripper_object_goal():
    o = _observation([0.0, 0.6, 0.2], [0.0, 0.7, 0.02], [0.1, 0.8, 0.2])
    s = mw.state(o)
    assert s.shape == (10,)
    np.testing.assert_allclose(s[7:10], [0.1, 0.8, 0.2])
    options = {spec.name: spec for spec in mw.make_options()}
    assert list(options) == ["reach", "hover", "descend", "grasp", "carry"]
    assert mw.reach(s)[3] == mw.OPEN and mw.reach(s)[0] > 0  # towards the goal, open
    assert mw.carry(s)[3] == mw.CLOSE
    at_goal = mw.state(_observation([0.1, 0.8, 0.2], [0.1, 0.8, 0.2], [0.1, 0.8, 0.2]))
    assert mw.reached(at_goal[None])[0] and mw.delivered(at_goal[None])[0]
    assert not mw.reached(s[None])[0]
    assert mw.make_demonstrator("reach-v3").choose(s) == "reach"
    assert mw.make_demonstrator("push-v3").choose(s) == "hover"


def test_without_metaworld_the_experiment_is_one_line(monkeypatch, capsys, tmp_path):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "metaworld" else real(name, *a))
    assert mw.main(["--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1 and out[0].startswith("skipped Meta-World transfer")
    assert not any(tmp_path.iterdir())


@pytest.mark.skipif(not HAS_METAWORLD, reason="needs the metaworld package")
def test_every_demonstrator_succeeds_and_the_pooled_reset_is_seeded():
    import gymnasium as gym

    from dynoplan.pipeline import record_demonstrations, task_env

    specs = mw.make_options()
    for task in mw.TASKS:
        env = task_env(gym.make(mw.ENV_IDS[task]), mw.success, mw.state)
        record_demonstrations(env, specs, mw.make_demonstrator(task), episodes=1, seed=0,
                              max_attempts=1)
    pooled = gym.make(mw.TRAIN_ENV_ID)
    first, info = pooled.reset(seed=3)
    again, info_again = pooled.reset(seed=3)
    np.testing.assert_array_equal(first, again)
    assert info["task"] == info_again["task"] and info["task"] in mw.TRAIN
    assert {pooled.reset(seed=s)[1]["task"] for s in range(20)} == set(mw.TRAIN)


def test_the_table_reads_every_finished_seed_and_an_empty_refit():
    row = {"expert": 1.0, "shared": 0.9, "random": 0.5, "demonstrations": 10,
           "fit_seconds": 5.0, "refit": 0.95, "refit_demonstrations": 10,
           "refit_exploration": 20, "refit_fit_seconds": 15.0}
    options = {"demonstrations": 20, "exploration_episodes": 40, "dynamics_seconds": 9.0}
    results = {"tasks": ["reach-v3", "push-v3"], "seed_list": [0, 1, 2],
               "train": ["reach-v3"],
               "seeds": {"0": {"options": options, "reach-v3": row,
                               "push-v3": {**row, "refit": None, "refit_demonstrations": None,
                                           "refit_exploration": None,
                                           "refit_fit_seconds": None}}}}
    results["seeds"]["0"]["reach-v3"] = {**row, "improvement": {
        "own_episodes": 60, "demonstrator_episodes": 2, "seconds": 30.0}}
    lines = mw.table(results).splitlines()
    assert lines[2].startswith("| reach-v3 | seen | 1.00 | 0.90 | 0.95 | 0.50 | 10, 5.0 | 10 + 20")
    assert lines[2].endswith("| 60, 2.0, 30.0 |")  # what its improvement round needed
    assert lines[3].startswith("| push-v3 | unseen |") and lines[3].endswith("| - | - |")
    assert "20 demonstrations (reach-v3) + 40 exploration" in mw.table(results)
