"""User-written options and a scripted demonstrator for ``MountainCarContinuous-v0``.

This module is what a researcher writes to use DynoPlan on an environment dynoplan did
not write: plain functions of the observation ``[position, velocity]``, turned into
options by :func:`dynoplan.adapters.option_spec`. Nothing here knows about dynamics
models, goal heuristics or regions: the pipeline learns those.

Run it with::

    dynoplan pipeline --env MountainCarContinuous-v0 \\
        --options examples.mountain_car.options:make_options --out results/mountain-car
"""

from typing import Any

import numpy as np

from dynoplan.adapters import OptionSpec, option_spec
from dynoplan.pipeline import Demonstrator

BETA = 0.05
"""Termination probability per step of every option (about 20 steps on average)."""


def push_left(observation: Any) -> np.ndarray:
    """Full force to the left."""
    return np.array([-1.0], dtype=np.float32)


def push_right(observation: Any) -> np.ndarray:
    """Full force to the right."""
    return np.array([1.0], dtype=np.float32)


def pump(observation: Any) -> np.ndarray:
    """Full force along the velocity: adds energy to the swing (right when at rest)."""
    return np.array([1.0 if observation[1] >= 0.0 else -1.0], dtype=np.float32)


def brake(observation: Any) -> np.ndarray:
    """Full force against the velocity: takes energy out of the swing."""
    return np.array([-1.0 if observation[1] >= 0.0 else 1.0], dtype=np.float32)


def make_options() -> list[OptionSpec]:
    """Four options: push left, push right, pump energy (force along the velocity) and
    brake (force against it), each stopping with probability ``BETA`` per step.

    ``brake`` is there on purpose, like the left-going option of the paper's random walk:
    an option that undoes progress, which the planner has to learn to avoid.
    """
    return [
        option_spec("push_left", push_left, termination=BETA),
        option_spec("push_right", push_right, termination=BETA),
        option_spec("pump", pump, termination=BETA),
        option_spec("brake", brake, termination=BETA),
    ]


class SwingDemonstrator(Demonstrator):
    """A scripted expert that swings: back up the left hill, then forward to the flag.

    It pushes left until the car stops on the left slope, then right; whenever the car
    stalls on the way up it swings back again. In half of the episodes (drawn from the
    episode's generator) it first wastes a push to the right, so that the demonstrations
    also show that pushing right from rest is not progress.
    """

    def reset(self, observation: Any, rng: np.random.Generator) -> None:
        self.direction = "push_right" if rng.random() < 0.5 else "push_left"
        self.moved = False

    def choose(self, observation: Any) -> str:
        velocity = float(observation[1])
        if self.moved:
            if self.direction == "push_left" and velocity >= 0.0:
                self.direction, self.moved = "push_right", False
            elif self.direction == "push_right" and velocity <= 0.0:
                self.direction, self.moved = "push_left", False
        self.moved = self.moved or abs(velocity) > 1e-3
        return self.direction


def make_demonstrator() -> Demonstrator:
    """The demonstrator the command line uses for ``--demos N``."""
    return SwingDemonstrator()
