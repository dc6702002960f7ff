"""Option start states, option trials, option-transition collection and fault injection
for the gear assembly (with a simple hold-still policy, so these tests do not depend on
the trained options)."""

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from dynoplan.control import Controller, RandomChoice
from dynoplan.data import read_dataset
from dynoplan.envs.gear.controllers import HoldStill
from dynoplan.envs.gear.env import HOME_Q, OBS_SLICES, GearAssemblyEnv
from dynoplan.envs.gear.faults import GraspSlip, ObservationNoise
from dynoplan.envs.gear.option_runs import collect_gear_transitions
from dynoplan.envs.gear.options.base import GearOptionPolicy
from dynoplan.envs.gear.options.catalog import reach_start
from dynoplan.envs.gear.options.starts import shifted_schedule
from dynoplan.envs.gear.options.trials import run_option_trials
from dynoplan.envs.gear.state import DECISION_STEPS, STATE_DIM, PlannerState, proximity_beta
from dynoplan.envs.gear.task import STAGE_INDEX
from dynoplan.errors import DynoplanError
from dynoplan.models.corruption import NoisyDynamics
from dynoplan.models.dynamics import stack_dynamics
from dynoplan.options import ConstantTermination, Option
from dynoplan.pipeline.fit_data import option_transitions
from dynoplan.types import FloatArray, Generator


class HoldFor(GearOptionPolicy):
    """Holds still for ``steps`` steps, then reports done; succeeds if the gear is held."""

    name = "hold"

    def __init__(self, env: GearAssemblyEnv, steps: int = 25) -> None:
        super().__init__(env)
        self.steps = steps
        self.taken = 0

    def reset(self, observation: Any, rng: Generator) -> None:
        self.taken, self.status = 0, "running"

    def act(self, observation: Any) -> FloatArray:
        self.taken += 1
        if self.taken >= self.steps:
            self.status = "done"
        return HoldStill(self.env)(observation)

    def succeeded(self, info: dict[str, Any]) -> bool:
        return int(info["pads_on_gear"]) >= 2


@pytest.fixture(scope="module")
def env() -> GearAssemblyEnv:
    return GearAssemblyEnv()


def test_each_option_starts_in_its_own_stage(env: GearAssemblyEnv) -> None:
    stages = {}
    for name in ("pick", "fast_move", "cautious_move", "insert"):
        start = reach_start(env, name, np.random.default_rng(3))
        stages[name] = start.info["stage"]
        assert start.human_mode == ("block" if name == "cautious_move" else "away")
    assert stages["pick"] == STAGE_INDEX["on_table"]
    assert stages["fast_move"] == STAGE_INDEX["in_hand"]
    assert stages["insert"] in (STAGE_INDEX["near_peg"], STAGE_INDEX["in_hand"])


def test_same_seed_same_start(env: GearAssemblyEnv) -> None:
    a = reach_start(env, "insert", np.random.default_rng(5)).observation
    b = reach_start(env, "insert", np.random.default_rng(5)).observation
    np.testing.assert_array_equal(a, b)


def test_a_blocking_human_arrives_soon_after_the_start(env: GearAssemblyEnv) -> None:
    reach_start(env, "fast_move", np.random.default_rng(0))
    schedule = shifted_schedule(env, "block", np.random.default_rng(1), delay=(0.0, 1.0))
    assert schedule.mode == "block"
    assert env.time <= schedule.times[1] <= env.time + 1.0
    assert np.allclose(schedule.position(env.time), schedule.positions[0])


def test_unknown_option_is_one_clear_error(env: GearAssemblyEnv) -> None:
    with pytest.raises(DynoplanError, match="unknown option 'grab'"):
        reach_start(env, "grab", np.random.default_rng(0))


def test_planner_state_and_proximity_beta() -> None:
    env = GearAssemblyEnv()
    obs, _ = env.reset(seed=0, options={"human_mode": "away"})
    s = PlannerState()(obs)
    assert s.shape == (STATE_DIM,)
    np.testing.assert_array_equal(s[:12], obs[OBS_SLICES["arm_qpos"]])
    near = s.copy()
    near[19:22] = near[13:16] + np.array([0.05, 0.0, 0.0])
    assert proximity_beta(s[None])[0] == 0.0  # the human rests far away
    assert proximity_beta(near[None])[0] > 0.5


def test_option_trials_write_a_summary(tmp_path: Path) -> None:
    summary = run_option_trials("fast_move", lambda e: HoldFor(e, 5), trials=2, seed=0,
                                out=tmp_path, progress=False)
    saved = json.loads((tmp_path / "summary.json").read_text())
    assert saved == summary
    for key in ("success_rate", "contacts", "min_human_distance", "plan_ms_p50"):
        assert key in saved
    assert saved["success_rate"] == 1.0  # holding the lifted gear keeps it in hand
    assert saved["plan_ms_p50"] is None  # it never planned
    with pytest.raises(DynoplanError, match="unknown option"):
        run_option_trials("grab", HoldFor, trials=1, seed=0, out=tmp_path, progress=False)


def test_collected_transitions_are_at_the_decision_rate(tmp_path: Path) -> None:
    out = tmp_path / "transitions"
    summary = collect_gear_transitions({"fast_move": lambda e: HoldFor(e, 3 * DECISION_STEPS)},
                                  runs_per_option=2, seed=0, out=out, progress=False)
    assert summary["runs"] == 2
    ds = read_dataset(out)
    assert ds.metadata.option_names[1] == "fast_move"
    pairs = option_transitions(list(ds), ds.metadata.option_names, PlannerState())
    assert pairs["fast_move"][0].shape[1] == STATE_DIM
    assert [n for n, (s, _) in pairs.items() if len(s)] == ["fast_move"]
    # 30 steps per run: offset 0 gives 3 decisions, offsets 1..9 give 2
    lengths = sorted(len(e) for e in ds)
    assert lengths == sorted(([3] + [2] * 9) * 2)
    first = ds[0].observations
    assert first.shape == (4, 50)


def test_grasp_slip_drops_the_gear_once(env: GearAssemblyEnv) -> None:
    start = reach_start(env, "fast_move", np.random.default_rng(2))
    assert start.info["pads_on_gear"] == 2
    slip = GraspSlip(env)
    slip._done, slip._left = False, 0
    obs = start.observation
    # lower the gear towards the table: the slip fires when it is held 1-6 cm up
    q = obs[OBS_SLICES["arm_qpos"]].copy()
    info: dict[str, Any] = {}
    for _ in range(60):
        obs, _, _, _, info = slip.step(np.concatenate([q, [1.0]]))
        if info["slipped"]:
            break
        q[1] += 0.01  # shoulder lift down
    assert info["slipped"]
    for _ in range(20):
        obs, _, _, _, info = slip.step(np.concatenate([q, [1.0]]))
    assert info["pads_on_gear"] < 2


def test_observation_noise_is_seeded_and_leaves_the_simulation_alone() -> None:
    a, b = ObservationNoise(GearAssemblyEnv()), ObservationNoise(GearAssemblyEnv())
    oa, _ = a.reset(seed=1)
    ob, _ = b.reset(seed=1)
    np.testing.assert_array_equal(oa, ob)
    clean = a.unwrapped._observation()  # type: ignore[attr-defined]
    assert 0 < np.abs(oa - clean).max() < 0.05


class _Shift:
    state_dim = 3

    def sample(self, states: FloatArray, rng: Generator) -> FloatArray:
        out: FloatArray = states + 1.0
        return out


def test_noisy_dynamics_adds_the_stated_noise() -> None:
    noisy = NoisyDynamics(_Shift(), std=np.array([0.0, 0.1, 1.0]))
    x = np.zeros((20000, 3))
    y = noisy.sample(x, np.random.default_rng(0))
    np.testing.assert_allclose(y.mean(axis=0), 1.0, atol=0.03)
    np.testing.assert_allclose(y.std(axis=0), [0.0, 0.1, 1.0], atol=0.02)
    stacked = stack_dynamics([noisy, NoisyDynamics(_Shift(), 0.0)])
    z = stacked.sample(np.zeros((2, 1000, 3)), np.random.default_rng(0))
    assert z[0, :, 2].std() > 0.8 and np.all(z[1] == 1.0)


def test_hold_still_keeps_the_robot_where_it_is() -> None:
    """100 steps (5 s) of holding: neither arm sags (holding the measured angles let the
    right arm lower the peg module 9 cm onto the table)."""
    env = GearAssemblyEnv()
    env.reset(seed=0, options={"human_mode": "away"})
    peg0 = env.peg_pose()[0].copy()

    class Never:
        def contains(self, states: FloatArray) -> np.ndarray:
            return np.zeros(len(states), dtype=bool)

    option = Option("never", HoldFor(env), _Shift(), ConstantTermination(0.0), Never())
    controller = Controller([option], RandomChoice([option]), max_decisions=100,
                            hold_action=HoldStill(env))
    trace = controller.run(env, np.random.default_rng(0), seed=0,
                           reset_options={"human_mode": "away"})
    assert trace.no_admissible == 100
    np.testing.assert_allclose(env.arm_qpos, HOME_Q, atol=0.02)
    assert np.linalg.norm(env.peg_pose()[0] - peg0) < 0.005


