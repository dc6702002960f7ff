"""``benchmarks/gear_controls.py``: its fit changes and its one error line."""

import pytest

from benchmarks import gear_controls


def test_generic_names_the_generic_fit_remedies_and_values_read_as_toml():
    changes = gear_controls.fit_overrides(["generic", "goal_epochs=20",
                                           "region_fit=heldout"])
    assert changes == {**gear_controls.GENERIC_FIT, "goal_epochs": 20,
                       "region_fit": "heldout"}


@pytest.mark.parametrize("item", ["nope=1", "goal_epochs"])
def test_an_unknown_fit_setting_is_one_error_line(item, tmp_path, capsys):
    code = gear_controls.main(["--run", str(tmp_path), "--fit", item,
                               "--work", str(tmp_path / "w")])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith(f"gear_controls: error: --fit {item!r}: expected KEY=VALUE")
    assert err.count("\n") == 1
    assert not (tmp_path / "w").exists()
