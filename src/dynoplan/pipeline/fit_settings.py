"""How the pipeline's models are learned: :class:`FitSettings` (recorded in the summary and
in ``models.json``)."""

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

from dynoplan.errors import DynoplanError

OFF_DECAYS = ("gaussian", "cauchy")
"""The shapes of :attr:`FitSettings.goal_off_decay`."""
OFF_UNITS = ("path", "displacement")
"""How :attr:`FitSettings.goal_off_radius` is measured (:attr:`FitSettings.goal_off_unit`)."""


@dataclass(frozen=True)
class FitSettings:
    """How the models are learned (recorded in the summary and in ``models.json``).

    Attributes:
        stride: environment steps per dynamics-model step (see the module docstring).
        option_model: what each option's dynamics predict: ``"step"``, the state
            ``stride`` steps later (the planner rolls it ``horizon`` model steps, drawing
            termination at each); ``"end"``, where the option ends from here (Sutton,
            Precup and Singh 1999: :func:`~dynoplan.pipeline.fit_data.option_end_pairs`),
            one model step per rollout, so an option that needs longer than any fixed
            horizon to show its worth is scored by where it ends.
        dynamics_hidden: hidden layer widths of each option's MLP ensemble.
        dynamics_members: ensemble size.
        dynamics_epochs: training epochs of each ensemble.
        dynamics_max_updates: fewer epochs when an option has so many transitions that
            ``dynamics_epochs`` would take more gradient steps than this (at least 5;
            ``None``: no bound), which bounds the training time on large collections.
        dynamics_min_updates: more epochs when an option has so few transitions that
            ``dynamics_epochs`` would take fewer gradient steps than this (``None``: no
            bound): 30 epochs of 264 transitions are 30 steps of 256 rows, and leave an
            option model hardly better than "no change" (the hold-out still picks the
            epoch kept; ``docs/suite.md``).
        dynamics_calibration: share of each option's runs, grouped by their ``seed``,
            held back from its fit to calibrate the predicted spread on
            (:func:`~dynoplan.pipeline.fit_dynamics.calibration_split`,
            :meth:`~dynoplan.models.neural_dynamics.MLPEnsembleDynamics.calibrate`); an
            option whose runs come from fewer than 4 seeds is not calibrated (0, the
            default: none). Only with ``option_model="step"``.
        goal_hidden: hidden width of the goal network.
        goal_members: goal ensemble size.
        goal_epochs: training epochs of the goal network.
        goal_ranking: weight of the goal network's ranking loss along demonstrations
            (:meth:`~dynoplan.models.goal_network.GoalNetwork.fit`; 0: none).
        goal_off_demos: the goal heuristic also fits the exploration episodes' states,
            each labelled with the progress of the nearest demonstration state, lowered
            with the distance to it
            (:func:`~dynoplan.pipeline.fit_goal.off_demonstration_progress`), so that it
            ranks states off the demonstrations below the demonstrated states they are
            near.
        goal_off_radius: how far from the demonstrations, in steps of a demonstration,
            an off-demonstration state's progress label falls to ``exp(-1)`` of its
            nearest demonstration state's (``goal_off_demos``).
        goal_off_unit: how ``goal_off_radius`` demonstration steps are measured:
            ``"path"``, that many times the median distance between consecutive
            demonstration states; ``"displacement"``, the median distance between
            demonstration states that many steps apart, which a state that jitters
            from step to step (bang-bang control, a discrete action) does not inflate.
        goal_off_around: copies of every demonstration state, each moved by Gaussian
            noise of one label radius (:func:`~dynoplan.pipeline.fit_goal.states_around`),
            fitted as off-demonstration states with their labels: the goal heuristic
            then falls away from the demonstrations in every direction, also where no
            exploration run went (0, the default: none; a named variant of the suite).
        goal_off_decay: how the label falls with the distance ``r``: ``"gaussian"``,
            ``exp(-(r / R)^2)``; ``"cauchy"``, ``1 / (1 + (r / R)^2)``, whose tail still
            ranks far states by their distance.
        goal_off_context: that distance leaves out the episode's context, the state
            dimensions that stay the same along every demonstration but differ between
            them (where a goal or an object was put at the reset): an exploration state
            in another episode is then as near the demonstrations as its moving parts
            are (``False``: every dimension that changes in the demonstrations counts).
            On by default since the suite's fourteenth round (``docs/suite.md``).
        goal_features, region_features: names of the task's feature maps the goal
            heuristic and the regions read (``None``: the planner state itself).
        regions: fit the safety regions (Eq. 5) and intersect every option's initiation
            set with its region.
        region_fit: ``"heldout"`` (default): components and thresholds chosen on
            held-out demonstrations (:meth:`SafetyRegions.fit_heldout`), so
            ``region_coverage`` is the share of *unseen* demonstration states inside;
            ``"bic"``: the paper's reading, BIC components and thresholds on the
            training states (with few demonstrations: needle-thin regions); ``"cv"``:
            BIC components, thresholds on the training states widened by what leaving
            demonstrations out shows (:func:`fit_regions_cross_validated`).
        region_coverage: share of an option's demonstration states inside its region
            (held out with ``"heldout"``, in-sample with ``"bic"`` and ``"cv"``).
        region_cv_coverage: ``"cv"``: share of left-out demonstrations' states of an
            option that its final threshold is widened to admit.
        region_slack: nats subtracted from every region threshold (widens them).
        region_components: mixture size (``None``: chosen in
            ``1..region_max_components``, by held-out likelihood or BIC).
        region_max_components: the largest mixture that may be chosen.
        region_folds: folds of whole demonstrations for ``"heldout"``.
        region_reg_covar: added to every covariance's diagonal, in units of each
            dimension's spread for ``"heldout"``, absolute for ``"cv"`` (``"bic"``: 1e-6).
        outcome_initiation: also learn where each option may start from the outcomes
            of its exploration runs (Bagaria et al. 2023; :func:`fit_outcome_initiation`)
            and intersect its initiation set with that.
        outcome_min_gain: a run is good when the goal heuristic's mean rose by more than
            this from its start to its end.
        constant_dimensions_still: a state dimension that never changes in the data
            (padding, a fixed goal) is kept still by the dynamics and not tested by the
            held-out regions (``False``: both treat it as any other dimension, so the
            networks' error moves it and the regions reject the move).
        region_undemonstrated: what an option that no demonstration shows gets:
            ``"runs"``: a region fitted (as above) on the states where it ran while
            collecting transitions, i.e. where its dynamics model has data; ``"none"``:
            no region (never admissible); ``"everywhere"``: its own initiation set
            alone (before 0.x the only behaviour); ``"outcomes"``: its own initiation
            set intersected with where its exploration runs made the goal heuristic
            rise (:func:`~dynoplan.pipeline.fit_initiation.fit_undemonstrated_initiation`;
            nowhere without a whole run of it). The pipeline warns either way.
    """

    stride: int = 1
    option_model: str = "end"
    dynamics_hidden: tuple[int, ...] = (64, 64)
    dynamics_members: int = 5
    dynamics_epochs: int = 30
    dynamics_max_updates: int | None = None
    dynamics_min_updates: int | None = 1000
    dynamics_calibration: float = 0.0
    goal_hidden: int = 64
    goal_members: int = 1
    goal_epochs: int = 150
    goal_ranking: float = 0.0
    goal_off_demos: bool = True
    goal_off_radius: float = 5.0
    goal_off_unit: str = "path"
    goal_off_around: int = 0
    goal_off_decay: str = "gaussian"
    goal_off_context: bool = True
    goal_features: str | None = None
    region_features: str | None = None
    regions: bool = True
    region_fit: str = "heldout"
    region_coverage: float = 0.95
    region_cv_coverage: float = 0.97
    region_slack: float = 0.0
    region_components: int | None = None
    region_max_components: int = 6
    region_folds: int = 5
    region_reg_covar: float = 1e-2
    region_undemonstrated: str = "none"
    outcome_initiation: bool = False
    outcome_min_gain: float = 0.0
    constant_dimensions_still: bool = True

    @classmethod
    def from_record(cls, record: Mapping[str, Any]) -> "FitSettings":
        """The settings as a summary or ``models.json`` records them (``asdict``, written
        as JSON: tuples become lists); fields this version does not know are left out."""
        known = {f.name for f in fields(cls)}
        values: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v
                                  for k, v in record.items() if k in known}
        return cls(**values)

    def validate(self) -> None:
        if self.stride < 1:
            raise DynoplanError(f"stride must be >= 1, got {self.stride}")
        if self.dynamics_members < 1 or self.dynamics_epochs < 1 or not self.dynamics_hidden:
            raise DynoplanError("dynamics_members, dynamics_epochs and dynamics_hidden must "
                                "be positive")
        if self.dynamics_min_updates is not None and self.dynamics_min_updates < 1:
            raise DynoplanError(f"dynamics_min_updates must be >= 1 or None, got "
                                f"{self.dynamics_min_updates}")
        if self.dynamics_max_updates is not None and self.dynamics_max_updates < 1:
            raise DynoplanError(f"dynamics_max_updates must be >= 1 or None, got "
                                f"{self.dynamics_max_updates}")
        if not 0.0 <= self.dynamics_calibration < 1.0:
            raise DynoplanError(f"dynamics_calibration must be in [0, 1), got "
                                f"{self.dynamics_calibration}")
        if self.dynamics_calibration and self.option_model != "step":
            raise DynoplanError("dynamics_calibration needs option_model='step' (a model to "
                                "an option's end is calibrated on no held-back runs)")
        if self.goal_hidden < 1 or self.goal_members < 1 or self.goal_epochs < 1:
            raise DynoplanError("goal_hidden, goal_members and goal_epochs must be positive")
        if not self.goal_ranking >= 0.0:
            raise DynoplanError(f"goal_ranking must be >= 0, got {self.goal_ranking}")
        if self.goal_off_around < 0:
            raise DynoplanError(f"goal_off_around must be >= 0, got {self.goal_off_around}")
        if self.goal_off_unit not in OFF_UNITS:
            raise DynoplanError(f"goal_off_unit must be one of {', '.join(OFF_UNITS)}, "
                                f"got {self.goal_off_unit!r}")
        if self.goal_off_decay not in OFF_DECAYS:
            raise DynoplanError(f"goal_off_decay must be one of {', '.join(OFF_DECAYS)}, "
                                f"got {self.goal_off_decay!r}")
        if not 0.0 < self.goal_off_radius < math.inf:
            raise DynoplanError(f"goal_off_radius must be > 0 and finite, got "
                                f"{self.goal_off_radius}")
        if not 0.0 < self.region_cv_coverage <= 1.0:
            raise DynoplanError(f"region_cv_coverage must be in (0, 1], got "
                                f"{self.region_cv_coverage}")
        if not 0.0 < self.region_coverage <= 1.0:
            raise DynoplanError(f"region_coverage must be in (0, 1], got {self.region_coverage}")
        if self.option_model not in OPTION_MODELS:
            raise DynoplanError(f"option_model must be one of {', '.join(OPTION_MODELS)}, got "
                                f"'{self.option_model}'")
        if self.region_fit not in REGION_FITS:
            raise DynoplanError(f"region_fit must be one of {', '.join(REGION_FITS)}, got "
                                f"'{self.region_fit}'")
        if self.region_undemonstrated not in UNDEMONSTRATED:
            raise DynoplanError(f"region_undemonstrated must be one of "
                                f"{', '.join(UNDEMONSTRATED)}, got "
                                f"'{self.region_undemonstrated}'")
        if self.region_folds < 2:
            raise DynoplanError(f"region_folds must be >= 2, got {self.region_folds}")
        if self.region_reg_covar <= 0.0:
            raise DynoplanError(f"region_reg_covar must be > 0, got {self.region_reg_covar}")
        if self.region_max_components < 1 or (self.region_components is not None
                                              and self.region_components < 1):
            raise DynoplanError("region_components and region_max_components must be >= 1")


OPTION_MODELS = ("step", "end")
"""Values of :attr:`FitSettings.option_model`."""
REGION_FITS = ("heldout", "bic", "cv")
"""Values of :attr:`FitSettings.region_fit`."""
UNDEMONSTRATED = ("runs", "none", "everywhere", "outcomes")
"""Values of :attr:`FitSettings.region_undemonstrated`."""


__all__ = ["OPTION_MODELS", "REGION_FITS", "UNDEMONSTRATED", "FitSettings"]
