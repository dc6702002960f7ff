"""Start states widen an option's region where the task starts, and nowhere else
(``region_starts``: :func:`~dynoplan.pipeline.fit_regions.start_regions`)."""

import numpy as np
import pytest
from safetensors.numpy import load_file

from dynoplan.data import Episode
from dynoplan.errors import DynoplanError
from dynoplan.models.regions import SafetyRegions
from dynoplan.pipeline import FitSettings, fit_option_regions


def _episode(states, labels):
    x = np.asarray(states, float)
    n = len(x) - 1
    return Episode(observations=x, actions=np.zeros((n, 2)), rewards=np.zeros(n),
                   terminations=np.zeros(n, bool), truncations=np.zeros(n, bool),
                   infos={"option": np.asarray(labels[:n], np.int64)})


# demonstrations: 'reach' acts around (0, 0), then 'grasp' around (4, 4); the task's other
# start states, where the demonstrator starts 'reach' too, lie around (0, 8)
_RNG = np.random.default_rng(0)
DEMOS = [_episode(np.vstack([_RNG.normal(0.0, 0.5, (20, 2)), _RNG.normal(4.0, 0.5, (21, 2))]),
                  [0] * 20 + [1] * 20) for _ in range(5)]
STARTS = _episode(_RNG.normal([0.0, 8.0], 0.5, (61, 2)), [0] * 60)
NAMES = ["reach", "grasp", "press"]


def test_start_states_widen_only_the_region_of_the_option_chosen_there():
    plain, _ = fit_option_regions(DEMOS, [], NAMES, FitSettings(), seed=0)
    widened, report = fit_option_regions(DEMOS, [], NAMES, FitSettings(), seed=0,
                                         starts=[STARTS])
    assert report["start_states"] == {"reach": 60}
    assert widened.option_names == plain.option_names  # no option of its own
    at_starts = _RNG.normal([0.0, 8.0], 0.3, (50, 2))
    assert plain.contains(at_starts, "reach").mean() < 0.05
    assert widened.contains(at_starts, "reach").mean() > 0.9
    # where the demonstrations ran each option, the widened regions admit what they did
    demo_states = np.vstack([e.observations[:-1] for e in DEMOS])
    labels = np.concatenate([e.infos["option"] for e in DEMOS])
    for k, name in enumerate(NAMES[:2]):
        own = demo_states[labels == k]
        assert widened.contains(own, name).mean() >= plain.contains(own, name).mean() - 0.02
    # a union, not one blob spanning both: between the demos' reach and the starts,
    # and where 'grasp' acts, 'reach' is still not admissible
    assert not widened.contains(np.array([[0.0, 4.0], [4.0, 4.0]]), "reach").any()
    np.testing.assert_array_equal(widened.contains(at_starts, "grasp"),
                                  plain.contains(at_starts, "grasp"))
    assert not widened.contains(at_starts, "press").any()  # never demonstrated: no region


def test_a_joined_region_is_the_union_and_survives_a_file(tmp_path):
    rng = np.random.default_rng(3)
    x = np.vstack([rng.normal(0.0, 0.5, (200, 2)), rng.normal(5.0, 0.2, (200, 2))])
    y = np.r_[np.zeros(200, int), np.ones(200, int)]
    both = SafetyRegions.fit(x, y, ["b", "a"], n_components=2, seed=0)
    joined = both.joined({"a": "b"})
    assert joined.option_names == ["b"]
    # around a's narrow cluster too, where a's density passes b's lower threshold
    # without being inside a's region
    query = np.vstack([rng.normal(2.5, 3.0, (500, 2)), rng.normal(5.0, 0.6, (300, 2))])
    union = both.contains(query, "b") | both.contains(query, "a")
    assert union.any() and not union.all()
    np.testing.assert_array_equal(joined.contains(query, "b"), union)
    np.testing.assert_array_equal(joined.contains_all(query)[:, 0], union)
    joined.save(tmp_path / "joined.safetensors")
    np.testing.assert_array_equal(
        SafetyRegions.load(tmp_path / "joined.safetensors").contains(query, "b"), union)
    # a plain fit's file holds no offsets: its bytes are those it always had
    both.save(tmp_path / "plain.safetensors")
    assert "log_offsets" not in load_file(tmp_path / "plain.safetensors")
    assert "log_offsets" in load_file(tmp_path / "joined.safetensors")
    with pytest.raises(DynoplanError, match="cannot join itself"):
        both.joined({"a": "a"})
    with pytest.raises(DynoplanError, match="unknown option"):
        both.joined({"c": "a"})
