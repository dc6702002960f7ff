"""The fit's data: planner states, option labels, transitions and runs cut from labelled
episodes (``infos["option"]``)."""

from collections.abc import Iterator, Sequence

import numpy as np

from dynoplan.control.controller import flat_state
from dynoplan.data.episodes import (
    DETOUR_KEY,
    FAILURE_KEY,
    INTERRUPTED_KEY,
    OPTION_KEY,
    Episode,
)
from dynoplan.errors import DynoplanError
from dynoplan.pipeline.collect import ObservationFn, decision_episodes, label_runs
from dynoplan.types import FloatArray, Generator


def episode_states(episode: Episode, state_fn: ObservationFn = flat_state) -> FloatArray:
    """``state_fn`` of every observation of ``episode``: ``(T+1, state_dim)`` float64."""
    return np.stack([np.asarray(state_fn(o), dtype=np.float64).reshape(-1)
                     for o in episode.observations])


def option_transitions(episodes: Sequence[Episode], option_names: Sequence[str],
                       state_fn: ObservationFn = flat_state,
                       stride: int = 1) -> dict[str, tuple[FloatArray, FloatArray]]:
    """Per option, the pairs ``(s_t, s_{t+stride})`` during which only it acted.

    Returns:
        ``{name: (states (N, d), next_states (N, d))}``, ``N`` possibly 0.

    Raises:
        DynoplanError: an episode has no option labels, or labels outside the names.
    """
    found: dict[str, tuple[list[FloatArray], list[FloatArray]]] = {
        n: ([], []) for n in option_names}
    for index, episode in enumerate(episodes):
        labels = option_labels(episode, index, len(option_names))
        if len(labels) < stride:
            continue
        rows = episode_states(episode, state_fn)
        windows = np.lib.stride_tricks.sliding_window_view(labels, stride)  # (T-k+1, k)
        same = (windows == windows[:, :1]).all(axis=1)
        for k, name in enumerate(option_names):
            t = np.flatnonzero(same & (windows[:, 0] == k))
            found[name][0].append(rows[t])
            found[name][1].append(rows[t + stride])
    d = None
    out: dict[str, tuple[FloatArray, FloatArray]] = {}
    for name, (s, n) in found.items():
        if s:
            out[name] = (np.concatenate(s), np.concatenate(n))
            d = out[name][0].shape[1]
    for name in option_names:
        if name not in out:
            out[name] = (np.zeros((0, d or 0)), np.zeros((0, d or 0)))
    return out


def option_labels(episode: Episode, index: int, n_options: int) -> np.ndarray:
    labels = episode.infos.get(OPTION_KEY)
    if labels is None:
        known = ", ".join(sorted(episode.infos)) or "none"
        raise DynoplanError(
            f"episode {index} has no option labels (infos['{OPTION_KEY}']; its infos: "
            f"{known}): every step of a demonstration must name the option that acted")
    if labels.size and (labels.min() < 0 or labels.max() >= n_options):
        raise DynoplanError(
            f"episode {index}: option labels must lie in 0..{n_options - 1}, found "
            f"{int(labels.min())}..{int(labels.max())}")
    return labels

def option_runs(episodes: Sequence[Episode], option_names: Sequence[str],
                state_fn: ObservationFn = flat_state, stride: int = 1,
                ) -> dict[str, tuple[FloatArray, FloatArray, np.ndarray]]:
    """Every run of every option that no one cut short: where it started, where it
    ended and how long it ran.

    A run is a maximal stretch of steps with the same option label. A run cut short
    (``infos["interrupted"]`` at its last step: a controller's replan, an explorer's
    step limit, an episode's time limit) is left out. With ``stride`` > 1
    its length is counted in model steps of ``stride`` environment steps (rounded down)
    and its "end" is the state after that many model steps.

    Returns:
        ``{name: (starts (R, d), ends (R, d), steps (R,))}``, ``R`` possibly 0.
    """
    found: dict[str, tuple[list[FloatArray], list[FloatArray], list[int]]] = {
        n: ([], [], []) for n in option_names}
    d = 0
    for name, rows, start, end, cut, _ in _runs(episodes, option_names, state_fn):
        d = rows.shape[1]
        if cut:
            continue
        steps = int(end - start) // stride
        found[name][0].append(rows[start])
        found[name][1].append(rows[start + steps * stride])
        found[name][2].append(steps)
    return {n: (np.array(a).reshape(-1, d), np.array(b).reshape(-1, d),
                np.array(c, dtype=np.int64)) for n, (a, b, c) in found.items()}


def decision_runs(episodes: Sequence[Episode], steps: int) -> list[Episode]:
    """Option transitions at the decision rate cut from labelled episodes recorded every
    env step (demonstrations): every run of one option label (:func:`label_runs`) as
    episodes at the decision rate (:func:`~dynoplan.pipeline.collect.decision_episodes`,
    ``steps`` env steps per decision), one per phase offset ``o``: its observations
    ``o, o + steps, ...`` up to the run's last observation, each step one decision of its
    option, the last truncated. A run shorter than ``steps`` gives nothing.

    Raises:
        DynoplanError: an episode has no option labels.
    """
    out: list[Episode] = []
    for index, episode in enumerate(episodes):
        labels = episode.options
        if labels is None:
            raise DynoplanError(f"episode {index} has no option labels "
                                f"(infos['{OPTION_KEY}']): runs are cut by the option that "
                                "acted")
        for start, end in label_runs(labels):
            out += decision_episodes(episode, steps, span=(start, end),
                                     truncated=True)
    return out


def _runs(episodes: Sequence[Episode], option_names: Sequence[str], state_fn: ObservationFn,
          ) -> Iterator[tuple[str, FloatArray, int, int, bool, bool]]:
    """Every run (a maximal stretch of steps with one option label) of ``episodes``: its
    option, its episode's states ``(T+1, d)``, its steps ``start:end``, whether it
    was cut short (``infos["interrupted"]`` at its last step: a controller's replan, an
    explorer's step limit, an episode's time limit) and whether it
    ended its episode in failure (``infos["failure"]`` at the episode's last step)."""
    for index, episode in enumerate(episodes):
        labels = option_labels(episode, index, len(option_names))
        rows = episode_states(episode, state_fn)
        interrupted = episode.infos.get(INTERRUPTED_KEY)
        failure = episode.infos.get(FAILURE_KEY)
        failed_end = failure is not None and len(failure) > 0 and bool(failure[-1])
        for start, end in label_runs(labels):
            cut = interrupted is not None and bool(interrupted[end - 1])
            yield (option_names[int(labels[start])], rows, int(start), int(end), cut,
                   failed_end and end == len(labels))

def option_end_pairs(episodes: Sequence[Episode], option_names: Sequence[str],
                     state_fn: ObservationFn = flat_state,
                     ) -> dict[str, tuple[FloatArray, FloatArray]]:
    """Per option, every state of every run paired with where that run ended: the data of
    an option model in the sense of Sutton, Precup and Singh (1999), which predicts where
    an option started in ``s`` ends, not where it is one step later.

    A run is a maximal stretch of steps with the same option label (:func:`option_runs`);
    it ends where its option terminated, left its set or its episode ended, which is
    where a controller chooses again. A run that a controller cut short to run another
    option (``infos["interrupted"]`` at its last step, as in a controller's own episodes)
    is left out: where it stopped is not where its option ends.

    Returns:
        ``{name: (states (N, d), end_states (N, d))}``, ``N`` possibly 0.
    """
    return {n: (states, ends) for n, (states, ends, _) in
            _whole_runs(episodes, option_names, state_fn).items()}


def option_run_failures(episodes: Sequence[Episode], option_names: Sequence[str],
                        state_fn: ObservationFn = flat_state,
                        ) -> dict[str, tuple[FloatArray, np.ndarray]]:
    """Per option, every state of every run (the states of :func:`option_end_pairs`) and
    whether that run ended its episode in failure: it ran to the episode's last step and
    ``infos["failure"]`` is True there (an exploration episode that terminated without
    success). An episode without ``infos["failure"]`` (a demonstration) did not fail.

    Returns:
        ``{name: (states (N, d), failed (N,) bool)}``, ``N`` possibly 0.
    """
    return {n: (states, failed) for n, (states, _, failed) in
            _whole_runs(episodes, option_names, state_fn).items()}


def _whole_runs(episodes: Sequence[Episode], option_names: Sequence[str],
                state_fn: ObservationFn,
                ) -> dict[str, tuple[FloatArray, FloatArray, np.ndarray]]:
    """Per option, every state of every run no one cut short, the state its run
    ended in and whether it ended its episode in failure: ``(states (N, d), ends (N, d),
    failed (N,) bool)``, ``N`` possibly 0."""
    found: dict[str, tuple[list[FloatArray], list[FloatArray], list[np.ndarray]]] = {
        n: ([], [], []) for n in option_names}
    d = 0
    for name, rows, start, end, cut, failed in _runs(episodes, option_names, state_fn):
        d = rows.shape[1]
        if cut:
            continue
        found[name][0].append(rows[start:end])
        found[name][1].append(np.repeat(rows[end][None], end - start, axis=0))
        found[name][2].append(np.full(end - start, failed))
    return {n: (np.concatenate(a) if a else np.zeros((0, d)),
                np.concatenate(b) if b else np.zeros((0, d)),
                np.concatenate(c) if c else np.zeros(0, dtype=bool))
            for n, (a, b, c) in found.items()}


def split_runs(episodes: Sequence[Episode], fraction: float,
               rng: Generator) -> tuple[list[Episode], list[Episode]]:
    """Hold out ``fraction`` of each option's runs (at least one when it has two).

    Each episode is one option's run, the option of its first label. Runs of one option
    that share an ``env`` seed (cut from one demonstration, or started from one reset) go
    to the same side, so that near-copies of a kept run never count as held out.

    Returns:
        ``(kept, held_out)``, each in the order of the options' labels, then of the
        permutation ``rng`` draws per option.
    """
    train: list[Episode] = []
    held: list[Episode] = []
    groups: dict[int, dict[object, list[Episode]]] = {}
    for index, episode in enumerate(episodes):
        labels = episode.options
        if labels is None or not len(labels):
            raise DynoplanError(f"episode {index} has no option labels (infos['{OPTION_KEY}'])"
                                ": runs are split by the option that acted")
        key = episode.seed if episode.seed is not None else ("episode", index)
        groups.setdefault(int(labels[0]), {}).setdefault(key, []).append(episode)
    for k in sorted(groups):
        runs = list(groups[k].values())
        order = rng.permutation(len(runs))
        n_held = min(max(1, round(fraction * len(runs))), len(runs) - 1)
        held += [e for i in order[:n_held] for e in runs[i]]
        train += [e for i in order[n_held:] for e in runs[i]]
    return train, held


def labelled_states(episodes: Sequence[Episode], n_options: int, state_fn: ObservationFn,
                     ) -> tuple[FloatArray, np.ndarray, np.ndarray]:
    """Every state an option was chosen in: ``(N, d)`` states, ``(N,)`` labels and
    episode ids. A demonstration's detour (``infos["detour"]``) is no one's choice: its
    steps are left out."""
    states, labels, groups = [], [], []
    for index, episode in enumerate(episodes):
        y = option_labels(episode, index, n_options)
        chosen = ~np.asarray(episode.infos.get(DETOUR_KEY, np.zeros(len(y), bool)), bool)
        labels.append(y[chosen])
        states.append(episode_states(episode, state_fn)[:-1][chosen])
        groups.append(np.full(int(chosen.sum()), index))
    if not states:
        return np.zeros((0, 0)), np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(states), np.concatenate(labels), np.concatenate(groups)


__all__ = ["decision_runs", "episode_states", "label_runs", "labelled_states",
           "option_end_pairs", "option_labels", "option_run_failures", "option_runs",
           "option_transitions", "split_runs"]
