"""Learned goal heuristic G(s): accuracy on held-out demonstrations, sampling, storage."""

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from dynoplan.data.episodes import Episode
from dynoplan.errors import DynoplanError
from dynoplan.models.goal import GoalHeuristic
from dynoplan.models.goal_network import (
    GoalNetwork,
    GoalTrainingReport,
    evaluate_goal,
    goal_training_set,
    progress_from_episode,
)
from dynoplan.models.regions import SafetyRegions
from dynoplan.models.storage import load_arrays, save_arrays

Trained = tuple[GoalNetwork, GoalTrainingReport, np.ndarray]


def _curve(p: np.ndarray, amp: float, offset: np.ndarray) -> np.ndarray:
    """A curved 5-D path; progress ``p`` is a smooth function of the state."""
    s = np.stack(
        [amp * np.cos(np.pi * p), amp * np.sin(np.pi * p), 2.0 * p**2,
         0.5 * np.sin(2.0 * np.pi * p), p], axis=1)
    return s + offset


def _demonstrations(seed: int, n: int,
                    steps: int = 60) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` noisy demonstrations: states ``(n*steps, 5)``, progress, demonstration ids."""
    rng = np.random.default_rng(seed)
    states: list[np.ndarray] = []
    progress: list[np.ndarray] = []
    ids: list[np.ndarray] = []
    for i in range(n):
        p = progress_from_episode(steps)
        s = _curve(p, rng.uniform(0.8, 1.2), rng.normal(0.0, 0.1, 5))
        states.append(s + rng.normal(0.0, 0.03, s.shape))
        progress.append(p)
        ids.append(np.full(steps, i))
    return np.concatenate(states), np.concatenate(progress), np.concatenate(ids)


@pytest.fixture(scope="module", autouse=True)
def _one_torch_thread() -> Iterator[None]:
    """Small networks gain nothing from intra-op threads, and on a shared CPU two
    spinning threads can make training ten times slower; restore the setting after."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def trained() -> Trained:
    x, y, ids = _demonstrations(0, 10)
    net, report = GoalNetwork.fit(x, y, hidden=64, epochs=100, batch_size=128,
                                  holdout_fraction=0.2, groups=ids, seed=0)
    return net, report, ids


def test_training_reduces_holdout_loss_and_holds_out_whole_demonstrations(trained: Trained) -> None:
    _, report, ids = trained
    assert len(report.train_loss) == len(report.holdout_loss) == 100
    assert report.n_train + report.n_holdout == len(ids)
    assert report.n_holdout == 2 * 60  # 20% of the 10 demonstrations, whole
    assert len(np.unique(ids[report.holdout_index])) == 2
    assert report.train_loss[-1] < report.train_loss[0] - 1.5
    best = report.holdout_loss[report.best_epoch]
    assert best == min(report.holdout_loss)
    assert best < report.holdout_loss[0] - 1.5


def test_heldout_trials_track_ground_truth_progress(trained: Trained) -> None:
    net = trained[0]
    x, y, _ = _demonstrations(1, 4)  # trials never seen in training
    scores = evaluate_goal(net, x, y)
    assert scores["spearman"] >= 0.95
    assert scores["mae"] <= 0.1
    assert scores["coverage_90"] >= 0.7
    # the start of a trial reads as near 0 and its end as near 1
    mean, _ = net.mean_std(x[[0, 59]])
    assert mean[0] < 0.1 and mean[1] > 0.9


def test_goal_network_is_a_goal_heuristic(trained: Trained) -> None:
    assert isinstance(trained[0], GoalHeuristic)


def test_samples_lie_in_unit_interval_and_repeat_with_the_seed(trained: Trained) -> None:
    net = trained[0]
    x, _, _ = _demonstrations(2, 2)
    a = net.sample(x, np.random.default_rng(7))
    b = net.sample(x, np.random.default_rng(7))
    c = net.sample(x, np.random.default_rng(8))
    assert a.shape == (len(x),) and a.dtype == np.float64
    assert np.all((a >= 0.0) & (a <= 1.0))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    # drawing does not touch torch's global random state
    before = torch.get_rng_state()
    net.sample(x, np.random.default_rng(0))
    assert torch.equal(before, torch.get_rng_state())


@pytest.mark.parametrize("members", [1, 3])
def test_mean_std_match_the_sampled_distribution(trained: Trained, members: int) -> None:
    if members == 1:
        net = trained[0]
    else:
        x, y, _ = _demonstrations(0, 6)
        net, _ = GoalNetwork.fit(x, y, hidden=32, members=3, epochs=40, seed=1)
    x, _, _ = _demonstrations(3, 1)
    states = x[[0, 15, 30, 45, 59]]
    mean, std = net.mean_std(states)
    draws = net.sample(np.repeat(states, 20000, axis=0), np.random.default_rng(0))
    draws = draws.reshape(len(states), 20000)
    np.testing.assert_allclose(draws.mean(axis=1), mean, atol=4 * std.max() / np.sqrt(20000))
    np.testing.assert_allclose(draws.std(axis=1), std, rtol=0.05)
    # the 90% interval holds ~90% of the draws
    lo, hi = net.interval(states, 0.9)
    inside = ((draws >= lo[:, None]) & (draws <= hi[:, None])).mean(axis=1)
    np.testing.assert_allclose(inside, 0.9, atol=0.02)


def test_fit_is_deterministic_given_the_seed_and_leaves_global_rng_alone() -> None:
    x, y, _ = _demonstrations(4, 3, steps=30)
    torch.manual_seed(123)
    before = torch.get_rng_state()
    a, ra = GoalNetwork.fit(x, y, hidden=16, epochs=5, seed=3, holdout_fraction=0.3)
    assert torch.equal(before, torch.get_rng_state())
    torch.manual_seed(999)  # a different global state must not matter
    b, rb = GoalNetwork.fit(x, y, hidden=16, epochs=5, seed=3, holdout_fraction=0.3)
    c, _ = GoalNetwork.fit(x, y, hidden=16, epochs=5, seed=4, holdout_fraction=0.3)
    assert ra.train_loss == rb.train_loss and ra.holdout_loss == rb.holdout_loss
    np.testing.assert_array_equal(a.mean_std(x)[0], b.mean_std(x)[0])
    assert not np.array_equal(a.mean_std(x)[0], c.mean_std(x)[0])


@pytest.mark.parametrize("members", [1, 2])
def test_save_and_load_round_trip_bit_exactly(tmp_path: Path, members: int) -> None:
    x, y, _ = _demonstrations(5, 3, steps=30)
    net, _ = GoalNetwork.fit(x, y, hidden=16, members=members, epochs=5, seed=0)
    path = net.save(tmp_path / "goal.safetensors")
    loaded = GoalNetwork.load(path)
    assert (loaded.state_dim, loaded.hidden, loaded.members) == (5, 16, members)
    for got, want in zip(loaded.mean_std(x), net.mean_std(x), strict=True):
        np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(loaded.sample(x, np.random.default_rng(1)),
                                  net.sample(x, np.random.default_rng(1)))
    _, meta = load_arrays(path, "goal_network")
    assert meta["state_dim"] == 5 and meta["hidden"] == 16 and meta["members"] == members


def test_corrupt_or_mismatched_files_are_rejected(tmp_path: Path) -> None:
    x, y, _ = _demonstrations(6, 2, steps=20)
    net, _ = GoalNetwork.fit(x, y, hidden=8, epochs=2, seed=0)
    path = net.save(tmp_path / "goal.safetensors")

    truncated = tmp_path / "truncated.safetensors"
    truncated.write_bytes(path.read_bytes()[:-40])
    garbage = tmp_path / "garbage.safetensors"
    garbage.write_bytes(b"\x00" * 64)
    regions = SafetyRegions.fit(x, (y > 0.5).astype(int), ["a", "b"], n_components=2)
    other_kind = regions.save(tmp_path / "regions.safetensors")
    arrays, meta = load_arrays(path, "goal_network")
    meta = {k: v for k, v in meta.items() if k not in ("kind", "format_version")}
    wrong_shape = save_arrays(tmp_path / "shape.safetensors", "goal_network",
                              {**arrays, "w2": arrays["w2"][:, :4]}, meta)
    not_finite = save_arrays(tmp_path / "nan.safetensors", "goal_network",
                             {**arrays, "b1": np.full_like(arrays["b1"], np.nan)}, meta)
    bad_meta = save_arrays(tmp_path / "meta.safetensors", "goal_network", arrays,
                           {**meta, "hidden": "eight"})

    cases = [
        (tmp_path / "missing.safetensors", "not found"),
        (truncated, "not a readable model file"),
        (garbage, "not a readable model file"),
        (other_kind, "holds a 'safety_regions' model"),
        (wrong_shape, "array 'w2' has shape"),
        (not_finite, "array 'b1' must be finite"),
        (bad_meta, "metadata lacks valid"),
    ]
    for file, message in cases:
        with pytest.raises(DynoplanError, match=message):
            GoalNetwork.load(file)


def test_bad_inputs_are_rejected_with_a_clear_message() -> None:
    x, y, _ = _demonstrations(7, 2, steps=20)
    bad_x = x.copy()
    bad_x[3, 2] = np.nan
    cases: list[tuple[tuple[np.ndarray, np.ndarray], dict[str, Any], str]] = [
        ((x[:, 0], y), {}, "states must have shape"),
        ((x, y[:-1]), {}, "progress must have shape"),
        ((bad_x, y), {}, "states contain NaN"),
        ((x, np.where(np.arange(len(y)) == 5, np.nan, y)), {}, "progress contains NaN"),
        ((x, y + 0.5), {}, r"progress must lie in \[0, 1\]"),
        ((x, y - 0.5), {}, r"progress must lie in \[0, 1\]"),
        ((x, y), {"epochs": 0}, "epochs must be a positive integer"),
        ((x, y), {"hidden": 2.5}, "hidden must be a positive integer"),
        ((x, y), {"lr": -1.0}, "lr must be positive"),
        ((x, y), {"holdout_fraction": 1.0}, "holdout_fraction must be in"),
        ((x, y), {"holdout_fraction": 0.5, "groups": np.zeros(3)}, "groups must have shape"),
        ((x, y), {"holdout_fraction": 0.5, "groups": np.zeros(len(y))}, "both must be non-empty"),
    ]
    for args, kwargs, message in cases:
        with pytest.raises(DynoplanError, match=message):
            GoalNetwork.fit(*args, epochs=kwargs.pop("epochs", 1), **kwargs)

    net, _ = GoalNetwork.fit(x, y, hidden=8, epochs=1)
    with pytest.raises(DynoplanError, match=r"states must have shape \(batch, 5\)"):
        net.mean_std(x[:, :4])
    with pytest.raises(DynoplanError, match=r"states must have shape \(batch, 5\)"):
        net.sample(x[0], np.random.default_rng(0))
    with pytest.raises(DynoplanError, match="progress must lie"):
        evaluate_goal(net, x, y * 2.0)


def test_progress_targets_from_demonstrations_without_labels() -> None:
    np.testing.assert_array_equal(progress_from_episode(5), [0.0, 0.25, 0.5, 0.75, 1.0])
    np.testing.assert_array_equal(progress_from_episode(1), [1.0])
    with pytest.raises(DynoplanError, match="positive integer"):
        progress_from_episode(0)

    def episode(steps: int, offset: float) -> Episode:
        obs = np.arange(steps + 1, dtype=np.float64)[:, None] + np.array([[0.0, offset]])
        return Episode(observations=obs, actions=np.zeros(steps), rewards=np.zeros(steps),
                       terminations=np.arange(steps) == steps - 1,
                       truncations=np.zeros(steps, dtype=bool))

    states, progress, groups = goal_training_set([episode(4, 0.0), episode(2, 1.0)])
    assert states.shape == (8, 2)
    np.testing.assert_array_equal(progress, [0, 0.25, 0.5, 0.75, 1, 0, 0.5, 1])
    np.testing.assert_array_equal(groups, [0, 0, 0, 0, 0, 1, 1, 1])
    only_first, _, _ = goal_training_set([episode(4, 0.0)], state_fn=lambda o: o[:, :1])
    assert only_first.shape == (5, 1)
    with pytest.raises(DynoplanError, match="no episodes"):
        goal_training_set([])


def test_evaluate_goal_scores_any_goal_heuristic() -> None:
    class Oracle:
        """Knows the true progress (the last state coordinate) up to a little spread."""

        def sample(self, states: np.ndarray, rng: np.random.Generator) -> np.ndarray:
            return np.clip(states[:, -1] + rng.normal(0, 0.01, len(states)), 0, 1)

        def mean_std(self, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            return states[:, -1].copy(), np.full(len(states), 0.05)

    p = np.linspace(0.05, 0.95, 50)
    states = np.stack([np.zeros_like(p), p], axis=1)
    scores = evaluate_goal(Oracle(), states, p)
    assert scores == pytest.approx({"spearman": 1.0, "mae": 0.0, "coverage_90": 1.0})
    shifted = evaluate_goal(Oracle(), states, np.clip(p + 0.3, 0, 1))
    assert shifted["mae"] > 0.2 and shifted["coverage_90"] < 0.2
    with pytest.raises(DynoplanError, match="not a GoalHeuristic"):
        evaluate_goal(object(), states, p)  # type: ignore[arg-type]
