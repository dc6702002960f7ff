"""Neural ensemble dynamics: training, storage, stacking, seeding, evaluation helpers."""

import copy

import numpy as np
import pytest
import torch
from scipy.stats import ks_2samp, norm

from dynoplan.errors import DynoplanError
from dynoplan.models.dynamics import DynamicsModel, LoopStackedDynamics, stack_dynamics
from dynoplan.models.ensemble_rollouts import StackedMLPEnsemble
from dynoplan.models.evaluation import (
    calibration,
    mixture_quantile,
    one_step_error,
    option_end_gap,
)
from dynoplan.models.neural_dynamics import MLPEnsembleDynamics
from dynoplan.models.storage import save_arrays
from dynoplan.options import ConstantTermination, FunctionPolicy, Option
from dynoplan.planning import OptionPlanner


def _linear_system(n=800, d=3, noise=0.05, seed=0):
    """s' = A s + b + N(0, noise^2) (one fixed system): a known answer to learn."""
    system = np.random.default_rng(1234)
    a = np.eye(d) + 0.1 * system.normal(size=(d, d))
    b = 0.3 * system.normal(size=d)
    rng = np.random.default_rng(seed)
    s = rng.normal(size=(n, d))
    return s, s @ a.T + b + noise * rng.normal(size=(n, d))


def _trained(seed=0):
    s, nxt = _linear_system()
    model = MLPEnsembleDynamics(3, hidden_sizes=(32, 32), members=3, option="reach", seed=seed)
    report = model.fit(s, nxt, epochs=15, batch_size=64, lr=1e-2, seed=seed)
    return model, report


@pytest.fixture(scope="module")
def trained():
    return _trained()


def test_training_lowers_held_out_loss_and_beats_the_no_change_baseline(trained):
    model, report = trained
    assert isinstance(model, DynamicsModel)
    assert len(report.train_loss) == len(report.holdout_loss) == 15
    assert report.n_holdout == 80 and report.n_train == 720
    assert min(report.holdout_loss) < report.holdout_loss[0] - 0.5
    assert report.holdout_loss[report.best_epoch] == min(report.holdout_loss)
    s, nxt = _linear_system(n=400, seed=1)
    err = one_step_error(model, s, nxt)
    assert err.ratio < 0.5
    assert err.model_rmse.shape == (3,)
    cal = calibration(model, s, nxt, level=0.9)
    assert 0.75 <= cal.coverage <= 0.99
    assert cal.per_dimension.shape == (3,)


def test_training_is_repeatable_with_a_seed(trained):
    model, report = trained
    again, report_again = _trained()
    assert report.holdout_loss == report_again.holdout_loss
    for w, w2 in zip(model.network.parameters(), again.network.parameters(), strict=True):
        assert torch.equal(w, w2)


def test_save_and_load_round_trip_is_bit_exact(trained, tmp_path):
    model, _ = trained
    path = model.save(tmp_path / "reach.safetensors")
    loaded = MLPEnsembleDynamics.load(path)
    assert loaded.option == "reach"
    assert loaded.architecture == model.architecture
    for p, q in zip(model.network.state_dict().values(), loaded.network.state_dict().values(),
                    strict=True):
        assert torch.equal(p, q)
    for name in ("input_mean", "input_std", "delta_mean", "delta_std"):
        assert np.array_equal(getattr(model, name), getattr(loaded, name))
    x = np.random.default_rng(3).normal(size=(50, 3))
    assert np.array_equal(model.sample(x, np.random.default_rng(7)),
                          loaded.sample(x, np.random.default_rng(7)))


def test_corrupt_and_mismatched_files_are_rejected(trained, tmp_path):
    model, _ = trained
    good = model.save(tmp_path / "good.safetensors")
    truncated = tmp_path / "truncated.safetensors"
    truncated.write_bytes(good.read_bytes()[:200])
    with pytest.raises(DynoplanError, match="not a readable model file"):
        MLPEnsembleDynamics.load(truncated)
    with pytest.raises(DynoplanError, match="not found"):
        MLPEnsembleDynamics.load(tmp_path / "missing.safetensors")
    other = save_arrays(tmp_path / "other.safetensors", "safety_regions",
                        {"x": np.zeros(2)}, {})
    with pytest.raises(DynoplanError, match="expected 'mlp_ensemble_dynamics'"):
        MLPEnsembleDynamics.load(other)
    # metadata that disagrees with the arrays
    meta = {"state_dim": 3, "hidden_sizes": [16, 16], "members": 3, "option": "x"}
    arrays = {f"weight_{i}": np.zeros((3, a, b), np.float32)
              for i, (a, b) in enumerate([(3, 32), (32, 32), (32, 6)])}
    bad = save_arrays(tmp_path / "bad.safetensors", "mlp_ensemble_dynamics", arrays, meta)
    with pytest.raises(DynoplanError, match=r"weight_0' has shape \(3, 3, 32\)"):
        MLPEnsembleDynamics.load(bad)
    no_dim = save_arrays(tmp_path / "nodim.safetensors", "mlp_ensemble_dynamics", arrays,
                         {"hidden_sizes": [32, 32], "members": 3})
    with pytest.raises(DynoplanError, match="'state_dim' must be a positive integer"):
        MLPEnsembleDynamics.load(no_dim)


def test_bad_training_input_is_one_clear_error():
    model = MLPEnsembleDynamics(3, hidden_sizes=(8, 8), members=2)
    s = np.zeros((10, 3))
    with pytest.raises(DynoplanError, match=r"\(N, 3\)"):
        model.fit(s, np.zeros((10, 4)), epochs=1)
    with pytest.raises(DynoplanError, match="finite"):
        model.fit(s, np.full((10, 3), np.nan), epochs=1)
    with pytest.raises(DynoplanError, match="holdout_fraction"):
        model.fit(s, s, epochs=1, holdout_fraction=1.0)


def test_same_seed_same_samples_and_no_global_torch_randomness():
    model = MLPEnsembleDynamics(4, hidden_sizes=(16, 16), members=3, seed=1)
    x = np.random.default_rng(0).normal(size=(10, 4))
    torch_state = torch.get_rng_state()
    a = model.sample(x, np.random.default_rng(42))
    b = model.sample(x, np.random.default_rng(42))
    c = model.sample(x, np.random.default_rng(43))
    assert torch.equal(torch_state, torch.get_rng_state())
    assert a.dtype == np.float64 and a.shape == (10, 4)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    # the initialisation is seeded too
    same = MLPEnsembleDynamics(4, hidden_sizes=(16, 16), members=3, seed=1)
    assert np.array_equal(same.sample(x, np.random.default_rng(42)), a)


def _distinct_models(members):
    """Three ensembles whose members disagree strongly, with different normalisers."""
    models = []
    for k in range(3):
        m = MLPEnsembleDynamics(2, hidden_sizes=(16, 16), members=members, seed=10 + k)
        with torch.no_grad():
            m.network.biases[-1][:, 0, :2] += torch.arange(members)[:, None] * 2.0 - k
            m.network.biases[-1][:, 0, 2:] -= 1.5
        m.input_mean = np.array([0.5, -1.0]) * k
        m.input_std = np.array([1.0, 2.0]) + k
        m.delta_mean = np.array([0.1, -0.2]) * k
        m.delta_std = np.array([0.5, 1.5]) + 0.5 * k
        m.refresh()
        models.append(m)
    return models


@pytest.mark.parametrize("members, samples", [(4, 4000), (3, 4001)])
def test_stacked_models_match_each_model_alone_in_distribution(members, samples):
    models = _distinct_models(members)
    stacked = MLPEnsembleDynamics.stack(models)
    assert isinstance(stacked, StackedMLPEnsemble)
    starts = np.array([[0.0, 0.0], [1.0, -1.0], [-2.0, 0.5]])
    states = np.repeat(starts[:, None, :], samples, axis=1)
    together = stacked.sample(states, np.random.default_rng(0))
    assert together.shape == (3, samples, 2)
    for o, model in enumerate(models):
        alone = model.sample(states[o], np.random.default_rng(100 + o))
        for dim in range(2):
            assert ks_2samp(together[o, :, dim], alone[:, dim]).pvalue > 1e-3
        # and both match the mixture the model predicts
        means, variances = model.predict(starts[o:o + 1])
        mix_mean = means.mean(axis=0)[0]
        mix_var = (variances + means ** 2).mean(axis=0)[0] - mix_mean ** 2
        se = np.sqrt(mix_var / samples)
        np.testing.assert_array_less(np.abs(together[o].mean(axis=0) - mix_mean), 5 * se)
        np.testing.assert_allclose(together[o].var(axis=0), mix_var, rtol=0.1)


def test_every_row_uses_a_uniformly_chosen_member():
    # members predict far-apart deltas with tiny noise: the member of a row is readable
    models = _distinct_models(members=3)
    model = models[0]
    with torch.no_grad():
        model.network.weights[-1].zero_()
        model.network.max_logvar.fill_(-12.0)
    model.refresh()
    rng = np.random.default_rng(5)
    counts = np.zeros((7, 3))
    for _ in range(3000):
        out = model.sample(np.zeros((7, 2)), rng)
        member = np.rint((out[:, 0] / model.delta_std[0] + 0.0) / 2.0).astype(int)
        counts[np.arange(7), member] += 1
    assert counts.sum(axis=1).tolist() == [3000] * 7
    np.testing.assert_allclose(counts / 3000, 1 / 3, atol=0.04)


def test_planner_rollouts_keep_one_member_each():
    # constant, far-apart member deltas with tiny noise: a rollout of 5 steps ends at
    # 5 x its member's delta; drawing a member per step would give sums in between
    model = _distinct_models(members=3)[0]
    with torch.no_grad():
        model.network.weights[-1].zero_()
        model.network.max_logvar.fill_(-12.0)
    model.refresh()
    step_deltas = np.array([model.sample(np.zeros((1, 2)), np.random.default_rng(k))[0, 0]
                            for k in range(200)])
    per_member = np.unique(np.round(step_deltas, 1))
    assert len(per_member) == 3
    options = [Option("o", FunctionPolicy(lambda obs, rng: 0), model, ConstantTermination(0.0))]
    planner = OptionPlanner(options, _SigmoidGoal(), horizon=5, samples=300)
    ends = planner.rollout([0], np.zeros(2), np.random.default_rng(0)).end_states[0, :, 0]
    nearest = np.abs(ends[:, None] - 5 * per_member[None, :])
    assert nearest.min(axis=1).max() < 0.2
    counts = np.bincount(nearest.argmin(axis=1), minlength=3)
    assert counts.min() >= 60  # every member carries about a third of the rollouts


def test_one_model_stacked_alone_gives_the_same_draws():
    model = _distinct_models(members=4)[1]
    x = np.random.default_rng(1).normal(size=(9, 2))
    alone = model.sample(x, np.random.default_rng(3))
    stacked = MLPEnsembleDynamics.stack([model]).sample(x[None], np.random.default_rng(3))[0]
    assert np.array_equal(alone, stacked)


@pytest.mark.parametrize("members, samples", [(4, 12), (3, 10)])
def test_a_model_in_several_slices_of_a_stack_gives_the_draws_of_separate_copies(members,
                                                                                  samples):
    # a level of the sequence planner stacks each option once per parent branch: the
    # engine computes each distinct model once per member, for all its slices, with
    # the draws a stack of separate copies makes from the same generator
    a, b = _distinct_models(members)[:2]
    shared = MLPEnsembleDynamics.stack([a, b, a, a])
    copies = MLPEnsembleDynamics.stack([a, b, copy.deepcopy(a), copy.deepcopy(a)])
    assert isinstance(shared, StackedMLPEnsemble) and isinstance(copies, StackedMLPEnsemble)
    assert (shared.models, copies.models) == (2, 4)
    states = np.random.default_rng(1).normal(size=(4, samples, 2))
    close = {"rtol": 1e-6, "atol": 1e-6}  # the products' blocks differ in size: rounding
    np.testing.assert_allclose(shared.sample(states, np.random.default_rng(0)),
                               copies.sample(states, np.random.default_rng(0)), **close)
    steps = [s.trajectory_sampler(samples, np.random.default_rng(2)) for s in (shared, copies)]
    for _ in range(3):
        np.testing.assert_allclose(steps[0](states), steps[1](states), **close)
    np.testing.assert_array_equal(steps[0].members, steps[1].members)


def test_options_that_share_one_model_roll_out_as_with_copies_of_it():
    # two options with one model object but different terminations: the planner keeps
    # their rollouts apart (row order) and draws as it does for two copies of the model
    a, b = _distinct_models(3)[:2]

    def options(third):
        return [Option(f"o{k}", FunctionPolicy(lambda obs, rng: 0), model,
                       ConstantTermination(beta))
                for k, (model, beta) in enumerate([(a, 0.0), (b, 0.1), (third, 0.3)])]

    idx, start = (0, 1, 2, 0), np.zeros(2)
    rolls = [OptionPlanner(options(m), _SigmoidGoal(), horizon=6, samples=9).rollout(
        idx, start, np.random.default_rng(0)) for m in (a, copy.deepcopy(a))]
    np.testing.assert_allclose(rolls[0].end_states, rolls[1].end_states, rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(rolls[0].steps, rolls[1].steps)
    np.testing.assert_array_equal(rolls[0].members, rolls[1].members)
    assert 0 < rolls[0].steps[2].mean() < rolls[0].steps[0].mean() == 6


def test_mixed_architectures_fall_back_to_a_loop():
    a = MLPEnsembleDynamics(2, hidden_sizes=(8, 8), members=2)
    b = MLPEnsembleDynamics(2, hidden_sizes=(16, 16), members=2)
    stacked = stack_dynamics([a, b])
    assert isinstance(stacked, LoopStackedDynamics)
    assert stacked.sample(np.zeros((2, 5, 2)), np.random.default_rng(0)).shape == (2, 5, 2)


class _SigmoidGoal:
    def sample(self, states, rng):
        return 1.0 / (1.0 + np.exp(-states[:, 0]))

    def mean_std(self, states):
        return self.sample(states, None), np.zeros(len(states))


def test_planner_rolls_out_neural_options_in_one_stack():
    options = [Option(f"o{k}", FunctionPolicy(lambda obs, rng: 0),
                      MLPEnsembleDynamics(3, hidden_sizes=(8, 8), members=2, seed=k),
                      ConstantTermination(0.0)) for k in range(3)]
    planner = OptionPlanner(options, _SigmoidGoal(), horizon=4, samples=10)
    plan = planner.plan(np.zeros(3), np.random.default_rng(0))
    assert plan.chosen is not None and (plan.steps == 4).all()
    again = planner.plan(np.zeros(3), np.random.default_rng(0))
    np.testing.assert_array_equal(plan.end_states, again.end_states)
    assert isinstance(stack_dynamics([o.dynamics for o in options]), StackedMLPEnsemble)


def test_mixture_quantile_and_calibration_of_a_known_gaussian():
    means = np.array([[0.0, 1.0]])
    stds = np.array([[1.0, 2.0]])
    np.testing.assert_allclose(mixture_quantile(means, stds, 0.95),
                               norm.ppf(0.95, loc=[0.0, 1.0], scale=[1.0, 2.0]), atol=1e-9)

    class Exact:
        """Two equal members N(s, 1): the truth, so 90% intervals hold 90%."""

        def predict(self, states):
            m = np.stack([states, states])
            return m, np.ones_like(m)

    rng = np.random.default_rng(0)
    s = rng.normal(size=(20000, 2))
    cal = calibration(Exact(), s, s + rng.normal(size=s.shape), level=0.9)
    assert abs(cal.coverage - 0.9) < 0.01
    np.testing.assert_allclose(cal.mean_width, 2 * norm.ppf(0.95), rtol=1e-6)


def test_calibration_widens_an_over_confident_model_to_the_nominal_coverage(tmp_path):
    model, _ = _trained()
    # the world turns out noisier than the training data: the intervals are too narrow
    s_cal, nxt_cal = _linear_system(n=600, noise=0.2, seed=5)
    s_new, nxt_new = _linear_system(n=600, noise=0.2, seed=6)
    before = calibration(model, s_new, nxt_new, 0.9).coverage
    scale = model.calibrate(s_cal, nxt_cal, 0.9)
    after = calibration(model, s_new, nxt_new, 0.9).coverage
    assert before < 0.75 and abs(after - 0.9) < 0.04 and (scale > 1.5).all()
    # the sampler spreads as the calibrated prediction says, and the scale is saved
    x = np.repeat(s_new[:1], 4000, axis=0)
    draws = model.sample(x, np.random.default_rng(0))
    means, variances = model.predict(s_new[:1])
    mix_var = (variances + means ** 2).mean(axis=0)[0] - means.mean(axis=0)[0] ** 2
    np.testing.assert_allclose(draws.var(axis=0), mix_var, rtol=0.1)
    loaded = MLPEnsembleDynamics.load(model.save(tmp_path / "m.safetensors"))
    np.testing.assert_array_equal(loaded.std_scale, scale)
    # a model that is already wide enough is left as it is (the scale only widens)
    wide = _trained()[0]
    s_easy, nxt_easy = _linear_system(n=600, noise=0.01, seed=7)
    np.testing.assert_array_equal(wide.calibrate(s_easy, nxt_easy), np.ones(3))


def test_option_end_gap_is_how_far_the_imagined_end_scores_from_the_real_one():
    class Drifting:
        """Deterministic: dimension 0 moves by +0.1 a step as the truth does, dimension 1
        (the truth keeps it still) drifts by +0.2 a step."""

        members = 2

        def predict(self, states):
            m = np.stack([states + np.array([0.1, 0.2])] * 2)
            return m, np.zeros_like(m)

    # three runs from the origin: 5 steps, 2 steps, and one of 0 steps (nothing to imagine)
    starts, ends = np.zeros((3, 2)), np.array([[0.5, 0.0], [0.2, 0.0], [0.0, 0.0]])
    rng = np.random.default_rng(0)
    first = option_end_gap(Drifting(), starts, ends, [5, 2, 0], lambda s: s[:, 0], 4, rng)
    second = option_end_gap(Drifting(), starts, ends, [5, 2, 0], lambda s: s[:, 1], 4, rng)
    assert first is not None and second is not None
    # a goal on the well-predicted dimension scores the imagined end as the real one
    assert first["gap"] == pytest.approx(0.0, abs=1e-12) and first["runs"] == 2
    # a goal on the drifting one is off by the drift over each run: 1.0 and 0.4
    assert second["gap"] == pytest.approx(0.7) and second["real"] == pytest.approx(0.0)
    assert second["imagined"] == pytest.approx(0.7)
    assert option_end_gap(Drifting(), starts[2:], ends[2:], [0], lambda s: s[:, 0], 4,
                          rng) is None


class _Unblocked:
    """A stack without ``block_sampler``: the planner gathers and scatters every step."""

    def __init__(self, stack):
        self.stack = stack

    def sample(self, states, rng):
        return self.stack.sample(states, rng)

    def trajectory_sampler(self, samples, rng):
        return self.stack.trajectory_sampler(samples, rng)


@pytest.mark.parametrize(("members", "samples", "end_inside"),
                         [(2, 10, False), (3, 10, True), (4, 7, False)])
def test_rollouts_in_block_order_equal_the_reordered_rollouts(members, samples, end_inside):
    # the same generator gives the same rollouts with and without the block order, also
    # where members do not divide samples (padding) and where rollouts stop early (beta,
    # a continuation set, a start state where some rollouts may not run)
    from dynoplan.options.initiation import InitiationFromCallable

    inside = InitiationFromCallable(lambda s: s[:, 0] < 0.6)
    options = [Option(f"o{k}", FunctionPolicy(lambda obs, rng: 0),
                      MLPEnsembleDynamics(3, hidden_sizes=(8, 8), members=members, seed=k),
                      ConstantTermination(0.1 * k), initiation=inside) for k in range(3)]
    planner = OptionPlanner(options, _SigmoidGoal(), horizon=6, samples=samples,
                            end_inside=end_inside)
    start = np.random.default_rng(5).normal(scale=0.3, size=(4, samples, 3))
    may = np.random.default_rng(6).random((4, samples)) < 0.8
    idx = (0, 1, 2, 1)
    blocked = planner.rollout(idx, start, np.random.default_rng(0), start_alive=may)
    stack, termination = planner._stack(idx)
    assert callable(getattr(stack, "block_sampler", None))
    planner._stacks[idx] = (_Unblocked(stack), termination)
    plain = planner.rollout(idx, start, np.random.default_rng(0), start_alive=may)
    for a, b in [(blocked.end_states, plain.end_states), (blocked.steps, plain.steps),
                 (blocked.valid, plain.valid), (blocked.members, plain.members)]:
        np.testing.assert_array_equal(a, b)
    assert (blocked.steps[~may] == 0).all() and (blocked.end_states[~may] == start[~may]).all()
    assert 0 < blocked.steps.mean() < 6
