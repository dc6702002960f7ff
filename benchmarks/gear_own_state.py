"""The insertion's dynamics on its own state against the planner state (issue 32): one-step
error and data needs, on a ``gear run`` folder's option runs.

The insertion may declare its own state (:data:`~dynoplan.envs.gear.options.insert.
INSERT_STATE`: its arm's six joints, the gripper, the tool, the gear and the human's
hand, 16 of the 22 planner values; ``gear run --own-states``). For a ``gear run`` folder
``RUN`` this reads its option runs (``RUN/transitions``), splits them as ``gear run``'s
fit does (the same held-out runs, :func:`~dynoplan.pipeline.fit_data.split_runs` from
``[seed, 1]``), and fits
the insertion's dynamics on a share of its training runs (``--fractions``, whole runs
drawn from ``[seed, 9]``), once on the planner state and once on its own, with the fit
settings of ``gear run``. On the held-out insertion runs, one decision ahead, it reports
the median error of the ensemble's mean prediction of the tool point and of the gear (cm)
and the RMSE over the insertion's own values (the coordinates both models predict)::

    python -m benchmarks.gear_own_state results/gear-seed0 --fractions 0.25,0.5,1 \\
        --out results/gear-own-state-seed0.md

Each row's two models are fitted from the same seed on the same transitions, so only the
state they read differs.
"""

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from dynoplan.data import read_dataset
from dynoplan.envs.gear.learning.settings import DEFAULT_METRICS, DEFAULT_SETTINGS
from dynoplan.envs.gear.options.catalog import gear_option_names
from dynoplan.envs.gear.options.insert import INSERT_NAME, INSERT_STATE
from dynoplan.envs.gear.state import STATE_SLICES, PlannerState
from dynoplan.errors import DynoplanError
from dynoplan.io import write_text
from dynoplan.models.trainer import deterministic_training
from dynoplan.options.state_map import MappedDynamics, on_option_state
from dynoplan.pipeline.fit_data import option_transitions, split_runs
from dynoplan.pipeline.fit_dynamics import fit_ensemble
from dynoplan.types import FloatArray

FRACTIONS = (0.25, 0.5, 1.0)
"""Shares of the insertion's training runs each pair of models is fitted on."""


def errors(predicted: FloatArray, truth: FloatArray) -> dict[str, float]:
    """Median tool and gear errors (cm) and the RMSE over the insertion's own values of
    planner-state predictions ``(N, 22)`` against ``truth`` ``(N, 22)``."""
    own = list(INSERT_STATE.indices)
    return {
        "tool_cm": float(np.median(np.linalg.norm(
            predicted[:, STATE_SLICES["tool_pos"]] - truth[:, STATE_SLICES["tool_pos"]],
            axis=1)) * 100),
        "gear_cm": float(np.median(np.linalg.norm(
            predicted[:, STATE_SLICES["gear_pos"]] - truth[:, STATE_SLICES["gear_pos"]],
            axis=1)) * 100),
        "own_rmse": float(np.sqrt(np.mean((predicted[:, own] - truth[:, own]) ** 2)))}


def compare(run: Path, fractions: tuple[float, ...], seed: int) -> list[dict[str, Any]]:
    """One row per fraction (module docstring)."""
    transitions = run / "transitions"
    if not (transitions / "data").is_dir():
        raise DynoplanError(f"{run}: no option runs in transitions/ (a gear run's folder)")
    names = list(gear_option_names())
    planner = PlannerState()
    runs = list(read_dataset(transitions))
    train, held = split_runs(runs, DEFAULT_METRICS.dynamics_heldout_fraction,
                             np.random.default_rng([seed, 1]))
    label = names.index(INSERT_NAME)
    own_runs = [e for e in train if e.options is not None and e.options[0] == label]
    if not own_runs:
        raise DynoplanError(f"{transitions}: no run of '{INSERT_NAME}'")
    held_s, held_next = option_transitions(held, names, planner)[INSERT_NAME]
    order = np.random.default_rng([seed, 9]).permutation(len(own_runs))
    rows = []
    for fraction in fractions:
        chosen = [own_runs[i] for i in order[:max(1, round(fraction * len(own_runs)))]]
        s, nxt = option_transitions(chosen, names, planner)[INSERT_NAME]
        with deterministic_training():  # as gear run's fit: the same models every time
            shared, _ = fit_ensemble(INSERT_NAME, s, nxt, seed, DEFAULT_SETTINGS)
            own, _ = fit_ensemble(INSERT_NAME, *on_option_state((s, nxt), INSERT_STATE),
                                  seed, DEFAULT_SETTINGS)
        plain = shared.predict(held_s)[0].mean(axis=0)
        mapped = MappedDynamics(own, INSERT_STATE).predict(held_s)[0].mean(axis=0)
        rows.append({"fraction": fraction, "runs": len(chosen), "transitions": len(s),
                     "held_out_transitions": len(held_s),
                     "planner_state": errors(plain, held_next),
                     "own_state": errors(mapped, held_next),
                     "no_change": errors(held_s, held_next)})
    return rows


def table(rows: list[dict[str, Any]], command: str) -> str:
    lines = [f"Produced by `{command}`.", "",
             "| share of the runs | runs (transitions) | tool error (cm): planner state / own "
             "state | gear error (cm): planner / own | RMSE of its own values: planner / own "
             "| no change: tool / gear (cm) |", "|---|---|---|---|---|---|"]
    for r in rows:
        p, o, n = r["planner_state"], r["own_state"], r["no_change"]
        lines.append(f"| {r['fraction']:g} | {r['runs']} ({r['transitions']}) | "
                     f"{p['tool_cm']:.2f} / {o['tool_cm']:.2f} | {p['gear_cm']:.2f} / "
                     f"{o['gear_cm']:.2f} | {p['own_rmse']:.4f} / {o['own_rmse']:.4f} | "
                     f"{n['tool_cm']:.2f} / {n['gear_cm']:.2f} |")
    held = rows[0]["held_out_transitions"] if rows else 0
    return "\n".join(lines) + f"\n\nHeld-out insertion transitions: {held}.\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.gear_own_state",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path, help="a gear run's --out")
    parser.add_argument("--fractions", default=",".join(f"{f:g}" for f in FRACTIONS))
    parser.add_argument("--seed", type=int, default=None,
                        help="the run's seed [its summary.json's]")
    parser.add_argument("--out", type=Path, default=None, help="write the table here too")
    args = parser.parse_args(argv)
    argv_used = argv if argv is not None else sys.argv[1:]
    command = "python -m benchmarks.gear_own_state " + " ".join(argv_used)
    try:
        fractions = tuple(float(f) for f in args.fractions.split(",") if f)
        if not fractions or not all(0.0 < f <= 1.0 for f in fractions):
            raise DynoplanError(f"--fractions must be in (0, 1], got {args.fractions!r}")
        seed = args.seed
        if seed is None:
            summary = args.run / "summary.json"
            if not summary.is_file():
                raise DynoplanError(f"{args.run}: no summary.json; give --seed")
            seed = int(json.loads(summary.read_text())["seed"])
        text = table(compare(args.run, fractions, seed), command)
        if args.out is not None:
            write_text(args.out, text)
    except (DynoplanError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(text, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
