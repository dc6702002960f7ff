"""`dynoplan gear demos`: demonstrations as a dataset, read back and validated."""

import subprocess
import sys

import numpy as np
import pytest

from dynoplan.data import read_dataset
from dynoplan.envs.gear.demonstrations import record_demos
from dynoplan.envs.gear.options import gear_option_names
from dynoplan.errors import DynoplanError


@pytest.fixture(scope="module")
def demos(tmp_path_factory):
    out = tmp_path_factory.mktemp("demos") / "gear-demos"
    summary = record_demos(2, seed=3, out=out, progress=False)
    return out, summary


def test_demonstrations_round_trip_with_labels_and_progress(demos):
    out, summary = demos
    dataset = read_dataset(out)
    assert len(dataset) == 2 and summary["success_rate"] == 1.0
    assert dataset.metadata.option_names == list(gear_option_names())
    assert dataset.metadata.env_id == "dynoplan/GearAssembly-v0"
    for episode in dataset:
        labels = episode.infos["option"]
        assert set(np.unique(labels)) >= {0, 1, 3}  # pick, fast move, insert at least
        assert labels[0] == 0 and labels[-1] == 3
        progress = episode.infos["progress"]
        assert np.all(np.diff(progress) > 0) and progress[-1] == 1.0
        assert episode.observations.shape[1] == 50


def test_a_truncated_dataset_is_rejected_in_one_line(demos, tmp_path):
    out, _ = demos
    broken = tmp_path / "broken"
    (broken / "data").mkdir(parents=True)
    (broken / "data" / "metadata.json").write_bytes((out / "data" / "metadata.json").read_bytes())
    data = (out / "data" / "main_data.hdf5").read_bytes()
    (broken / "data" / "main_data.hdf5").write_bytes(data[: len(data) // 2])
    with pytest.raises(DynoplanError, match="truncated or corrupt") as info:
        read_dataset(broken)
    assert "\n" not in str(info.value)


def test_cli_rejects_zero_demonstrations_in_one_line_before_training_anything(tmp_path):
    # the default demonstrator, the operator, needs the option networks: a bad request
    # fails before they are trained (a minute), not after
    result = subprocess.run(
        [sys.executable, "-c", "from dynoplan.cli.main import main; main()", "gear", "demos",
         "--n", "0", "--out", str(tmp_path / "d"), "--models", str(tmp_path / "m")],
        capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        "dynoplan: error: Invalid value for '--n': Input should be greater than or equal to 1"]
    assert not (tmp_path / "d").exists() and not (tmp_path / "m").exists()


def test_cli_rejects_an_unknown_demonstrator_in_one_line(tmp_path):
    result = subprocess.run(
        [sys.executable, "-c", "from dynoplan.cli.main import main; main()", "gear", "demos",
         "--n", "2", "--demonstrator", "teacher", "--out", str(tmp_path / "d"),
         "--models", str(tmp_path / "m")],
        capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        "dynoplan: error: unknown demonstrator 'teacher'; expected one of options, expert"]
    assert not (tmp_path / "d").exists() and not (tmp_path / "m").exists()
