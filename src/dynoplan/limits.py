"""The bounds on every count and seed dynoplan accepts, in one place.

The command line checks each flag against these bounds before any work starts (a value
outside them is one ``dynoplan: error: Invalid value for '--flag': ...`` line, exit 2),
and so does a sweep configuration for its fields. They keep every run within the memory
of a workstation and every seed within what numpy, torch and OMPL accept; the
documentation lists them (``docs/guide/cli.md``). Sizes read from model files are
bounded by the file itself instead (:func:`dynoplan.models.mlp_file.check_parameter_count`).
"""

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

STEPS_MAX = 100_000
"""Environment steps or decisions per episode or trial, and steps between re-plans."""

STRIDE_MAX = 1_000
"""Environment steps per model step."""

EPOCHS_MAX = 100_000
"""Training epochs of one model."""

POINTS_MAX = 100_000
"""States embedded by t-SNE in a figure."""

CELLS_MAX = 10_000
"""Cells (combinations) of one sweep grid."""

__all__ = ["CELLS_MAX", "EPISODES_MAX", "EPOCHS_MAX", "HORIZON_MAX", "POINTS_MAX",
           "RANDOM_WALK_EPISODES_MAX", "SAMPLES_MAX", "SEED_MAX", "STEPS_MAX", "STRIDE_MAX"]
