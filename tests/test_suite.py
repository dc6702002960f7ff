"""The composition suite: its tasks keep the contract and their demonstrators succeed; a
task whose package is missing is skipped with one line; a small run writes the table."""

import json

import pytest

from benchmarks.suite import __main__ as suite
from benchmarks.suite import compare, regions, registry, rerun, trace
from dynoplan.pipeline import probe_options, record_demonstrations

INSTALLED = [e for e in registry.TASKS if e.missing() is None]


@pytest.mark.parametrize("entry", INSTALLED, ids=[e.name for e in INSTALLED])
def test_every_installed_task_keeps_the_contract_and_its_demonstrator_succeeds(entry):
    task = entry.load()
    env = task.make_env()
    options = task.module.make_options()
    assert len(options) >= 3 and probe_options(env, options) >= 1
    demos = record_demonstrations(env, options, task.module.make_demonstrator(), episodes=2,
                                  seed=0, max_attempts=2)  # both attempts succeed
    used = {int(k) for demo in demos for k in demo.options}
    assert len(used) >= 2, "the demonstrator chains options"
    assert len(used) < len(options), "at least one option (a distractor) is never used"
    disturbed = task.make_env(disturbed=True)
    assert disturbed.reset(seed=1)[0].shape == env.reset(seed=1)[0].shape
    assert isinstance(task.module.DISTURBANCE, str) and task.module.DISTURBANCE


def test_a_task_whose_package_is_missing_is_skipped_with_one_line(tmp_path, monkeypatch,
                                                                  capsys):
    absent = registry.SuiteEntry("absent", "benchmarks.suite.tasks.absent",
                                 "no_such_package_dynoplan", "absent")
    monkeypatch.setattr(registry, "TASKS", (absent,))
    assert suite.main(["--tasks", "absent", "--out", str(tmp_path)]) == 0
    err = capsys.readouterr().err
    assert err == ("skipped absent: needs the 'no_such_package_dynoplan' package "
                   "(pip install 'dynoplan[absent]')\n")
    assert json.loads((tmp_path / "suite.json").read_text())["tasks"] == []


def test_a_trace_of_a_missing_run_is_one_error_line(tmp_path, capsys):
    assert trace.main([str(tmp_path), "minigrid-doorkey", "0"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("trace: error: ") and err.count("\n") == 1
    assert trace.main([str(tmp_path), "minigrid-doorkey", "0", "--set", "fit.stride=2"]) == 2
    assert "control.*" in capsys.readouterr().err
    assert regions.main([str(tmp_path), "minigrid-doorkey", "0"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("regions: error: ") and err.count("\n") == 1


def test_an_unknown_task_or_setting_is_one_error_line(tmp_path, capsys):
    assert suite.main(["--tasks", "nope", "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().err.startswith("suite: error: unknown suite task(s) nope")
    assert suite.main(["--set", "control.horizn=3", "--out", str(tmp_path)]) == 2
    assert "unknown setting 'control.horizn'" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.skipif(registry.select("minigrid-doorkey")[0].missing() is not None,
                    reason="needs minigrid (pip install 'dynoplan[minigrid]')")
def test_a_small_suite_run_writes_every_row_with_the_demonstrator_as_the_bar(tmp_path,
                                                                            capsys):
    assert suite.main(["--tasks", "minigrid-doorkey", "--seeds", "0", "--episodes", "3",
                       "--set", "demos=3", "--set", "exploration_episodes=4",
                       "--set", "fit.dynamics_epochs=5", "--set", "fit.dynamics_min_updates=50",
                       "--set", "fit.goal_epochs=30",
                       "--set", "control.samples=8", "--out", str(tmp_path)]) == 0
    result = json.loads((tmp_path / "suite.json").read_text())
    row = result["tasks"][0]
    assert row["task"] == "minigrid-doorkey" and row["demonstrator"] == [1.0]
    assert row["best_option"] == [0.0]  # the task needs composition
    assert len(row["disturbed_dynoplan"]) == 1
    run = result["runs"][0]
    assert set(run["controllers"]) >= {"demonstrator", "dynoplan", "random"}
    # the cost of a task, on the clock and on the processor
    assert row["cpu_s"] > 0 and row["wall_s"] > 0
    # the task's elapsed time spans its run, within the whole command's
    assert 0 < row["elapsed_s"] <= result["elapsed_s"]
    assert abs(row["elapsed_s"] - run["wall_s"]) < 1.0  # one seed, run alone
    assert "| minigrid-doorkey |" in (tmp_path / "suite.md").read_text()
    assert "CPU (s)" in (tmp_path / "suite.md").read_text()
    # DynoPlan again on the saved models, and with the goal fitted again as the run
    # fitted it: the run's own row both times
    for extra in ([], ["--set", "fit.goal_epochs=30"]):
        table = tmp_path / "rerun.md"
        assert rerun.main([str(tmp_path), *extra, "--out", str(table)]) == 0
        cells = [c.strip() for c in table.read_text().splitlines()[-1].split("|")[1:-1]]
        assert cells[0] == "minigrid-doorkey" and cells[1:3] == cells[3:5]
    assert rerun.main([str(tmp_path), "--set", "fit.stride=2"]) == 2
    # the same episodes decision by decision: the run's own success
    capsys.readouterr()
    assert trace.main([str(tmp_path), "minigrid-doorkey", "0", "--decisions", "0"]) == 0
    lines = capsys.readouterr().out.splitlines()
    rate = run["controllers"]["dynoplan"]["success_rate"]
    assert lines[-1] == f"DynoPlan: {round(3 * rate)} of 3 (the run's: {rate:.2f})"
    assert lines[0].startswith("  step    0  G ")  # episode 0's first decision
    # with the goal fitted again as the run fitted it: the run's own success again
    assert trace.main([str(tmp_path), "minigrid-doorkey", "0", "--set",
                       "fit.goal_epochs=30"]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == lines[-1]
    assert trace.main([str(tmp_path), "minigrid-doorkey", "0", "--set", "fit.stride=2"]) == 2
    assert "fit.goal_*" in capsys.readouterr().err
    assert sum(line[0].isdigit() for line in lines) == 3  # one line per episode
    # how far the regions reach: on fresh demonstrations, without and with start states
    assert regions.main([str(tmp_path), "minigrid-doorkey", "0", "--fresh", "2",
                         "--starts", "5"]) == 0
    out = capsys.readouterr().out
    assert out.count("fresh states inside their option's region: go_to_key ") == 2
    assert "regions on the demonstrations and 5 start states:" in out


def test_compare_merges_groups_of_tasks_and_gives_the_mean_and_the_disturbed_rows(tmp_path):
    def task(name, ours, disturbed):
        return {"task": name, "demonstrator": [1.0, 1.0], "dynoplan": ours,
                "disturbed_demonstrator": [1.0, 0.5], "disturbed_dynoplan": disturbed}

    for folder, tasks in (("a", [task("cart", [1.0, 0.5], [0.5, 0.5])]),
                          ("b", [task("door", [1.0, 1.0], [0.0, 0.0])])):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "suite.json").write_text(json.dumps(
            {"settings": {"demos": 10}, "tasks": tasks}))
    table = compare.compare([str(tmp_path / "a"), str(tmp_path / "b")]).splitlines()
    assert table[0] == "| settings changed | cart | door | mean ratio |"
    assert table[2] == "| demos=10 | 1.00 / 0.50 (0.75) | 1.00 / 1.00 (1.00) | 0.875 |"
    assert table[3] == ("| disturbed, demos=10 | 0.50 / 0.50 (0.67) | 0.00 / 0.00 (0.00) "
                        "| 0.333 |")
