"""Learned models of the gear assembly (issue 5): goal heuristic, safety regions, dynamics.

:func:`train_gear_models` fits everything DynoPlan plans with by the pipeline's one fit,
:func:`~dynoplan.pipeline.fit.fit_models` (as every task's models are fitted), on the
gear's data and with the gear's :class:`~dynoplan.pipeline.fit.FitSettings`
(:data:`~dynoplan.envs.gear.learning.settings.DEFAULT_SETTINGS`), and measures it on
held-out trials (``metrics.json``):

- the goal heuristic ``G`` (:class:`~dynoplan.models.goal_network.GoalNetwork`, a Beta
  over progress) on every demonstration state, target = the demonstration's normalised
  time ``t / T`` (what ``infos["progress"]`` records; ``0`` for the reset observation);
- the safety regions of Eq. 5 (:class:`~dynoplan.models.regions.SafetyRegions`) of the
  options the demonstrations show: a Gaussian mixture with ``M`` chosen by BIC on the
  demonstration states, components assigned to options by their states' labels, and
  per-option thresholds calibrated by leaving demonstrations out (``region_fit="cv"``);
  an option registered after the paper's four has no region unless demonstrated;
- one dynamics model ``D_w`` per registered option (:class:`~dynoplan.models.neural_dynamics.
  MLPEnsembleDynamics`) on its runs at the decision rate (one step =
  :data:`~dynoplan.envs.gear.state.DECISION_STEPS` environment steps: ``fit_models``'
  ``dynamics_runs``), from the option transitions collected by ``dynoplan gear collect``
  or, without them, from the demonstrations subsampled
  (:func:`~dynoplan.pipeline.fit_data.decision_runs`), each option's spread calibrated
  on runs held back from its fit (``FitSettings.dynamics_calibration``).

The goal heuristic and the regions read named feature maps
(:mod:`dynoplan.envs.gear.features`; ``objects`` and ``relative`` by default, the same
in ``dynoplan gear train`` and ``dynoplan gear run``): the gripper, the tool relative to
the gear and the gear, and for the regions also the capped tool-hand distance; not the
arm's joint angles. The planner asks the goal about the ends of imagined option runs;
the dynamics predict the tool and the gear there much better than the joints, so a goal
that reads the joints scores an imagined insertion far below what really comes of it
(``metrics.json``'s ``dynamics.<option>.goal_end_gap``). The human enters planning
through the dynamics models (which predict all 22 columns), the terminations and the
regions' capped distance.

What is the gear's own here is reading its datasets and the held-out measurement of
``metrics.json``; the models folder is the pipeline's
(:meth:`~dynoplan.pipeline.fit.FittedModels.write`, with the seed and the state's names
in its manifest; :func:`~dynoplan.envs.gear.models_folder.load_gear_models` reads it).
The rest lives in :mod:`.settings` (the gear's
:class:`~dynoplan.pipeline.fit.FitSettings` and
:class:`~dynoplan.envs.gear.learning.settings.GearMetricsSettings`), :mod:`.data`
(datasets to arrays) and :mod:`.metrics` (far-away states).
"""

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from dynoplan.data import Episode
from dynoplan.envs.gear.features import FEATURE_MAPS, FeatureMap, feature_map
from dynoplan.envs.gear.learning.data import (
    CAUTIOUS,
    check_disjoint,
    demo_arrays,
    option_trajectories,
    read_demos,
    read_labelled,
)
from dynoplan.envs.gear.learning.metrics import far_states
from dynoplan.envs.gear.learning.settings import (
    DEFAULT_METRICS,
    DEFAULT_SETTINGS,
    QUICK_METRICS,
    QUICK_SETTINGS,
    GearMetricsSettings,
)
from dynoplan.envs.gear.models_folder import METRICS_FILE, TASK_NAME
from dynoplan.envs.gear.options.catalog import gear_option, gear_option_names
from dynoplan.envs.gear.state import DECISION_STEPS, STATE_DIM, STATE_NAMES, PlannerState
from dynoplan.errors import DynoplanError
from dynoplan.io import ensure_writable_dir, write_json
from dynoplan.models.evaluation import (
    EnsembleModel,
    calibration,
    n_step_report,
    one_step_error,
    option_end_gap,
)
from dynoplan.models.features import GoalOnFeatures, RegionsOnFeatures
from dynoplan.models.folder import MANIFEST_FILE
from dynoplan.models.goal_network import GoalTrainingReport, evaluate_goal
from dynoplan.models.neural_dynamics import MLPEnsembleDynamics
from dynoplan.models.trainer import TrainingReport, deterministic_training
from dynoplan.options.state_map import (
    CoordinateMap,
    MappedDynamics,
    StateMap,
)
from dynoplan.pipeline.fit import (
    FitSettings,
    FittedModels,
    GoalModel,
    RegionsModel,
    dynamics_epochs,
    fit_models,
)
from dynoplan.pipeline.fit_data import (
    decision_runs,
    labelled_states,
    option_transitions,
    split_runs,
)
from dynoplan.pipeline.fit_dynamics import CALIBRATION_LEVEL, ensemble_fitter
from dynoplan.progress import track
from dynoplan.timing import StageClock
from dynoplan.types import FloatArray, IntArray

__all__ = ["gear_state_maps", "train_gear_models"]


def train_gear_models(demos: Path, transitions: Path | None, out: Path, seed: int,
                      heldout_demos: Path, quick: bool, progress: bool,
                      settings: FitSettings | None = None,
                      measures: GearMetricsSettings | None = None,
                      region_demos: Path | None = None,
                      region_starts: Path | None = None,
                      own_states: bool = False) -> dict[str, Any]:
    """Fit the goal heuristic, the safety regions and one dynamics model per option.

    Args:
        demos: the demonstrations dataset (``dynoplan gear demos``): option labels and
            progress; trains the goal heuristic and the regions (and the dynamics
            without ``transitions``).
        transitions: option transitions at the decision rate (``dynoplan gear collect``);
            ``None``: the demonstrations subsampled
            (:func:`~dynoplan.pipeline.fit_data.decision_runs`).
        out: folder for the models, ``models.json`` and ``metrics.json``.
        seed: seeds every fit, split and evaluation draw.
        heldout_demos: held-out trials, not among ``demos``, for the goal and region
            metrics (``dynoplan gear demos --heldout``; ``dynoplan gear train`` records
            them when none are given:
            :func:`~dynoplan.envs.gear.stages.learned_models`).
        quick: :data:`QUICK_SETTINGS` and :data:`QUICK_METRICS` instead of
            :data:`DEFAULT_SETTINGS` and :data:`DEFAULT_METRICS`.
        progress: progress bars on stderr.
        settings, measures: override ``quick``.
        region_demos: the demonstrations the safety regions are fitted on (default:
            ``demos``; the improvement rounds' ``regions`` False: the demonstrator's alone).
        region_starts: start states labelled by the operator's first choice
            (:func:`~dynoplan.envs.gear.stages.start_states`), which widen the regions
            where the options start the task (``None``: none).
        own_states: every option whose registry record declares its own state
            (:attr:`~dynoplan.envs.gear.options.registry.GearOption.state_map`) gets its
            dynamics on that state; the models folder records which
            (:attr:`~dynoplan.pipeline.fit.FittedModels.option_state_dims`), and the
            controllers roll those options in it (``False``: every option on the planner
            state).

    Returns:
        The content of ``metrics.json``. The model files are the same to the bit for the
        same data and ``seed`` on one machine: every fit runs inside
        :func:`~dynoplan.models.trainer.deterministic_training` and draws from
        generators seeded from ``seed``; only ``metrics.json``'s ``seconds`` differ.

    Raises:
        DynoplanError: unreadable or mislabelled datasets, held-out trials that share
            seeds with the demonstrations, too little data for an option, or an
            unwritable ``out``.
    """
    cfg = settings or (QUICK_SETTINGS if quick else DEFAULT_SETTINGS)
    if cfg.region_undemonstrated != "everywhere" or cfg.outcome_initiation:
        raise DynoplanError("the gear's models leave undemonstrated options without a region "
                            "(region_undemonstrated='everywhere') and learn initiation from "
                            "outcome runs ('gear outcomes'), not in training")
    if cfg.option_model != "step":
        raise DynoplanError("the gear's dynamics predict one decision ahead "
                            "(option_model='step'): its option runs do not record where a "
                            "run was cut short, which an option model to the end needs")
    cfg.validate()
    for name in (cfg.goal_features, cfg.region_features):  # one line before any work
        gear_features(name)
    measure = measures or (QUICK_METRICS if quick else DEFAULT_METRICS)
    started = time.perf_counter()
    out = ensure_writable_dir(out)
    planner = PlannerState()
    train_set = read_demos(demos, "demonstrations")
    clock = StageClock()

    region_set = list(train_set if region_demos is None
                      else read_demos(region_demos, "region demonstrations"))
    start_set = ([] if region_starts is None
                 else list(read_labelled(region_starts, "start states")))
    held_set = read_demos(heldout_demos, "held-out trials")
    check_disjoint(train_set, held_set, heldout_demos)
    if transitions is None:
        dyn_train = decision_runs(list(train_set), DECISION_STEPS)
        dyn_held = decision_runs(list(held_set), DECISION_STEPS)
        dynamics_data = "demonstrations subsampled"
    else:
        collected = read_labelled(transitions, "option transitions")
        steps = collected.metadata.extra.get("decision_steps", DECISION_STEPS)
        if steps != DECISION_STEPS:
            raise DynoplanError(f"{transitions}: recorded every {steps} environment steps, "
                                f"the models step every {DECISION_STEPS}")
        dyn_train, dyn_held = split_runs(list(collected), measure.dynamics_heldout_fraction,
                                         np.random.default_rng([seed, 1]))
        dynamics_data = "option transitions"

    held = demo_arrays(held_set, planner)
    # a folder half-rewritten by a failed run must not load as a set of models
    for stale in (MANIFEST_FILE, METRICS_FILE):
        (out / stale).unlink(missing_ok=True)
    maps = gear_state_maps() if own_states else {}
    options = [replace(gear_option(n), state_map=maps.get(n)) for n in gear_option_names()]
    goal_training: list[GoalTrainingReport] = []
    dynamics_training: dict[str, TrainingReport] = {}
    done: dict[str, Any] = {}

    def fit() -> None:  # the pipeline's fit, then the folder the gear's controllers read
        fitted = fit_models(options, dyn_train, list(train_set), cfg, seed, planner,
                            ensemble_fitter(cfg, dynamics_training), task=TASK_NAME,
                            feature_maps=FEATURE_MAPS, region_demos=region_set,
                            region_starts=start_set, dynamics_runs=dyn_train,
                            goal_training=goal_training)
        done["models"] = replace(fitted, extra={**fitted.extra, "seed": seed,
                                                "state_names": list(STATE_NAMES)})
        done["models"].write(out)

    def goal_metrics() -> None:
        done["goal"] = _goal_report(done["models"].goal, goal_training[0],
                                    done["models"].report["goal"], held)

    def region_metrics() -> None:
        done["regions"] = _regions_report(done["models"].regions,
                                          done["models"].report["regions"], region_set,
                                          list(held_set), planner, cfg, measure, seed)

    def dynamics_metrics() -> None:
        done["dynamics"] = _dynamics_reports(done["models"], dynamics_training, dyn_held,
                                             planner, cfg, measure, seed, maps)

    stages: list[tuple[str, Callable[[], None]]] = [
        ("fit", fit), ("goal metrics", goal_metrics), ("region metrics", region_metrics),
        ("dynamics metrics", dynamics_metrics)]
    with deterministic_training():  # the same files whatever threads the caller set
        for name, run in track(stages, "gear models", total=len(stages), enabled=progress):
            clock.stage(name, run)
    goal, regions, dyn_reports = done["goal"], done["regions"], done["dynamics"]
    # coverage over all held-out transitions (options without any do not count)
    dyn_rows = [r for r in dyn_reports.values() if r["coverage_90"] is not None]
    held_rows = np.array([r["transitions_heldout"] for r in dyn_rows], dtype=np.float64)
    coverages = np.array([r["coverage_90"] for r in dyn_rows], dtype=np.float64)
    seconds = {**clock.rounded(2), "total": round(time.perf_counter() - started, 2)}
    metrics: dict[str, Any] = {
        "goal_spearman": goal["spearman"],
        "goal_mae": goal["mae"],
        "region_inside_rate": regions["inside_rate"],
        "region_far_outside_rate": regions["far_outside_rate"],
        "dynamics_coverage_90": float(np.sum(coverages * held_rows) / held_rows.sum())
        if held_rows.sum() else None,
        "dynamics_data": dynamics_data,
        "goal": goal,
        "regions": regions,
        "dynamics": dyn_reports,
        "data": {"demos": str(demos), "demo_episodes": len(train_set),
                 "heldout_demos": str(heldout_demos), "heldout_episodes": len(held_set),
                 "transitions": None if transitions is None else str(transitions),
                 "transition_episodes_train": len(dyn_train),
                 "transition_episodes_heldout": len(dyn_held)},
        "state_dim": STATE_DIM,
        "option_names": list(gear_option_names()),
        "option_states": {n: _state_names(m) for n, m in maps.items()},
        "decision_steps": DECISION_STEPS,
        "goal_features": list(gear_features(cfg.goal_features).names),
        "region_features": list(gear_features(cfg.region_features).names),
        "seed": seed,
        "settings": {**asdict(cfg), **asdict(measure),
                     "quick": settings is None and measures is None and quick},
        "seconds": seconds,
    }
    write_json(out / METRICS_FILE, metrics)
    return metrics


def gear_features(name: str | None) -> FeatureMap:
    """The gear's feature map ``name``: the goal heuristic and the regions read one."""
    if name is None:
        raise DynoplanError("the gear's goal heuristic and regions read a named feature map "
                            "(FitSettings.goal_features and region_features)")
    return feature_map(name)


def _goal_report(goal: GoalModel, training: GoalTrainingReport,
                 fit_report: Mapping[str, Any],
                 held: Sequence[tuple[FloatArray, FloatArray, IntArray]]) -> dict[str, Any]:
    """``metrics.json``'s ``goal``: the goal heuristic fitted by
    :func:`~dynoplan.pipeline.fit.fit_models` (on the demonstrations' states and their
    progress ``t / T``, which ``infos["progress"]`` records too; ``training`` and
    ``fit_report`` its network's training and the fit's report) measured on the held-out
    trials ``held``."""
    assert isinstance(goal, GoalOnFeatures)  # the gear's goal reads a feature map
    f, network = goal.features, goal.network
    xh = np.concatenate([f(s) for s, _, _ in held])
    yh = np.concatenate([p for _, p, _ in held])
    pooled = evaluate_goal(network, xh, yh)
    interrupted = np.array([bool((lab == CAUTIOUS).any()) for _, _, lab in held])
    per_trial = [float(stats.spearmanr(network.mean_std(f(s))[0], p).statistic)
                 for s, p, _ in held]
    per_trial_mae = [float(np.mean(np.abs(network.mean_std(f(s))[0] - p)))
                     for s, p, _ in held]
    calm = [i for i in range(len(held)) if not interrupted[i]]
    calm_metrics = None
    if calm:
        calm_metrics = evaluate_goal(network, np.concatenate([f(held[i][0]) for i in calm]),
                                     np.concatenate([held[i][1] for i in calm]))
    return {
        "spearman": float(np.mean(per_trial)),
        "mae": float(np.mean(per_trial_mae)),
        "spearman_pooled": pooled["spearman"],
        "mae_pooled": pooled["mae"],
        "coverage_90": pooled["coverage_90"],
        "heldout_states": len(yh),
        "per_trial_spearman": per_trial,
        "per_trial_mae": per_trial_mae,
        "per_trial_interrupted": interrupted.tolist(),
        "uninterrupted": calm_metrics,
        "train_loss_first_last": [training.train_loss[0], training.train_loss[-1]],
        "train_states": fit_report["states"],
        "off_demo_states": fit_report["off_demo_states"],
        "note": "truth = the trial's normalised time (infos['progress']); spearman and "
                "mae are means over held-out trials of each trial's rank correlation and "
                "error along that trial (Fig. 3a's view: the planner ranks futures of one "
                "episode); *_pooled pool the states of all trials, where the same state has "
                "different normalised times in trials of different lengths. Trials "
                "'interrupted' had cautious_move steps (the expert slowed, waited or "
                "backed away for the human), where time advances but the state does not",
    }


def _regions_report(regions: RegionsModel | None, info: Mapping[str, Any],
                    train_set: Sequence[Episode], held_set: Sequence[Episode],
                    planner: PlannerState, cfg: FitSettings, measure: GearMetricsSettings,
                    seed: int) -> dict[str, Any]:
    """``metrics.json``'s ``regions``: the demonstrated options' regions fitted by
    :func:`~dynoplan.pipeline.fit.fit_models` on ``train_set`` (``info`` its report;
    undemonstrated options get none) measured on the held-out trials ``held_set`` and
    on states far from every demonstration."""
    assert isinstance(regions, RegionsOnFeatures)  # the gear's regions read a feature map
    features = regions.features
    names = gear_option_names()
    fitted = regions.regions
    s, y, _ = labelled_states(train_set, len(names), planner)
    # ``column`` maps an option's label to its region, -1 for none
    column = np.full(len(names), -1)
    column[[names.index(n) for n in regions.option_names]] = np.arange(len(regions.option_names))
    sh, yh, _ = labelled_states(held_set, len(names), planner)
    member = regions.contains_all(sh)  # (states, options with a region)
    mine = np.flatnonzero(column[yh] >= 0)  # held-out states of options with a region
    own = member[mine, column[yh[mine]]]
    by_option = {n: (float(own[yh[mine] == k].mean()) if (yh == k).any() else None)
                 for k, n in enumerate(names) if column[k] >= 0}
    # how specific each region is: held-out states of the other options inside it
    others = {n: float(member[yh != k, column[k]].mean()) if (yh != k).any() else None
              for k, n in enumerate(names) if column[k] >= 0}
    train_own = regions.contains_all(s)[np.arange(len(s)), column[y]]
    far, far_info = far_states(s, sh, np.random.default_rng([seed, 2]), measure.far_states,
                               cfg.region_reg_covar, features)
    far_outside = float((~regions.contains_all(far).any(axis=1)).mean()) if len(far) else None
    return {
        "inside_rate": float(own.mean()),
        "inside_rate_by_option": by_option,
        "inside_any_rate": float(member.any(axis=1).mean()),
        "other_options_inside_rate": others,
        "train_inside_rate": float(train_own.mean()),
        "far_outside_rate": far_outside,
        "far_states": far_info,
        "heldout_states": len(yh),
        **info,
        "members": fitted.members.astype(int).tolist(),
    }


def gear_state_maps() -> dict[str, StateMap]:
    """The registered options that declare their own state, and its map
    (:attr:`~dynoplan.envs.gear.options.registry.GearOption.state_map`)."""
    maps = {name: gear_option(name).state_map for name in gear_option_names()}
    return {name: m for name, m in maps.items() if m is not None}


def _state_names(state_map: StateMap) -> list[str]:
    """The names of an option's own state's values: the planner state's for a
    :class:`~dynoplan.options.state_map.CoordinateMap`, else ``z0, z1, ...``."""
    if isinstance(state_map, CoordinateMap):
        return [STATE_NAMES[i] for i in state_map.indices]
    return [f"z{i}" for i in range(state_map.option_dim)]


def _dynamics_reports(fitted: FittedModels, training: Mapping[str, TrainingReport],
                      held_eps: Sequence[Episode], planner: PlannerState, cfg: FitSettings,
                      measure: GearMetricsSettings, seed: int,
                      maps: Mapping[str, StateMap]) -> dict[str, Any]:
    """``metrics.json``'s ``dynamics``: every registered option's dynamics, fitted by
    :func:`~dynoplan.pipeline.fit.fit_models` (on its own state when ``maps`` holds one;
    ``training`` their training reports), measured on ``held_eps`` in the planner
    state."""
    names = gear_option_names()
    goal = fitted.goal

    def score(states: FloatArray) -> FloatArray:
        return goal.mean_std(states)[0]

    reports: dict[str, Any] = {}
    for k, name in enumerate(names):
        model = fitted.dynamics[name]
        assert isinstance(model, MLPEnsembleDynamics)  # the default fitter's
        own = maps.get(name)
        row = fitted.report["dynamics"][name]
        reports[name] = _dynamics_report(
            k, name, model if own is None else MappedDynamics(model, own), training[name],
            row, row.get("calibration_runs", 0), held_eps, planner, cfg, measure, seed,
            score, STATE_NAMES if own is None else _state_names(own))
    return reports


def _dynamics_report(k: int, name: str, model: EnsembleModel, report: TrainingReport,
                     fit_row: dict[str, Any], calibration_episodes: int,
                     held_eps: Sequence[Episode], planner: PlannerState, cfg: FitSettings,
                     measure: GearMetricsSettings, seed: int,
                     goal: Callable[[FloatArray], FloatArray],
                     fitted_names: Sequence[str]) -> dict[str, Any]:
    """Option ``name``'s (label ``k``) row of ``metrics.json``'s ``dynamics``: its fit
    (``fit_row`` of :func:`~dynoplan.pipeline.fit_dynamics.fit_dynamics`, ``report`` of
    its training; ``fitted_names`` the values its model reads) and, on its held-out runs
    among ``held_eps``, one-step, n-step and calibration errors and the end gap of the
    goal's mean score ``goal``, all on planner states (``model`` predicts them)."""
    names = gear_option_names()
    sh, nxth = option_transitions(held_eps, names, planner)[name]
    epochs = dynamics_epochs(fit_row["transitions"], cfg)
    std_scale = fit_row["std_scale"]
    row: dict[str, Any] = {
        "transitions_train": fit_row["transitions"],
        "transitions_heldout": len(sh),
        "holdout_nll_first_best": [report.holdout_loss[0],
                                   report.holdout_loss[report.best_epoch]]
        if report.holdout_loss else None,
        "train_nll_first_last": [report.train_loss[0], report.train_loss[-1]],
        "epochs": epochs,
        "best_epoch": report.best_epoch,
        "calibration_episodes": calibration_episodes,
        "std_scale": None if std_scale is None else dict(zip(
            fitted_names, np.round(std_scale, 3).tolist(), strict=True)),
    }
    if len(sh) == 0:  # nothing of this option among the held-out data: no report
        return {**row, "one_step_rmse": None, "one_step_no_change_rmse": None,
                "one_step_ratio": None, "n_step": None, "goal_end_gap": None,
                "coverage_90": None}
    one = one_step_error(model, sh, nxth)
    cal = calibration(model, sh, nxth, CALIBRATION_LEVEL)
    trajectories = option_trajectories(held_eps, planner, k)
    multi = n_step_report(model, trajectories, measure.n_step, measure.rollouts,
                          np.random.default_rng([seed, 3, k]))
    # each held-out run as the planner sees it: from its start, at most the horizon
    lengths = [min(len(run) - 1, measure.end_gap_horizon) for run in trajectories]
    starts = np.array([run[0] for run in trajectories]).reshape(-1, STATE_DIM)
    ends = np.array([run[m] for run, m in zip(trajectories, lengths, strict=True)]
                    ).reshape(-1, STATE_DIM)
    end_gap = option_end_gap(model, starts, ends, lengths, goal, measure.rollouts,
                             np.random.default_rng([seed, 5, k]))
    if end_gap is not None:
        end_gap["horizon"] = measure.end_gap_horizon
    return {
        **row,
        "one_step_rmse": one.model_rmse_total,
        "one_step_no_change_rmse": one.baseline_rmse_total,
        "one_step_ratio": one.ratio,
        "n_step": multi,
        "goal_end_gap": end_gap,
        "coverage_90": cal.coverage,
        "coverage_90_by_dimension": dict(zip(STATE_NAMES, cal.per_dimension.tolist(),
                                             strict=True)),
    }

