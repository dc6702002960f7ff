"""``dynoplan gear seeds``: one table of each controller's mean and range over seeds."""

import json

from test_bad_input import assert_one_line_error, invoke


def _run(folder, seed, dynoplan, random, regions=None):
    folder.mkdir()
    results = [{"controller": "dynoplan", "episodes": 100, "success_rate": dynoplan,
                "time_to_success_s": 8.0 + seed, "episodes_with_contact": 10,
                "contacts_moving": 2000, "out_of_region_starts": 0},
               {"controller": "random", "episodes": 100, "success_rate": random,
                "time_to_success_s": None, "episodes_with_contact": 9,
                "contacts_moving": 1500, "out_of_region_starts": 0}]
    ablation = [{**results[0], "episodes": 30, "success_rate": 0.0}]  # dynoplan, first 30
    if regions is not None:
        ablation.append({"controller": "dynoplan_regions", "episodes": 30,
                         "success_rate": regions})
    (folder / "summary.json").write_text(json.dumps(
        {"seed": seed, "results": results, "ablation": ablation}))
    return folder


def test_the_table_gives_each_controllers_mean_and_range_over_the_seeds(tmp_path, monkeypatch,
                                                                         capsys):
    runs = [_run(tmp_path / "s0", 0, 0.95, 0.56, 0.57), _run(tmp_path / "s1", 1, 0.97, 0.50),
            _run(tmp_path / "s2", 2, 0.99, 0.44, 0.63)]
    out = tmp_path / "tables" / "seeds.md"
    code, _, err = invoke(monkeypatch, capsys, "gear", "seeds", *map(str, runs), "--out",
                          str(out))
    assert code == 0, err
    text = out.read_text()
    assert "Seeds 0, 1, 2" in text
    # the results' row, not the ablation's row of the same name (its first 30 episodes)
    assert "| `dynoplan` | 100 | 97% (95%-99%) | 9.0 (8.0-10.0) |" in text
    assert "| `random` | 100 | 50% (44%-56%) | – |" in text
    # a row only some seeds have is over those seeds
    assert "| `dynoplan_regions` | 30 | 60% (57%-63%) |" in text
    assert text.startswith("Produced by `dynoplan gear seeds ")


def test_a_folder_that_is_not_a_run_and_a_repeated_seed_are_one_line(tmp_path, monkeypatch,
                                                                     capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    code, _, err = invoke(monkeypatch, capsys, "gear", "seeds", str(empty), "--out",
                          str(tmp_path / "t.md"))
    assert_one_line_error(code, err, "summary.json")
    runs = [_run(tmp_path / "a", 0, 0.9, 0.5), _run(tmp_path / "b", 0, 0.9, 0.5)]
    code, _, err = invoke(monkeypatch, capsys, "gear", "seeds", *map(str, runs), "--out",
                          str(tmp_path / "t.md"))
    assert_one_line_error(code, err, "same seed")
    assert not (tmp_path / "t.md").exists()
