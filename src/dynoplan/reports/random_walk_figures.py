"""Figures of the random-walk experiment (the paper's Figure 2(b), and robustness)."""

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from dynoplan.control.controller import EpisodeTrace
from dynoplan.io import write_with


def plot_mdp_solution(trace: EpisodeTrace, path: Path, goal_state: int, title: str) -> None:
    """Figure 2(b): per planning step, each option's predicted end states, the choice, truth.

    At planning step ``k`` the planner rolls every option forward from the true state
    (red line); the bars at ``k + 1`` show where each option's rollouts ended (10th to
    90th percentile, dot at the mean). The chosen option is ringed; the red line then
    shows the true state after running it.
    """
    decisions = [d for d in trace.decisions if d.option is not None]
    names = decisions[0].plan.option_names
    colors = plt.get_cmap("tab10")(np.arange(len(names)))
    fig, ax = plt.subplots(figsize=(8, 4.8))
    width = 0.6 / len(names)
    for k, d in enumerate(decisions):
        for o, name in enumerate(names):
            ends = d.plan.end_states[o, :, 0]
            if not np.isfinite(ends).any():
                continue
            x = k + 1 + (o - (len(names) - 1) / 2) * width
            lo, hi = np.percentile(ends, [10, 90])
            ax.vlines(x, lo, hi, color=colors[o], lw=3, alpha=0.8,
                      label=name if k == 0 else "_nolegend_")
            ax.plot(x, ends.mean(), "o", color=colors[o], ms=4)
            if name == d.option:
                ax.plot(x, ends.mean(), "o", ms=13, mfc="none", mec="black", mew=1.5,
                        label="chosen" if k == 0 else "_nolegend_")
    truth = [decisions[0].state[0]] + [d.state_after[0] for d in decisions]
    ax.plot(range(len(truth)), truth, "-s", color="red", lw=2, label="true state")
    ax.axhline(goal_state, color="gray", ls="--", lw=1)
    ax.set_xlabel("planning step")
    ax.set_ylabel("state")
    ax.set_ylim(-0.5, goal_state + 0.5)
    ax.set_xticks(range(len(truth)))
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8, loc="upper left", ncol=2)
    fig.tight_layout()
    write_with(path, lambda tmp: fig.savefig(tmp, dpi=150))
    plt.close(fig)


def plot_robustness(rows: Sequence[dict[str, Any]], path: Path) -> None:
    """Success rate and planning steps (median, 90th percentile) against misprediction."""
    noise = [r["noise"] for r in rows]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(9, 3.6))
    a1.plot(noise, [r["success_rate"] for r in rows], "o-")
    a1.set_ylim(-0.02, 1.02)
    a1.set_xlabel("misprediction probability")
    a1.set_ylabel("success rate (<= max decisions)")
    for key, label in [("planning_steps_median", "median"), ("planning_steps_p90", "90th pct")]:
        ys = [np.nan if r[key] is None else r[key] for r in rows]
        a2.plot(noise, ys, "o-", label=label)
    a2.set_xlabel("misprediction probability")
    a2.set_ylabel("planning steps to the goal")
    a2.legend()
    fig.suptitle("DynoPlan on the random walk: robustness to model mismatch", fontsize=10)
    fig.tight_layout()
    write_with(path, lambda tmp: fig.savefig(tmp, dpi=150))
    plt.close(fig)
