"""Safety regions (Eq. 5): the formula, calibration, any dimension, storage."""

import numpy as np
import pytest
from scipy.stats import multivariate_normal

from dynoplan.errors import DynoplanError
from dynoplan.models.regions import SafetyRegions


def _two_clusters(rng, d=2, n=300):
    a = rng.normal(0.0, 0.5, size=(n, d))
    b = rng.normal(4.0, 0.5, size=(n, d))
    return np.vstack([a, b]), np.r_[np.zeros(n, int), np.ones(n, int)]


def test_eq5_matches_a_hand_computation_in_2d():
    rng = np.random.default_rng(0)
    x, y = _two_clusters(rng)
    regions = SafetyRegions.fit(x, y, ["a", "b"], n_components=4, seed=0)
    query = rng.normal(2.0, 2.0, size=(50, 2))
    for k, name in enumerate(["a", "b"]):
        expected = np.zeros(len(query))
        for i in np.flatnonzero(regions.members[k]):
            prec_chol = regions.precisions_cholesky[i]
            cov = np.linalg.inv(prec_chol @ prec_chol.T)
            pdf = multivariate_normal(regions.means[i], cov).pdf(query)
            expected = np.maximum(expected, pdf)
        np.testing.assert_allclose(regions.likelihood(query, name), expected, rtol=1e-8)


def test_a_state_asked_about_again_gets_the_answer_a_fresh_mixture_gives():
    """The controller asks about one state for every option in turn; the answers come from
    memory then, and must stay those of a mixture that never saw a question."""
    rng = np.random.default_rng(2)
    x, y = _two_clusters(rng)
    regions = SafetyRegions.fit(x, y, ["a", "b"], n_components=4, seed=0)
    fresh = SafetyRegions(*_parts(regions))
    states = rng.normal(2.0, 2.0, size=(6, 2))
    for s in [states[0], states[0], states[1], states[0], states[1] + 1e-12]:
        for name in ["a", "b", "a"]:
            never_asked = SafetyRegions(*_parts(regions))
            assert regions.contains(s[None], name) == never_asked.contains(s[None], name)
            np.testing.assert_array_equal(regions.log_likelihood(s[None], name),
                                          never_asked.log_likelihood(s[None], name))
    np.testing.assert_array_equal(regions.contains_all(states), fresh.contains_all(states))
    with pytest.raises(ValueError):  # the remembered answer cannot be changed by a caller
        regions.component_log_density(states[:1])[0, 0] = 0.0


def _parts(regions):
    return (regions.option_names, regions.means, regions.precisions_cholesky,
            regions.members, regions.log_thresholds)


def test_each_option_owns_the_components_of_its_states():
    rng = np.random.default_rng(1)
    x, y = _two_clusters(rng)
    regions = SafetyRegions.fit(x, y, ["a", "b"], n_components=2, seed=0)
    assert regions.members.sum() == 2
    assert not (regions.members[0] & regions.members[1]).any()


def test_regions_hold_their_demonstrations_and_exclude_far_states():
    rng = np.random.default_rng(2)
    x, y = _two_clusters(rng, d=5, n=400)
    regions = SafetyRegions.fit(x, y, ["a", "b"], seed=0)  # M chosen by BIC
    held_out, held_y = _two_clusters(np.random.default_rng(3), d=5, n=400)
    inside_a = regions.contains(held_out[held_y == 0], "a").mean()
    inside_b = regions.contains(held_out[held_y == 1], "b").mean()
    assert inside_a >= 0.95 and inside_b >= 0.95
    far = np.full((10, 5), 30.0)
    assert not regions.contains_all(far).any()
    # the state in a's cluster is not in b's region
    assert not regions.contains(np.zeros((1, 5)), "b")[0]


def test_save_and_load_round_trip_bit_exactly(tmp_path):
    rng = np.random.default_rng(4)
    x, y = _two_clusters(rng)
    regions = SafetyRegions.fit(x, y, ["a", "b"], n_components=3, seed=0)
    path = regions.save(tmp_path / "regions.safetensors")
    loaded = SafetyRegions.load(path)
    assert loaded.option_names == ["a", "b"]
    for field in ("means", "precisions_cholesky", "members", "log_thresholds"):
        np.testing.assert_array_equal(getattr(loaded, field), getattr(regions, field))


def test_corrupt_and_missing_files_are_rejected_with_one_line(tmp_path):
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"\x00\x01garbage")
    with pytest.raises(DynoplanError, match="not a readable model file"):
        SafetyRegions.load(bad)
    with pytest.raises(DynoplanError, match="not found"):
        SafetyRegions.load(tmp_path / "missing.safetensors")
    rng = np.random.default_rng(5)
    x, y = _two_clusters(rng)
    path = SafetyRegions.fit(x, y, ["a", "b"], n_components=2).save(tmp_path / "r.safetensors")
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(DynoplanError):
        SafetyRegions.load(path)


def test_bad_fitting_input_is_a_clear_error():
    x = np.zeros((10, 2))
    with pytest.raises(DynoplanError, match="no demonstration states"):
        SafetyRegions.fit(x, np.zeros(10, int), ["a", "b"])
    x[0, 0] = np.nan
    with pytest.raises(DynoplanError, match="NaN"):
        SafetyRegions.fit(x, np.r_[np.zeros(5, int), np.ones(5, int)], ["a", "b"])
    regions = SafetyRegions.fit(np.random.default_rng(0).normal(size=(20, 2)),
                                np.r_[np.zeros(10, int), np.ones(10, int)], ["a", "b"],
                                n_components=1)
    with pytest.raises(DynoplanError, match="unknown option 'c'"):
        regions.contains(np.zeros((1, 2)), "c")
    with pytest.raises(DynoplanError, match=r"shape \(batch, 2\)"):
        regions.contains(np.zeros((1, 3)), "a")


def _mixture_sample(rng, n):
    """A known distribution: two elongated Gaussians in 3-D, labels 0 and 1."""
    a = rng.normal(0.0, [0.5, 0.1, 2.0], size=(n, 3))
    b = rng.normal([4.0, 1.0, -3.0], [1.0, 0.3, 0.2], size=(n, 3))
    return np.vstack([a, b]), np.r_[np.zeros(n, int), np.ones(n, int)]


def test_heldout_fit_covers_fresh_states_at_the_stated_rate():
    x, y = _mixture_sample(np.random.default_rng(0), 120)
    groups = np.r_[np.arange(120) // 20, 100 + np.arange(120) // 20]  # six "demonstrations" each
    regions, report = SafetyRegions.fit_heldout(x, y, ["a", "b"], groups, coverage=0.9,
                                                max_components=3, seed=0)
    assert report["method"] == "heldout" and report["per_option"]["a"]["heldout_states"] == 120
    fresh, fresh_y = _mixture_sample(np.random.default_rng(1), 4000)
    for k in (0, 1):
        inside = regions.contains(fresh[fresh_y == k], k).mean()
        assert 0.85 <= inside <= 0.97, (k, inside)
    assert not regions.contains_all(np.full((4, 3), 40.0)).any()


def test_heldout_fit_is_the_same_in_any_units():
    """Standardisation: scaling one dimension by 1000 does not change membership."""
    x, y = _mixture_sample(np.random.default_rng(2), 80)
    scaled = x * np.array([1.0, 1000.0, 1.0])
    query, _ = _mixture_sample(np.random.default_rng(3), 200)
    r1, _ = SafetyRegions.fit_heldout(x, y, ["a", "b"], n_components=2, seed=0)
    r2, _ = SafetyRegions.fit_heldout(scaled, y, ["a", "b"], n_components=2, seed=0)
    np.testing.assert_array_equal(r1.contains_all(query),
                                  r2.contains_all(query * np.array([1.0, 1000.0, 1.0])))


def test_merged_and_nowhere_regions():
    x, y = _two_clusters(np.random.default_rng(6))
    a = SafetyRegions.fit(x[y == 0], np.zeros(int((y == 0).sum()), int), ["a"], n_components=1)
    b = SafetyRegions.fit(x[y == 1], np.zeros(int((y == 1).sum()), int), ["b"], n_components=1)
    merged = SafetyRegions.merge(SafetyRegions.merge(a, b), SafetyRegions.nowhere(["c"], 2))
    assert merged.option_names == ["a", "b", "c"] and merged.n_components == 2
    np.testing.assert_array_equal(merged.contains(x, "a"), a.contains(x, "a"))
    np.testing.assert_array_equal(merged.contains(x, "b"), b.contains(x, "b"))
    assert not merged.contains(x, "c").any() and not merged.contains_all(x)[:, 2].any()
    with pytest.raises(DynoplanError, match="both regions hold"):
        SafetyRegions.merge(a, a)
