"""The gear assembly end to end (``dynoplan gear run --quick``), the options' own sets,
the margin rule and the termination rate of the controller."""

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from dynoplan.cli.main import app
from dynoplan.control import Controller, FixedChoice
from dynoplan.envs.gear.controllers import (
    CARRIED_GEAR_HEIGHT,
    GEAR_CONTROL,
    VARIANTS,
    holding_gear,
    not_carried,
    own_sets,
)
from dynoplan.envs.gear.env import CONTROL_DT, HOME_Q, RIGHT_HOLD
from dynoplan.envs.gear.evaluation import video_episode
from dynoplan.envs.gear.features import HUMAN_DISTANCE_CAP, RELATIVE, feature_map
from dynoplan.envs.gear.options.moves import PreInsertionBeta
from dynoplan.envs.gear.reports.results import RESULT_COLUMNS, failure_table, summarise
from dynoplan.envs.gear.scene import FINGER_TRAVEL, TABLE_TOP_Z
from dynoplan.envs.gear.state import STATE_DIM, STATE_SLICES
from dynoplan.errors import DynoplanError
from dynoplan.options import AllOf, ConstantTermination, FunctionPolicy, Option
from dynoplan.options.initiation import Everywhere, InitiationFromCallable
from dynoplan.pipeline.evaluate import EpisodeRecord, summarize

REQUIRED = ("controller", "success_rate", "contacts", "min_human_distance",
            "out_of_region_starts", "switches", "decision_ms_p50", "decision_ms_p99")


def _state(gripper: float, gear_z: float) -> np.ndarray:
    s = np.zeros(STATE_DIM)
    s[STATE_SLICES["gripper"]] = gripper
    s[STATE_SLICES["gear_pos"].stop - 1] = gear_z
    return s


def test_moves_need_the_gear_lifted_in_a_closed_gripper():
    states = np.stack([
        _state(0.2 * FINGER_TRAVEL, TABLE_TOP_Z + 0.05),  # held and lifted
        _state(FINGER_TRAVEL, TABLE_TOP_Z + 0.05),  # open gripper
        _state(0.2 * FINGER_TRAVEL, TABLE_TOP_Z + 0.001),  # closed, gear on the table
    ])
    assert holding_gear(states).tolist() == [True, False, False]
    left_half = InitiationFromCallable(lambda s: s[:, 0] < 0.5)
    both = AllOf(left_half, InitiationFromCallable(holding_gear))
    states[:, 0] = [0.0, 0.0, 0.0]
    states2 = states.copy()
    states2[:, 0] = 1.0
    assert both.contains(states).tolist() == [True, False, False]
    assert not both.contains(states2).any()


def test_the_pick_is_not_admissible_once_the_gear_is_carried():
    states = np.stack([
        _state(FINGER_TRAVEL, TABLE_TOP_Z + 0.001),  # gear on the table, gripper open
        _state(0.2 * FINGER_TRAVEL, TABLE_TOP_Z + 0.05),  # lifting
        _state(0.2 * FINGER_TRAVEL, TABLE_TOP_Z + CARRIED_GEAR_HEIGHT + 0.01),  # carried
        _state(FINGER_TRAVEL, TABLE_TOP_Z + CARRIED_GEAR_HEIGHT + 0.01),  # let go up there
    ])
    assert not_carried(states).tolist() == [True, True, False, True]


def test_relative_features_read_the_tool_offset_and_the_capped_hand_distance():
    s = np.zeros((2, STATE_DIM))
    s[:, STATE_SLICES["gripper"]] = 0.02
    s[:, STATE_SLICES["tool_pos"]] = [0.5, 0.2, 0.9]
    s[:, STATE_SLICES["gear_pos"]] = [0.5, 0.2, 0.8]
    s[0, STATE_SLICES["human_pos"]] = [0.5, 0.5, 0.9]  # 0.3 m from the tool
    s[1, STATE_SLICES["human_pos"]] = [3.0, 0.2, 0.9]  # 2.5 m: beyond the cap
    f = RELATIVE(s)
    assert f.shape == (2, RELATIVE.dim) == (2, len(RELATIVE.names))
    np.testing.assert_allclose(f[0], [0.02, 0.0, 0.0, 0.1, 0.5, 0.2, 0.8, 0.3])
    assert f[1, -1] == HUMAN_DISTANCE_CAP
    with pytest.raises(DynoplanError, match="unknown feature map"):
        feature_map("joints")
    with pytest.raises(DynoplanError, match="shape"):
        RELATIVE(np.zeros((2, 19)))


def test_controller_draws_termination_only_every_decision_period():
    """With beta = 1 drawn every 5 steps, an option runs exactly 5 steps per decision."""
    import gymnasium as gym

    env = gym.make("dynoplan/RandomWalk19-v0")
    option = Option("right", FunctionPolicy(lambda obs, rng: 1), _ZeroDynamics(),
                    ConstantTermination(1.0), Everywhere())
    controller = Controller([option], FixedChoice([option], "right"), max_decisions=3,
                            termination_every=5)
    trace = controller.run(env, np.random.default_rng(0), seed=0)
    steps = [d.steps for d in trace.decisions if d.stop_reason == "terminated"]
    assert steps and all(s == 5 for s in steps)
    every_step = Controller([option], FixedChoice([option], "right"), max_decisions=3)
    trace = every_step.run(env, np.random.default_rng(0), seed=0)
    assert all(d.steps == 1 for d in trace.decisions)


class _ZeroDynamics:
    state_dim = 1

    def sample(self, states: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        return states.copy()


@pytest.mark.slow
def test_gear_run_quick_writes_every_result_with_every_column(quick_gear_run: Path):
    out = quick_gear_run  # gear run --quick --episodes 3 --oracle-episodes 1 (conftest)
    with (out / "results.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [r["controller"] for r in rows] == ["dynoplan", "random", "oracle", "fixed_script",
                                             "flat_ppo", "dynoplan+rules",
                                             "dynoplan_regions", "dynoplan epistemic=0.3",
                                             "dynoplan gear-tuned"]
    assert set(REQUIRED) <= set(rows[0]) and tuple(rows[0]) == RESULT_COLUMNS
    by_name = {r["controller"]: r for r in rows}
    # the learned planner, the oracle on the same learned sets and the planner on the
    # rules assemble the gear in every quick episode, without touching the human
    for name in ("dynoplan", "oracle", "dynoplan+rules"):
        assert float(by_name[name]["success_rate"]) == 1.0, name
        assert int(by_name[name]["contacts"]) == 0, name
    assert float(by_name["dynoplan"]["time_to_success_s"]) < 40.0  # the episodes' limit
    summary = json.loads((out / "summary.json").read_text())
    assert summary["wall_s"] > 0 and summary["workers"]["count"] >= 1  # --workers auto
    assert set(summary["stages_s"]) == {"networks", "demos", "collect", "train", "figures",
                                        "flat_ppo", "outcomes", "improve", "evaluate",
                                        "faults"}  # --no-video
    # one improvement round on DynoPlan's own episodes (quick: 3), refitted in improve/,
    # and one batch that checks the refit; the models that did best are the run's
    curve = summary["improvement"]
    assert [c["episodes"] for c in curve] == [3, 3] and curve[1]["check"]
    assert [c["kept"] for c in curve].count(True) == 1
    assert (out / "improve" / "round-1" / "models" / "goal.safetensors").is_file()
    # the initiation learned from outcomes is fitted by the run, part of the learned sets
    assert (out / "models" / "initiation.safetensors").is_file()
    # the ablation rows run on the first --ablation-episodes (quick: 2) episodes, and
    # results.md compares them with DynoPlan on the same ones
    assert [int(by_name[r]["episodes"]) for r in ("dynoplan_regions",
                                                   "dynoplan epistemic=0.3",
                                                   "dynoplan gear-tuned")] == [2, 2, 2]
    assert [r["episodes"] for r in summary["ablation"]] == [2] * 6
    assert {f["fault"] for f in summary["faults"]} == {"dynamics_noise", "observation_noise",
                                                      "grasp_slip"}
    assert summary["results"][0]["episodes"] == 3 and summary["results"][2]["episodes"] == 1
    # the learned planner chooses only admissible options, so it never starts one outside
    # its region; the oracle is measured against the same regions
    assert summary["results"][0]["out_of_region_starts"] == 0
    for name in ("results.md", "figures", "models/metrics.json", "flat_ppo/flat_policy.json",
                 "demos", "heldout", "transitions"):
        assert (out / name).exists(), name
    assert "| dynoplan |" in (out / "results.md").read_text()
    assert "## Ablation" in (out / "results.md").read_text()


MODEL_FILES = ("models/models.json", "flat_ppo/flat_policy.json")
"""Model files beside the ``.safetensors`` that must repeat to the byte too."""


def _episodes_without_latencies(path: Path) -> dict[str, list[dict]]:
    """``episodes.json`` without the measured wall-clock ``decision_ms`` of each episode."""
    return {name: [{k: v for k, v in e.items() if k != "decision_ms"} for e in episodes]
            for name, episodes in json.loads(path.read_text()).items()}


@pytest.mark.slow
def test_the_same_command_twice_writes_the_same_models_and_episodes(quick_gear_run: Path,
                                                                    quick_gear_rerun: Path):
    """Same seed, same result: two ``gear run --quick`` (3 episodes, in one process, one
    after the other) write every ``.safetensors`` (option networks, goal, regions,
    dynamics, initiation, flat PPO) and the JSON beside them to the same bytes, and the
    same episode records but for the measured latencies."""
    first, again = quick_gear_run, quick_gear_rerun
    tensors = sorted(p.relative_to(first) for p in first.rglob("*.safetensors"))
    assert sorted(p.relative_to(again) for p in again.rglob("*.safetensors")) == tensors
    assert len(tensors) >= 10  # 2 option networks, goal, regions, 4 dynamics, initiation, ppo
    differ = [str(p) for p in (*tensors, *map(Path, MODEL_FILES))
              if (first / p).read_bytes() != (again / p).read_bytes()]
    assert differ == []
    assert (_episodes_without_latencies(first / "episodes.json")
            == _episodes_without_latencies(again / "episodes.json"))


def test_the_video_shows_the_shortest_successful_switch_to_the_cautious_move():
    def episode(options, mode="cross", success=True, seconds=10.0):
        steps = round(seconds / CONTROL_DT)
        return EpisodeRecord(0, success, steps, 0.0, len(options), 0, 0, 0, (), (), options,
                             {"human_mode": mode, "contacts": 0, "min_human_distance": 1.0})

    fast, cautious = ("pick", "fast_move", "insert"), ("pick", "cautious_move", "insert")
    episodes = [episode(fast), episode(cautious, success=False, seconds=5.0),
                episode(cautious, seconds=20.0), episode(cautious, seconds=12.0),
                episode(cautious, mode="away", seconds=1.0)]
    assert video_episode(episodes) == 3
    assert video_episode([episode(fast, "away"), episode(fast), episode(fast)]) == 1
    assert video_episode([episode(fast, "away", seconds=3.0)]) == 0


def test_failed_episodes_are_counted_by_how_they_ended():
    def episode(success, steps, holds, option_steps):
        return EpisodeRecord(0, success, steps, 0.0, 1, 0, 0, holds, (),
                             tuple(option_steps), (),
                             {"human_mode": "cross", "contacts": 0, "min_human_distance": 1.0})

    episodes = [episode(True, 300, 0, [("pick", 300)]),
                episode(False, 225, 94, [("pick", 131)]),  # the gear fell: ended early
                episode(False, 800, 710, [("pick", 90)]),  # held to the limit
                episode(False, 800, 400, [("pick", 400)]),  # half held: held
                episode(False, 800, 56, [("insert", 50), ("pick", 694)]),
                episode(False, 800, 74, [("insert", 614), ("pick", 112)]),
                episode(False, 800, 0, []),  # no options (a flat policy)
                episode(False, 800, 800, [])]  # nothing admissible from the first step
    row = summarise("dynoplan_safe", episodes)
    assert row["failures"] == {"held": 2, "dropped": 1, "insert": 1, "pick": 1, "ran": 1,
                               "never started": 1}
    assert ("| dynoplan_safe | 7 | held 2, dropped 1, insert 1, never started 1, pick 1, "
            "ran 1 |") in failure_table([row])
    assert summarise("x", episodes[:1])["failures"] == {}
    # the columns every task has come from the one summary of episodes
    every = summarize(episodes)
    assert (row["success_rate"], row["holds"], row["switches"]) == (
        every["success_rate"], every["no_admissible"], every["switches"]) == (0.125, 2134, 0)


@pytest.mark.parametrize("args", [["--episodes", "0"], ["--improve", "-1"],
                                  ["--improve", "101"]])
def test_gear_run_rejects_bad_episode_counts(tmp_path: Path, args):
    result = CliRunner().invoke(app, ["gear", "run", "--quick", "--out", str(tmp_path / "x"),
                                      *args])
    assert result.exit_code == 2
    assert not (tmp_path / "x").exists()


def test_near_the_goal_the_hand_decides_between_insert_and_the_cautious_move():
    """At the pre-insertion pose with the gear held, the insertion may start only with the
    hand 0.55 m clear of the tool (and goes on to 0.5 m); nearer, the cautious move may
    start instead (it stands guard). The moves start only outside the insertion corridor
    above the peg (not with the gear on its way down it)."""
    goal = PreInsertionBeta()
    s = np.zeros((3, STATE_DIM))
    s[:, STATE_SLICES["arm_qpos"]] = HOME_Q
    s[:, STATE_SLICES["gripper"]] = 0.2 * FINGER_TRAVEL
    s[:, STATE_SLICES["gear_pos"]] = goal.target(RIGHT_HOLD)
    s[:, STATE_SLICES["tool_pos"]] = goal.target(RIGHT_HOLD) + np.array([0.0, 0.0, 0.03])
    tool = s[0, STATE_SLICES["tool_pos"]]
    for row, hand_distance in enumerate((0.7, 0.52, 0.3)):
        s[row, STATE_SLICES["human_pos"]] = tool + np.array([hand_distance, 0.0, 0.0])
    s = np.concatenate([s, np.repeat(s[:1], 3, axis=0)])  # 3 more rows, hand far
    s[3, STATE_SLICES["gear_pos"]] += [0.0, 0.2, 0.0]  # 20 cm from the goal, hand far
    s[4, STATE_SLICES["gear_pos"]] += [0.0, 0.0, -0.07]  # on its way down the peg
    s[5, STATE_SLICES["gear_pos"]] += [0.0, 0.0, 0.07]  # above the corridor
    sets = {name: own_sets(name, "rules") for name in ("fast_move", "cautious_move", "insert")}
    start = {name: sets[name][0].contains(s).tolist() for name in sets}
    go_on = {name: (sets[name][1] or sets[name][0]).contains(s).tolist() for name in sets}
    assert start["insert"] == [True, False, False, True, True, True]
    assert go_on["insert"] == [True, True, False, True, True, True]
    assert start["cautious_move"] == [False, True, True, True, False, True]
    assert start["fast_move"] == [False, False, False, True, False, True]
    assert all(go_on["fast_move"])  # once running, a move ends at its goal by itself


@pytest.mark.slow
def test_gear_episode_replays_an_evaluation_episode_decision_by_decision(quick_gear_run: Path,
                                                                         tmp_path: Path):
    out = tmp_path / "episode"
    planner = json.loads((quick_gear_run / "summary.json").read_text())[
        "settings"]["evaluation"]["planner"]  # --quick's horizon and samples
    result = CliRunner().invoke(app, ["gear", "episode", "--index", "2", "--models",
                                      str(quick_gear_run / "models"), "--out", str(out),
                                      "--video", "--horizon", str(planner["horizon"]),
                                      "--samples", str(planner["samples"])])
    assert result.exit_code == 0, result.output
    replay = json.loads((out / "summary.json").read_text())
    evaluated = json.loads((quick_gear_run / "episodes.json").read_text())["dynoplan"][2]
    for key in ("env_seed", "success", "env_steps", "switches", "no_admissible",
                "out_of_region_starts", "options", "option_steps", "task_metrics"):
        assert replay[key] == evaluated[key], key
    with (out / "trace.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [r["option"] for r in rows] == evaluated["options"]
    assert sum(int(r["contacts"]) for r in rows) == evaluated["task_metrics"]["contacts"]
    assert {"score_pick", "score_insert", "admissible", "tool_hand_m"} <= set(rows[0])
    # the rendered episode is the same episode
    assert replay["video"]["success"] == evaluated["success"]
    assert (out / "episode.mp4").stat().st_size > 10_000
    # with the decision drawn on it: the running option's line, yellow, top left
    import imageio.v2 as imageio

    first = imageio.get_reader(out / "episode.mp4").get_data(0)[:30, :320].astype(int)
    assert ((first[..., 0] > 180) & (first[..., 1] > 150) & (first[..., 2] < 120)).sum() > 20


def test_gear_episode_rejects_an_unknown_controller_without_writing(tmp_path: Path):
    out = tmp_path / "episode"
    result = subprocess.run(
        [sys.executable, "-c", "from dynoplan.cli.main import main; main()", "gear",
         "episode", "--index", "0", "--controller", "flat_ppo", "--out", str(out)],
        capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        "dynoplan: error: unknown controller 'flat_ppo'; expected one of "
        f"{', '.join(VARIANTS)} (flat_ppo has no decisions)"]
    assert not out.exists()


def test_the_gear_commands_set_the_planners_depth():
    from dynoplan.cli.gear import _planner_settings

    assert _planner_settings(None, None, None, False).depth == GEAR_CONTROL.depth == 1
    assert _planner_settings(None, None, None, False, depth=2).depth == 2
    for command in ("evaluate", "episode"):
        shown = CliRunner().invoke(app, ["gear", command, "--help"], env={"COLUMNS": "200"})
        assert "--depth" in shown.output


def test_the_gear_controllers_do_not_repeat_an_option_without_effect_unless_told_to():
    from dynoplan.cli.gear import _planner_settings

    assert GEAR_CONTROL.no_effect_share == pytest.approx(0.01)  # 1 % of each spread
    assert _planner_settings(None, None, None, False) == GEAR_CONTROL
    ablation = _planner_settings(None, None, None, False, repeat_no_effect=True)
    assert ablation.no_effect_tolerance is None and ablation.no_effect_share is None
    for command in ("evaluate", "episode"):  # rich reads the width from COLUMNS
        shown = CliRunner().invoke(app, ["gear", command, "--help"], env={"COLUMNS": "200"})
        assert "--repeat-no-effect" in shown.output


@pytest.mark.slow
def test_start_states_labelled_by_the_operator_reach_the_pick_region(quick_gear_run: Path,
                                                                    tmp_path: Path):
    # the regions fitted on the demonstrations and the operator's start states admit
    # "pick" at those states; without them, the quick run's 10 demonstrations may not
    import shutil

    from dynoplan.data import read_dataset
    from dynoplan.envs.gear.learning.settings import QUICK_METRICS, QUICK_SETTINGS
    from dynoplan.envs.gear.models_folder import load_gear_models
    from dynoplan.envs.gear.stages import STARTS_DIR, learned_models, start_states
    from dynoplan.envs.gear.state import PlannerState

    shutil.copytree(quick_gear_run / "demos", tmp_path / "demos")
    report = start_states(30, 0, tmp_path / STARTS_DIR, quick_gear_run / "models")
    assert report["states"] == 30 and report["chosen"] == {"pick": 30}
    starts = read_dataset(tmp_path / STARTS_DIR).episodes[0]
    states = PlannerState()(starts.observations[:-1])
    admitted = {}
    for name, with_starts in (("with", tmp_path / STARTS_DIR), ("without", None)):
        models = tmp_path / f"models-{name}"
        shutil.copytree(quick_gear_run / "models", models)
        learned_models(tmp_path / "demos", quick_gear_run / "transitions", models, 0,
                       quick_gear_run / "heldout", QUICK_SETTINGS, QUICK_METRICS,
                       progress=False, region_starts=with_starts)
        regions = load_gear_models(models).regions
        admitted[name] = float(np.mean(regions.contains(states, "pick")))
    assert admitted["with"] >= 0.9 and admitted["with"] >= admitted["without"]


@pytest.mark.slow
def test_the_operator_demonstrates_from_the_starts_it_is_given(quick_gear_run: Path):
    """improve_demos on the gear: the operator runs from the starts where DynoPlan failed,
    each episode the one its seed starts, labelled as the run's demonstrations."""
    from dynoplan.data import read_dataset
    from dynoplan.envs.gear.evaluation import improvement_seeds
    from dynoplan.envs.gear.improve import operator_demonstrations

    starts = improvement_seeds(0, 2)
    shown = operator_demonstrations(quick_gear_run / "models", starts)
    assert shown, "the operator succeeds from the quick run's starts"
    assert {e.seed for e in shown} <= {s.env_seed for s in starts}
    demos = read_dataset(quick_gear_run / "demos")
    assert all(set(e.infos) == {"option", "progress"} for e in shown)
    assert all(e.infos["progress"][-1] == 1.0 for e in shown)
    assert shown[0].observations.shape[1] == next(iter(demos)).observations.shape[1]


def test_zero_oracle_or_ablation_episodes_leave_those_rows_out(tmp_path):
    """``gear run --oracle-episodes 0 --ablation-episodes 0``: the evaluation has no
    oracle and no ablation row (it used to end the whole run with 'no episodes to
    summarise' after every stage had run)."""
    from dynoplan.envs.gear.evaluation import ABLATION_ROWS, controller_rows
    from dynoplan.pipeline.control_settings import ControllerSettings
    from dynoplan.seeding import episode_seeds

    seeds = episode_seeds(0, 3)
    rows = controller_rows(tmp_path, seeds, ControllerSettings(), ablation=ABLATION_ROWS,
                           oracle_episodes=0, ablation_episodes=0)
    assert "oracle" not in rows and not set(ABLATION_ROWS) & set(rows)
    assert rows and all(len(row[1]) == 3 for row in rows.values())
    some = controller_rows(tmp_path, seeds, ControllerSettings(), ablation=ABLATION_ROWS,
                           oracle_episodes=1, ablation_episodes=2)
    assert len(some["oracle"][1]) == 1
    assert all(len(some[name][1]) == 2 for name in ABLATION_ROWS)
