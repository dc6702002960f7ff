"""How wrong is the constant-velocity model of the hand? Error by time ahead, per behaviour.

The safe planner predicts the hand with
:class:`~dynoplan.safety.constraint.ConstantVelocityHuman`: from its position and
measured velocity now, it keeps the velocity; the prediction's spread is
``spread0 + spread1 * t``. This script draws the hand's schedules of ``--episodes``
seeded episodes per behaviour (:func:`~dynoplan.envs.gear.human.sample_schedule`, the
gear at its default position, the peg at its home tip), takes a decision every 0.5 s of
the first 20 s, predicts 0.5 .. 5 s ahead (the planner's horizon) and reports, per
behaviour and time ahead, the 95th-percentile error (m) and the share of predictions
within one spread (the constraint's margin), over all decisions and over those where the
hand moves (now or before the time predicted; at rest the prediction is exact).

Run ``python benchmarks/human_motion.py [--episodes 200] [--json]``.
"""

import argparse
import json
from typing import Any

import numpy as np

from dynoplan.envs.gear.human import BEHAVIOURS, sample_schedule

GEAR_XY = np.array([0.6, 0.3])
PEG_TIP = np.array([0.615, -0.089, 0.911])
DECISION_S = 0.5
AHEAD_S = (0.5, 1.0, 2.0, 3.0, 5.0)
SPREAD = (0.02, 0.3)  # ConstantVelocityHuman's default


def errors(behaviour: str, episodes: int,
           seed: int) -> dict[float, tuple[np.ndarray, np.ndarray]]:
    """Per time ahead, the prediction errors (m) over episodes and decision times, and
    whether the hand moves (now, or before the time predicted)."""
    out: dict[float, list[float]] = {a: [] for a in AHEAD_S}
    moves: dict[float, list[bool]] = {a: [] for a in AHEAD_S}
    times = np.arange(0.0, 20.0, DECISION_S)
    for e in range(episodes):
        schedule = sample_schedule(np.random.default_rng([seed, e]), GEAR_XY, PEG_TIP,
                                   mode=behaviour)
        now = schedule.position(times)
        velocity = np.stack([schedule.velocity(float(t)) for t in times])
        for ahead in AHEAD_S:
            truth = schedule.position(times + ahead)
            out[ahead] += np.linalg.norm(now + velocity * ahead - truth, axis=1).tolist()
            moves[ahead] += ((np.linalg.norm(velocity, axis=1) > 0)
                             | (np.linalg.norm(truth - now, axis=1) > 0)).tolist()
    return {a: (np.asarray(out[a]), np.asarray(moves[a])) for a in AHEAD_S}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args()
    result: dict[str, Any] = {"episodes": args.episodes, "seed": args.seed,
                              "spread": list(SPREAD), "rows": []}
    for behaviour in BEHAVIOURS:
        for ahead, (err, moving) in errors(behaviour, args.episodes, args.seed).items():
            spread = SPREAD[0] + SPREAD[1] * ahead
            active = err[moving] if moving.any() else np.zeros(1)
            result["rows"].append({
                "behaviour": behaviour, "ahead_s": ahead,
                "p95_m": round(float(np.quantile(err, 0.95)), 3),
                "within_spread": round(float(np.mean(err <= spread)), 3),
                "moving_share": round(float(np.mean(moving)), 3),
                "moving_median_m": round(float(np.median(active)), 3),
                "moving_within_spread": round(float(np.mean(active <= spread)), 3)})
    if args.json:
        print(json.dumps(result))
        return
    print("| behaviour | ahead (s) | p95 error (m) | within spread | hand moving | "
          "median error, moving (m) | within spread, moving |")
    print("|---|---|---|---|---|---|---|")
    for r in result["rows"]:
        print(f"| {r['behaviour']} | {r['ahead_s']} | {r['p95_m']} | {r['within_spread']} | "
              f"{r['moving_share']} | {r['moving_median_m']} | {r['moving_within_spread']} |")


if __name__ == "__main__":
    main()
