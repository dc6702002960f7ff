"""Learning what the planner needs from labelled episodes: :func:`fit_models` and its
result :class:`FittedModels` (the one in-memory form of a models folder). Each part is a
module of its own, whose public names this module re-exports:

- :mod:`~dynoplan.pipeline.fit_settings`: :class:`FitSettings`;
- :mod:`~dynoplan.pipeline.fit_data`: states, labels, transitions and runs of episodes;
- :mod:`~dynoplan.pipeline.fit_dynamics`: per option, a dynamics model ``D_w`` on its
  transitions (:func:`fit_dynamics`); by default a probabilistic MLP ensemble
  (:class:`~dynoplan.models.neural_dynamics.MLPEnsembleDynamics`), any other learner can
  be passed as a :data:`DynamicsFitter`;
- :mod:`~dynoplan.pipeline.fit_goal`: the goal heuristic ``G`` on the demonstrations'
  progress (:func:`fit_goal`);
- :mod:`~dynoplan.pipeline.fit_regions`: the safety regions of Eq. 5 on the
  demonstrations' option labels (:func:`fit_option_regions`);
- :mod:`~dynoplan.pipeline.fit_initiation`: initiation sets learned from outcomes.

**Model stride.** With ``stride = k > 1`` a dynamics model predicts ``k`` environment
steps at once (``s_{t+k}`` from ``s_t`` while the option runs), so a planning horizon of
``n`` model steps looks ``n * k`` environment steps ahead with ``k`` times fewer model
calls and less compounding error. The planner then draws termination once per model
step with ``1 - (1 - beta(s))^k`` (:class:`StridedTermination`), the probability that
the option stops somewhere in those ``k`` steps when ``beta`` hardly changes over them.
"""

import os
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from dynoplan.adapters.spec import OptionSpec
from dynoplan.control.controller import flat_state
from dynoplan.data.episodes import Episode
from dynoplan.errors import DynoplanError, DynoplanWarning
from dynoplan.io import staged_folder
from dynoplan.models.dynamics import DynamicsModel, StackedDynamics
from dynoplan.models.features import FeatureMap, GoalOnFeatures, RegionsOnFeatures
from dynoplan.models.folder import (
    FAILURE_FILE,
    GOAL_FILE,
    INITIATION_FILE,
    MANIFEST_FILE,
    REGIONS_FILE,
    dynamics_file,
    read_manifest,
    write_manifest,
)
from dynoplan.models.goal_network import GoalNetwork, GoalTrainingReport
from dynoplan.models.neural_dynamics import MLPEnsembleDynamics
from dynoplan.models.outcome_initiation import (
    OutcomeInitiation,
    OutcomeInitiationOnFeatures,
    RunFailure,
)
from dynoplan.models.regions import SafetyRegions
from dynoplan.options.initiation import AllOf, Everywhere, Initiation, InRegion
from dynoplan.options.option import Option
from dynoplan.options.state_map import StateMap, on_option_state, planner_dynamics
from dynoplan.pipeline.collect import ObservationFn
from dynoplan.pipeline.diagnostics import constant_dimensions, constant_dimensions_warning
from dynoplan.pipeline.fit_data import (
    decision_runs,
    episode_states,
    labelled_states,
    option_end_pairs,
    option_labels,
    option_runs,
    option_transitions,
)
from dynoplan.pipeline.fit_dynamics import (
    DYNAMICS_BATCH,
    DynamicsFitter,
    StridedTermination,
    calibration_split,
    dynamics_epochs,
    ensemble_fitter,
    fit_dynamics,
    goal_end_gaps,
    strided,
)
from dynoplan.pipeline.fit_failure import fit_failure
from dynoplan.pipeline.fit_goal import GoalModel, fit_goal, fit_goal_network
from dynoplan.pipeline.fit_initiation import (
    OutcomeModel,
    fit_initiation_from_outcomes,
    fit_outcome_initiation,
    fit_undemonstrated_initiation,
    outcome_starts,
)
from dynoplan.pipeline.fit_regions import (
    RegionsModel,
    fit_labelled_regions,
    fit_option_regions,
    fit_regions,
    fit_regions_cross_validated,
)
from dynoplan.pipeline.fit_settings import REGION_FITS, UNDEMONSTRATED, FitSettings
from dynoplan.types import FloatArray

OPTION_STATE_DIMS = "option_state_dims"
"""Manifest field: ``{option: size of its own state}`` for options with a state map."""


@dataclass
class FittedModels:
    """Everything learned: per-option dynamics, the goal heuristic, the regions.

    The one in-memory form of a models folder (:mod:`dynoplan.models.folder`) for every
    task: :meth:`save` writes it, :meth:`load` reads it back.

    Attributes:
        option_names: all options, in order.
        dynamics: ``{name: D_w}``, each on planner states ``(batch, state_dim)``.
        goal: the goal heuristic ``G`` on planner states.
        regions: the fitted Eq. 5 regions on planner states (``None`` when not fitted);
            their ``option_names`` are the demonstrated options.
        stride: environment steps per model step.
        report: what fitting measured (transitions, errors, goal fit).
        use_regions: whether the regions are the options' initiation sets.
        task: the task's name (recorded in the manifest).
        extra: further manifest fields (seed, settings, ...), kept as they are.
        learned_initiation: per option ``P(ok | s)`` learned from its runs' outcomes
            (:mod:`dynoplan.models.outcome_initiation`), or ``None``.
        failure: per option ``P(ok | s)``, the chance that its run does not end the
            episode in failure (:mod:`~dynoplan.pipeline.fit_failure`), or ``None`` (no
            run failed).
        seconds: how long parts of the fit took in this process (``{"goal": s}``), never
            written by :meth:`save`: a models folder's bytes depend on its data and seed
            alone.
    """

    option_names: list[str]
    dynamics: dict[str, DynamicsModel]
    goal: GoalModel
    regions: RegionsModel | None = None
    stride: int = 1
    report: dict[str, Any] = field(default_factory=dict)
    use_regions: bool = True
    task: str = ""
    extra: dict[str, Any] = field(default_factory=dict)
    learned_initiation: OutcomeModel | None = None
    failure: OutcomeInitiation | None = None
    seconds: dict[str, float] = field(default_factory=dict, compare=False)

    @property
    def option_model(self) -> str:
        """What the dynamics predict: ``"step"`` or ``"end"`` (``FitSettings.option_model``,
        recorded in the report's settings)."""
        return str((self.report.get("settings") or {}).get("option_model", "step"))

    @property
    def state_scale(self) -> FloatArray | None:
        """``(state_dim,)`` the spread of every state coordinate over the fitted data
        (``None`` for models fitted before it was recorded)."""
        scale = self.report.get("state_scale")
        return None if scale is None else np.asarray(scale, dtype=np.float64)

    @property
    def state_dim(self) -> int:
        """Size of the planner states every model is queried with."""
        return int(self.goal.state_dim)

    @property
    def option_state_dims(self) -> dict[str, int]:
        """Per option on its own state space (:mod:`dynoplan.options.state_map`), the size
        of that state (its dynamics read it, not the planner state)."""
        dims = self.extra.get(OPTION_STATE_DIMS) or {}
        return {str(k): int(v) for k, v in dims.items()}

    def region(self, name: str) -> Initiation | None:
        """Option ``name``'s learned region, or ``None`` (no region, or regions unused)."""
        if self.use_regions and self.regions is not None and name in self.regions.option_names:
            return InRegion(self.regions, name)
        return None

    def outcome(self, name: str) -> Initiation | None:
        """Option ``name``'s initiation set learned from its runs' outcomes, or ``None``."""
        learned = self.learned_initiation
        if learned is not None and name in learned.option_names:
            return InRegion(learned, name)
        return None

    def likelihood(self, name: str) -> Callable[[FloatArray], FloatArray] | None:
        """Option ``name``'s ``log L(s | w)`` at planner states (its region's,
        :attr:`~dynoplan.options.option.Option.likelihood`), or ``None`` (no region, or
        regions unused)."""
        if self.regions is None or self.region(name) is None:
            return None
        return partial(self.regions.log_likelihood, option=name)

    def demonstrated(self, name: str) -> bool:
        """Whether the demonstrations ran option ``name`` (the regions' report lists the
        options they did not run; :attr:`~dynoplan.options.option.Option.demonstrated`)."""
        return name not in ((self.report.get("regions") or {}).get("undemonstrated") or {})

    def sets(self, name: str, own: Initiation, own_continuation: Initiation | None = None
             ) -> tuple[Initiation, Initiation | None]:
        """Option ``name``'s initiation and continuation sets (``None``: the same as the
        initiation) from its own sets ``own`` and ``own_continuation`` (``None``: ``own``).

        The initiation set is ``own`` intersected with the option's region when it has
        one, and with its set learned from outcomes when it has one. The continuation set
        is its own continuation set intersected with its region: the set learned from
        outcomes says where to *start*, and a running option goes on while it is in its
        own set and region."""
        region = self.region(name)
        base = own if region is None else region if isinstance(own, Everywhere) \
            else AllOf(own, region)
        outcome = self.outcome(name)
        initiation = base if outcome is None else outcome if isinstance(base, Everywhere) \
            else AllOf(base, outcome)
        if own_continuation is None:
            return initiation, None if outcome is None else base
        return initiation, own_continuation if region is None else AllOf(own_continuation,
                                                                        region)

    def initiation(self, spec: OptionSpec) -> Initiation:
        """The option's initiation set from its own (:meth:`sets`)."""
        return self.sets(spec.name, spec.initiation, spec.continuation)[0]

    def continuation(self, spec: OptionSpec) -> Initiation | None:
        """The option's continuation set from its own (:meth:`sets`; ``None``: the same
        as :meth:`initiation`)."""
        return self.sets(spec.name, spec.initiation, spec.continuation)[1]

    def build(self, specs: Sequence[OptionSpec]) -> tuple[list[Option], list[Option]]:
        """The options the controller runs and the same options as the planner sees them.

        Both lists carry the learned dynamics and the initiation sets; the planner's
        terminations are per model step (:func:`strided`). Every option's ``fallback`` is
        its own initiation set (the user's, without the learned region and outcomes): where
        no option may start under its learned set, a controller may let the options whose
        own sets hold compete (``ControllerSettings.fallback_own_sets``).
        """
        run, plan = [], []
        for spec in specs:
            if spec.name not in self.dynamics:
                raise DynoplanError(f"no dynamics model for option '{spec.name}'")
            initiation, continuation = self.sets(spec.name, spec.initiation,
                                                 spec.continuation)
            model = self.dynamics[spec.name]
            own = self.option_state_dims.get(spec.name)
            mapped = None if spec.state_map is None else spec.state_map.option_dim
            if own != mapped:
                raise DynoplanError(
                    f"option '{spec.name}': its dynamics model "
                    + (f"reads its own state of {own} values" if own is not None
                       else "reads the planner state")
                    + (f", its state map gives {mapped}" if mapped is not None
                       else ", and it has no state map"))
            failure = (RunFailure(self.failure, spec.name) if self.failure is not None
                       and spec.name in self.failure.option_names else None)
            run.append(Option(spec.name, spec.policy, model, spec.termination, initiation,
                              continuation, fallback=spec.initiation,
                              state_map=spec.state_map, failure=failure,
                              demonstrated=self.demonstrated(spec.name),
                              likelihood=self.likelihood(spec.name)))
            # the planner's option shares where the controller's last run ended without
            # effect (Option.runs); an option model's one step ends the option anyway
            plan.append(replace(run[-1], termination=spec.termination
                                if self.option_model == "end"
                                else strided(spec.termination, self.stride)))
        return run, plan

    def save(self, folder: str | os.PathLike[str]) -> Path:
        """Write every model file, then ``models.json`` (the manifest) into ``folder``.

        Dynamics models without a ``save`` method are listed with ``null``. The files are
        written into a folder beside ``folder`` that replaces it when complete
        (:func:`~dynoplan.io.staged_folder`): a failed save leaves the previous models.
        """
        with staged_folder(folder, keep=True) as staged:
            self.write(staged)
        return Path(folder)

    def write(self, out: Path) -> None:
        """Write every model file, then ``models.json``, into the folder ``out`` as it is
        (for a caller that stages the folder itself; :meth:`save` stages it). The
        manifest records :attr:`report` under ``report`` unless it is empty, and every
        field of :attr:`extra` at its top level."""
        files: dict[str, str | None] = {}
        for name, model in self.dynamics.items():
            save = getattr(model, "save", None)
            files[name] = dynamics_file(name) if callable(save) else None
            if callable(save):
                save(out / dynamics_file(name))
        network, goal_features = _unwrap_goal(self.goal)
        network.save(out / GOAL_FILE)
        regions = None
        if self.regions is not None:
            fitted, region_features = _unwrap_regions(self.regions)
            fitted.save(out / REGIONS_FILE)
            regions = (REGIONS_FILE, region_features)
        initiation = None
        if self.learned_initiation is not None:
            outcome, outcome_features = (
                (self.learned_initiation.initiation, self.learned_initiation.features.name)
                if isinstance(self.learned_initiation, OutcomeInitiationOnFeatures)
                else (self.learned_initiation, None))
            outcome.save(out / INITIATION_FILE)
            initiation = (INITIATION_FILE, outcome_features)
        if self.failure is not None:
            self.failure.save(out / FAILURE_FILE)
        write_manifest(out, task=self.task, state_dim=self.state_dim,
                       option_names=self.option_names, stride=self.stride,
                       use_regions=self.use_regions, goal=(GOAL_FILE, goal_features),
                       regions=regions, dynamics=files,
                       extra={**({"report": self.report} if self.report else {}),
                              **self.extra}, initiation=initiation,
                       failure=None if self.failure is None else FAILURE_FILE)

    @classmethod
    def load(cls, folder: str | os.PathLike[str],
             feature_maps: Mapping[str, FeatureMap] | None = None,
             retrain: str = "train the models again",
             known_options: Sequence[str] | None = None) -> "FittedModels":
        """Read a models folder (MLP-ensemble dynamics).

        Args:
            feature_maps: the task's named feature maps, for models fitted on one.
            retrain: how to make a new folder, said when the folder is missing or old.
            known_options: the task's options (``None``: any); another name in the
                manifest's ``option_names`` is refused.

        Raises:
            DynoplanError: one line: a missing, old or malformed manifest, a file outside
                the folder, missing or modified, or a model that does not fit the
                manifest (another option, state size or feature map).
        """
        manifest = read_manifest(folder, retrain, known_options=known_options)
        index = manifest.folder / MANIFEST_FILE
        maps = dict(feature_maps or {})

        def feature_map(name: str | None, what: str) -> FeatureMap | None:
            if name is None:
                return None
            if name not in maps:
                raise DynoplanError(f"{index}: {what} reads the feature map '{name}', which "
                                    f"this task does not define ({', '.join(maps) or 'none'})")
            if maps[name].state_dim != manifest.state_dim:
                raise DynoplanError(f"{index}: feature map '{name}' reads {maps[name].state_dim}"
                                    f" values, the manifest's state_dim is {manifest.state_dim}")
            return maps[name]

        def reads(file: Path, dim: int, fmap: FeatureMap | None) -> None:
            if fmap is not None and dim != fmap.dim:
                raise DynoplanError(f"{file}: reads {dim} features, the manifest's feature "
                                    f"map '{fmap.name}' has {fmap.dim}")
            if fmap is None and dim != manifest.state_dim:
                raise DynoplanError(f"{file}: reads {dim} values, the manifest's state_dim "
                                    f"is {manifest.state_dim}")

        goal_map = feature_map(manifest.goal.features, "the goal heuristic")
        network = GoalNetwork.load(manifest.goal.path)
        reads(manifest.goal.path, network.state_dim, goal_map)
        goal: GoalModel = network if goal_map is None else GoalOnFeatures(network, goal_map)
        regions: RegionsModel | None = None
        if manifest.regions is not None:
            region_map = feature_map(manifest.regions.features, "the safety regions")
            fitted = SafetyRegions.load(manifest.regions.path)
            reads(manifest.regions.path, fitted.state_dim, region_map)
            unknown = [n for n in fitted.option_names if n not in manifest.option_names]
            if unknown:
                raise DynoplanError(f"{manifest.regions.path}: regions of options {unknown} "
                                    f"not in the manifest's {manifest.option_names}")
            regions = fitted if region_map is None else RegionsOnFeatures(fitted, region_map)
        dynamics: dict[str, DynamicsModel] = {}
        own_dims = manifest.extra.get(OPTION_STATE_DIMS) or {}
        if not isinstance(own_dims, dict) or not all(
                isinstance(v, int) and not isinstance(v, bool) and v > 0
                and k in manifest.option_names for k, v in own_dims.items()):
            raise DynoplanError(f"{index}: field '{OPTION_STATE_DIMS}' must map options of "
                                "'option_names' to positive state sizes")
        for name, file in manifest.dynamics.items():
            if file is None:
                raise DynoplanError(f"{index}: option '{name}' has no dynamics model file")
            model = MLPEnsembleDynamics.load(file)
            expected = own_dims.get(name, manifest.state_dim)
            if model.state_dim != expected or model.option != name:
                raise DynoplanError(f"{file}: a model of option '{model.option}' on "
                                    f"{model.state_dim} values, expected '{name}' on "
                                    f"{expected}")
            dynamics[name] = model
        learned: OutcomeModel | None = None
        if manifest.initiation is not None:
            outcome_map = feature_map(manifest.initiation.features, "the learned initiation")
            outcome = OutcomeInitiation.load(manifest.initiation.path)
            reads(manifest.initiation.path, outcome.state_dim, outcome_map)
            learned = (outcome if outcome_map is None
                       else OutcomeInitiationOnFeatures(outcome, outcome_map))
        failure = None
        if manifest.failure is not None:
            failure = OutcomeInitiation.load(manifest.failure.path)
            reads(manifest.failure.path, failure.state_dim, None)
        extra = dict(manifest.extra)
        report = extra.pop("report", {})
        return cls(manifest.option_names, dynamics, goal, regions, manifest.stride,
                   report if isinstance(report, dict) else {}, manifest.use_regions,
                   manifest.task, extra, learned, failure)

    def stacked_dynamics(self) -> StackedDynamics:
        """All options' ensembles as one ``(options, samples, state_dim)`` sampler."""
        models = [self.dynamics[n] for n in self.option_names]
        if not all(isinstance(m, MLPEnsembleDynamics) for m in models):
            raise DynoplanError("stacking needs every option's dynamics to be an MLP ensemble")
        return MLPEnsembleDynamics.stack(models)  # type: ignore[arg-type]


def _unwrap_goal(goal: GoalModel) -> tuple[GoalNetwork, str | None]:
    if isinstance(goal, GoalOnFeatures):
        return goal.network, goal.features.name
    return goal, None


def _unwrap_regions(regions: RegionsModel) -> tuple[SafetyRegions, str | None]:
    if isinstance(regions, RegionsOnFeatures):
        return regions.regions, regions.features.name
    return regions, None


class OptionToFit(Protocol):
    """What :func:`fit_models` reads of an option: its name and its own state
    (``None``: the planner state). An :class:`~dynoplan.adapters.spec.OptionSpec` is one,
    and so is a task's own record of an option (the gear's registry entries)."""

    @property
    def name(self) -> str: ...

    @property
    def state_map(self) -> StateMap | None: ...


def fit_models(specs: Sequence[OptionToFit], transitions: Sequence[Episode],
               demos: Sequence[Episode], settings: FitSettings, seed: int,
               state_fn: ObservationFn = flat_state,
               fitter: DynamicsFitter | None = None,
               progress: Callable[[str], None] | None = None,
               task: str = "",
               feature_maps: Mapping[str, FeatureMap] | None = None,
               region_demos: Sequence[Episode] | None = None,
               region_starts: Sequence[Episode] = (),
               dynamics_runs: Sequence[Episode] | None = None,
               goal_training: list[GoalTrainingReport] | None = None) -> FittedModels:
    """Fit dynamics (on transitions and demonstrations), goal and regions (on demonstrations).

    Args:
        transitions: the options' runs at the environment's rate (exploration episodes,
            option runs), labelled by the option that acted.
        progress: called with a short message before each stage (for a status line).
        task: the task's name, recorded in the models folder.
        feature_maps: the task's named feature maps (for ``settings.goal_features`` and
            ``settings.region_features``).
        region_demos: the demonstrations the regions are fitted on, when not ``demos``
            (the improvement rounds' ``improve_regions=False``).
        region_starts: start states labelled by the demonstrator's first choice, which
            widen the regions where the options start the task
            (:func:`~dynoplan.pipeline.fit_regions.fit_option_regions`).
        dynamics_runs: for a task that records its option runs at the decision rate
            (one episode per run of one option, each step one model step: the gear's),
            those runs: the dynamics, their end gaps and the state scale read them in
            place of ``transitions`` and ``demos`` at every ``stride``-th step (the
            goal's off-demonstration states and the regions still read ``transitions``).
        goal_training: when given, receives the goal network's training report.

    With ``settings.dynamics_calibration`` each option's runs (``dynamics_runs``, else
    :func:`~dynoplan.pipeline.fit_data.decision_runs` of the transitions and
    demonstrations) are split into those its model is fitted on and those that
    calibrate its spread (the report's ``dynamics.<option>.std_scale`` and
    ``calibration_runs``).
    """
    settings.validate()
    goal_map = named_feature_map(settings.goal_features, feature_maps)
    region_map = named_feature_map(settings.region_features, feature_maps)
    names = [s.name for s in specs]
    say = progress or (lambda _msg: None)
    say("dynamics")
    maps = {s.name: s.state_map for s in specs if s.state_map is not None}
    data, stride = (([*transitions, *demos], settings.stride) if dynamics_runs is None
                    else (list(dynamics_runs), 1))
    pairs, held_back = _dynamics_pairs(data, stride, dynamics_runs is not None, names, maps,
                                       settings, seed, state_fn)
    dynamics, dyn_report = fit_dynamics(
        pairs, seed, fitter or ensemble_fitter(settings),
        calibration=None if held_back is None else held_back[0],
        remedy="collect more episodes or lower the stride" if dynamics_runs is None
        else "record more runs of it")
    if held_back is not None:
        for name, runs in held_back[1].items():
            dyn_report[name]["calibration_runs"] = runs
    say("goal heuristic")
    goal, goal_report = fit_goal(demos, settings, seed, state_fn, goal_map, transitions,
                                 training=goal_training)
    goal_report["end_gap"] = goal_end_gaps(
        {n: planner_dynamics(m, maps.get(n)) for n, m in dynamics.items()}, goal,
        data, state_fn, stride, seed, to_end=settings.option_model == "end")
    regions = None
    region_report: dict[str, Any] | None = None
    if settings.regions:
        say("safety regions")
        regions, region_report = fit_option_regions(
            demos if region_demos is None else region_demos, transitions, names, settings,
            seed, state_fn, region_map, region_starts)
        region_report["options"] = regions.option_names
        for message in region_report["warnings"]:
            warnings.warn(message, DynoplanWarning, stacklevel=2)
    learned: OutcomeInitiation | None = None
    outcome_report: dict[str, Any] | None = None
    by_outcomes = [n for n, how in (region_report or {}).get("undemonstrated", {}).items()
                   if how == "outcomes"]
    if settings.outcome_initiation:  # every option's, the undemonstrated ones' too
        say("outcome initiation")
        learned, outcome_report = fit_outcome_initiation(transitions, names, goal, settings,
                                                         seed, state_fn)
    elif by_outcomes:
        say("undemonstrated options' initiation")
        learned, outcome_report = fit_undemonstrated_initiation(
            transitions, names, by_outcomes, goal, settings, seed, state_fn)
    every_state = np.concatenate([episode_states(e, state_fn) for e in
                                  [*(transitions if dynamics_runs is None else dynamics_runs),
                                   *demos]])
    constant = constant_dimensions(every_state)
    note = constant_dimensions_warning(constant, every_state.shape[1],
                                       settings.constant_dimensions_still)
    if note is not None:
        warnings.warn(note, DynoplanWarning, stacklevel=2)
    failure, failure_report = fit_failure([*transitions, *demos], names, seed, state_fn)
    report = {"settings": asdict(settings), "dynamics": dyn_report, "goal": goal_report,
              "regions": region_report, "outcome_initiation": outcome_report,
              **({"failure": failure_report} if failure is not None else {}),
              "constant_dimensions": constant, "state_scale": every_state.std(axis=0).tolist(),
              "warnings": [] if note is None else [note]}
    extra = {OPTION_STATE_DIMS: {n: m.option_dim for n, m in maps.items()}} if maps else {}
    return FittedModels(names, dynamics, goal, regions, settings.stride, report,
                        settings.regions, task, extra, learned, failure)


Pairs = dict[str, tuple[FloatArray, FloatArray]]


def _dynamics_pairs(episodes: Sequence[Episode], stride: int, one_run_each: bool,
                    names: Sequence[str], maps: Mapping[str, StateMap],
                    settings: FitSettings, seed: int, state_fn: ObservationFn
                    ) -> tuple[Pairs, tuple[Pairs, dict[str, int]] | None]:
    """Per option the pairs its dynamics are fitted on (:func:`fit_models`), on its own
    state where ``maps`` holds one; with ``settings.dynamics_calibration`` also the pairs
    held back to calibrate its spread and the number of runs they come from (else
    ``None``). ``one_run_each``: every episode is one run of one option, one model step
    a step (``fit_models``' ``dynamics_runs``); else the episodes are cut into such runs
    (:func:`~dynoplan.pipeline.fit_data.decision_runs` every ``stride`` steps) before
    whole runs are held back."""
    if settings.option_model == "end":
        pairs = option_end_pairs(episodes, names, state_fn)
        held = None
    elif not settings.dynamics_calibration:
        pairs = option_transitions(episodes, names, state_fn, stride)
        held = None
    else:
        runs = episodes if one_run_each else decision_runs(episodes, stride)
        split = calibration_split(runs, names, settings.dynamics_calibration, seed)
        pairs = {n: option_transitions(kept, names, state_fn)[n]
                 for n, (kept, _) in split.items()}
        held = ({n: option_transitions(back, names, state_fn)[n]
                 for n, (_, back) in split.items() if back},
                {n: len(back) for n, (_, back) in split.items()})
    for name, state_map in maps.items():  # each such option's dynamics on its own state
        pairs[name] = on_option_state(pairs[name], state_map)
        if held is not None and name in held[0]:
            held[0][name] = on_option_state(held[0][name], state_map)
    return pairs, held


def named_feature_map(name: str | None,
                      feature_maps: Mapping[str, FeatureMap] | None) -> FeatureMap | None:
    """The task's feature map ``name`` (``None``: none).

    Raises:
        DynoplanError: the task defines no feature map of that name.
    """
    if name is None:
        return None
    maps = dict(feature_maps or {})
    if name not in maps:
        raise DynoplanError(f"feature map '{name}': the task defines "
                            f"{', '.join(maps) or 'none'}")
    return maps[name]


__all__ = [
    "DYNAMICS_BATCH",
    "REGION_FITS",
    "UNDEMONSTRATED",
    "DynamicsFitter",
    "FitSettings",
    "FittedModels",
    "GoalModel",
    "OptionToFit",
    "OutcomeModel",
    "RegionsModel",
    "StridedTermination",
    "dynamics_epochs",
    "ensemble_fitter",
    "episode_states",
    "fit_dynamics",
    "fit_goal",
    "fit_goal_network",
    "fit_initiation_from_outcomes",
    "fit_labelled_regions",
    "fit_models",
    "fit_option_regions",
    "fit_outcome_initiation",
    "fit_regions",
    "fit_regions_cross_validated",
    "fit_undemonstrated_initiation",
    "labelled_states",
    "named_feature_map",
    "option_labels",
    "option_runs",
    "option_transitions",
    "outcome_starts",
    "strided",
]
