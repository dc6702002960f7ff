"""The figure of ``dynoplan sweep``: success rate and decision latency across the grid."""

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from dynoplan.io import write_with


def plot_sweep(rows: Sequence[dict[str, Any]], swept: Sequence[str], path: Path) -> None:
    """Two panels, success rate and decision latency (p50, ms), against the first swept
    key that is not ``seed`` (the x axis); one line per combination of the other swept
    keys; over seeds, the mean with the min-max range as error bars.

    ``rows`` are the sweep's table rows (the swept keys, ``success_rate``,
    ``decision_ms_p50``).
    """
    keys = [k for k in swept if k != "seed"]
    x_key = keys[0] if keys else "seed"
    others = [k for k in keys if k != x_key]
    xs = sorted({r[x_key] for r in rows}, key=_order)
    series: dict[tuple[Any, ...], list[dict[str, Any]]] = {}
    for r in rows:
        series.setdefault(tuple(r[k] for k in others), []).append(r)
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for (ax, column, label) in ((axes[0], "success_rate", "success rate"),
                                (axes[1], "decision_ms_p50", "decision latency p50 (ms)")):
        for combo, members in series.items():
            mean, low, high = [], [], []
            for x in xs:
                values = [float(r[column]) for r in members
                          if r[x_key] == x and r.get(column) is not None]
                mean.append(np.mean(values) if values else np.nan)
                low.append(np.min(values) if values else np.nan)
                high.append(np.max(values) if values else np.nan)
            m = np.asarray(mean)
            positions = np.arange(len(xs))
            name = ", ".join(f"{k}={v}" for k, v in zip(others, combo, strict=True)) or "all"
            ax.errorbar(positions, m, yerr=[m - np.asarray(low), np.asarray(high) - m],
                        marker="o", capsize=3, label=name)
        ax.set_xticks(np.arange(len(xs)), [str(x) for x in xs])
        ax.set_xlabel(x_key)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].set_ylim(-0.05, 1.05)
    axes[0].legend(fontsize=7, loc="best")
    fig.suptitle("sweep" + (" (mean over seeds, min-max bars)" if "seed" in swept else ""),
                 fontsize=10)
    fig.tight_layout()
    write_with(path, lambda tmp: fig.savefig(tmp, dpi=120))
    plt.close(fig)


def _order(value: Any) -> tuple[int, Any]:
    """Numbers in numeric order before strings."""
    return (0, value) if isinstance(value, int | float) else (1, str(value))


__all__ = ["plot_sweep"]
