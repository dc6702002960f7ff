"""The controller that chooses, runs, monitors and re-chooses options."""

from dynoplan.control.batched import BatchChooser, run_batched
from dynoplan.control.choosers import (
    Exploring,
    FixedChoice,
    OptionChooser,
    RandomChoice,
    ScriptedSequence,
)
from dynoplan.control.controller import Controller, Decision, EpisodeTrace

__all__ = [
    "BatchChooser",
    "Controller",
    "Decision",
    "EpisodeTrace",
    "Exploring",
    "FixedChoice",
    "OptionChooser",
    "RandomChoice",
    "ScriptedSequence",
    "run_batched",
]
