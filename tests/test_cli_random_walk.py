"""`dynoplan random-walk` end to end: outputs, determinism, bad input."""

import json
import subprocess
import sys

import pytest

CLI = [sys.executable, "-c", "from dynoplan.cli.main import main; main()"]


def _run(*args, check=True):
    return subprocess.run([*CLI, *args], capture_output=True, text=True, check=check,
                          timeout=300)


@pytest.mark.slow
def test_random_walk_writes_summary_figures_and_is_deterministic(tmp_path):
    common = ["random-walk", "--episodes", "40", "--seed", "5", "--quiet"]
    _run(*common, "--out", str(tmp_path / "a"))
    _run(*common, "--out", str(tmp_path / "b"))
    a = json.loads((tmp_path / "a" / "summary.json").read_text())
    b = json.loads((tmp_path / "b" / "summary.json").read_text())
    for key in ("success_rate", "planning_steps_median", "planning_steps_p90", "episodes",
                "noise", "seconds"):
        assert key in a
    assert a["episodes"] == 40 and a["noise"] == 0.2
    assert set(a["baselines"]) == {"option:right_0.9", "option:right_0.5", "option:right_0.2",
                                   "option:random", "option:left_0.5", "random"}
    assert [r["noise"] for r in a["robustness"]] == [0.0, 0.1, 0.2, 0.3, 0.4, 0.5]

    def strip(summary):
        for row in [summary, *summary["baselines"].values(), *summary["robustness"]]:
            row.pop("seconds")
            row.pop("cpu_seconds")
        return summary

    assert strip(a) == strip(b)
    for name in ("figure_mdp_solution.png", "robustness.png", "robustness.csv"):
        assert (tmp_path / "a" / name).stat().st_size > 1000 or name.endswith(".csv")
    assert not list((tmp_path / "a").glob(".*tmp*"))  # no temporary files left behind


@pytest.mark.slow
def test_depth_two_and_one_by_one_reach_the_goal_on_the_walk(tmp_path):
    for flags in (["--depth", "2"], ["--one-by-one"], ["--one-by-one", "--depth", "2"]):
        out = tmp_path / "-".join(flags)
        _run("random-walk", "--episodes", "30", "--quiet", "--out", str(out), *flags)
        summary = json.loads((out / "summary.json").read_text())
        assert summary["success_rate"] == 1.0, flags
        assert summary["planning_steps_median"] <= 7, flags
        assert summary["settings"]["depth"] == (2 if "2" in flags else 1)
        assert summary["settings"]["lockstep"] == ("--one-by-one" not in flags)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--noise", "-0.1"], "--noise must be a probability"),
        (["--episodes", "0"], "Invalid value for '--episodes'"),
        (["--no-such-flag"], "No such option"),
        (["--start-state", "20"], "--start-state must be in"),
        (["--depth", "0"], "Invalid value for '--depth'"),
    ],
)
def test_bad_arguments_give_one_line_and_exit_2(tmp_path, args, message):
    result = _run("random-walk", "--out", str(tmp_path / "o"), *args, check=False)
    assert result.returncode == 2
    assert result.stderr.strip().count("\n") == 0, result.stderr
    assert message in result.stderr
    assert "Traceback" not in result.stderr
    assert not (tmp_path / "o" / "summary.json").exists()


def test_unwritable_output_folder_is_one_clear_line(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    result = _run("random-walk", "--episodes", "1", "--out", str(blocker / "out"), check=False)
    assert result.returncode == 2
    assert result.stderr.strip() == f"dynoplan: error: cannot write to {blocker}: not a directory"
