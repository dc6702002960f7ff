"""``benchmarks/gear_own_state.py``: the insertion's dynamics on its own state against the
planner state, on a gear run's option runs."""

import pytest

from benchmarks import gear_own_state


@pytest.mark.parametrize("args", [[], ["--fractions", "0"], ["--fractions", "x"]])
def test_a_folder_without_option_runs_or_a_bad_share_is_one_error_line(args, tmp_path, capsys):
    code = gear_own_state.main([str(tmp_path), "--seed", "0", *args])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith("error: ") and err.count("\n") == 1


@pytest.mark.slow
def test_both_models_are_measured_on_the_held_out_insertions(quick_gear_run, tmp_path, capsys):
    out = tmp_path / "own.md"
    assert gear_own_state.main([str(quick_gear_run), "--fractions", "1", "--out",
                                str(out)]) == 0
    rows = [line for line in out.read_text().splitlines() if line.startswith("| 1 |")]
    assert len(rows) == 1
    cells = [c.strip() for c in rows[0].strip("|").split("|")]
    planner, own = (float(v) for v in cells[2].split(" / "))
    assert planner > 0 and own > 0  # both fitted and measured, in cm
    assert "Held-out insertion transitions:" in out.read_text()
