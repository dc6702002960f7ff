"""How :func:`~dynoplan.experiments.gear_models.train_gear_models` learns and evaluates.

:class:`GearTrainSettings` is recorded in ``metrics.json`` and ``models.json``;
:data:`DEFAULT_SETTINGS` is what ``dynoplan gear train`` uses, :data:`QUICK_SETTINGS`
(``--quick``) what CI and smoke tests use.
"""

from dataclasses import dataclass

from dynoplan.envs.gear.features import RELATIVE
from dynoplan.models.neural_dynamics import DEFAULT_HIDDEN, DEFAULT_MEMBERS


@dataclass(frozen=True)
class GearTrainSettings:
    """How :func:`~dynoplan.experiments.gear_models.train_gear_models` learns and evaluates.

    Attributes:
        goal_hidden, goal_members, goal_epochs: the goal network (width of both hidden
            layers, ensemble size, epochs).
        goal_ranking: weight of the goal network's ranking loss along demonstrations
            (:meth:`~dynoplan.models.goal_network.GoalNetwork.fit`; 0: none).
        region_reg_covar: variance (rad^2 or m^2) added to every mixture covariance's
            diagonal: a floor of about 5 cm / 0.05 rad on the regions' width, so that
            directions the 10 demonstrations hardly vary in do not make regions
            needle-thin.
        region_max_components: BIC chooses ``M`` in ``1..region_max_components``.
        region_coverage: fraction of an option's own demonstration states its threshold
            admits before the cross-validated slack.
        region_cv_coverage: fraction of left-out demonstrations' states of option ``k``
            that the final threshold of ``k`` is widened to admit.
        dynamics_hidden, dynamics_members, dynamics_epochs: each option's ensemble.
        dynamics_max_updates: fewer epochs when an option has so many transitions that
            ``dynamics_epochs`` would take more gradient steps than this (bounds the
            training time on large collections).
        dynamics_heldout_fraction: share of each option's transition episodes (grouped by
            their ``seed``) held out for the dynamics report, when option transitions are
            given.
        dynamics_calibration_fraction: share of the remaining runs (grouped the same way)
            kept out of the fit to calibrate the predicted spread
            (:meth:`~dynoplan.models.neural_dynamics.MLPEnsembleDynamics.calibrate`);
            options with runs from fewer than 4 seeds are not calibrated.
        n_step: decision steps of the n-step report.
        rollouts: Monte-Carlo rollouts per start state in the n-step report.
        heldout_episodes: held-out trials ``dynoplan gear train`` records when none are
            given (:func:`~dynoplan.experiments.gear_stages.learned_models`; ``gear run``
            records as many as demonstrations).
        far_states: candidate far-away states for ``region_far_outside_rate``.
        region_features: name of the feature map the regions read
            (:data:`~dynoplan.envs.gear.features.FEATURE_MAPS`).
    """

    goal_hidden: int = 64
    goal_members: int = 3
    goal_epochs: int = 150
    goal_ranking: float = 0.0
    region_reg_covar: float = 3e-3
    region_max_components: int = 8
    region_coverage: float = 0.99
    region_cv_coverage: float = 0.97
    dynamics_hidden: tuple[int, ...] = DEFAULT_HIDDEN
    dynamics_members: int = DEFAULT_MEMBERS
    dynamics_epochs: int = 50
    dynamics_max_updates: int = 1500
    dynamics_heldout_fraction: float = 0.2
    dynamics_calibration_fraction: float = 0.15
    n_step: int = 3
    rollouts: int = 32
    heldout_episodes: int = 10
    far_states: int = 2000
    region_features: str = RELATIVE.name


DEFAULT_SETTINGS = GearTrainSettings()
QUICK_SETTINGS = GearTrainSettings(
    goal_hidden=32, goal_epochs=40, region_max_components=4, dynamics_hidden=(64, 64),
    dynamics_epochs=15, rollouts=8, heldout_episodes=3, far_states=400)
"""Small settings for CI and smoke tests (well under 30 s of training)."""
