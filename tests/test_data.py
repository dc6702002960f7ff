"""Episodes and datasets: bit-exact round trips, clear errors, atomic writes, Minari."""

import json
import os
import warnings
from pathlib import Path

import gymnasium as gym
import h5py
import numpy as np
import pytest

from dynoplan.data import (
    FORMAT_VERSION,
    Dataset,
    DatasetMetadata,
    Episode,
    EpisodeFieldError,
    dataset_path,
    read_dataset,
    write_dataset,
)
from dynoplan.data import dataset as dataset_module
from dynoplan.errors import DynoplanError
from dynoplan.pipeline.fit_data import labelled_states, option_transitions

OPTIONS = ["pick", "fast_move", "cautious_move", "insert"]
DATASET_ID = "dynoplan/gear-assembly/expert-v0"


def make_episode(rng: np.random.Generator, steps: int = 6, seed: int | None = None) -> Episode:
    """A gear-assembly-like demonstration: float32 observations, labelled steps."""
    return Episode(
        observations=rng.normal(size=(steps + 1, 5)).astype(np.float32),
        actions=rng.normal(size=(steps, 3)),
        rewards=rng.normal(size=steps),
        terminations=np.arange(steps) == steps - 1,
        truncations=np.zeros(steps, dtype=bool),
        infos={
            "option": rng.integers(0, len(OPTIONS), size=steps),
            "progress": np.sort(rng.uniform(size=steps)),
            "stage": rng.integers(0, 5, size=steps).astype(np.int32),
            "min_human_distance": rng.uniform(0.1, 2.0, size=steps),
            "success": np.arange(steps) == steps - 1,
            "human/position": rng.normal(size=(steps, 3)).astype(np.float32),
        },
        seed=seed,
    )


def make_metadata(**changes) -> DatasetMetadata:
    fields = {
        "dataset_id": DATASET_ID,
        "env_id": "Pendulum-v1",
        "env_spec": gym.spec("Pendulum-v1").to_json(),
        "option_names": list(OPTIONS),
        "seed": 7,
        "extra": {"demonstrations": 2, "expert": "scripted"},
    }
    fields.update(changes)
    return DatasetMetadata(**fields)


@pytest.fixture
def episodes() -> list[Episode]:
    rng = np.random.default_rng(0)
    return [make_episode(rng, 6, seed=11), make_episode(rng, 9)]


@pytest.fixture
def written(tmp_path, episodes) -> Path:
    return write_dataset(tmp_path / "expert-v0", episodes, make_metadata())


def assert_same_episode(a: Episode, b: Episode) -> None:
    for name in ("observations", "actions", "rewards", "terminations", "truncations"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype, name
        assert x.tobytes() == y.tobytes(), name
    assert a.infos.keys() == b.infos.keys()
    for key in a.infos:
        assert a.infos[key].dtype == b.infos[key].dtype, key
        assert a.infos[key].tobytes() == b.infos[key].tobytes(), key
    assert a.seed == b.seed


def assert_one_line_error(exc: pytest.ExceptionInfo, *parts: str) -> None:
    message = str(exc.value)
    assert "\n" not in message
    for part in parts:
        assert part in message, f"{part!r} not in {message!r}"


# --- round trips ---------------------------------------------------------------------


def test_round_trip_is_bit_exact(written, episodes):
    dataset = read_dataset(written)
    assert isinstance(dataset, Dataset)
    assert len(dataset) == 2
    assert dataset.total_steps == 15
    assert dataset.path == written
    for original, loaded in zip(episodes, dataset, strict=True):
        assert_same_episode(original, loaded)
    meta = dataset.metadata
    assert meta.dataset_id == DATASET_ID
    assert meta.env_id == "Pendulum-v1"
    assert meta.env_spec == gym.spec("Pendulum-v1").to_json()
    assert meta.option_names == OPTIONS
    assert meta.seed == 7
    assert meta.extra == {"demonstrations": 2, "expert": "scripted"}
    assert meta.format_version == FORMAT_VERSION
    assert meta.observation_space == gym.spaces.Box(-np.inf, np.inf, (5,), np.float32)
    assert meta.action_space == gym.spaces.Box(-np.inf, np.inf, (3,), np.float64)


def test_layout_is_minaris(written):
    data = written / "data"
    assert sorted(os.listdir(written)) == ["data"]
    assert sorted(os.listdir(data)) == ["main_data.hdf5", "metadata.json"]
    meta = json.loads((data / "metadata.json").read_text())
    assert meta["data_format"] == "hdf5"
    assert meta["minari_version"] == "0.5.4"
    assert (meta["total_episodes"], meta["total_steps"]) == (2, 15)
    assert meta["dynoplan"]["option_names"] == OPTIONS
    with h5py.File(data / "main_data.hdf5", "r") as h5:
        group = h5["episode_0"]
        assert dict(group.attrs) == {"id": 0, "total_steps": 6, "seed": 11}
        assert "seed" not in h5["episode_1"].attrs
        assert group["observations"].shape == (7, 5)
        # Minari's convention: infos hold T+1 rows, the (unrecorded) reset info first.
        assert group["infos/option"].shape == (7,)
        assert group["infos/option"][0] == -1
        assert np.isnan(group["infos/progress"][0])
        assert group["infos/human/position"].shape == (7, 3)


def test_discrete_actions_and_given_spaces_round_trip(tmp_path):
    steps = 4
    walk = Episode(
        observations=np.arange(steps + 1, dtype=np.float64)[:, None],
        actions=np.array([1, 1, 0, 1]),
        rewards=np.array([0.0, 0.0, 0.0, 1.0]),
        terminations=[0, 0, 0, 1],
        truncations=[0, 0, 0, 0],
    )
    obs_space = gym.spaces.Box(0.0, 20.0, (1,), np.float64)
    meta = DatasetMetadata("random-walk/expert-v0", observation_space=obs_space)
    loaded = read_dataset(write_dataset(tmp_path / "walk", [walk], meta))
    assert_same_episode(walk, loaded[0])
    assert loaded[0].terminations.dtype == np.bool_
    assert loaded.metadata.action_space == gym.spaces.Discrete(2)
    assert loaded.metadata.observation_space == obs_space
    assert loaded.metadata.option_names == []


def test_read_accepts_the_data_subfolder(written):
    assert len(read_dataset(written / "data")) == 2


def test_overwrite_replaces_the_dataset(tmp_path, written, episodes):
    write_dataset(written, episodes[:1], make_metadata(seed=8))
    dataset = read_dataset(written)
    assert len(dataset) == 1
    assert dataset.metadata.seed == 8
    assert sorted(os.listdir(tmp_path)) == ["expert-v0"]


def test_dataset_path_follows_minari_root(monkeypatch, tmp_path):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    assert dataset_path(DATASET_ID) == tmp_path / DATASET_ID
    assert dataset_path(DATASET_ID, root="/data") == Path("/data") / DATASET_ID


# --- labelled arrays for learners --------------------------------------------------------


def test_the_fit_takes_labelled_states_from_a_read_dataset(written, episodes):
    dataset = read_dataset(written)
    states, labels, groups = labelled_states(list(dataset), len(OPTIONS), lambda o: o)
    assert states.shape == (15, 5)
    assert labels.dtype == np.int64
    np.testing.assert_array_equal(states[:6], episodes[0].observations[:6])
    np.testing.assert_array_equal(states[6:], episodes[1].observations[:9])
    np.testing.assert_array_equal(labels, np.concatenate([e.infos["option"] for e in episodes]))
    np.testing.assert_array_equal(groups, [0] * 6 + [1] * 9)


def test_the_fit_takes_each_options_transitions_from_a_read_dataset(written, episodes):
    pairs = option_transitions(list(read_dataset(written)), OPTIONS, lambda o: o[:2])
    for k, name in enumerate(OPTIONS):
        states, nexts = pairs[name]
        np.testing.assert_array_equal(states, np.concatenate(
            [e.observations[:-1, :2][e.infos["option"] == k] for e in episodes]))
        np.testing.assert_array_equal(nexts, np.concatenate(
            [e.observations[1:, :2][e.infos["option"] == k] for e in episodes]))
    assert sum(len(pairs[n][0]) for n in OPTIONS) == 15


def test_the_fit_refuses_unlabelled_episodes(episodes):
    unlabelled = Episode(episodes[0].observations, episodes[0].actions, episodes[0].rewards,
                         episodes[0].terminations, episodes[0].truncations,
                         {"progress": episodes[0].infos["progress"]})
    with pytest.raises(DynoplanError) as exc:
        labelled_states([unlabelled], len(OPTIONS), lambda o: o)
    assert_one_line_error(exc, "episode 0", "infos['option']")


# --- validation of episodes ---------------------------------------------------------------


def episode_fields(steps: int = 4) -> dict:
    return {
        "observations": np.zeros((steps + 1, 2)),
        "actions": np.zeros((steps, 1)),
        "rewards": np.zeros(steps),
        "terminations": np.zeros(steps, dtype=bool),
        "truncations": np.zeros(steps, dtype=bool),
        "infos": {"option": np.zeros(steps, dtype=np.int64), "progress": np.zeros(steps)},
    }


@pytest.mark.parametrize(
    ("change", "field", "expected"),
    [
        ({"observations": np.zeros((4, 2))}, "observations", "expected T+1 = 5 rows"),
        ({"observations": np.zeros(5)}, "observations", "(T+1, obs_dim)"),
        ({"actions": np.zeros((0, 1))}, "actions", "T >= 1"),
        ({"observations": np.zeros((5, 2), dtype=np.int64)}, "observations", "float dtype"),
        ({"observations": np.full((5, 2), np.nan)}, "observations", "NaN or inf at row 0"),
        ({"rewards": np.zeros(3)}, "rewards", "expected shape (T,) = (4,)"),
        ({"terminations": np.array([0, 2, 0, 0])}, "terminations", "booleans"),
        ({"infos": {"option": np.zeros(3, dtype=int)}}, "infos/option", "(T,) = (4,)"),
        ({"infos": {"stage": np.zeros(5, dtype=int)}}, "infos/stage", "T = 4 rows"),
        ({"infos": {"option": np.full(4, 0.5)}}, "infos/option", "integer values"),
        ({"infos": {"progress": np.full(4, 1.5)}}, "infos/progress", "[0, 1]"),
        ({"infos": {"note": np.array(["a"] * 4)}}, "infos/note", "numbers or booleans"),
        ({"infos": {"a": np.zeros(4), "a/b": np.zeros(4)}}, "infos/a", "group"),
        ({"seed": "1"}, "seed", "int or None"),
    ],
)
def test_episode_rejects_malformed_fields(change, field, expected):
    fields = episode_fields()
    fields.update(change)
    with pytest.raises(EpisodeFieldError) as exc:
        Episode(**fields)
    assert exc.value.field == field
    assert_one_line_error(exc, f"Episode {field}:", expected)


def test_metadata_rejects_malformed_fields():
    with pytest.raises(DynoplanError, match="dataset_id 'gear': expected Minari's form"):
        DatasetMetadata("gear")
    with pytest.raises(DynoplanError, match="option_names: names must be unique"):
        DatasetMetadata(DATASET_ID, option_names=["a", "a"])
    with pytest.raises(DynoplanError, match=r"format_version 2: .* reads versions 0\.\.1"):
        DatasetMetadata(DATASET_ID, format_version=2)
    with pytest.raises(DynoplanError, match="extra: expected JSON-serialisable"):
        DatasetMetadata(DATASET_ID, extra={"x": object()})
    with pytest.raises(DynoplanError, match=r"env_spec: expected EnvSpec\.to_json"):
        DatasetMetadata(DATASET_ID, env_spec="{not json")


# --- errors when writing ------------------------------------------------------------------


def test_write_rejects_labels_outside_option_names(tmp_path, episodes):
    target = tmp_path / "ds"
    with pytest.raises(DynoplanError) as exc:
        write_dataset(target, episodes, make_metadata(option_names=["pick", "insert"]))
    assert_one_line_error(exc, "episode 0", "infos/option", "outside 0..1 (2 option_names)")
    assert not target.exists()


def test_write_rejects_inconsistent_episodes(tmp_path, episodes):
    other = Episode(**episode_fields())
    with pytest.raises(DynoplanError) as exc:
        write_dataset(tmp_path / "ds", [episodes[0], other], make_metadata())
    assert_one_line_error(exc, "episode 1", "differ from episode 0")
    with pytest.raises(DynoplanError, match="no episodes to write"):
        write_dataset(tmp_path / "ds", [], make_metadata())


def test_write_rejects_data_outside_given_space(tmp_path, episodes):
    meta = make_metadata(observation_space=gym.spaces.Box(-1, 1, (4,), np.float32))
    with pytest.raises(DynoplanError) as exc:
        write_dataset(tmp_path / "ds", episodes, meta)
    assert_one_line_error(exc, "episode 0", "(5,)", "(4,)")


def test_write_never_replaces_a_folder_that_is_not_a_dataset(tmp_path, episodes):
    precious = tmp_path / "results"
    precious.mkdir()
    (precious / "paper.tex").write_text("keep me")
    with pytest.raises(DynoplanError) as exc:
        write_dataset(precious, episodes, make_metadata())
    assert_one_line_error(exc, str(precious), "not a dataset folder", "refusing")
    assert (precious / "paper.tex").read_text() == "keep me"


# --- atomicity ------------------------------------------------------------------------------


def failing_hdf5_writer(file: Path, episodes: list[Episode]) -> None:
    with h5py.File(file, "w") as h5:  # leave a partial file behind, then fail
        h5.create_group("episode_0")
    raise OSError("disk full")


def test_failed_write_leaves_no_dataset(tmp_path, episodes, monkeypatch):
    monkeypatch.setattr(dataset_module, "_write_hdf5", failing_hdf5_writer)
    target = tmp_path / "ds"
    with pytest.raises(OSError, match="disk full"):
        write_dataset(target, episodes, make_metadata())
    assert os.listdir(tmp_path) == []


def test_failed_overwrite_keeps_the_old_dataset(tmp_path, written, episodes, monkeypatch):
    before = {p.name: p.read_bytes() for p in (written / "data").iterdir()}

    def failing_json(path, obj):
        raise OSError("no space left")

    monkeypatch.setattr(dataset_module, "write_json", failing_json)
    with pytest.raises(OSError, match="no space left"):
        write_dataset(written, episodes[:1], make_metadata())
    assert sorted(os.listdir(tmp_path)) == ["expert-v0"]
    assert {p.name: p.read_bytes() for p in (written / "data").iterdir()} == before
    assert len(read_dataset(written)) == 2


# --- errors when reading --------------------------------------------------------------------


def edit_metadata(folder: Path, **changes) -> None:
    file = folder / "data" / "metadata.json"
    doc = json.loads(file.read_text())
    for key, value in changes.items():
        target = doc["dynoplan"] if key in doc["dynoplan"] else doc
        target[key] = value
    file.write_text(json.dumps(doc))


def test_read_missing_folder_or_files(tmp_path, written):
    with pytest.raises(DynoplanError) as exc:
        read_dataset(tmp_path / "absent")
    assert_one_line_error(exc, "absent", "dataset folder not found")
    (written / "data" / "metadata.json").unlink()
    with pytest.raises(DynoplanError) as exc:
        read_dataset(written)
    assert_one_line_error(exc, "metadata.json", "file not found")
    (written / "data" / "main_data.hdf5").unlink()
    with pytest.raises(DynoplanError) as exc:
        read_dataset(written)
    assert_one_line_error(exc, "main_data.hdf5", "file not found")


def test_read_truncated_hdf5(written):
    file = written / "data" / "main_data.hdf5"
    data = file.read_bytes()
    file.write_bytes(data[: len(data) // 2])
    with pytest.raises(DynoplanError) as exc:
        read_dataset(written)
    assert_one_line_error(exc, str(file), "truncated or corrupt")


def test_read_garbage_hdf5(written):
    file = written / "data" / "main_data.hdf5"
    file.write_bytes(b"not an hdf5 file at all" * 10)
    with pytest.raises(DynoplanError) as exc:
        read_dataset(written)
    assert_one_line_error(exc, "main_data.hdf5", "truncated or corrupt")


def rewrite(folder: Path, path: str, values: np.ndarray | None) -> None:
    with h5py.File(folder / "data" / "main_data.hdf5", "a") as h5:
        del h5[path]
        if values is not None:
            h5.create_dataset(path, data=values)


def declare(folder: Path, path: str, shape: tuple[int, ...], dtype: str = "f8") -> None:
    """Replace ``path`` by a chunked dataset that declares ``shape`` and stores nothing
    (the file stays small; reading it would allocate all of it)."""
    with h5py.File(folder / "data" / "main_data.hdf5", "a") as h5:
        del h5[path]
        h5.create_dataset(path, shape=shape, dtype=dtype, chunks=(1, *shape[1:2], *[1] * (
            len(shape) - 2)), maxshape=(None, *shape[1:]))


@pytest.mark.parametrize(("path", "shape", "needle"), [
    ("episode_0/observations", (10**12, 10**9), "declares 1000000000000 rows"),
    ("episode_1/actions", (3, 10**12), "beyond the"),
    ("episode_1/infos/human/position", (10, 2**40, 4), "beyond the"),
    ("episode_0/rewards", (17,), "more than total_steps + 1 = 16"),
])
def test_read_bounds_declared_shapes_before_reading(written, path, shape, needle):
    """A file that declares a huge dataset is refused before any array is allocated."""
    declare(written, path, shape)
    assert (written / "data" / "main_data.hdf5").stat().st_size < 10**6
    with pytest.raises(DynoplanError) as exc:
        read_dataset(written)
    assert_one_line_error(exc, "main_data.hdf5", path.partition("/")[2], needle)


def test_read_missing_episode_group(written):
    rewrite(written, "episode_1", None)
    with pytest.raises(DynoplanError) as exc:
        read_dataset(written)
    assert_one_line_error(exc, "main_data.hdf5", "episode_1", "missing", "total_episodes = 2")


def test_read_missing_dataset(written):
    rewrite(written, "episode_0/rewards", None)
    with pytest.raises(DynoplanError) as exc:
        read_dataset(written)
    assert_one_line_error(exc, "main_data.hdf5", "episode_0/rewards", "missing")


def test_read_observations_without_t_plus_one_rows(written, episodes):
    rewrite(written, "episode_1/observations", episodes[1].observations[:-1])
    with pytest.raises(DynoplanError) as exc:
        read_dataset(written)
    assert_one_line_error(exc, "main_data.hdf5", "episode_1/observations", "T+1 = 10 rows")


def test_read_labels_of_wrong_length(written):
    rewrite(written, "episode_0/infos/option", np.zeros(3, dtype=np.int64))
    with pytest.raises(DynoplanError) as exc:
        read_dataset(written)
    assert_one_line_error(exc, "episode_0/infos/option", "expected T+1 = 7 rows")


def test_read_nan_observations(written, episodes):
    bad = episodes[0].observations.copy()
    bad[3, 1] = np.nan
    rewrite(written, "episode_0/observations", bad)
    with pytest.raises(DynoplanError) as exc:
        read_dataset(written)
    assert_one_line_error(exc, "main_data.hdf5", "episode_0/observations", "NaN or inf at row 3")


def test_read_newer_format_version(written):
    edit_metadata(written, format_version=FORMAT_VERSION + 1)
    with pytest.raises(DynoplanError) as exc:
        read_dataset(written)
    assert_one_line_error(exc, "metadata.json", "dynoplan.format_version", "upgrade")


def test_read_labels_outside_option_names(written):
    edit_metadata(written, option_names=["pick"])
    with pytest.raises(DynoplanError) as exc:
        read_dataset(written)
    assert_one_line_error(exc, "episode_0/infos/option", "outside 0..0 (1 option_names)")


@pytest.mark.parametrize(
    ("change", "expected"),
    [
        ({"total_steps": 14}, "total_steps is 14 but the episodes hold 15 steps"),
        ({"total_episodes": "2"}, "field 'total_episodes': expected int"),
        ({"seed": True}, "field 'dynoplan.seed': expected int or null"),
        ({"data_format": "arrow"}, "field 'data_format': expected 'hdf5'"),
        ({"action_space": '{"type": "Text"}'}, "Text spaces are not supported"),
    ],
)
def test_read_malformed_metadata(written, change, expected):
    edit_metadata(written, **change)
    with pytest.raises(DynoplanError) as exc:
        read_dataset(written)
    assert_one_line_error(exc, "metadata.json", expected)


def test_read_invalid_json(written):
    (written / "data" / "metadata.json").write_text("{ truncated")
    with pytest.raises(DynoplanError) as exc:
        read_dataset(written)
    assert_one_line_error(exc, "metadata.json", "not a readable dataset metadata file")


# --- Minari reads our datasets, we read Minari's ---------------------------------------------
# Run when the dev extra minari[hdf5]==0.5.4 is installed; skipped otherwise.


def test_minari_loads_our_dataset(tmp_path, episodes, monkeypatch):
    minari = pytest.importorskip("minari")
    pytest.importorskip("PIL")  # minari's HDF5 reader imports Pillow, which minari[hdf5] omits
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    write_dataset(dataset_path(DATASET_ID), episodes, make_metadata())

    loaded = minari.load_dataset(DATASET_ID)
    assert loaded.total_episodes == 2
    assert loaded.total_steps == 15
    assert loaded.env_spec.id == "Pendulum-v1"
    assert DATASET_ID in minari.list_local_datasets()
    for ours, theirs in zip(episodes, loaded.iterate_episodes(), strict=True):
        np.testing.assert_array_equal(theirs.observations, ours.observations)
        np.testing.assert_array_equal(theirs.actions, ours.actions)
        np.testing.assert_array_equal(theirs.rewards, ours.rewards)
        np.testing.assert_array_equal(theirs.terminations, ours.terminations)
        # Minari's infos start with the reset row.
        np.testing.assert_array_equal(theirs.infos["option"][1:], ours.infos["option"])
        np.testing.assert_array_equal(
            theirs.infos["human"]["position"][1:], ours.infos["human/position"]
        )
    seeds = [m.get("seed") for m in loaded.storage.get_episode_metadata([0, 1])]
    assert seeds == [11, None]


def test_we_read_a_dataset_written_by_minari(tmp_path, monkeypatch):
    minari = pytest.importorskip("minari")
    pytest.importorskip("PIL")  # minari's HDF5 reader imports Pillow, which minari[hdf5] omits
    from minari.data_collector import EpisodeBuffer

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    rng = np.random.default_rng(1)
    steps = 5
    buffer = EpisodeBuffer(
        seed=3,
        observations=rng.normal(size=(steps + 1, 4)).astype(np.float32),
        actions=rng.integers(0, 2, size=steps),
        rewards=list(rng.normal(size=steps)),
        terminations=[False] * (steps - 1) + [True],
        truncations=[False] * steps,
        infos={"progress": np.linspace(0.0, 1.0, steps + 1)},
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Minari warns about missing author, permalink, ...
        minari.create_dataset_from_buffers(
            "other/walk-v0",
            [buffer],
            observation_space=gym.spaces.Box(-np.inf, np.inf, (4,), np.float32),
            action_space=gym.spaces.Discrete(2),
            author="someone",
        )
    dataset = read_dataset(dataset_path("other/walk-v0"))
    assert dataset.metadata.format_version == 0
    assert dataset.metadata.extra["author"] == ["someone"]
    episode = dataset[0]
    assert episode.seed == 3
    np.testing.assert_array_equal(episode.observations, buffer.observations)
    np.testing.assert_array_equal(episode.infos["progress"], np.linspace(0.0, 1.0, steps + 1)[1:])
