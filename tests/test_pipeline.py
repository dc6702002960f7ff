"""The generic pipeline: collect, fit, control, evaluate on a user's environment; bad input."""

import json
import subprocess
import sys
import textwrap

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

from dynoplan import DynoplanError
from dynoplan.adapters import make_option, option_spec
from dynoplan.control.controller import flat_state
from dynoplan.data import DatasetMetadata, Episode, read_dataset, write_dataset
from dynoplan.pipeline import (
    ControllerSettings,
    FitSettings,
    FittedModels,
    PipelineSettings,
    RandomOptions,
    StridedTermination,
    box_state_dim,
    collect_transitions,
    demos_from_dataset,
    load_object,
    option_transitions,
    probe_options,
    record_demonstrations,
    run_pipeline,
)
from dynoplan.pipeline.collect import Detour, successful_attempts
from dynoplan.pipeline.diagnostics import episode_history_warning
from dynoplan.pipeline.evaluate import evaluate_controllers
from dynoplan.pipeline.fit import strided
from dynoplan.pipeline.fit_data import labelled_states


class Line(gym.Env):
    """x on a line, starts in [-1, 1]; the action (clipped to [-1, 1]) is added; goal x >= 5."""

    def __init__(self):
        self.observation_space = spaces.Box(-100, 100, (1,), np.float64)
        self.action_space = spaces.Box(-1, 1, (1,), np.float32)
        self.x = 0.0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x = float(self.np_random.uniform(-1, 1))
        return np.array([self.x]), {}

    def step(self, action):
        self.x += float(np.clip(np.asarray(action).reshape(-1)[0], -1, 1))
        done = self.x >= 5
        return np.array([self.x]), float(done), done, False, {"is_success": done}


def line_env():
    return gym.wrappers.TimeLimit(Line(), 40)


def line_options():
    return [option_spec("right", lambda obs: np.array([1.0], np.float32), termination=0.1),
            option_spec("left", lambda obs: np.array([-1.0], np.float32), termination=0.1)]


SMALL = PipelineSettings(
    demos=4, exploration_episodes=8, exploration_option_steps=20, episodes=4, seed=3,
    fit=FitSettings(dynamics_hidden=(32, 32), dynamics_members=2, dynamics_epochs=20,
                    goal_hidden=16, goal_epochs=60, region_components=1, region_slack=2.0),
    control=ControllerSettings(horizon=5, samples=8, replan_every=5, max_decisions=60))


def _comparable(evaluation):
    return {k: {m: v for m, v in row.items() if not m.startswith("latency")}
            for k, row in evaluation.items()}


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    out = tmp_path_factory.mktemp("line")
    return out, run_pipeline(line_env(), line_options(), demonstrator=lambda obs: "right",
                             settings=SMALL, out=out)


def test_pipeline_learns_to_go_right_and_beats_going_left(result):
    _, res = result
    assert set(res.evaluation) == {"demonstrator", "dynoplan", "option:right",
                                   "option:left", "random"}
    # the demonstrator is the bar, on the same episodes: it only goes right
    assert res.evaluation["demonstrator"]["success_rate"] == 1.0
    assert res.evaluation["demonstrator"]["option_share"] == {"right": 1.0}
    assert res.evaluation["demonstrator"]["latency_ms_p50"] is None  # it does not plan
    assert res.summary["composition_ratio"] == 1.0
    assert res.evaluation["dynoplan"]["success_rate"] == 1.0
    assert res.evaluation["option:right"]["success_rate"] == 1.0
    assert res.evaluation["option:left"]["success_rate"] == 0.0
    # 'left' is never demonstrated: its region comes from its own exploration runs
    assert res.models.regions is not None
    assert res.models.regions.option_names == ["right", "left"]
    assert res.models.report["regions"]["undemonstrated"] == {"left": "none"}
    assert [o.demonstrated for o in res.options] == [True, False]
    # each option with a region carries its likelihood (regions_without_gain reads it)
    states = np.array([[0.0], [3.0]])
    for option in res.options:
        assert option.likelihood is not None
        np.testing.assert_array_equal(option.likelihood(states),
                                      res.models.regions.log_likelihood(states, option.name))
    assert res.summary["demonstrations"]["episodes"] == 4
    assert "| dynoplan | 1 |" in res.table


def test_pipeline_writes_datasets_models_and_summary(result):
    out, res = result
    summary = json.loads((out / "summary.json").read_text())
    assert summary["controllers"]["dynoplan"]["success_rate"] == 1.0
    assert summary["options"] == ["right", "left"] and summary["state_dim"] == 1
    results = (out / "results.md").read_text()
    # the results and which options each controller ran
    assert results.count("| option:") == 4 and results.count("| demonstrator |") == 2
    assert "1.00 of the demonstrator's success" in results
    demos = read_dataset(out / "demos")
    assert demos.metadata.option_names == ["right", "left"] and len(demos) == 4
    assert all(np.all(e.options == 0) for e in demos)  # the demonstrator only went right
    assert np.isclose(demos[0].infos["progress"][-1], 1.0)
    assert len(read_dataset(out / "transitions")) == 8
    loaded = FittedModels.load(out / "models")
    states = np.array([[0.0], [2.0]])
    for name in ("right", "left"):
        a = res.models.dynamics[name].sample(states, np.random.default_rng(1))
        b = loaded.dynamics[name].sample(states, np.random.default_rng(1))
        assert np.array_equal(a, b)
    assert np.array_equal(loaded.goal.mean_std(states)[0], res.models.goal.mean_std(states)[0])
    assert loaded.regions is not None and loaded.regions.option_names == ["right", "left"]


def test_summary_reports_where_each_option_may_start(result):
    out, _ = result
    summary = json.loads((out / "summary.json").read_text())
    rows = summary["admissibility"]
    assert set(rows) == {"right", "left"}
    for row in rows.values():
        assert 0.0 <= row["start_states"] <= 1.0 and 0.0 <= row["demo_states"] <= 1.0
    assert rows["left"]["own_demo_states"] is None  # never demonstrated
    assert rows["right"]["own_demo_states"] >= 0.9
    assert isinstance(summary["warnings"], list) and summary["warnings"]
    assert set(summary["stage_seconds"]) >= {"demonstrations", "safety regions", "evaluation"}
    assert "admissible at evaluation start states" in (out / "results.md").read_text()


def test_pipeline_is_deterministic_given_the_seed(result):
    _, res = result
    again = run_pipeline(line_env(), line_options(), demonstrator=lambda obs: "right",
                         settings=SMALL)
    assert _comparable(again.evaluation) == _comparable(res.evaluation)


class WornLine(Line):
    """:class:`Line` whose actions weaken with every step it ever took, across resets: an
    environment that keeps state across ``reset`` (as PyBullet's contact solver does)."""

    def __init__(self):
        super().__init__()
        self.wear = 0
        self.closed = False

    def step(self, action):
        self.wear += 1
        return super().step(np.asarray(action) * (1.0 - 0.01 * self.wear))

    def close(self):
        self.closed = True


def test_an_environment_that_keeps_state_across_reset_is_reported_in_one_line():
    assert episode_history_warning(line_env(), 3, 4) is None
    message = episode_history_warning(gym.wrappers.TimeLimit(WornLine(), 40), 3, 4)
    assert message is not None and "\n" not in message
    assert "the episode of seed 3 went differently after another episode ran" in message


def test_a_row_on_a_fresh_environment_is_the_same_alone_or_after_other_rows(result):
    _, res = result
    made = []

    def fresh():
        made.append(gym.wrappers.TimeLimit(WornLine(), 40))
        return made[-1]

    def rows(kinds, fresh_env):
        evaluation = evaluate_controllers(
            fresh(), res.options, res.models.goal, SMALL.control, 6, 11,
            res.planner_options, kinds, fresh_env=fresh_env)
        return {k: v["steps_to_success_mean"] for k, v in evaluation.items()}

    alone = rows(["random"], None)
    # on one environment, what ran before a row changes it; on fresh ones it does not
    assert rows(["option:right", "random"], None)["random"] != alone["random"]
    assert rows(["option:right", "random"], fresh)["random"] == rows(["random"], fresh)["random"]
    # the row's own environment is closed after the rows; the caller's is left open
    assert made[-1].unwrapped.closed and not made[-2].unwrapped.closed


def test_recorded_demonstrations_can_be_reused_from_a_dataset(result, tmp_path):
    out, _ = result
    dataset = read_dataset(out / "demos")
    # the same demonstrations, with the options given in another order
    swapped = [line_options()[1], line_options()[0]]
    demos = demos_from_dataset(dataset, [o.name for o in swapped])
    assert all(np.all(e.options == 1) for e in demos)


def test_option_transitions_respect_the_stride():
    ep = Episode(observations=np.arange(7.0)[:, None], actions=np.zeros((6, 1)),
                 rewards=np.zeros(6), terminations=np.zeros(6, bool),
                 truncations=np.zeros(6, bool), infos={"option": np.array([0, 0, 0, 1, 1, 0])})
    pairs = option_transitions([ep], ["a", "b"], stride=2)
    assert pairs["a"][0].ravel().tolist() == [0.0, 1.0]
    assert pairs["a"][1].ravel().tolist() == [2.0, 3.0]
    assert pairs["b"][0].ravel().tolist() == [3.0]
    beta = strided(termination=line_options()[0].termination, stride=3)
    assert np.isclose(beta.probability(np.zeros((1, 1)))[0], 1 - 0.9 ** 3)
    custom = StridedTermination(type("T", (), {"probability": lambda self, s: s[:, 0]})(), 2)
    assert np.allclose(custom.probability(np.array([[0.5]])), [0.75])


def test_random_options_explore_and_record_labels():
    specs = line_options()
    rec = record_demonstrations(line_env(), specs, RandomOptions(specs, max_option_steps=5),
                                episodes=1, seed=0, max_attempts=50)
    labels = rec[0].options
    assert set(np.unique(labels)) <= {0, 1} and rec[0].infos["progress"][-1] == 1.0


def test_exploration_branches_off_the_demonstrations_where_they_went():
    specs = line_options()
    demos = record_demonstrations(line_env(), specs, lambda obs: "right", episodes=2, seed=1)
    on_path = {round(float(x), 9) for d in demos for x in d.observations[:, 0]}
    plain = collect_transitions(line_env(), specs, 2, seed=5, max_option_steps=3)
    branched = collect_transitions(line_env(), specs, 2, seed=5, demos=demos, branches=2,
                                   max_option_steps=3)
    # the first two start at a reset of their own, as without branches; the other two
    # on a demonstration's path (its seed, its first actions)
    assert all(np.array_equal(a.observations, b.observations)
               for a, b in zip(plain, branched[:2], strict=True))
    assert [round(float(e.observations[0, 0]), 9) in on_path for e in branched] == [
        False, False, True, True]
    assert {e.seed for e in branched[2:]} <= {d.seed for d in demos}
    with pytest.raises(DynoplanError, match="must be >= 0, got -1"):
        collect_transitions(line_env(), specs, 2, seed=5, demos=demos, branches=-1)


def test_a_detour_is_a_run_of_another_option_that_the_demonstrator_recovers_from():
    specs = line_options()
    demos = record_demonstrations(line_env(), specs, lambda obs: "right", episodes=3, seed=1)
    detour = Detour.around(lambda obs: "right", specs, demos)
    assert detour.within == int(np.median([len(d) for d in demos]))
    recorded = record_demonstrations(line_env(), specs, detour, episodes=6, seed=2)
    again = record_demonstrations(line_env(), specs, detour, episodes=6, seed=2)
    assert all(np.array_equal(a.observations, b.observations)
               for a, b in zip(recorded, again, strict=True))
    went_left = detoured = 0
    for episode in recorded:
        marked = episode.infos["detour"]
        # at most one detour (none where the episode ended before it was due), after the
        # first step, of consecutive steps; the rest is the demonstrator's
        steps = np.flatnonzero(marked)
        assert not len(steps) or (steps[0] >= 1 and np.all(np.diff(steps) == 1))
        detoured += bool(len(steps))
        assert np.all(episode.options[~marked] == 0)
        went_left += int(np.any(episode.options[marked] == 1))
        # it still reached the goal: progress runs to 1 over the whole episode
        assert episode.infos["progress"][-1] == 1.0 and episode.observations[-1, 0] >= 5
    assert detoured >= 4 and went_left > 0  # some went the wrong way and were made up for
    # the regions see the demonstrator's choices only; the dynamics see every step
    states, labels, _ = labelled_states(recorded, 2, flat_state)
    assert len(states) == sum(int((~e.infos["detour"]).sum()) for e in recorded)
    assert set(labels.tolist()) == {0}
    pairs = option_transitions(recorded, ["right", "left"])
    assert len(pairs["left"][0]) == sum(int((e.options == 1).sum()) for e in recorded) > 0
    with pytest.raises(DynoplanError, match="within >= 2 and max_steps >= 1"):
        Detour(lambda obs: "right", specs, within=1)


def test_a_run_with_detours_writes_them_beside_the_demonstrations(tmp_path):
    settings = PipelineSettings(**{**SMALL.__dict__, "demo_detours": 2, "improve": 0})
    res = run_pipeline(line_env(), line_options(), demonstrator=lambda obs: "right",
                       settings=settings, out=tmp_path)
    demos = read_dataset(tmp_path / "demos").episodes
    assert len(demos) == settings.demos + 2
    assert [bool(d.infos["detour"].any()) for d in demos[:settings.demos]] == [False] * 4
    assert res.evaluation["dynoplan"]["success_rate"] == 1.0


# --- bad input ---------------------------------------------------------------------------


class Still:
    def __init__(self, d):
        self.state_dim = d

    def sample(self, states, rng):
        return np.asarray(states, dtype=np.float64)


def test_a_non_box_observation_space_is_a_clear_error():
    with pytest.raises(DynoplanError, match=r"Discrete\(16\).*needs a Box"):
        box_state_dim(gym.make("FrozenLake-v1"))
    with pytest.raises(DynoplanError, match="needs a Box"):
        run_pipeline("FrozenLake-v1", line_options(), demonstrator=lambda obs: "right")


@pytest.mark.parametrize(("option", "message"), [
    (option_spec("tall", lambda obs: np.array([1.0], np.float32),
                 termination=lambda s: s[:, 2] > 0),
     r"option 'tall': termination failed on states of shape \(2, 1\): IndexError"),
    (option_spec("flat", lambda obs: np.array([1.0], np.float32),
                 initiation=lambda s: np.ones(len(s) * 3, bool)),
     r"option 'flat': initiation returned shape \(6,\).*disagrees"),
    (make_option("three", lambda obs: np.array([1.0], np.float32), Still(3)),
     "option 'three': dynamics model has state_dim 3, the environment's states have 1"),
    (option_spec("wide", lambda obs: np.array([1.0, 0.0], np.float32)),
     r"option 'wide': policy returned an action of shape \(2,\)"),
])
def test_options_that_disagree_with_the_environment_are_clear_errors(option, message):
    with pytest.raises(DynoplanError, match=message):
        probe_options(line_env(), [line_options()[0], option])


def test_repeated_option_names_are_an_error():
    with pytest.raises(DynoplanError, match="repeated: right"):
        probe_options(line_env(), [line_options()[0], line_options()[0]])


def test_a_demonstration_without_option_labels_is_a_clear_error(tmp_path):
    unlabelled = Episode(observations=np.zeros((3, 1)), actions=np.zeros((2, 1)),
                         rewards=np.zeros(2), terminations=np.zeros(2, bool),
                         truncations=np.zeros(2, bool))
    with pytest.raises(DynoplanError, match="demonstration 0 has no option labels"):
        run_pipeline(line_env(), line_options(), demos=[unlabelled], settings=SMALL)
    with pytest.raises(DynoplanError, match="episode 0 has no option labels"):
        option_transitions([unlabelled], ["right", "left"])
    write_dataset(tmp_path / "d", [unlabelled], DatasetMetadata("test/unlabelled-v0"))
    with pytest.raises(DynoplanError, match="has no option labels"):
        demos_from_dataset(read_dataset(tmp_path / "d"), ["right", "left"])


def test_demonstrations_naming_unknown_options_are_an_error(tmp_path):
    labelled = Episode(observations=np.zeros((3, 1)), actions=np.zeros((2, 1)),
                       rewards=np.zeros(2), terminations=np.zeros(2, bool),
                       truncations=np.zeros(2, bool), infos={"option": np.array([0, 0])})
    write_dataset(tmp_path / "d", [labelled], DatasetMetadata("test/other-v0",
                                                               option_names=["jump"]))
    with pytest.raises(DynoplanError, match=r"\['jump'\] are not among the options"):
        demos_from_dataset(read_dataset(tmp_path / "d"), ["right", "left"])


def test_demonstrators_that_misbehave_are_clear_errors():
    specs = line_options()
    with pytest.raises(DynoplanError, match="chose 'up', which is not an option"):
        record_demonstrations(line_env(), specs, lambda obs: "up", episodes=1, seed=0)
    with pytest.raises(DynoplanError, match="only 0 of 2 demonstrations reached the goal"):
        record_demonstrations(line_env(), specs, lambda obs: "left", episodes=1, seed=0,
                              max_attempts=2)
    with pytest.raises(DynoplanError, match="give a demonstrator"):
        run_pipeline(line_env(), specs, settings=SMALL)


def test_successful_attempts_in_rounds_run_the_attempts_one_by_one_would():
    ok = [False, True, False, True, True, False, True]  # attempt i succeeds
    rounds = []

    def run(pairs):
        rounds.append(pairs)
        return [ok[i] for _, i in pairs]

    found, tried = successful_attempts(3, len(ok), run, bool)
    # round 1: attempts 0..2 to requests 0..2; round 2: 3, 4 to the failed 0 and 2
    assert rounds == [[(0, 0), (1, 1), (2, 2)], [(0, 3), (2, 4)]]
    assert found == [(3, True), (1, True), (4, True)] and tried == 5  # stops at the 3rd
    found, tried = successful_attempts(5, len(ok), lambda pairs: [ok[i] for _, i in pairs],
                                       bool)
    assert tried == len(ok) and sum(f is not None for f in found) == 4


def test_a_demonstrator_may_restart_an_option_act_itself_and_read_the_info():
    from dynoplan.options.option import OptionPolicy
    from dynoplan.pipeline import Decision, Demonstrator, record_episode
    from dynoplan.pipeline.collect import demonstrator_from

    class Counted(OptionPolicy):
        """Acts +1; counts its starts."""

        starts = 0

        def reset(self, observation, rng):
            Counted.starts += 1

        def act(self, observation):
            return np.array([1.0], np.float32)

    class Script(Demonstrator):
        """right; right started again; one step of its own (-0.5, labelled left); right."""

        def __init__(self):
            self.infos = []

        def reset(self, observation, rng):
            self.step = 0

        def observe(self, info):
            self.infos.append(info)

        def choose(self, observation):
            self.step += 1
            return {1: "right", 2: Decision("right", restart=True),
                    3: Decision("left", action=np.array([-0.5], np.float32))}.get(
                        self.step, "right")

    specs = [option_spec("right", Counted(), termination=0.0)]
    script = Script()
    recording = record_episode(line_env(), specs, script, 0, np.random.default_rng(0),
                               max_steps=5, option_names=["right", "left"])
    episode = recording.episode
    assert episode.infos["option"].tolist() == [0, 0, 1, 0, 0]
    np.testing.assert_array_equal(np.asarray(episode.actions).ravel(), [1, 1, -0.5, 1, 1])
    assert Counted.starts == 3  # the first step, the restart, after its own action
    assert len(script.infos) == 6 and script.infos[0] == {}  # the reset's and every step's
    with pytest.raises(DynoplanError, match="chose 'up', which is not an option"):
        record_episode(line_env(), specs,
                       demonstrator_from(lambda obs: Decision("up", action=np.zeros(1))), 0,
                       np.random.default_rng(0), max_steps=2)


def test_load_object_names_what_is_wrong(tmp_path):
    for ref, message in (("no_colon", "expected MODULE:NAME"),
                         ("not_a_module_xyz:f", "cannot import module"),
                         ("json:nothing_here", "has no 'nothing_here'"),
                         (f"{tmp_path}/missing.py:f", "not found")):
        with pytest.raises(DynoplanError, match=message):
            load_object(ref)
    module = tmp_path / "opts.py"
    module.write_text("VALUE = 42\n")
    assert load_object(f"{module}:VALUE") == 42


# --- command line ------------------------------------------------------------------------

MOUNT = ("from dynoplan.cli.main import app, main\n"
         "from dynoplan.cli.generic import generic_app\n"
         "if not any(g.name == 'pipeline' for g in app.registered_groups):\n"
         "    app.add_typer(generic_app, name='pipeline')\n"
         "main()\n")

OPTIONS_MODULE = textwrap.dedent('''
    import gymnasium as gym
    import numpy as np
    from gymnasium import spaces
    from dynoplan.adapters import option_spec

    class Line(gym.Env):
        def __init__(self):
            self.observation_space = spaces.Box(-100, 100, (1,), np.float64)
            self.action_space = spaces.Box(-1, 1, (1,), np.float32)

        def reset(self, *, seed=None, options=None):
            super().reset(seed=seed)
            self.x = float(self.np_random.uniform(-1, 1))
            return np.array([self.x]), {}

        def step(self, action):
            self.x += float(np.clip(action[0], -1, 1))
            done = self.x >= 5
            return np.array([self.x]), float(done), done, False, {}

    if "TestLine-v0" not in gym.registry:
        gym.register("TestLine-v0", entry_point=Line, max_episode_steps=40)

    def make_options():
        return [option_spec("right", lambda o: np.array([1.0], np.float32), termination=0.1),
                option_spec("left", lambda o: np.array([-1.0], np.float32), termination=0.1)]

    def make_demonstrator():
        return lambda observation: "right"
''')


def _cli(*args, cwd=None):
    return subprocess.run([sys.executable, "-c", MOUNT, *args], capture_output=True, text=True,
                          timeout=300, cwd=cwd)


def test_cli_runs_the_pipeline_on_a_user_environment(tmp_path):
    (tmp_path / "line_options.py").write_text(OPTIONS_MODULE)
    done = _cli("pipeline", "--env", "TestLine-v0", "--options", "line_options:make_options",
                "--demos", "2", "--explore", "4", "--episodes", "3", "--horizon", "5",
                "--samples", "8", "--dynamics-epochs", "5", "--dynamics-min-updates", "50",
                "--goal-epochs", "30", "--out", "out", "--quiet", "--workers", "1",
                cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert set(summary["controllers"]) == {"demonstrator", "dynoplan", "option:right",
                                           "option:left", "random"}
    assert summary["controllers"]["option:left"]["success_rate"] == 0.0
    assert summary["command"].startswith("dynoplan pipeline --env TestLine-v0")
    assert "| dynoplan |" in done.stdout


@pytest.mark.slow
def test_cli_pipeline_on_ray_workers_gives_the_same_table_as_one_worker(tmp_path):
    (tmp_path / "line_options.py").write_text(OPTIONS_MODULE)
    common = ["pipeline", "--env", "TestLine-v0", "--options", "line_options:make_options",
              "--demos", "2", "--explore", "4", "--episodes", "6", "--horizon", "5",
              "--samples", "8", "--dynamics-epochs", "5", "--dynamics-min-updates", "50",
              "--goal-epochs", "30", "--quiet"]
    tables = {}
    for workers in ("1", "2"):
        done = _cli(*common, "--out", f"out{workers}", "--workers", workers, cwd=tmp_path)
        assert done.returncode == 0, done.stderr
        summary = json.loads((tmp_path / f"out{workers}" / "summary.json").read_text())
        tables[workers] = _comparable(summary["controllers"])
    assert tables["1"] == tables["2"]
    assert tables["1"]["option:right"]["success_rate"] == 1.0


@pytest.mark.parametrize(("args", "message"), [
    (["--env", "FrozenLake-v1", "--options", "line_options:make_options"], "needs a Box"),
    (["--env", "TestLine-v0", "--options", "line_options:nope"], "has no 'nope'"),
    (["--env", "TestLine-v0", "--options", "line_options:make_options", "--demo-dataset",
      "missing"], "dataset folder not found"),
    (["--env", "TestLine-v0", "--options", "line_options:make_options", "--replan-every",
      "-1"], "Invalid value for '--replan-every'"),
    (["--env", "TestLine-v0", "--options", "bare_options:make_options"],
     "'bare_options' defines no make_demonstrator(); give --demonstrator"),
])
def test_cli_user_errors_are_one_line_with_exit_status_2(tmp_path, monkeypatch, capsys, args,
                                                        message):
    from dynoplan.cli.generic import generic_app
    from dynoplan.cli.main import app, main

    if not any(g.name == "pipeline" for g in app.registered_groups):
        app.add_typer(generic_app, name="pipeline")
    (tmp_path / "line_options.py").write_text(OPTIONS_MODULE)
    (tmp_path / "bare_options.py").write_text("from line_options import make_options\n")
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(sys, "argv", ["dynoplan", "pipeline", *args, "--out", "out", "--quiet"])
    with pytest.raises(SystemExit) as exit_info:
        main()
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err
    assert err.startswith("dynoplan: error: ")


def test_start_states_are_labelled_by_the_demonstrators_first_choice():
    from dynoplan.pipeline import CallableDemonstrator
    from dynoplan.pipeline.collect import start_choices

    # the demonstrator starts "up" right of 0 and "back" left of it; at x < -0.5 it
    # chooses nothing, and those starts are left out
    def first(obs):
        x = float(obs[0])
        return None if x < -0.5 else ("up" if x > 0 else "back")

    starts = start_choices(line_env(), CallableDemonstrator(first), ["back", "up"], 3, 40)
    assert starts is not None
    x = starts.observations[:-1, 0]
    assert len(starts) == len(x) and 20 <= len(x) < 40  # about a quarter left out
    assert np.all(x >= -0.5) and np.array_equal(starts.observations[-1], starts.observations[-2])
    assert starts.options.tolist() == [1 if v > 0 else 0 for v in x]
    again = start_choices(line_env(), CallableDemonstrator(first), ["back", "up"], 3, 40)
    assert np.array_equal(again.observations, starts.observations)  # seeded
    assert start_choices(line_env(), CallableDemonstrator(lambda o: None), ["up"], 3, 5) is None
