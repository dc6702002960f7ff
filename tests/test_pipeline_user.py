"""The pipeline as a user meets it: success functions, every setting from the command line
and a TOML file, Dict observations, out-of-region starts under --no-regions."""

import textwrap
from dataclasses import replace
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

from dynoplan.adapters import option_spec
from dynoplan.errors import DynoplanError, DynoplanWarning
from dynoplan.pipeline import (
    ControllerSettings,
    FitSettings,
    PipelineSettings,
    run_pipeline,
    task_env,
)
from dynoplan.pipeline.config import flag, pipeline_settings, read_config, setting_keys
from test_bad_input import assert_one_line_error
from test_bad_input import invoke as invoke_main
from test_pipeline import Line


class Drift(Line):
    """:class:`Line` that never terminates and reports no success."""

    def step(self, action):
        obs, *_ = super().step(action)
        return obs, -abs(5.0 - self.x), False, False, {}


class DictDrift(Drift):
    """:class:`Drift` with a Dict observation: ``{"x": (1,), "goal": (1,)}``."""

    def __init__(self):
        super().__init__()
        self.observation_space = spaces.Dict({"x": spaces.Box(-100, 100, (1,), np.float64),
                                              "goal": spaces.Box(5, 5, (1,), np.float64)})

    def reset(self, *, seed=None, options=None):
        obs, info = super().reset(seed=seed)
        return {"x": obs, "goal": np.array([5.0])}, info

    def step(self, action):
        obs, *rest = super().step(action)
        return {"x": obs, "goal": np.array([5.0])}, *rest


def reached(observation, info):
    return observation[0] >= 5.0


def drift_options():
    return [option_spec("right", lambda obs: np.array([1.0], np.float32), termination=0.1),
            option_spec("left", lambda obs: np.array([-1.0], np.float32), termination=0.1,
                        initiation=lambda s: s[:, 0] > 0.0)]


SMALL = PipelineSettings(
    demos=3, exploration_episodes=6, exploration_option_steps=20, episodes=4, seed=3,
    fit=FitSettings(dynamics_hidden=(32, 32), dynamics_members=2, dynamics_epochs=10,
                    goal_hidden=16, goal_epochs=40, region_components=1, region_slack=2.0),
    control=ControllerSettings(horizon=5, samples=8, replan_every=5, max_decisions=60))


def drift_env(cls=Drift):
    return gym.wrappers.TimeLimit(cls(), 40)


# --- success defined by a function ----------------------------------------------------


def test_a_task_that_never_terminates_succeeds_by_its_success_function():
    result = run_pipeline(drift_env(), drift_options(), demonstrator=lambda obs: "right",
                          settings=SMALL, success=reached)
    right = result.evaluation["option:right"]
    assert right["success_rate"] == 1.0
    # x starts in [-1, 1] and moves 1 per step: the first success is within 7 steps, and
    # the episode ends there (not at the 40-step limit)
    assert right["steps_to_success_mean"] <= 7.0
    assert right["env_steps_mean"] <= 7.0
    assert result.evaluation["option:left"]["success_rate"] == 0.0
    assert all(e.infos["progress"][-1] == 1.0 for e in result.demos)


def test_without_a_success_function_a_task_that_never_terminates_names_the_fix():
    with pytest.raises(DynoplanError, match="demonstrations reached the goal"):
        run_pipeline(drift_env(), drift_options(), demonstrator=lambda obs: "right",
                     settings=SMALL)


def test_a_success_function_that_raises_is_one_error_naming_it():
    def broken(observation, info):
        return info["missing"]

    with pytest.raises(DynoplanError, match=r"success function .* failed at step 1: KeyError"):
        run_pipeline(drift_env(), drift_options(), demonstrator=lambda obs: "right",
                     settings=SMALL, success=broken)


def test_out_of_region_starts_do_not_count_the_users_own_initiation_sets():
    settings = replace(SMALL, fit=replace(SMALL.fit, regions=False))
    result = run_pipeline(drift_env(), drift_options(), demonstrator=lambda obs: "right",
                          settings=settings, success=reached)
    # option:left alone starts where its own initiation set (x > 0) says no, but no
    # region was fitted, so no start is out of region
    assert {row["out_of_region_starts"] for row in result.evaluation.values()} == {0}


# --- Dict observations ------------------------------------------------------------------


def test_a_dict_observation_is_flattened_with_a_warning():
    with pytest.warns(DynoplanWarning, match=r"Dict observation flattened to 2 values in key "
                                             r"order \(goal, x\)"):
        env = task_env(drift_env(DictDrift))
    obs, _ = env.reset(seed=0)
    assert obs.shape == (2,) and obs[0] == 5.0


def test_a_dict_observation_with_a_state_fn_runs_the_pipeline():
    def position(observation):
        return observation["x"]

    def reached_dict(observation, info):
        return observation["x"][0] >= 5.0

    result = run_pipeline(drift_env(DictDrift), drift_options(),
                          demonstrator=lambda obs: "right", settings=SMALL,
                          success=reached_dict, state_fn=position)
    assert result.summary["state_dim"] == 1
    assert result.evaluation["option:right"]["success_rate"] == 1.0


def test_a_dict_space_that_does_not_flatten_needs_a_state_fn():
    env = drift_env(DictDrift)
    env.observation_space = spaces.Dict({"path": spaces.Sequence(spaces.Box(0, 1, (2,)))})
    with pytest.raises(DynoplanError, match="give a state_fn"):
        task_env(env)


# --- the command line: flags, --config, settings.toml -----------------------------------

OPTIONS_MODULE = textwrap.dedent('''
    import gymnasium as gym
    import numpy as np

    from gymnasium import spaces

    from dynoplan.adapters import option_spec
    from test_pipeline_user import DictDrift, Drift


    class Paths(DictDrift):
        def __init__(self):
            super().__init__()
            self.observation_space = spaces.Dict(
                {"path": spaces.Sequence(spaces.Box(0, 1, (2,)))})


    if "TestDrift-v0" not in gym.registry:
        gym.register("TestDrift-v0", entry_point=Drift, max_episode_steps=40)
        gym.register("TestPaths-v0", entry_point=Paths, max_episode_steps=40)


    def make_options():
        return [option_spec("right", lambda obs: np.array([1.0], np.float32),
                            termination=0.1),
                option_spec("left", lambda obs: np.array([-1.0], np.float32),
                            termination=0.1)]


    def make_demonstrator():
        return lambda observation: "right"


    def reached(observation, info):
        return observation[0] >= 5.0


    def broken(observation, info):
        raise ValueError("no goal here")


    class Shoved(gym.Wrapper):
        """The drift, counting its episodes (the test's 'disturbance')."""
        resets = 0

        def reset(self, **kwargs):
            Shoved.resets += 1
            return self.env.reset(**kwargs)


    def shove(env):
        return Shoved(env)


    def not_a_wrapper(env):
        return 3
''')
SMALL_FLAGS = ["--demos", "2", "--explore", "4", "--episodes", "3", "--horizon", "5",
               "--samples", "8", "--dynamics-epochs", "5", "--dynamics-min-updates", "50",
               "--dynamics-members", "2",
               "--goal-epochs", "30", "--region-components", "1", "--workers", "1",
               "--quiet"]


def invoke(monkeypatch, capsys, tmp_path, *args):
    """``dynoplan pipeline ARGS`` in this process, in ``tmp_path`` with the options
    module: exit status, stdout, stderr."""
    (tmp_path / "drift_options.py").write_text(OPTIONS_MODULE)
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.syspath_prepend(str(Path(__file__).parent))
    return invoke_main(monkeypatch, capsys, "pipeline", *args)


def test_settings_toml_repeats_the_run_and_flags_override_it(tmp_path, monkeypatch, capsys):
    import json

    code, _, err = invoke(monkeypatch, capsys, tmp_path, "--env", "TestDrift-v0",
                            "--options", "drift_options:make_options",
                            "--success", "drift_options:reached", "--risk", "0.5",
                            "--margin", "0.1", "--region-slack", "1.5", *SMALL_FLAGS,
                            "--out", "first")
    assert code == 0, err
    written = (tmp_path / "first" / "settings.toml").read_text()
    assert 'success = "drift_options:reached"' in written and "risk = 0.5" in written
    code, _, err = invoke(monkeypatch, capsys, tmp_path, "--config", "first/settings.toml",
                          "--workers", "1", "--quiet", "--out", "again")
    assert code == 0, err
    assert (tmp_path / "again" / "settings.toml").read_text() == written

    def comparable(folder):
        summary = json.loads((tmp_path / folder / "summary.json").read_text())
        return summary["settings"], {k: {m: v for m, v in row.items()
                                         if not m.startswith("latency")}
                                     for k, row in summary["controllers"].items()}

    assert comparable("first") == comparable("again")
    assert comparable("first")[1]["option:right"]["success_rate"] == 1.0
    code, _, err = invoke(monkeypatch, capsys, tmp_path, "--config", "first/settings.toml",
                          "--risk", "0", "--workers", "1", "--quiet", "--out", "other")
    assert code == 0, err
    assert "risk = 0.0" in (tmp_path / "other" / "settings.toml").read_text()


def test_an_unknown_setting_in_the_config_is_one_line(tmp_path, monkeypatch, capsys):
    (tmp_path / "bad.toml").write_text('env = "TestDrift-v0"\n[fit]\nregion_slak = 1.0\n')
    code, _, err = invoke(monkeypatch, capsys, tmp_path, "--config", "bad.toml",
                          "--options", "drift_options:make_options", "--out", "out")
    assert_one_line_error(code, err, "unknown setting 'fit.region_slak'", "fit.region_slack")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(("text", "needle"), [
    ('[control]\nhorizon = "long"\n', "control.horizon must be an integer"),
    ("seed = -1\n", "seed must be in"),
    ("[plan]\nhorizon = 3\n", "unknown section [plan]"),
    ("horizon = \n", "not valid TOML"),
])
def test_a_bad_value_in_the_config_is_one_line(tmp_path, monkeypatch, capsys, text, needle):
    (tmp_path / "bad.toml").write_text(text)
    code, _, err = invoke(monkeypatch, capsys, tmp_path, "--config", "bad.toml", "--env",
                          "TestDrift-v0", "--options", "drift_options:make_options")
    assert_one_line_error(code, err, needle)


def test_a_success_function_that_raises_is_one_line_on_the_command_line(tmp_path, monkeypatch,
                                                                         capsys):
    code, _, err = invoke(monkeypatch, capsys, tmp_path, "--env", "TestDrift-v0",
                          "--options", "drift_options:make_options",
                          "--success", "drift_options:broken", *SMALL_FLAGS, "--out", "out")
    assert_one_line_error(code, err, "success function 'drift_options:broken' failed at step 1",
                   "ValueError: no goal here")
    assert not (tmp_path / "out").exists()


def test_a_dict_space_without_a_map_is_one_line(tmp_path, monkeypatch, capsys):
    code, _, err = invoke(monkeypatch, capsys, tmp_path, "--env", "TestPaths-v0",
                          "--options", "drift_options:make_options", "--out", "out")
    assert_one_line_error(code, err, "give a state_fn", "--state-fn")


def test_every_setting_has_a_flag():
    from typer.testing import CliRunner

    from dynoplan.cli.main import app

    help_text = CliRunner().invoke(app, ["pipeline", "--help"], env={"COLUMNS": "250"}).output
    for key in setting_keys():
        assert flag(key) in help_text, key
    for name in ("--config", "--success", "--state-fn"):
        assert name in help_text


def test_settings_read_back_as_written(tmp_path):
    from dynoplan.pipeline.config import settings_toml

    settings = PipelineSettings(
        demos=7, controllers=("dynoplan", "random"),
        fit=FitSettings(dynamics_hidden=(16, 8), region_components=3, region_slack=0.25),
        control=ControllerSettings(replan_every=None, risk=1.5, hold_action=(0.0, -1.0)))
    path = tmp_path / "settings.toml"
    path.write_text(settings_toml({"env": "E-v0", "options": "m:f"}, settings))
    values = read_config(path)
    assert values["env"] == "E-v0"
    assert pipeline_settings(values, str(path)) == settings


def test_an_unknown_controller_is_one_line_before_any_work(tmp_path, monkeypatch, capsys):
    code, _, err = invoke(monkeypatch, capsys, tmp_path, "--env", "TestDrift-v0",
                          "--options", "drift_options:make_options", "--controllers",
                          "dynoplan,option:nosuch", "--out", "out")
    assert_one_line_error(code, err, "unknown controller(s) option:nosuch", "option:right")
    assert not (tmp_path / "out").exists()


def test_the_rounds_rehearse_under_the_disturbance_the_command_line_names(tmp_path, monkeypatch,
                                                                           capsys):
    task = ["--env", "TestDrift-v0", "--options", "drift_options:make_options",
            "--success", "drift_options:reached", *SMALL_FLAGS, "--improve-episodes", "2"]
    code, _, err = invoke(monkeypatch, capsys, tmp_path, *task, "--improve-disturbed", "0.5",
                          "--out", "none")
    assert_one_line_error(code, err, "improve_disturbed", "disturbed environment")
    assert not (tmp_path / "none").exists()
    code, _, err = invoke(monkeypatch, capsys, tmp_path, *task, "--improve-disturbed", "0.5",
                          "--disturbance", "drift_options:not_a_wrapper", "--out", "bad")
    assert_one_line_error(code, err, "drift_options:not_a_wrapper", "must return an environment")
    code, _, err = invoke(monkeypatch, capsys, tmp_path, *task, "--improve-disturbed", "0.5",
                          "--disturbance", "drift_options:shove", "--out", "shoved")
    assert code == 0, err
    import drift_options

    assert drift_options.Shoved.resets >= 2  # a share of the round's episodes ran there
    assert 'disturbance = "drift_options:shove"' in \
        (tmp_path / "shoved" / "settings.toml").read_text()
