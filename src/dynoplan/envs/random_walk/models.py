"""Noisy dynamics and goal models of the random walk (the paper: misprediction 0.2).

The closed loop of an option that steps right with probability ``p_right`` moves
``s -> s + 1`` with probability ``p_right`` and ``s -> max(s - 1, 0)`` otherwise; the goal
state is absorbing. A model *mispredicts* with probability ``noise``: it returns a state
drawn uniformly from the wrong ones (all states ``0..goal`` except the true next state).
The goal model's truth is ``G(s) = s / goal``; with probability ``noise`` it returns the
value of a uniformly drawn wrong state instead.
"""

from collections.abc import Sequence

import numpy as np

from dynoplan.types import FloatArray, Generator, IntArray


def _wrong_state(true: FloatArray, goal_state: int, u: FloatArray) -> FloatArray:
    """A uniform draw from ``{0..goal_state} \\ {true}`` per element, from uniforms ``u``."""
    r = np.floor(u * goal_state)  # goal_state equally likely choices
    r += r >= true
    return r


class NoisyWalkDynamics:
    """``D_w`` of a random-walk option; states are ``(..., 1)`` arrays of state indices.

    Args:
        p_right: probability that the option's policy steps right.
        noise: probability of a misprediction.
        goal_state: the absorbing goal state (20 by default).
    """

    def __init__(self, p_right: float, noise: float, goal_state: int = 20) -> None:
        if not (0.0 <= p_right <= 1.0 and 0.0 <= noise <= 1.0):
            raise ValueError("p_right and noise must be probabilities")
        self.p_right = float(p_right)
        self.noise = float(noise)
        self.goal_state = int(goal_state)

    @property
    def state_dim(self) -> int:
        return 1

    def sample(self, states: FloatArray, rng: Generator) -> FloatArray:
        """``(..., 1)`` -> ``(..., 1)``: one draw of the next state per row."""
        return _sample(states, np.asarray(self.p_right), np.asarray(self.noise),
                       self.goal_state, rng)

    @classmethod
    def stack(cls, items: Sequence["NoisyWalkDynamics"]) -> "_StackedWalkDynamics":
        goals = {m.goal_state for m in items}
        if len(goals) != 1:
            raise ValueError("stacked random-walk models must share the goal state")
        return _StackedWalkDynamics(np.array([m.p_right for m in items]),
                                    np.array([m.noise for m in items]), goals.pop())


class _StackedWalkDynamics:
    def __init__(self, p_right: FloatArray, noise: FloatArray, goal_state: int) -> None:
        self.p_right = p_right[:, None, None]  # (options, 1, 1) against (O, S, 1)
        self.noise = noise[:, None, None]
        self.goal_state = goal_state
        self._p_right = np.ascontiguousarray(p_right, dtype=np.float64)  # (options,)
        # one misprediction probability for all options: a scalar, no gather per row
        self._noise: float | FloatArray = float(noise[0]) if np.all(noise == noise[0]) \
            else np.ascontiguousarray(noise, dtype=np.float64)

    def sample(self, states: FloatArray, rng: Generator) -> FloatArray:
        return _sample(states, self.p_right, self.noise, self.goal_state, rng)

    def sample_rows(self, states: FloatArray, branches: IntArray,
                    rng: Generator) -> FloatArray:
        """``(rows, 1)`` -> ``(rows, 1)``; row ``i`` follows option ``branches[i]``."""
        noise = self._noise if isinstance(self._noise, float) else self._noise.take(branches)
        return _sample_rows(states, self._p_right.take(branches), noise, self.goal_state, rng)


def _sample(states: FloatArray, p_right: FloatArray, noise: FloatArray, goal_state: int,
            rng: Generator) -> FloatArray:
    u = rng.random((2, *states.shape))
    moved = (u[0] < p_right) * 2.0 - 1.0
    moved += states
    np.maximum(moved, 0.0, out=moved)
    # one uniform decides both: mispredict when u < noise, and then u / noise is uniform
    wrong = np.floor(u[1] * (goal_state / np.maximum(noise, 1e-300)))
    wrong += wrong >= moved
    out = np.where(u[1] < noise, wrong, moved)
    np.copyto(out, states, where=states >= goal_state)  # the goal is absorbing
    return out


def _sample_rows(states: FloatArray, p_right: FloatArray, noise: float | FloatArray,
                 goal_state: int, rng: Generator) -> FloatArray:
    """:func:`_sample` of ``(rows, 1)`` states, ``p_right`` and ``noise`` per row
    (``(rows,)``, or one ``noise`` for all): the same draws and the same next states,
    with the wrong states computed only where the model mispredicts."""
    s = states.reshape(-1)
    u = rng.random((2, s.size))  # the order of _sample's (2, rows, 1) draws
    moved = (u[0] < p_right) * 2.0 - 1.0
    moved += s
    np.maximum(moved, 0.0, out=moved)
    wrong_at = np.flatnonzero(u[1] < noise)
    if wrong_at.size:
        scale = goal_state / np.maximum(noise if isinstance(noise, float)
                                        else noise.take(wrong_at), 1e-300)
        wrong = np.floor(u[1].take(wrong_at) * scale)
        wrong += wrong >= moved.take(wrong_at)
        moved[wrong_at] = wrong
    at_goal = np.flatnonzero(s >= goal_state)  # the goal is absorbing
    if at_goal.size:
        moved[at_goal] = s.take(at_goal)
    return moved.reshape(states.shape)


class NoisyWalkGoal:
    """``G(s) = s / goal`` observed through misprediction noise (a distribution)."""

    def __init__(self, noise: float, goal_state: int = 20) -> None:
        if not 0.0 <= noise <= 1.0:
            raise ValueError("noise must be a probability")
        self.noise = float(noise)
        self.goal_state = int(goal_state)

    def sample(self, states: FloatArray, rng: Generator) -> FloatArray:
        """``(batch, 1)`` -> ``(batch,)`` progress draws in ``[0, 1]``."""
        s = np.clip(np.rint(states[..., 0]), 0, self.goal_state)
        u = rng.random((2, *s.shape))
        shown = s.reshape(-1)  # a new array: the wrong states go in where drawn
        wrong_at = np.flatnonzero(u[0] < self.noise)
        if wrong_at.size:
            shown[wrong_at] = _wrong_state(shown.take(wrong_at), self.goal_state,
                                           u[1].reshape(-1).take(wrong_at))
        return shown.reshape(s.shape) / self.goal_state

    def mean_std(self, states: FloatArray) -> tuple[FloatArray, FloatArray]:
        s = np.clip(np.rint(states[..., 0]), 0, self.goal_state)
        n = self.goal_state
        # wrong states are uniform over {0..n} \ {s}: mean and second moment in closed form
        total, total_sq = n * (n + 1) / 2.0, n * (n + 1) * (2 * n + 1) / 6.0
        wrong_mean = (total - s) / n
        wrong_sq = (total_sq - s * s) / n
        mean = (1 - self.noise) * s + self.noise * wrong_mean
        second = (1 - self.noise) * s * s + self.noise * wrong_sq
        std = np.sqrt(np.maximum(second - mean * mean, 0.0))
        return mean / n, std / n
