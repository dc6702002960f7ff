"""How :func:`~dynoplan.envs.gear.learning.training.train_gear_models` learns (the pipeline's
:class:`~dynoplan.pipeline.fit.FitSettings`) and what it measures on held-out data
(:class:`GearMetricsSettings`); both are recorded in ``metrics.json``, the first in
``models.json``. :data:`DEFAULT_SETTINGS` and :data:`DEFAULT_METRICS` are what
``dynoplan gear train`` uses, :data:`QUICK_SETTINGS` and :data:`QUICK_METRICS`
(``--quick``) what CI and smoke tests use.
"""

from dataclasses import dataclass, replace

from dynoplan.envs.gear.features import OBJECTS, RELATIVE
from dynoplan.envs.gear.state import DECISION_STEPS
from dynoplan.models.neural_dynamics import DEFAULT_HIDDEN, DEFAULT_MEMBERS
from dynoplan.pipeline.fit import FitSettings

DEFAULT_SETTINGS = FitSettings(
    stride=DECISION_STEPS, dynamics_hidden=DEFAULT_HIDDEN, dynamics_members=DEFAULT_MEMBERS,
    dynamics_epochs=50, dynamics_max_updates=1500, goal_hidden=64, goal_members=3,
    goal_epochs=150, goal_features=OBJECTS.name, region_features=RELATIVE.name,
    region_fit="cv", region_coverage=0.99, region_cv_coverage=0.97, region_reg_covar=3e-3,
    region_max_components=8, region_undemonstrated="everywhere", option_model="step",
    goal_off_demos=False, constant_dimensions_still=False, dynamics_min_updates=None,
    dynamics_calibration=0.15)
"""The gear's models, one step per decision:

- the goal heuristic reads the ``objects`` features (the gripper, the tool relative to
  the gear, the gear), neither the arm's joint angles nor the human: the planner asks it
  about states the options' dynamics imagine, and those predict where the tool and the
  gear go far better than which joint angles take them there; where the task stands
  does not depend on where the human is (``metrics.json``'s
  ``dynamics.<option>.goal_end_gap``; the ablation in ``docs/gear-options.md``, "The
  remedy: the goal reads what the dynamics predict");
- the regions read the ``relative`` features, are fitted with ``"cv"`` (BIC components,
  thresholds widened by leaving demonstrations out), and ``region_reg_covar`` 3e-3 (rad^2
  or m^2, absolute) is a floor of about 5 cm / 0.05 rad on their width, so that
  directions the 10 demonstrations hardly vary in do not make regions needle-thin;
- an option the demonstrations do not show gets no region (``"everywhere"``: its own
  conditions alone decide where it starts);
- one-step dynamics, a goal on the demonstrations alone, constant dimensions learned
  as any other and no lower bound on the dynamics' gradient steps: the generic
  pipeline's remedies of the composition suite, measured on the gear's three seeds
  (``docs/suite.md``, the eighth round), cost its seed 1 eight points and lengthened
  its episodes, so its fit keeps these (and a model to an option's end needs option
  runs that record where they were cut);
- each option's spread calibrated on 15 % of its runs held back from its fit
  (``dynamics_calibration``)."""

QUICK_SETTINGS = replace(DEFAULT_SETTINGS, goal_hidden=32, goal_epochs=40,
                         region_max_components=4, dynamics_hidden=(64, 64), dynamics_epochs=15)
"""Small settings for CI and smoke tests (well under 30 s of training)."""


@dataclass(frozen=True)
class GearMetricsSettings:
    """How the gear's collected runs are split and what is measured on held-out data.

    Attributes:
        dynamics_heldout_fraction: share of each option's transition episodes (grouped by
            their ``seed``) held out for the dynamics report, when option transitions are
            given.
        n_step, rollouts: decision steps and Monte-Carlo rollouts per start state of the
            n-step report (and of the goal's end gap).
        end_gap_horizon: the most decision steps each held-out run of an option is
            imagined for the goal's end gap
            (:func:`~dynoplan.models.evaluation.option_end_gap`; the planner's horizon).
        heldout_episodes: held-out trials ``dynoplan gear train`` records when none are
            given (:func:`~dynoplan.envs.gear.stages.learned_models`; ``gear run``
            records as many as demonstrations).
        far_states: candidate far-away states for ``region_far_outside_rate``.
    """

    dynamics_heldout_fraction: float = 0.2
    n_step: int = 3
    rollouts: int = 32
    end_gap_horizon: int = 10
    heldout_episodes: int = 10
    far_states: int = 2000


DEFAULT_METRICS = GearMetricsSettings()
QUICK_METRICS = GearMetricsSettings(rollouts=8, heldout_episodes=3, far_states=400)
