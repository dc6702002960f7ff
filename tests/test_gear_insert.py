"""The insert option: scripted demonstrations with noise injection, behaviour cloning of
the MLP policy, its model file, and the policy in closed loop."""

import json

import numpy as np
import pytest
import torch
from safetensors.numpy import save_file

from dynoplan.envs.gear.env import GRIPPER_CLOSED, OBS_SLICES, GearAssemblyEnv
from dynoplan.envs.gear.options.catalog import reach_start
from dynoplan.envs.gear.options.insert import (
    FEATURE_DIM,
    InsertionNetwork,
    InsertPolicy,
    PegTipModel,
    insertion_features,
)
from dynoplan.envs.gear.options.insert_training import (
    InsertionDemos,
    ScriptedInserter,
    collect_demonstrations,
    fit_insertion,
    train_insertion,
)
from dynoplan.envs.gear.state import PlannerState
from dynoplan.envs.gear.task import SEAT_DEPTH
from dynoplan.errors import DynoplanError
from dynoplan.models.storage import save_arrays
from dynoplan.options.termination import Termination


@pytest.fixture(scope="module")
def env():
    e = GearAssemblyEnv(max_episode_steps=10_000)
    yield e
    e.close()


@pytest.fixture(scope="module")
def demos(env) -> InsertionDemos:
    return collect_demonstrations(env, episodes=5, seed=11, noise_std=0.01)


@pytest.fixture(scope="module")
def trained(demos) -> tuple[InsertionNetwork, dict]:
    network = InsertionNetwork((32, 32), seed=0)
    report = fit_insertion(network, demos, epochs=60, batch_size=32, held_out_fraction=0.4,
                           seed=0)
    return network, report


def test_demonstrations_are_seated_insertions_with_clean_labels(demos):
    assert demos.n_episodes == 5
    assert demos.seated == 5  # the teacher seats the gear even with noise injected
    assert demos.features.shape == (len(demos), FEATURE_DIM)
    assert demos.steps.shape == (len(demos), 6)
    assert set(np.unique(demos.episodes)) == set(range(5))
    assert np.isfinite(demos.features).all() and np.isfinite(demos.steps).all()
    # Seated rows end each episode deep on the peg: the last gear height is below the tip.
    last = [np.flatnonzero(demos.episodes == e)[-1] for e in range(5)]
    assert (demos.features[last, 2] < 0.0).all()


def test_teacher_action_is_a_function_of_the_observation(env):
    start = reach_start(env, "insert", np.random.default_rng([5, 0]))
    teacher = ScriptedInserter()
    a1 = teacher.act(start.observation)
    a2 = ScriptedInserter().act(start.observation)
    np.testing.assert_array_equal(a1, a2)
    assert a1.shape == (13,) and a1[12] == GRIPPER_CLOSED
    np.testing.assert_array_equal(a1[6:12], start.observation[6:12])


def test_behaviour_cloning_reduces_held_out_loss(demos, trained):
    _, report = trained
    assert report["held_out_samples"] > 0 and report["train_samples"] > 0
    assert report["held_out_episodes"] >= 1
    # Standardised MSE: predicting the mean scores about 1; an untrained net about that.
    untrained = InsertionNetwork((32, 32), seed=0)
    untrained.set_normalisation(demos.features, demos.steps)
    x, y = untrained.normalise(demos.features, demos.steps)
    with torch.no_grad():
        before = float(((untrained.network(x) - y) ** 2).mean())
    assert report["final_held_out_loss"] < 0.5 * before
    assert report["final_held_out_loss"] < report["held_out_loss"][0]
    assert report["final_held_out_loss"] == min(report["held_out_loss"])


def test_save_load_round_trips_bit_exactly(trained, tmp_path):
    network, _ = trained
    network.report = {"episodes": 5, "note": "tiny"}
    path = network.save(tmp_path / "insert.safetensors")
    loaded = InsertionNetwork.load(path)
    assert loaded.hidden_sizes == network.hidden_sizes
    assert loaded.report == network.report
    for a, b in zip(network.linears, loaded.linears, strict=True):
        np.testing.assert_array_equal(a.weight.detach().numpy(), b.weight.detach().numpy())
        np.testing.assert_array_equal(a.bias.detach().numpy(), b.bias.detach().numpy())
    for name in ("input_mean", "input_std", "output_mean", "output_std"):
        np.testing.assert_array_equal(getattr(network, name), getattr(loaded, name))
    x = np.random.default_rng(0).normal(size=(7, FEATURE_DIM))
    np.testing.assert_array_equal(network.predict(x), loaded.predict(x))


def test_the_same_fit_writes_the_same_file_whatever_threads_the_caller_set(demos, tmp_path):
    """Two fits of the same demonstrations and seed write the same bytes: no wall-clock
    times in the file, and the caller's thread count (1 or 2 here) does not reach the
    training, which runs on its own fixed thread count and leaves the caller's as it was."""
    before = torch.get_num_threads()
    files = []
    try:
        for threads in (2, 1):
            torch.set_num_threads(threads)
            path = tmp_path / f"t{threads}.safetensors"
            report = train_insertion(path, demos, seed=0, epochs=20, hidden_sizes=(64, 64),
                                     held_out_fraction=0.4)
            assert torch.get_num_threads() == threads
            assert report["train_seconds"] > 0.0  # the caller still gets the times
            files.append(path.read_bytes())
    finally:
        torch.set_num_threads(before)
    assert files[0] == files[1]
    assert "seconds" not in InsertionNetwork.load(tmp_path / "t1.safetensors").report


def _one_line_error(path) -> str:
    with pytest.raises(DynoplanError) as err:
        InsertionNetwork.load(path)
    message = str(err.value)
    assert "\n" not in message
    return message


def test_missing_corrupt_and_mismatched_files_are_rejected(trained, tmp_path):
    network, _ = trained
    assert "not found" in _one_line_error(tmp_path / "missing.safetensors")
    garbage = tmp_path / "garbage.safetensors"
    garbage.write_bytes(b"\x00\x01 definitely not safetensors" * 10)
    _one_line_error(garbage)
    good = network.save(tmp_path / "good.safetensors")
    truncated = tmp_path / "truncated.safetensors"
    truncated.write_bytes(good.read_bytes()[:-100])
    _one_line_error(truncated)
    other = save_arrays(tmp_path / "other.safetensors", "mlp_ensemble_dynamics",
                        {"a": np.zeros(3)}, {})
    assert "expected 'gear_insertion_policy'" in _one_line_error(other)
    # Right kind, wrong input size.
    arrays = {f"weight_{i}": lin.weight.detach().numpy() for i, lin in
              enumerate(network.linears)}
    meta = {"kind": "gear_insertion_policy", "format_version": 1, "input_dim": 19,
            "output_dim": 6, "hidden_sizes": [32, 32], "activation": "silu"}
    mismatched = tmp_path / "mismatched.safetensors"
    save_file(arrays, str(mismatched), metadata={"dynoplan": json.dumps(meta)})
    assert "input_dim" in _one_line_error(mismatched)
    # Right metadata, a weight of the wrong shape.
    _, meta_good = _read_meta(good)
    bad_arrays = dict(_read_arrays(good))
    bad_arrays["weight_1"] = np.zeros((32, 31), dtype=np.float32)
    wrong_shape = tmp_path / "wrong_shape.safetensors"
    save_file(bad_arrays, str(wrong_shape), metadata={"dynoplan": json.dumps(meta_good)})
    assert "weight_1" in _one_line_error(wrong_shape)


def _read_arrays(path):
    from safetensors.numpy import load_file

    return load_file(str(path))


def _read_meta(path):
    from safetensors import safe_open

    with safe_open(str(path), framework="numpy") as f:
        raw = f.metadata()["dynoplan"]
    return raw, json.loads(raw)


def test_policy_actions_are_finite_and_within_joint_limits(env, trained):
    network, _ = trained
    policy = InsertPolicy(env, network)
    with pytest.raises(RuntimeError):
        policy.act(np.zeros(50))
    start = reach_start(env, "insert", np.random.default_rng([99, 3]))
    obs = start.observation
    policy.reset(obs, np.random.default_rng(0))
    assert policy.status == "running" and policy.plan_ms == []
    right = env.arm_targets[6:12]  # the right arm held where commanded, not where it sags
    lim = env.joint_limits
    for _ in range(15):
        action = policy.act(obs)
        assert action.shape == (13,) and np.isfinite(action).all()
        assert (action[:12] >= lim[:, 0]).all() and (action[:12] <= lim[:, 1]).all()
        assert np.max(np.abs(action[:6] - obs[:6])) <= policy.cfg.max_joint_step + 1e-12
        np.testing.assert_array_equal(action[6:12], right)
        assert action[12] == GRIPPER_CLOSED
        obs, _, terminated, _, _ = env.step(action)
        if terminated:
            break
    with pytest.raises(DynoplanError):
        policy.act(np.zeros(49))


def test_started_while_the_arm_moves_it_holds_the_start_pose_first(env, trained):
    network, _ = trained
    policy = InsertPolicy(env, network)
    start = reach_start(env, "insert", np.random.default_rng([99, 4]))
    moving = start.observation.copy()
    moving[OBS_SLICES["arm_qvel"]][:6] = 0.5  # rad/s, still arriving
    policy.reset(moving, np.random.default_rng(0))
    held = policy.act(moving)
    np.testing.assert_array_equal(held[:6], moving[:6])
    still = moving.copy()
    still[:6] += 0.01  # it has drifted on and stopped: the network takes over from here
    still[OBS_SLICES["arm_qvel"]] = 0.0
    stepped = policy.act(still)
    assert not np.array_equal(stepped[:6], moving[:6])
    # a start at rest goes to the network at once
    policy.reset(still, np.random.default_rng(0))
    assert not np.array_equal(policy.act(still)[:6], still[:6])


def test_termination_is_high_when_seated_and_near_the_human(env, trained):
    network, _ = trained
    policy = InsertPolicy(env, network)
    start = reach_start(env, "insert", np.random.default_rng([99, 4]))
    policy.reset(start.observation, np.random.default_rng(0))
    beta = policy.termination()
    assert isinstance(beta, Termination)
    tip, rot = env.peg_pose()
    # The peg tip from the right-arm joints matches the simulator's.
    peg = PegTipModel(start.observation[6:12])
    np.testing.assert_allclose(peg.tip(start.observation[6:12])[0], tip, atol=1e-6)
    state = PlannerState()(start.observation)
    states = np.repeat(state[None], 3, axis=0)
    states[:, 19:22] = states[:, 13:16] + np.array([2.0, 0.0, 0.0])  # human far away
    states[1, 16:19] = tip - rot[:, 2] * (SEAT_DEPTH + 0.003)  # seated
    states[2, 19:22] = states[2, 13:16] + np.array([0.05, 0.0, 0.0])  # human at the tool
    p = beta.probability(states)
    assert p.shape == (3,)
    assert p[0] == pytest.approx(policy.cfg.termination_base)
    assert p[1] == pytest.approx(1.0)
    assert p[2] > 0.8


def test_features_reject_wrong_shapes():
    with pytest.raises(DynoplanError):
        insertion_features(np.zeros((2, 49)))
    assert insertion_features(np.tile(np.r_[np.zeros(29), 1.0, np.zeros(6), 1.0,
                                            np.zeros(13)], (3, 1))).shape == (3, FEATURE_DIM)


@pytest.mark.slow
def test_small_trained_policy_seats_the_gear(tmp_path):
    """End to end: demonstrations, training, file, and the policy in closed loop from
    seeded pre-insertion starts (seeds disjoint from the training ones)."""
    path = tmp_path / "insert.safetensors"
    report = train_insertion(path, demos=12, seed=5, epochs=60, hidden_sizes=(64, 64))
    assert report["episodes"] == 12 and report["samples"] > 100
    assert report["final_held_out_loss"] < 0.3
    for key in ("noise_std", "epochs", "train_seconds", "data_seconds", "final_train_loss"):
        assert key in report
    env = GearAssemblyEnv()
    policy = InsertPolicy.from_file(env, path)
    assert policy.network.report["samples"] == report["samples"]
    seated = 0
    for trial in range(3):
        start = reach_start(env, "insert", np.random.default_rng([777, trial]))
        obs = start.observation
        policy.reset(obs, np.random.default_rng(trial))
        info = start.info
        for _ in range(300):
            obs, _, terminated, _, info = env.step(policy.act(obs))
            if terminated or policy.finished():
                break
        seated += int(policy.succeeded(info))
    env.close()
    assert seated >= 2
