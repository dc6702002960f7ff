"""The pick option (OMPL to pre-grasp, approach, close, lift) and its neural grasp recogniser."""

import json
import struct

import numpy as np
import pytest

from dynoplan.envs.gear.env import OBS_SLICES, GearAssemblyEnv
from dynoplan.envs.gear.options.catalog import reach_start
from dynoplan.envs.gear.options.motion import LeftArmPlanner
from dynoplan.envs.gear.options.pick import PickPolicy
from dynoplan.envs.gear.options.recognition import (
    FEATURE_NAMES,
    MODEL_KIND,
    GraspRecognizer,
    fit_recognizer,
    generate_grasp_data,
    grasp_features,
    train_recognizer,
)
from dynoplan.envs.gear.state import STATE_DIM, STATE_SLICES
from dynoplan.errors import DynoplanError
from dynoplan.models.storage import save_arrays

STEP_CAP = 600


@pytest.fixture(scope="module")
def env():
    e = GearAssemblyEnv()
    yield e
    e.close()


@pytest.fixture(scope="module")
def data(env):
    return generate_grasp_data(env, 16, seed=3)


@pytest.fixture(scope="module")
def trained(data):
    return fit_recognizer(data, seed=0, epochs=80)


def run_pick(env, policy, rng, perceive=None, on_segment=None):
    """One option trial as the lead's runner does it; returns the last info."""
    start = reach_start(env, "pick", rng)
    obs, info = start.observation, start.info
    policy.reset(obs if perceive is None else perceive(obs), rng)
    seen = 0
    for _ in range(STEP_CAP):
        if policy.finished():
            break
        action = policy.act(obs)
        if on_segment is not None:
            while seen < len(policy.segments):
                on_segment(*policy.segments[seen])
                seen += 1
        obs, _, terminated, truncated, info = env.step(action)
        assert info["robot_collisions"] == 0
        if terminated or truncated:
            break
    return info


def test_recognizer_beats_chance_on_held_out_episodes(data, trained):
    _, report = trained
    assert set(data.perturbations) >= {"nominal", "offset"}
    assert 0.1 < data.labels.mean() < 0.9  # both classes are present
    assert report["held_out_episodes"] >= 1 and report["held_out_size"] > 100
    majority = max(report["held_out_positive_fraction"], 1 - report["held_out_positive_fraction"])
    assert report["held_out_accuracy"] >= 0.9
    assert report["held_out_accuracy"] > majority + 0.05


def test_recognizer_tells_open_gripper_from_held_gear(env, trained):
    model, _ = trained
    rng = np.random.default_rng([5, 0])
    start = reach_start(env, "pick", rng)
    assert model.probability(start.observation) < 0.5  # gripper open, gear on the table
    probs = model.probability(np.stack([start.observation] * 3))
    assert isinstance(probs, np.ndarray) and probs.shape == (3,)


def test_save_load_round_trips_bit_exactly(tmp_path, data, trained):
    model, report = trained
    path = model.save(tmp_path / "grasp.safetensors")
    loaded = GraspRecognizer.load(path)
    features = grasp_features(data.observations[::7])
    np.testing.assert_array_equal(loaded.logits(features), model.logits(features))
    np.testing.assert_array_equal(loaded.feature_std, model.feature_std)
    for a, b in zip(loaded.network.parameters(), model.network.parameters(), strict=True):
        assert np.array_equal(a.detach().numpy(), b.detach().numpy())
    assert loaded.report["held_out_accuracy"] == report["held_out_accuracy"]


def test_the_same_fit_writes_the_same_file_whatever_threads_the_caller_set(tmp_path, data):
    """Two fits of the same data and seed write the same bytes: no wall-clock times in
    the file, and the caller's thread count (1 or 2 here) does not reach the training,
    which runs on its own fixed thread count and leaves the caller's as it was."""
    import torch

    before = torch.get_num_threads()
    files = []
    try:
        for threads in (2, 1):
            torch.set_num_threads(threads)
            report = train_recognizer(tmp_path / f"t{threads}.safetensors", data, seed=0,
                                      epochs=20)
            assert torch.get_num_threads() == threads
            assert report["train_seconds"] > 0.0  # the caller still gets the times
            files.append((tmp_path / f"t{threads}.safetensors").read_bytes())
    finally:
        torch.set_num_threads(before)
    assert files[0] == files[1]
    assert "train_seconds" not in GraspRecognizer.load(tmp_path / "t1.safetensors").report


def test_bad_files_are_rejected_with_one_clear_error(tmp_path, trained):
    model, _ = trained
    good = model.save(tmp_path / "good.safetensors")
    raw = good.read_bytes()
    truncated = tmp_path / "truncated.safetensors"
    truncated.write_bytes(raw[: len(raw) // 2])
    garbage = tmp_path / "garbage.safetensors"
    garbage.write_bytes(b"not a model at all")
    other_kind = tmp_path / "other.safetensors"
    save_arrays(other_kind, "mlp_ensemble_dynamics", {"x": np.zeros(3)}, {})
    # a recogniser over other features: rewrite the JSON header with another feature list
    n = struct.unpack("<Q", raw[:8])[0]
    header = json.loads(raw[8:8 + n])
    meta = json.loads(header["__metadata__"]["dynoplan"])
    assert meta["kind"] == MODEL_KIND
    meta["feature_names"] = list(reversed(FEATURE_NAMES))
    header["__metadata__"]["dynoplan"] = json.dumps(meta)
    text = json.dumps(header).encode()
    text += b" " * (-len(text) % 8)
    mismatched = tmp_path / "mismatched.safetensors"
    mismatched.write_bytes(struct.pack("<Q", len(text)) + text + raw[8 + n:])
    for path in (truncated, garbage, other_kind, mismatched, tmp_path / "missing.safetensors"):
        with pytest.raises(DynoplanError) as err:
            GraspRecognizer.load(path)
        assert "\n" not in str(err.value) and str(path) in str(err.value)


@pytest.mark.slow
def test_pick_succeeds_and_every_planned_waypoint_is_collision_free(env, trained):
    model, _ = trained
    policy = PickPolicy(env, model)
    checker = LeftArmPlanner(env)
    checked: list[str] = []

    def check(phase, waypoints):
        # the scene as the policy saw it when it planned this segment
        checker.sync(carry_gear=phase in ("lift", "verify"))
        assert all(checker.is_valid(q[:6]) for q in waypoints), phase
        assert checker.path_is_valid(waypoints[:, :6]), phase
        checked.append(phase)

    for trial in range(2):
        info = run_pick(env, policy, np.random.default_rng([0, trial]), on_segment=check)
        assert policy.status == "done" and policy.succeeded(info)
        assert policy.attempts == 1 and len(policy.plan_ms) == 1
        assert policy.grasp_probability > 0.5
        gear, _ = env.gear_pose()
        assert gear[2] > 0.72 + 0.1  # lifted, ready for the move to the peg
    assert {"move", "approach", "lift"} <= set(checked)


@pytest.mark.slow
def test_pick_recognises_a_missed_grasp_and_tries_again(env, trained):
    model, _ = trained
    policy = PickPolicy(env, model)

    def misperceive(obs):  # the first attempt aims 4.5 cm beside the gear
        wrong = obs.copy()
        wrong[OBS_SLICES["gear_pos"]] += np.array([0.0, 0.045, 0.0])
        return wrong

    info = run_pick(env, policy, np.random.default_rng([0, 1]), perceive=misperceive)
    assert policy.attempts == 2
    assert policy.status == "done" and policy.succeeded(info)
    assert [p for p, _ in policy.segments].count("release") == 1


def test_termination_rises_as_the_human_comes_close(env, trained):
    policy = PickPolicy(env, trained[0])
    states = np.zeros((3, STATE_DIM))
    states[:, STATE_SLICES["tool_pos"]] = [0.5, 0.2, 0.95]
    states[:, STATE_SLICES["human_pos"]] = [[1.25, 0.35, 0.95], [0.8, 0.2, 0.95],
                                            [0.55, 0.2, 0.95]]
    beta = policy.termination().probability(states)
    assert beta[0] == 0.0 and 0.0 < beta[1] < beta[2]


def test_pick_has_not_succeeded_before_it_runs(env, trained):
    policy = PickPolicy(env, trained[0])
    start = reach_start(env, "pick", np.random.default_rng([2, 0]))
    assert not policy.succeeded(start.info)


def test_a_plans_extra_test_does_not_outlive_the_plan(env):
    """The moves check their goal with ``is_valid`` after planning; a human clearance
    given to an earlier plan (of this episode or of one before it) must not decide that
    check: the same goal was judged differently after another episode had run."""
    planner = LeftArmPlanner(env)
    env.reset(seed=0)
    start = env.arm_qpos
    assert planner.is_valid(start[:6])
    refused = planner.plan(start, start[:6], carry_gear=False, extra_valid=lambda q: False)
    assert not refused.solved
    assert planner.is_valid(start[:6])  # the scene's test alone again
