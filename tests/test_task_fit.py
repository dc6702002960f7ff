"""Tasks over option models learned once (``dynoplan task fit``), and options on their own
state spaces (``Option.state_map``)."""

import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from dynoplan.data.dataset import read_dataset, write_dataset
from dynoplan.data.episodes import OPTION_KEY, Episode
from dynoplan.data.metadata import DatasetMetadata
from dynoplan.envs.random_walk import NoisyWalkGoal, make_random_walk_options
from dynoplan.envs.random_walk.tasks import (
    make_demonstrator,
    make_options,
    reach_10,
    reach_15,
    reach_20,
    walk_state,
)
from dynoplan.errors import DynoplanError
from dynoplan.models.folder import file_sha256, read_manifest
from dynoplan.options.state_map import CoordinateMap, IdentityMap, MappedDynamics
from dynoplan.pipeline import ControllerSettings, FitSettings, PipelineSettings, run_pipeline
from dynoplan.pipeline.collect import collect_transitions, make_env
from dynoplan.pipeline.fit import FittedModels
from dynoplan.pipeline.gym_task import task_env
from dynoplan.pipeline.task_fit import run_task
from dynoplan.planning import OptionPlanner

WALK = "dynoplan/RandomWalk19-v0"
TASKS = "dynoplan.envs.random_walk.tasks"
SMALL = PipelineSettings(
    demos=3, exploration_episodes=10, exploration_option_steps=30, episodes=10, seed=1,
    fit=FitSettings(dynamics_hidden=(32, 32), dynamics_members=2, dynamics_epochs=20,
                    dynamics_min_updates=200, goal_hidden=32, goal_epochs=150, regions=False),
    control=ControllerSettings(samples=16, max_decisions=200),
    controllers=("dynoplan",))


@pytest.fixture(scope="module")
def options_folder(tmp_path_factory):
    """The walk's option dynamics fitted once, on the task "reach 20"."""
    out = tmp_path_factory.mktemp("walk") / "options"
    run_pipeline(WALK, make_options(), demonstrator=make_demonstrator(), settings=SMALL,
                 out=out, state_fn=walk_state, success=reach_20)
    return out


@pytest.fixture(scope="module")
def two_tasks(options_folder, tmp_path_factory):
    """Two tasks, "reach 10" and "reach 15", on those dynamics: ``{goal: (result, out)}``."""
    root = tmp_path_factory.mktemp("tasks")
    return {goal: (run_task(WALK, options_folder, make_options(),
                            demonstrator=make_demonstrator(), settings=SMALL,
                            out=root / f"reach-{goal}", state_fn=walk_state, success=success),
                   root / f"reach-{goal}")
            for goal, success in ((10, reach_10), (15, reach_15))}


def test_one_options_folder_serves_two_tasks(options_folder, two_tasks):
    source = read_manifest(options_folder / "models")
    sha = {n: file_sha256(p) for n, p in source.dynamics.items() if p is not None}
    assert len(sha) == 5
    for goal, (result, out) in two_tasks.items():
        needed = result.summary["task_fit"]
        # the task needed only its own demonstrations, and says how many and how long
        assert needed["demonstrations"] == SMALL.demos
        assert needed["fit_seconds"] > 0
        manifest = read_manifest(out / "models")
        # the options' dynamics, byte for byte, in a folder that loads on its own
        assert {n: file_sha256(p) for n, p in manifest.dynamics.items()
                if p is not None} == sha
        assert manifest.extra["options_models"]["dynamics_sha256"] == sha
        # and each task is solved on them
        assert result.evaluation["dynoplan"]["success_rate"] >= 0.9, goal
    # each task has its own goal heuristic: state 10 is the end of the first task only
    at_10 = {goal: float(FittedModels.load(out / "models").goal.mean_std(
        np.array([[10.0]]))[0][0]) for goal, (_, out) in two_tasks.items()}
    assert at_10[10] > at_10[15] + 0.1, at_10


def test_a_task_with_an_option_the_folder_lacks_is_one_line(options_folder, tmp_path):
    module = tmp_path / "more_options.py"
    module.write_text(
        "from dynoplan.adapters import option_spec\n"
        f"from {TASKS} import make_options as walk_options, make_demonstrator\n"
        "def make_options():\n"
        "    return [*walk_options(), option_spec('jump', lambda s: 1, termination=1.0)]\n")
    out = tmp_path / "out"
    proc = _task_fit_cli(options_folder, out, options=f"{module}:make_options")
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("dynoplan: error: ") and "'jump'" in lines[0], lines[0]
    assert "right_0.9" in lines[0]  # says which options the folder has
    assert not out.exists()


def _task_fit_cli(options_folder, out, *extra, options=f"{TASKS}:make_options"):
    """``dynoplan task fit`` of "reach 10" on ``options_folder`` in a subprocess."""
    return subprocess.run(
        [sys.executable, "-c", "from dynoplan.cli.main import main; main()", "task", "fit",
         "--options-models", str(options_folder), "--env", WALK, "--options", options,
         "--state-fn", f"{TASKS}:walk_state", "--success", f"{TASKS}:reach_10",
         "--no-regions", "--workers", "1", "--quiet", "--out", str(out), *extra],
        capture_output=True, text=True, timeout=300)


def test_the_tasks_own_option_runs_reach_its_fit(options_folder, two_tasks, tmp_path):
    """``runs=``: the goal heuristic of "reach 10" is fitted with its own exploration in
    place of the options folder's ("reach 20"); the dynamics stay the folder's, byte for
    byte, and models.json says where the runs came from."""
    names = [s.name for s in make_options()]
    env = task_env(make_env(WALK), reach_10, walk_state)
    own = collect_transitions(env, make_options(), 6, 7, max_option_steps=30)
    write_dataset(tmp_path / "runs", own, DatasetMetadata("test/reach-10-runs-v0",
                                                          option_names=names))
    result = run_task(WALK, options_folder, make_options(), demonstrator=make_demonstrator(),
                      settings=replace(SMALL, episodes=2), out=tmp_path / "out",
                      state_fn=walk_state, success=reach_10, runs=tmp_path / "runs")
    manifest = read_manifest(tmp_path / "out" / "models")
    record = manifest.extra["options_models"]
    assert record["runs"] == {"source": str((tmp_path / "runs").resolve()),
                              "episodes": len(own), "steps": sum(len(e) for e in own)}
    assert result.summary["task_fit"]["option_runs"] == record["runs"]
    folder_runs = read_manifest(two_tasks[10][1] / "models").extra["options_models"]["runs"]
    assert folder_runs["source"] == str((options_folder / "transitions").resolve())
    source = read_manifest(options_folder / "models")
    for name, file in source.dynamics.items():
        assert file is not None and manifest.dynamics[name] is not None
        assert manifest.dynamics[name].read_bytes() == file.read_bytes()
    # the same demonstrations and seeds, other option runs: another goal heuristic
    states = np.arange(19, dtype=np.float64)[:, None]
    with_runs = result.models.goal.mean_std(states)[0]
    without = two_tasks[10][0].models.goal.mean_std(states)[0]
    assert result.summary["models"]["goal"]["off_demo_states"] == sum(
        len(e) + 1 for e in own)
    assert not np.allclose(with_runs, without)


def test_the_tasks_improvement_rounds_refit_its_goal_not_the_dynamics(options_folder,
                                                                      tmp_path):
    """run_task's improvement rounds (run_pipeline's): DynoPlan's own episodes of "reach
    10" refit the task's goal heuristic; the dynamics stay the folder's, byte for byte;
    the learning curve, the own episodes and the runs they gave are recorded."""
    settings = replace(SMALL, episodes=2, improve_episodes=4, improve_keep="last")
    runs = {}
    for name, s in (("improved", settings), ("plain", replace(settings, improve=0))):
        runs[name] = run_task(WALK, options_folder, make_options(),
                              demonstrator=make_demonstrator(), settings=s,
                              out=tmp_path / name, state_fn=walk_state, success=reach_10)
    improved, plain = runs["improved"].summary, runs["plain"].summary
    assert "improvement" not in plain and "improvement" not in plain["task_fit"]
    assert [c["round"] for c in improved["improvement"]] == [1]  # "last": no check batch
    assert improved["task_fit"]["improvement"]["own_episodes"] == 8  # 4 measured, 4 exploring
    record = read_manifest(tmp_path / "improved" / "models").extra["options_models"]
    assert record["own_runs"]["episodes"] > 0 and record["own_runs"]["steps"] > 0
    source = read_manifest(options_folder / "models")
    manifest = read_manifest(tmp_path / "improved" / "models")
    for name, file in source.dynamics.items():
        assert file is not None and manifest.dynamics[name] is not None
        assert manifest.dynamics[name].read_bytes() == file.read_bytes()
    states = np.arange(19, dtype=np.float64)[:, None]
    assert not np.allclose(runs["improved"].models.goal.mean_std(states)[0],
                           runs["plain"].models.goal.mean_std(states)[0])
    assert improved["models"]["goal"]["off_demo_states"] > plain["models"]["goal"][
        "off_demo_states"]


def test_a_task_fit_with_the_same_seed_writes_the_same_bytes(options_folder, tmp_path):
    """Two task fits of "reach 10" with the same seed and its improvement round write the
    same models folder, byte for byte, manifest included (no timing in it)."""
    settings = replace(SMALL, episodes=2, improve_episodes=4)
    for name in ("a", "b"):
        run_task(WALK, options_folder, make_options(), demonstrator=make_demonstrator(),
                 settings=settings, out=tmp_path / name, state_fn=walk_state,
                 success=reach_10)
    files = sorted(p.name for p in (tmp_path / "a" / "models").iterdir())
    assert "models.json" in files and "goal.safetensors" in files
    assert files == sorted(p.name for p in (tmp_path / "b" / "models").iterdir())
    for file in files:
        assert ((tmp_path / "a" / "models" / file).read_bytes()
                == (tmp_path / "b" / "models" / file).read_bytes()), file


def _with_outcome_initiation(options_folder, out, goal_judged: bool = False):
    """A copy of the walk's options folder ``out`` with an initiation learned from outcome
    runs (the options' own ends, as ``gear outcomes`` learns it): the first option may
    start left of 10, the second right of 10. ``goal_judged``: the report says it judged
    the runs by the folder's goal (``FitSettings.outcome_initiation``)."""
    import shutil

    from dynoplan.models.folder import INITIATION_FILE, set_initiation
    from dynoplan.models.outcome_initiation import OutcomeInitiation

    shutil.copytree(options_folder, out)
    models = FittedModels.load(out / "models")
    states = np.arange(19, dtype=np.float64)[:, None].repeat(4, axis=0)
    names = models.option_names
    initiation, _ = OutcomeInitiation.fit(
        {names[0]: states, names[1]: states},
        {names[0]: states[:, 0] < 10, names[1]: states[:, 0] > 10}, seed=0)
    if goal_judged:
        models = replace(models, report={**models.report, "outcome_initiation": {"fitted": 1}})
        models.save(out / "models")
    initiation.save(out / "models" / INITIATION_FILE)
    set_initiation(out / "models", INITIATION_FILE)
    return out


def test_a_task_reuses_the_options_initiation_learned_from_their_outcomes(options_folder,
                                                                          tmp_path):
    """What the options folder learned of where each option works (its initiation from
    outcome runs) travels with the dynamics, byte for byte, and limits where the task's
    options may start with run_task(reuse_initiation=True); without it (the default) it
    is left out, and an initiation that judged the runs by the first task's goal is never
    reused."""
    settings = replace(SMALL, episodes=2, improve=0)
    folder = _with_outcome_initiation(options_folder, tmp_path / "options")
    source = read_manifest(folder / "models")
    results = {}
    for name, reuse in (("reused", {"reuse_initiation": True}), ("left-out", {})):
        results[name] = run_task(WALK, folder, make_options(),
                                 demonstrator=make_demonstrator(), settings=settings,
                                 out=tmp_path / name, state_fn=walk_state, success=reach_10,
                                 **reuse)
    manifest = read_manifest(tmp_path / "reused" / "models")
    assert source.initiation is not None and manifest.initiation is not None
    assert manifest.initiation.path.read_bytes() == source.initiation.path.read_bytes()
    record = manifest.extra["options_models"]
    assert record["initiation_sha256"] == file_sha256(source.initiation.path)
    assert results["reused"].summary["task_fit"]["reused_initiation"] is True
    first = results["reused"].options[0]
    assert first.initiation.contains(np.array([[3.0]]))[0]
    assert not first.initiation.contains(np.array([[16.0]]))[0]
    assert read_manifest(tmp_path / "left-out" / "models").initiation is None
    assert results["left-out"].summary["task_fit"]["reused_initiation"] is False
    judged = _with_outcome_initiation(options_folder, tmp_path / "judged", goal_judged=True)
    result = run_task(WALK, judged, make_options(), demonstrator=make_demonstrator(),
                      settings=settings, out=tmp_path / "judged-task", state_fn=walk_state,
                      success=reach_10, reuse_initiation=True)
    assert read_manifest(tmp_path / "judged-task" / "models").initiation is None
    assert result.summary["task_fit"]["reused_initiation"] is False


def test_option_runs_of_another_option_set_are_one_line(options_folder, tmp_path):
    runs = read_dataset(options_folder / "transitions")
    names = [s.name for s in make_options()]
    write_dataset(tmp_path / "jump", runs.episodes[:2],
                  DatasetMetadata("test/jump-v0", option_names=["jump", *names[1:]]))
    for dataset, needles in ((tmp_path / "jump", ("'jump'", "option runs")),
                             (tmp_path / "missing", ("dataset folder not found",))):
        proc = _task_fit_cli(options_folder, tmp_path / "out", "--runs", str(dataset))
        assert proc.returncode == 2, proc.stderr
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1, proc.stderr
        assert lines[0].startswith(f"dynoplan: error: {dataset}"), lines[0]
        assert all(n in lines[0] for n in needles), lines[0]
        assert not (tmp_path / "out").exists()


def test_option_runs_of_another_state_size_are_an_error(options_folder):
    wide = Episode(np.zeros((3, 2)), np.zeros(2, np.int64), np.zeros(2), np.zeros(2, bool),
                   np.zeros(2, bool), {OPTION_KEY: np.array([0, 1])})
    with pytest.raises(DynoplanError, match="option run 0 has states of 2 values, the "
                                            "option dynamics read 1"):
        run_task(WALK, options_folder, make_options(), demonstrator=make_demonstrator(),
                 settings=SMALL, state_fn=walk_state, success=reach_10, runs=[wide])


def test_coordinate_map_round_trips():
    state_map = CoordinateMap(4, (2, 0))
    s = np.random.default_rng(0).normal(size=(5, 4))
    z = state_map.to_option(s)
    assert z.shape == (5, 2) and np.array_equal(z, s[:, [2, 0]])
    assert np.array_equal(state_map.to_planner(s, z), s)  # planner -> option -> planner
    new = z + 1.0
    back = state_map.to_planner(s, new)
    assert np.array_equal(state_map.to_option(back), new)  # option -> planner -> option
    assert np.array_equal(back[:, [1, 3]], s[:, [1, 3]])  # the rest is not the option's
    with pytest.raises(ValueError):
        CoordinateMap(3, (0, 3))


def test_identity_map_rolls_out_as_without():
    options = make_random_walk_options(0.2)
    mapped = [replace(o, state_map=IdentityMap(1)) for o in options]
    goal = NoisyWalkGoal(0.2)
    for state in (0.0, 7.0, 18.0):
        plain = OptionPlanner(options, goal, horizon=20, samples=64).plan(
            np.array([state]), np.random.default_rng(5))
        same = OptionPlanner(mapped, goal, horizon=20, samples=64).plan(
            np.array([state]), np.random.default_rng(5))
        assert same.chosen == plain.chosen
        np.testing.assert_array_equal(same.end_states, plain.end_states)
        np.testing.assert_array_equal(same.scores, plain.scores)


def test_an_option_is_rolled_in_its_own_state_and_scored_in_the_task():
    """A 2-D planner state ``(position, battery)``: the walk's option knows only the
    position; the battery, which it does not change, stays as it is in its rollouts."""
    walk = make_random_walk_options(0.0)[2]  # right, beta 0.2
    option = replace(walk, state_map=CoordinateMap(2, (0,)))
    assert isinstance(option.planner_dynamics, MappedDynamics)
    assert option.planner_dynamics.state_dim == 2

    class PositionGoal:
        def sample(self, states, rng):
            return np.clip(states[:, 0] / 20.0, 0, 1)

        def mean_std(self, states):
            return np.clip(states[:, 0] / 20.0, 0, 1), np.zeros(len(states))

    plan = OptionPlanner([option], PositionGoal(), horizon=5, samples=32).plan(
        np.array([3.0, 0.7]), np.random.default_rng(0))
    ends = plan.end_states[0]
    assert np.all(ends[:, 1] == 0.7)
    assert np.all(ends[:, 0] == 3.0 + plan.steps[0])  # one step right per model step
    assert plan.scores[0] > 3.0 / 20.0


def test_options_on_their_own_state_are_fitted_saved_and_solve_the_task(tmp_path):
    """A planner state (position, 0.5): each option's dynamics are fitted on the position
    alone, the models folder says so and loads, and the task is solved."""
    mapped = [replace(spec, state_map=CoordinateMap(2, (0,))) for spec in make_options()]

    def with_flag(observation):
        return np.array([float(observation), 0.5])

    result = run_pipeline(WALK, mapped, demonstrator=make_demonstrator(), settings=SMALL,
                          out=tmp_path / "run", state_fn=with_flag, success=reach_20)
    assert all(m.state_dim == 1 for m in result.models.dynamics.values())
    loaded = FittedModels.load(tmp_path / "run" / "models")
    assert loaded.option_state_dims == {spec.name: 1 for spec in mapped}
    assert all(o.planner_dynamics.state_dim == 2 for o in loaded.build(mapped)[1])
    assert result.evaluation["dynoplan"]["success_rate"] >= 0.9


def test_a_tasks_own_controllers_on_one_worker_give_the_same_table(options_folder,
                                                                    two_tasks, tmp_path):
    """``own_controllers``: the task rebuilds its controllers from the saved models
    (``Task.make_runner``, as workers do) on one worker too; for a user's task those are
    the pipeline's, so the episodes are the same."""
    from dynoplan.pipeline import GymTask

    task = GymTask(WALK, f"{TASKS}:make_options", f"{TASKS}:reach_10", f"{TASKS}:walk_state")
    own = run_task(task.make_env(), options_folder, make_options(),
                   demonstrator=make_demonstrator(), settings=SMALL, out=tmp_path / "own",
                   task=task, own_controllers=True)
    generic = two_tasks[10][0].evaluation["dynoplan"]
    assert own.evaluation["dynoplan"]["success_rate"] == generic["success_rate"]
    assert own.evaluation["dynoplan"]["env_steps_mean"] == generic["env_steps_mean"]
