"""The bounds on every count and seed dynoplan accepts, in one place.

The command line checks each flag against these bounds before any work starts (a value
outside them is one ``dynoplan: error: Invalid value for '--flag': ...`` line, exit 2),
and so does a sweep configuration for its fields. They keep every run within the memory
of a workstation and every seed within what numpy, torch and OMPL accept; the
documentation lists them (``docs/guide/cli.md``). Sizes read from model files are
bounded by the file itself instead (:func:`dynoplan.models.mlp_file.check_parameter_count`).
"""

import math

SEED_MAX = 2**32 - 1
"""Largest seed (seeds are unsigned 32-bit integers; derived seeds add small offsets)."""

EPISODES_MAX = 10_000
"""Episodes, demonstrations, runs or trials of one command."""

RANDOM_WALK_EPISODES_MAX = 100_000
"""Episodes of ``dynoplan random-walk`` per controller (cheap: about 50 kB each)."""

HORIZON_MAX = 1_000
"""Planning horizon ``n`` (model steps)."""

SAMPLES_MAX = 10_000
"""Monte-Carlo rollouts per option (with :data:`HORIZON_MAX`, one decision rolls out at
most 10^7 states per option)."""

DEPTH_MAX = 6
"""Options per sequence of the look-ahead planner (a level has up to options^depth
branches)."""

STEPS_MAX = 100_000
"""Environment steps or decisions per episode or trial, and steps between re-plans."""

STRIDE_MAX = 1_000
"""Environment steps per model step."""

EPOCHS_MAX = 100_000
"""Training epochs of one model."""

POINTS_MAX = 100_000
"""States embedded by t-SNE in a figure."""

DATASET_BYTES_MAX = 2**34
"""Bytes the arrays of one dataset file may declare in all (16 GiB), checked before any
is read: a chunked HDF5 dataset may declare any shape without storing it."""

CELLS_MAX = 10_000
"""Cells (combinations) of one sweep grid."""

SETTING_BOUNDS: dict[str, tuple[float, float]] = {
    "demos": (1, EPISODES_MAX), "exploration_episodes": (1, EPISODES_MAX),
    "exploration_option_steps": (1, STEPS_MAX), "exploration_branches": (0, EPISODES_MAX),
    "demo_detours": (0, EPISODES_MAX),
    "region_starts": (0, EPISODES_MAX),
    "episodes": (1, EPISODES_MAX),
    "seed": (0, SEED_MAX), "improve": (0, 100), "improve_episodes": (1, EPISODES_MAX),
    "improve_explore": (0.0, 1.0), "improve_demos": (0, EPISODES_MAX),
    "improve_disturbed": (0.0, 1.0),
    "fit.stride": (1, STRIDE_MAX), "fit.dynamics_members": (1, 100),
    "fit.dynamics_epochs": (1, EPOCHS_MAX), "fit.goal_hidden": (1, 100_000),
    "fit.goal_members": (1, 100), "fit.goal_epochs": (1, EPOCHS_MAX),
    "fit.region_coverage": (0.0, 1.0), "fit.region_slack": (0.0, math.inf),
    "fit.region_components": (1, 100), "fit.region_max_components": (1, 100),
    "fit.region_folds": (2, 1000), "fit.region_reg_covar": (0.0, math.inf),
    "fit.outcome_min_gain": (-math.inf, math.inf),
    "fit.dynamics_max_updates": (1, 10**9), "fit.dynamics_min_updates": (1, 10**9),
    "fit.dynamics_calibration": (0.0, 1.0),
    "fit.goal_ranking": (0.0, math.inf), "fit.goal_off_radius": (0.01, 1e6),
    "fit.goal_off_around": (0, 100),
    "fit.region_cv_coverage": (0.0, 1.0),
    "control.horizon": (1, HORIZON_MAX), "control.samples": (1, SAMPLES_MAX),
    "control.depth": (1, DEPTH_MAX),
    "control.risk": (-1e6, 1e6), "control.replan_every": (0, STEPS_MAX),
    "control.margin": (0.0, math.inf), "control.commit": (0.0, math.inf),
    "control.max_decisions": (1, STEPS_MAX),
    "control.max_option_steps": (1, STEPS_MAX), "control.dynamics_noise": (0.0, math.inf),
    "control.epistemic": (0.0, 1e6), "control.no_effect_tolerance": (0.0, math.inf),
    "control.no_effect_share": (0.0, math.inf), "control.loop_share": (0.0, math.inf),
    "control.stall_progress": (0.0, math.inf),
}
"""Smallest and largest value of every numeric setting of the generic pipeline
(:mod:`dynoplan.pipeline.config`; ``section.field`` keys); the command line's flags have
the same bounds."""

__all__ = ["CELLS_MAX", "DATASET_BYTES_MAX", "DEPTH_MAX", "EPISODES_MAX", "EPOCHS_MAX",
           "HORIZON_MAX", "POINTS_MAX", "RANDOM_WALK_EPISODES_MAX", "SAMPLES_MAX", "SEED_MAX",
           "SETTING_BOUNDS", "STEPS_MAX", "STRIDE_MAX"]
