"""The scripted gear expert, its recordings, the summary, the renders and the CLI."""

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from dynoplan.cli.gear import gear_app
from dynoplan.envs.gear.demonstrations import (
    ExpertDemonstrator,
    record_expert_episodes,
    render_scene,
    run_expert,
    run_expert_episode,
)
from dynoplan.envs.gear.env import ACT_DIM, OBS_DIM, GearAssemblyEnv
from dynoplan.envs.gear.expert import CAUTIOUS_MOVE, FAST_MOVE, INSERT, PICK, GearExpert
from dynoplan.envs.gear.options import PAPER_OPTIONS
from dynoplan.errors import DynoplanError


@pytest.fixture(scope="module")
def env_and_expert():
    env = GearAssemblyEnv()
    yield env, ExpertDemonstrator(GearExpert(env))
    env.close()


def test_option_names_are_the_papers():
    from dynoplan.envs.gear.options import gear_option_names

    assert PAPER_OPTIONS == ("pick", "fast_move", "cautious_move", "insert")
    assert (PICK, FAST_MOVE, CAUTIOUS_MOVE, INSERT) == (0, 1, 2, 3)
    # registered first, so the demonstrators' labels are the pipeline's
    assert gear_option_names()[:4] == PAPER_OPTIONS


def test_expert_assembles_the_gear_through_the_four_phases(env_and_expert):
    env, expert = env_and_expert
    ep = run_expert_episode(env, expert, seed=5, human_mode="away")
    options = ep["infos"]["option"]
    assert ep["infos"]["success"][-1] and ep["terminations"][-1]
    assert ep["infos"]["human_contacts"].sum() == 0
    # pick, then fast_move, then insert, in that order and without going back
    firsts = [int(np.argmax(options == k)) for k in (PICK, FAST_MOVE, INSERT)]
    assert firsts == sorted(firsts) and options[0] == PICK and options[-1] == INSERT
    assert CAUTIOUS_MOVE not in options  # nobody around
    assert ep["observations"].shape == (len(ep["actions"]) + 1, OBS_DIM)
    assert ep["actions"].shape == (len(options), ACT_DIM)


def test_expert_gives_way_to_a_blocking_human_without_touching_it(env_and_expert):
    env, expert = env_and_expert
    ep = run_expert_episode(env, expert, seed=1, human_mode="block")
    assert ep["infos"]["success"][-1]
    assert ep["infos"]["human_contacts"].sum() == 0
    assert ep["infos"]["min_human_distance"].min() > 0.0
    assert CAUTIOUS_MOVE in ep["infos"]["option"]


def test_expert_is_deterministic(env_and_expert):
    env, expert = env_and_expert
    a = run_expert_episode(env, expert, seed=3)
    b = run_expert_episode(env, expert, seed=3)
    np.testing.assert_array_equal(a["actions"], b["actions"])
    np.testing.assert_array_equal(a["infos"]["option"], b["infos"]["option"])


def test_recorded_episodes_have_the_dataset_fields():
    episodes = record_expert_episodes(1, seed=0)
    ep = episodes[0]
    steps = len(ep["actions"])
    assert ep["observations"].shape == (steps + 1, OBS_DIM)
    for key in ("rewards", "terminations", "truncations"):
        assert ep[key].shape == (steps,)
    infos = ep["infos"]
    assert infos["option"].dtype == np.int64 and set(infos["option"]) <= {0, 1, 2, 3}
    progress = infos["progress"]
    assert progress[-1] == 1.0 and np.all(np.diff(progress) > 0) and progress[0] > 0
    for key in ("stage", "min_human_distance", "success"):
        assert infos[key].shape == (steps,)


def test_run_expert_writes_the_summary(tmp_path):
    summary = run_expert(2, seed=4, out=tmp_path, progress=False)
    on_disk = json.loads((tmp_path / "summary.json").read_text())
    assert on_disk == summary
    for key in ("success_rate", "contacts", "realtime_factor", "min_human_distance"):
        assert key in summary
    # the scripted expert assembles the gear in both episodes
    assert summary["episodes"] == 2 and summary["success_rate"] == 1.0


def test_bad_arguments_are_user_errors(tmp_path):
    with pytest.raises(DynoplanError):
        run_expert(0, seed=0, out=tmp_path, progress=False)
    result = CliRunner().invoke(gear_app, ["expert", "--episodes", "1", "--human", "dance",
                                           "--out", str(tmp_path)])
    assert result.exit_code == 2 and "'--human'" in result.output  # a usage error


def test_cli_expert_and_render_without_video(tmp_path):
    runner = CliRunner()
    result = runner.invoke(gear_app, ["expert", "--episodes", "1", "--seed", "2", "--quiet",
                                      "--out", str(tmp_path / "expert")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "expert" / "summary.json").exists()
    result = runner.invoke(gear_app, ["render", "--no-video", "--out", str(tmp_path / "r")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "r" / "scene.png").stat().st_size > 10_000


@pytest.mark.slow
def test_render_writes_a_video(tmp_path):
    written = render_scene(tmp_path, seed=0, video=True, width=320, height=240)
    assert written["video"].stat().st_size > 10_000
    import imageio.v2 as imageio
    frames = imageio.mimread(written["video"], memtest=False)
    assert len(frames) > 50 and frames[0].shape == (240, 320, 3)


@pytest.mark.slow
def test_expert_success_and_safety_over_many_episodes(tmp_path):
    summary = run_expert(20, seed=123, out=tmp_path, progress=False)
    assert summary["success_rate"] >= 0.9
    assert summary["contacts"] == 0
