"""Figures of the gear assembly's learned models (the paper's Figure 3).

- :func:`plot_goal_trial` -- Fig. 3(a): the goal heuristic's estimate with its 90% interval
  against ground-truth progress along one held-out trial.
- :func:`plot_tsne_regions` -- Fig. 3(b): t-SNE of planner states over a set of
  trajectories, with and without the human interfering, coloured by the option that was
  running, over the safety regions shaded in the same colours.
- :func:`make_gear_figures` -- both, from a models folder and the demonstration datasets.
"""

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from scipy import stats
from sklearn.manifold import TSNE
from sklearn.neighbors import NearestNeighbors
from threadpoolctl import threadpool_limits

from dynoplan.data import Dataset, read_dataset
from dynoplan.envs.gear.env import CONTROL_DT
from dynoplan.envs.gear.learning.data import CAUTIOUS, demo_arrays
from dynoplan.envs.gear.models_folder import HELDOUT_DIR, load_gear_models
from dynoplan.envs.gear.options.catalog import gear_option, gear_option_names
from dynoplan.envs.gear.state import PlannerState
from dynoplan.errors import DynoplanError
from dynoplan.io import check_writable, staged_folder, write_json, write_with
from dynoplan.models.features import RegionsOnFeatures
from dynoplan.pipeline.fit import GoalModel
from dynoplan.progress import track
from dynoplan.types import BoolArray, FloatArray, IntArray

SPARE_COLORS = ("#ff7f0e", "#8c564b", "#17becf", "#bcbd22", "#7f7f7f", "#d62728")
"""Colours of registered options that do not name one (the paper's four do: magenta
pick, greens for the two moves, blue insert)."""


def option_colors(names: Sequence[str]) -> list[str]:
    """Each registered option's colour in figures, in the order of ``names``."""
    out, spare = [], 0
    for name in names:
        color = gear_option(name).color
        if color is None:
            color, spare = SPARE_COLORS[spare % len(SPARE_COLORS)], spare + 1
        out.append(color)
    return out

GOAL_FIGURE = "fig3a_goal_heuristic.png"
TSNE_FIGURE = "fig3b_tsne_regions.png"


def plot_goal_trial(goal: GoalModel, states: FloatArray, truth: FloatArray,
                    labels: IntArray, path: Path, title: str,
                    option_names: Sequence[str] | None = None) -> dict[str, float]:
    """Fig. 3(a): ``G``'s mean and 90% interval against ground-truth progress.

    Args:
        states: ``(T+1, 22)`` planner states of one trial; ``truth``: ``(T+1,)`` its
            progress; ``labels``: ``(T,)`` the option run at each step (the background).
        option_names: what the labels index (default: the registered options).
    Returns:
        The trial's Spearman correlation and mean absolute error.
    """
    names = list(option_names or gear_option_names())
    colors = option_colors(names)
    mean, _ = goal.mean_std(states)
    lo, hi = goal.interval(states, 0.9)
    t = np.arange(len(truth)) * CONTROL_DT
    rho = float(stats.spearmanr(mean, truth).statistic)
    mae = float(np.mean(np.abs(mean - truth)))
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    starts = np.flatnonzero(np.r_[True, labels[1:] != labels[:-1]])
    ends = np.r_[starts[1:], len(labels)]
    for a, b in zip(starts, ends, strict=True):
        ax.axvspan(t[a], t[b], color=colors[int(labels[a])], alpha=0.12, lw=0)
    ax.fill_between(t, lo, hi, color="tab:red", alpha=0.25, lw=0, label="G(s): 90% interval")
    ax.plot(t, mean, color="tab:red", lw=2, label="G(s): mean")
    ax.plot(t, truth, color="black", ls="--", lw=1.5, label="ground-truth progress")
    handles, _ = ax.get_legend_handles_labels()
    shown = sorted({int(x) for x in labels})
    handles += [Patch(color=colors[k], alpha=0.3, label=names[k]) for k in shown]
    ax.legend(handles=handles, fontsize=8, loc="upper left")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("progress")
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlim(t[0], t[-1])
    ax.set_title(f"{title}\nSpearman {rho:.3f}, MAE {mae:.3f}", fontsize=9)
    fig.tight_layout()
    write_with(path, lambda tmp: fig.savefig(tmp, dpi=150))
    plt.close(fig)
    return {"spearman": rho, "mae": mae}


def plot_tsne_regions(states: FloatArray, labels: IntArray, interrupted: BoolArray,
                      regions: RegionsOnFeatures, path: Path, seed: int,
                      title: str = "", option_names: Sequence[str] | None = None
                      ) -> dict[str, Any]:
    """Fig. 3(b): t-SNE of planner states, coloured by option, over the shaded regions.

    The embedding is of the columns the regions read, each scaled by its spread. A
    point of the plane is shaded in option ``k``'s colour when most of its 15 nearest
    embedded states lie in region ``k`` (membership computed in the state space by
    Eq. 5); the plane far from every embedded state is left blank.

    Args:
        states: ``(N, 22)``; labels: ``(N,)`` option that ran; interrupted: ``(N,)`` the
            state comes from a trial in which the human made the robot give way.
        option_names: what the labels index (default: the registered options); the
            regions cover those the demonstrations show.
    Returns:
        ``{"points", "region_share"}``: number of points and, per option, the share of
        points inside its region (``None`` without points or without a region).
    """
    names = list(option_names or gear_option_names())
    colors = option_colors(names)
    region_colors = [colors[names.index(n)] for n in regions.option_names]
    column = np.array([regions.option_names.index(n) if n in regions.option_names else -1
                       for n in names])  # label -> region column, -1: no region
    x = regions.features(states)
    scale = np.maximum(x.std(axis=0), 1e-3)
    z = (x - x.mean(axis=0)) / scale
    perplexity = float(min(30.0, max(2.0, (len(z) - 1) / 3.0)))
    tsne = TSNE(n_components=2, perplexity=perplexity, init="pca", random_state=seed)
    # One OpenMP thread: t-SNE's 1000 gradient steps each end on a barrier, and with the
    # cores busy (Ray workers, other jobs) spinning threads made this figure take 30 s
    # instead of 2; one thread gives the same embedding here.
    with threadpool_limits(limits=1, user_api="openmp"):
        emb = tsne.fit_transform(z)
    member = regions.contains_all(states)  # (N, options)

    pad = 0.05 * (emb.max(axis=0) - emb.min(axis=0))
    lo, hi = emb.min(axis=0) - pad, emb.max(axis=0) + pad
    gx, gy = np.meshgrid(np.linspace(lo[0], hi[0], 220), np.linspace(lo[1], hi[1], 220))
    grid = np.c_[gx.ravel(), gy.ravel()]
    k = min(15, len(emb))
    dist, idx = NearestNeighbors(n_neighbors=k).fit(emb).kneighbors(grid)
    spacing = float(np.median(NearestNeighbors(n_neighbors=2).fit(emb).kneighbors(emb)[0][:, 1]))
    near = dist[:, 0] <= 4.0 * max(spacing, 1e-9)

    fig, ax = plt.subplots(figsize=(6.4, 5.6))
    for o in range(member.shape[1]):
        share = member[idx, o].mean(axis=1)
        share = np.where(near, share, 0.0).reshape(gx.shape)
        ax.contourf(gx, gy, share, levels=[0.5, 1.01], colors=[region_colors[o]], alpha=0.12)
        ax.contour(gx, gy, share, levels=[0.5], colors=[region_colors[o]], linewidths=1.0)
    for flag, marker in ((False, "o"), (True, "^")):
        rows = interrupted == flag
        ax.scatter(emb[rows, 0], emb[rows, 1], s=7, marker=marker, linewidths=0,
                   c=[colors[int(o)] for o in labels[rows]], alpha=0.85)
    handles: list[Any] = [Patch(color=region_colors[o], alpha=0.5, label=f"{name} (region)")
                          for o, name in enumerate(regions.option_names)]
    handles += [Line2D([], [], ls="", marker="o", color="gray", label="human away"),
                Line2D([], [], ls="", marker="^", color="gray", label="human interferes")]
    ax.legend(handles=handles, fontsize=7, loc="best")
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_xlabel("t-SNE 1")
    ax.set_ylabel("t-SNE 2")
    ax.set_title(title or "planner states by option, safety regions shaded", fontsize=9)
    fig.tight_layout()
    write_with(path, lambda tmp: fig.savefig(tmp, dpi=150))
    plt.close(fig)
    mine = np.flatnonzero(column[labels] >= 0)  # points of options with a region
    own = member[mine, column[labels[mine]]]
    return {"points": len(labels),
            "region_share": {n: float(own[labels[mine] == o].mean())
                             if column[o] >= 0 and (labels == o).any() else None
                             for o, n in enumerate(names)}}


def _trial_arrays(dataset: Dataset, planner: PlannerState
                  ) -> list[tuple[FloatArray, FloatArray, IntArray, bool]]:
    """The trials' arrays (:func:`~dynoplan.envs.gear.learning.data.demo_arrays`), each
    with whether the human interfered (a cautious-move step)."""
    return [(states, truth, labels, bool((labels == CAUTIOUS).any()))
            for states, truth, labels in demo_arrays(dataset, planner)]


def make_gear_figures(models: Path, demos: Path, heldout: Path | None, out: Path,
                      seed: int = 0, trial: int = 0, max_points: int = 1500,
                      progress: bool = False) -> dict[str, Any]:
    """Write Fig. 3(a) and 3(b) into ``out`` and ``figures.json`` (what they show).

    Args:
        models: a folder written by :func:`~dynoplan.envs.gear.learning.training.train_gear_models`.
        demos: the demonstrations the models were trained on.
        heldout: held-out trials; ``None``: ``models/heldout-demos``.
        trial: index of the held-out trial drawn in Fig. 3(a).
        max_points: states embedded by t-SNE (an even subsample of all trials' states).
        seed: seeds the subsample and t-SNE.
    Returns:
        The content of ``figures.json``: the files and the numbers each figure shows.
    """
    loaded = load_gear_models(models)
    if not isinstance(loaded.regions, RegionsOnFeatures):
        raise DynoplanError(f"{models}: Fig. 3(b) needs regions fitted on a feature map")
    regions = loaded.regions
    if heldout is None:
        heldout = models / HELDOUT_DIR
    train_set, held_set = read_dataset(demos), read_dataset(heldout)
    if not 0 <= trial < len(held_set):
        raise DynoplanError(f"--trial must be in 0..{len(held_set) - 1}, got {trial}")
    if max_points < 10:
        raise DynoplanError(f"max_points must be >= 10, got {max_points}")
    check_writable(out)  # before the t-SNE
    planner = PlannerState()
    train, held = _trial_arrays(train_set, planner), _trial_arrays(held_set, planner)
    states, truth, labels, interrupted = held[trial]
    seed_of = held_set[trial].seed
    mode = held_set.metadata.extra.get("human_modes", [None] * len(held_set))[trial]
    pool = [(s[:-1], lab, np.full(len(lab), flag)) for s, _, lab, flag in train + held]
    all_states = np.concatenate([p[0] for p in pool])
    all_labels = np.concatenate([p[1] for p in pool])
    all_flags = np.concatenate([p[2] for p in pool])
    rng = np.random.default_rng(seed)
    keep = np.sort(rng.choice(len(all_states), size=min(max_points, len(all_states)),
                              replace=False))
    with staged_folder(out) as stage:  # the figures and figures.json together, or none
        numbers: dict[str, dict[str, Any]] = {}

        def fig3a() -> None:
            numbers["fig3a"] = plot_goal_trial(
                loaded.goal, states, truth, labels, stage / GOAL_FIGURE,
                f"goal heuristic on held-out trial {trial} (env seed {seed_of}, human {mode})",
                loaded.option_names)

        def fig3b() -> None:
            numbers["fig3b"] = plot_tsne_regions(
                all_states[keep], all_labels[keep], all_flags[keep], regions,
                stage / TSNE_FIGURE, seed,
                f"t-SNE of {len(keep)} planner states from {len(pool)} trials "
                f"({sum(bool(p[2][0]) for p in pool)} with the human interfering)",
                loaded.option_names)

        for draw in track([fig3a, fig3b], "gear figures", total=2, enabled=progress):
            draw()
        summary = {
            "fig3a": {"file": str(out / GOAL_FIGURE), "heldout": str(heldout), "trial": trial,
                      "env_seed": seed_of, "human_mode": mode, "interrupted": interrupted,
                      **numbers["fig3a"]},
            "fig3b": {"file": str(out / TSNE_FIGURE), "trials": len(train) + len(held),
                      **numbers["fig3b"]},
            "models": str(models),
            "seed": seed,
        }
        write_json(stage / "figures.json", summary)
    return summary

