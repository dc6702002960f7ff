"""Learned gear-assembly models (issue 5): training, metrics, storage, figures.

The Eq. 5 hand computation in 2-D lives in tests/test_regions.py.
"""

import hashlib
import json
import shutil
from dataclasses import replace
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest

from dynoplan.data import Episode, read_dataset
from dynoplan.envs.gear.controllers import GEAR_CONTROL, option_state_map
from dynoplan.envs.gear.demonstrations import record_demos
from dynoplan.envs.gear.features import RELATIVE, TASK
from dynoplan.envs.gear.learning.data import write_demonstration_transitions
from dynoplan.envs.gear.learning.settings import QUICK_METRICS, QUICK_SETTINGS
from dynoplan.envs.gear.learning.training import train_gear_models
from dynoplan.envs.gear.models_folder import HELDOUT_DIR, METRICS_FILE, load_gear_models
from dynoplan.envs.gear.options import gear_option_names
from dynoplan.envs.gear.options.catalog import network_files
from dynoplan.envs.gear.options.insert import INSERT_NAME, INSERT_STATE
from dynoplan.envs.gear.reports.figures import GOAL_FIGURE, TSNE_FIGURE, make_gear_figures
from dynoplan.envs.gear.stages import learned_models
from dynoplan.envs.gear.state import DECISION_STEPS, STATE_DIM, STATE_NAMES, PlannerState
from dynoplan.errors import DynoplanError
from dynoplan.models.folder import GOAL_FILE, MANIFEST_FILE, REGIONS_FILE, dynamics_file
from dynoplan.models.goal_network import GoalNetwork
from dynoplan.models.regions import SafetyRegions
from dynoplan.options.state_map import MappedDynamics
from dynoplan.pipeline.evaluate import no_effect_tolerance
from dynoplan.pipeline.fit import fit_regions_cross_validated
from dynoplan.pipeline.fit_data import decision_runs, episode_states, option_transitions

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = tmp_path_factory.mktemp("gear-models")
    record_demos(3, seed=0, out=root / "demos", progress=False)
    record_demos(2, seed=1000, out=root / "heldout", progress=False)
    return root


@pytest.fixture(scope="module")
def trained(data):
    out = data / "models"
    metrics = train_gear_models(data / "demos", None, out, seed=0,
                                heldout_demos=data / "heldout", quick=True, progress=False)
    return out, metrics


def test_metrics_file_has_every_field_and_the_models_load(trained):
    out, metrics = trained
    on_disk = json.loads((out / METRICS_FILE).read_text())
    assert on_disk["goal_spearman"] == pytest.approx(metrics["goal_spearman"])
    for key in ("goal_spearman", "goal_mae", "region_inside_rate", "region_far_outside_rate",
                "dynamics_coverage_90"):
        assert np.isfinite(on_disk[key]), key
    assert on_disk["dynamics_data"] == "demonstrations subsampled"
    assert set(on_disk["dynamics"]) == set(gear_option_names())
    for row in on_disk["dynamics"].values():
        assert row["one_step_rmse"] > 0 and row["one_step_no_change_rmse"] > 0
        assert row["coverage_90"] > 0.4  # an over-confident model covers next to nothing
    # the calibrated 90% intervals cover most held-out next states (3 demonstrations)
    assert on_disk["dynamics_coverage_90"] > 0.75
    # held-out states of the demonstrated task, not memorised ones
    assert on_disk["goal"]["heldout_states"] > 100 and on_disk["data"]["heldout_episodes"] == 2
    # held-out trial 0 goes wait, pick, move, insert, which three demonstrations cover;
    # trial 1 backs away from the human mid-insertion, which they do not
    assert on_disk["goal"]["per_trial_spearman"][0] > 0.9
    assert on_disk["region_inside_rate"] > 0.8
    # the regions read the relative features by default (as in gear run): the tool's
    # offset from the gear and the capped tool-hand distance, not the arm's joints
    assert on_disk["region_features"] == list(RELATIVE.names)
    assert 0.0 <= on_disk["region_far_outside_rate"] <= 1.0
    assert on_disk["regions"]["far_states"]["far"] > 100

    models = load_gear_models(out)
    assert models.option_names == list(gear_option_names())
    states = np.zeros((5, STATE_DIM))
    mean, std = models.goal.mean_std(states)
    assert mean.shape == (5,) and np.all((mean >= 0) & (mean <= 1)) and np.all(std >= 0)
    assert models.regions.contains_all(states).shape == (5, len(gear_option_names()))
    nxt = models.stacked_dynamics().sample(np.zeros((4, 8, STATE_DIM)), np.random.default_rng(0))
    assert nxt.shape == (4, 8, STATE_DIM) and np.isfinite(nxt).all()


def test_the_models_record_the_spread_of_the_fitted_states_for_the_controller(data, trained):
    """As a pipeline fit, the gear's models record every planner-state coordinate's
    spread over the fitted data (here the demonstrations and their decision-rate runs),
    which the controller's no-effect share scales by."""
    out, _ = trained
    demos = list(read_dataset(data / "demos"))
    planner = PlannerState()
    fitted = [*decision_runs(demos, DECISION_STEPS), *demos]
    spread = np.concatenate([episode_states(e, planner) for e in fitted]).std(axis=0)
    scale = load_gear_models(out).state_scale
    assert scale is not None and scale.shape == (STATE_DIM,)
    np.testing.assert_array_equal(scale, spread)
    share = replace(GEAR_CONTROL, no_effect_tolerance=None, no_effect_share=0.01)
    np.testing.assert_array_equal(no_effect_tolerance(share, scale), 0.01 * spread)


def test_task_feature_regions_reject_states_far_from_every_demonstration(data, tmp_path):
    """On the ``task`` features (arm joints, gripper, tool, gear), a state far from every
    demonstration in the state lies outside every region; the ``relative`` features
    forget where the arm's joints are, so there the far states are not all outside."""
    metrics = train_gear_models(data / "demos", None, tmp_path / "models", seed=0,
                                heldout_demos=data / "heldout", quick=True, progress=False,
                                settings=replace(QUICK_SETTINGS, region_features=TASK.name))
    assert metrics["region_features"] == list(TASK.names)
    assert metrics["region_far_outside_rate"] >= 0.99


def test_training_on_a_tiny_dataset_reduces_held_out_loss(trained):
    _, metrics = trained
    for name, row in metrics["dynamics"].items():
        first, best = row["holdout_nll_first_best"]
        assert best < first, name
    first, last = metrics["goal"]["train_loss_first_last"]
    assert last < first


def test_save_and_load_round_trip_bit_exactly(trained, tmp_path):
    out, _ = trained
    models = load_gear_models(out)
    models.goal.network.save(tmp_path / GOAL_FILE)
    models.regions.regions.save(tmp_path / REGIONS_FILE)
    for name, model in models.dynamics.items():
        model.save(tmp_path / dynamics_file(name))
    for file in [GOAL_FILE, REGIONS_FILE, *(dynamics_file(n) for n in gear_option_names())]:
        assert (tmp_path / file).read_bytes() == (out / file).read_bytes(), file
    again = load_gear_models(out)
    states = np.random.default_rng(0).normal(size=(20, STATE_DIM))
    np.testing.assert_array_equal(again.goal.mean_std(states)[0], models.goal.mean_std(states)[0])


def test_the_insertion_on_its_own_state_rolls_there_and_leaves_the_rest_alone(data, trained,
                                                                              tmp_path):
    """With ``own_states`` the insertion's dynamics read its 16 values (arm, gripper, tool,
    gear, the human's hand); the folder says so, the controllers roll it through its map,
    and the other options' models are the same files as without."""
    out, _ = trained
    own = tmp_path / "own"
    metrics = train_gear_models(data / "demos", None, own, seed=0,
                                heldout_demos=data / "heldout", quick=True, progress=False,
                                own_states=True)
    assert metrics["option_states"] == {INSERT_NAME: [STATE_NAMES[i]
                                                      for i in INSERT_STATE.indices]}
    models = load_gear_models(own)
    assert models.option_state_dims == {INSERT_NAME: 16}
    assert models.dynamics[INSERT_NAME].state_dim == 16
    for name in gear_option_names():
        same = (own / dynamics_file(name)).read_bytes() == (out / dynamics_file(name)).read_bytes()
        assert same == (name != INSERT_NAME), name
        assert option_state_map(name, models) == (INSERT_STATE if name == INSERT_NAME else None)
    # a rollout step of the insertion keeps the right arm, which holds the peg, as it was
    states = np.array(next(iter(read_dataset(data / "demos"))).observations[:5])
    planner = PlannerState()(states)
    step = MappedDynamics(models.dynamics[INSERT_NAME], INSERT_STATE).sample(
        planner, np.random.default_rng(0))
    kept = [i for i in range(STATE_DIM) if i not in INSERT_STATE.indices]
    np.testing.assert_array_equal(step[:, kept], planner[:, kept])
    assert not np.allclose(step[:, list(INSERT_STATE.indices)],
                           planner[:, list(INSERT_STATE.indices)])
    # a folder whose own state the registered option does not declare is refused
    wrong = replace(models, extra={**models.extra, "option_state_dims": {"pick": 16}})
    with pytest.raises(DynoplanError, match=r"option 'pick'.*declares none"):
        option_state_map("pick", wrong)


def _copy(out: Path, tmp_path: Path) -> Path:
    folder = tmp_path / "models"
    shutil.copytree(out, folder)
    return folder


def _one_line_error(folder: Path, match: str) -> None:
    with pytest.raises(DynoplanError, match=match) as info:
        load_gear_models(folder)
    assert "\n" not in str(info.value)


def test_missing_truncated_and_mismatched_files_are_rejected(trained, tmp_path):
    out, _ = trained
    _one_line_error(tmp_path, "models.json: not found")

    folder = _copy(out, tmp_path / "a")
    (folder / dynamics_file("insert")).unlink()
    _one_line_error(folder, "model file not found")

    folder = _copy(out, tmp_path / "b")
    data = (folder / REGIONS_FILE).read_bytes()
    (folder / REGIONS_FILE).write_bytes(data[: len(data) // 2])
    _one_line_error(folder, "truncated")

    folder = _copy(out, tmp_path / "c")
    (folder / MANIFEST_FILE).write_text("{not json")
    _one_line_error(folder, "not a readable models manifest")

    for key, value in (("state_dim", 12), ("option_names", ["pick", "insert"]),
                       ("stride", 5), ("task", "another")):
        folder = _copy(out, tmp_path / f"d-{key}")
        manifest = json.loads((folder / MANIFEST_FILE).read_text())
        manifest[key] = value
        (folder / MANIFEST_FILE).write_text(json.dumps(manifest))
        _one_line_error(folder, key)

    # a readable model of the wrong shape, with a checksum that matches it
    folder = _copy(out, tmp_path / "e")
    other, _ = GoalNetwork.fit(np.random.default_rng(0).normal(size=(40, 3)),
                               np.linspace(0, 1, 40), hidden=4, epochs=1)
    other.save(folder / GOAL_FILE)
    manifest = json.loads((folder / MANIFEST_FILE).read_text())
    manifest["goal"]["sha256"] = hashlib.sha256((folder / GOAL_FILE).read_bytes()).hexdigest()
    (folder / MANIFEST_FILE).write_text(json.dumps(manifest))
    _one_line_error(folder, "reads 3 features")
    # a manifest that points outside its folder
    folder = _copy(out, tmp_path / "g")
    manifest = json.loads((folder / MANIFEST_FILE).read_text())
    shutil.copy(folder / GOAL_FILE, tmp_path / GOAL_FILE)
    manifest["goal"]["file"] = f"../{GOAL_FILE}"
    (folder / MANIFEST_FILE).write_text(json.dumps(manifest))
    _one_line_error(folder, "outside the models folder")
    # models from older formats: the gear's v2 (kind gear_models), the pipeline's v1
    folder = _copy(out, tmp_path / "f")
    manifest = json.loads((folder / MANIFEST_FILE).read_text())
    manifest.update(kind="gear_models", format_version=2)
    (folder / MANIFEST_FILE).write_text(json.dumps(manifest))
    _one_line_error(folder, "format_version 2 is not 3.*dynoplan gear train")
    (folder / MANIFEST_FILE).write_text(json.dumps({"format_version": 1, "option_names": ["a"]}))
    _one_line_error(folder, "format_version 1 is not 3")
    # a feature map this task does not define
    folder = _copy(out, tmp_path / "h")
    manifest = json.loads((folder / MANIFEST_FILE).read_text())
    manifest["regions"]["features"] = "columns"
    (folder / MANIFEST_FILE).write_text(json.dumps(manifest))
    _one_line_error(folder, "feature map 'columns'")


def test_train_records_missing_held_out_trials_by_the_demonstrations_demonstrator(data,
                                                                                  tmp_path):
    """``gear train`` without ``--heldout``: the settings' held-out trials (quick: 3) from
    seed + 1000 in MODELS/heldout-demos, by whoever recorded the demonstrations (here the
    scripted expert, which needs no option network), and kept for the next fit."""
    out = tmp_path / "models"
    metrics = learned_models(data / "demos", None, out, 0, None, QUICK_SETTINGS, QUICK_METRICS,
                             progress=False)
    held = read_dataset(out / HELDOUT_DIR)
    assert len(held) == QUICK_METRICS.heldout_episodes == metrics["data"]["heldout_episodes"]
    assert held.metadata.seed == 1000 and held.metadata.extra["demonstrator"] == "expert"
    assert not any((out / f).exists() for f in network_files().values())
    recorded = (out / HELDOUT_DIR / "data" / "main_data.hdf5").stat().st_mtime_ns
    learned_models(data / "demos", None, out, 0, None, QUICK_SETTINGS, QUICK_METRICS,
                             progress=False)
    assert (out / HELDOUT_DIR / "data" / "main_data.hdf5").stat().st_mtime_ns == recorded


def test_held_out_trials_must_not_repeat_the_demonstrations(data, tmp_path):
    with pytest.raises(DynoplanError, match="share episode seeds"):
        train_gear_models(data / "demos", None, tmp_path / "m", seed=0,
                          heldout_demos=data / "demos", quick=True, progress=False)


def test_demonstrations_become_decision_rate_runs_of_one_option(tmp_path):
    labels = np.r_[np.zeros(25), np.ones(5), np.full(12, 3)].astype(np.int64)
    steps = len(labels)
    obs = np.arange((steps + 1) * 50, dtype=np.float64).reshape(steps + 1, 50) / 1e3
    demo = Episode(observations=obs, actions=np.zeros((steps, 13)), rewards=np.zeros(steps),
                   terminations=np.zeros(steps, bool), truncations=np.zeros(steps, bool),
                   infos={"option": labels}, seed=5)
    runs = decision_runs([demo], DECISION_STEPS)
    # option 0: steps 0..24, one run per offset 0..9; option 1 (5 steps): none;
    # option 3: steps 30..41 (observations 30..42), offsets 0..2 reach a second decision
    assert [int(r.options[0]) for r in runs] == [0] * DECISION_STEPS + [3] * 3
    first = runs[0]
    np.testing.assert_array_equal(first.observations, obs[[0, 10, 20]])
    np.testing.assert_array_equal(runs[-1].observations, obs[[32, 42]])
    names = gear_option_names()
    pairs = option_transitions(runs, names)
    assert [n for n in names if len(pairs[n][0])] == [names[0], names[3]]
    # every transition is DECISION_STEPS environment steps of one option
    for s, nxt in pairs.values():
        np.testing.assert_allclose(nxt - s, DECISION_STEPS * 50 / 1e3)


def test_models_train_on_a_transitions_dataset_at_the_decision_rate(data, tmp_path):
    path = write_demonstration_transitions(data / "demos", tmp_path / "transitions")
    dataset = read_dataset(path)
    assert dataset.metadata.option_names == list(gear_option_names())
    assert dataset.metadata.extra["decision_steps"] == DECISION_STEPS
    for episode in dataset:
        assert (episode.actions == episode.options).all()
        assert len(np.unique(episode.options)) == 1
    metrics = train_gear_models(data / "demos", path, tmp_path / "m", seed=0,
                                heldout_demos=data / "heldout", quick=True, progress=False)
    assert metrics["dynamics_data"] == "option transitions"
    assert metrics["data"]["transition_episodes_heldout"] > 0
    assert load_gear_models(tmp_path / "m").option_names == list(gear_option_names())

    slower = write_demonstration_transitions(data / "demos", tmp_path / "every5", 5)
    with pytest.raises(DynoplanError, match="recorded every 5 environment steps"):
        train_gear_models(data / "demos", slower, tmp_path / "m5", seed=0,
                          heldout_demos=data / "heldout", quick=True, progress=False)


def test_cross_validated_thresholds_admit_unseen_demonstrations():
    # five "demonstrations" per option, each a small cluster offset from the others
    rng = np.random.default_rng(0)
    centres = {0: np.array([0.0, 0.0]), 1: np.array([6.0, 0.0])}

    def demos(n_demos: int, seed: int):
        r = np.random.default_rng(seed)
        xs, ys, gs = [], [], []
        for g in range(n_demos):
            for k, c in centres.items():
                xs.append(c + r.normal(0, 0.6, 2) + r.normal(0, 0.1, (40, 2)))
                ys.append(np.full(40, k))
                gs.append(np.full(40, g))
        return np.concatenate(xs), np.concatenate(ys), np.concatenate(gs)

    x, y, g = demos(5, 1)
    kw = dict(reg_covar=1e-6, max_components=6, coverage=0.99, seed=0)
    plain = SafetyRegions.fit(x, y, ["a", "b"], **kw)
    wide, info = fit_regions_cross_validated(x, y, g, ["a", "b"], cv_coverage=0.97, **kw)
    assert info["folds"] == 5 and min(info["slack_nats"]) >= 0.0
    np.testing.assert_allclose(plain.log_thresholds - wide.log_thresholds, info["slack_nats"],
                               atol=1e-3)
    xh, yh, _ = demos(20, 2)
    inside = lambda r: r.contains_all(xh)[np.arange(len(xh)), yh].mean()  # noqa: E731
    assert inside(wide) >= 0.93 and inside(wide) > inside(plain)
    assert not wide.contains_all(rng.normal(30.0, 1.0, size=(50, 2))).any()


@pytest.mark.parametrize("change", [{"region_undemonstrated": "runs"},
                                    {"outcome_initiation": True}])
def test_fit_settings_the_gear_does_not_train_are_rejected(tmp_path, change):
    settings = replace(QUICK_SETTINGS, **change)
    with pytest.raises(DynoplanError, match="undemonstrated options without a region"):
        train_gear_models(tmp_path / "demos", None, tmp_path / "m", seed=0,
                          heldout_demos=tmp_path / "held", quick=True, progress=False,
                          settings=settings)
    assert not (tmp_path / "m").exists()  # rejected before anything is written


def test_an_option_model_to_the_end_is_rejected_before_anything_is_written(tmp_path):
    with pytest.raises(DynoplanError, match="one decision ahead"):
        train_gear_models(tmp_path / "demos", None, tmp_path / "m", seed=0,
                          heldout_demos=tmp_path / "held", quick=True, progress=False,
                          settings=replace(QUICK_SETTINGS, option_model="end"))
    assert not (tmp_path / "m").exists()


@pytest.mark.parametrize("field", ["goal_features", "region_features"])
def test_a_fit_without_a_feature_map_is_one_error_before_anything_is_written(tmp_path, field):
    with pytest.raises(DynoplanError, match="read a named feature map"):
        train_gear_models(tmp_path / "demos", None, tmp_path / "m", seed=0,
                          heldout_demos=tmp_path / "held", quick=True, progress=False,
                          settings=replace(QUICK_SETTINGS, **{field: None}))
    assert not (tmp_path / "m").exists()


def test_the_goal_off_the_demonstrations_fits_the_option_runs_states_too(data, trained,
                                                                          tmp_path):
    """``goal_off_demos`` is not silently ignored by the gear's fit: the goal network also
    fits the states of the runs the dynamics learn from, and scores differently."""
    metrics = train_gear_models(data / "demos", None, tmp_path / "m", seed=0,
                                heldout_demos=data / "heldout", quick=True, progress=False,
                                settings=replace(QUICK_SETTINGS, goal_off_demos=True))
    plain = trained[1]["goal"]
    assert plain["off_demo_states"] == 0
    assert metrics["goal"]["off_demo_states"] > 0
    assert metrics["goal"]["train_states"] == plain["train_states"]
    assert (tmp_path / "m" / GOAL_FILE).read_bytes() != (trained[0] / GOAL_FILE).read_bytes()


def test_figures_are_drawn_from_the_trained_models(trained, data, tmp_path):
    out, _ = trained
    summary = make_gear_figures(out, data / "demos", data / "heldout", tmp_path / "figs",
                                seed=0, trial=1, max_points=300)
    for name in (GOAL_FIGURE, TSNE_FIGURE):
        image = matplotlib.image.imread(tmp_path / "figs" / name)
        assert image.ndim == 3 and image.shape[0] > 300
    assert summary["fig3b"]["points"] == 300
    # Fig. 3(a) shows the same numbers as metrics.json for that held-out trial
    assert summary["fig3a"]["spearman"] == pytest.approx(
        json.loads((out / METRICS_FILE).read_text())["goal"]["per_trial_spearman"][1])
    assert json.loads((tmp_path / "figs" / "figures.json").read_text())["fig3a"]["trial"] == 1
    with pytest.raises(DynoplanError, match="--trial"):
        make_gear_figures(out, data / "demos", data / "heldout", tmp_path / "x", trial=7)
