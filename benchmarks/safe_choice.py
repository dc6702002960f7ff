"""Where the S_p violations of a gear controller happen: while an option runs, or while
the controller holds because no option is admissible.

For seeded episodes of the unseen human behaviours (the same episodes as ``dynoplan gear
evaluate --human unseen`` for seed 0, without the runtime monitor), every env step is
labelled by what drove it: the option that ran, or ``hold`` (the chance constraint, or
the sets, left no option). Per label: the steps, the steps after which the arm moved
(fastest point at 0.01 m/s or more, for whatever reason: a held arm the hand pushes moves
too), S_p violations among those (ISO/TS 15066 for the measured speeds), physics steps in
contact, and, for options, the decisions whose chosen option the constraint predicted
safe (unsafe share 0) against those it was violated in.

    python benchmarks/safe_choice.py --controller dynoplan_safe --episodes 6 \\
        --models results/gear/models --out results/safety/safe_choice.md
"""

import argparse
from collections import defaultdict
from pathlib import Path

import numpy as np

from dynoplan.envs.gear.controllers import GEAR_CONTROL
from dynoplan.envs.gear.evaluation import EVAL_SEED_OFFSET
from dynoplan.envs.gear.human import UNSEEN_BEHAVIOURS
from dynoplan.envs.gear.pipeline_task import GearTask
from dynoplan.pipeline.evaluate import ControllerRunner
from dynoplan.reports.tables import markdown_table
from dynoplan.safety import AT_REST_SPEED, protective_separation
from dynoplan.seeding import episode_seeds

COLUMNS = ("driven_by", "steps", "steps_moving", "sp_violations_moving", "contacts",
           "decisions", "decisions_with_violation", "predicted_safe_but_violated")


def tally(controller: str, models: Path, episodes: int) -> list[dict[str, object]]:
    """One row per label (an option or ``hold``), over the first ``episodes`` episodes."""
    runner = GearTask(human=UNSEEN_BEHAVIOURS).make_runner(controller, models, GEAR_CONTROL)
    if not isinstance(runner, ControllerRunner):
        raise SystemExit(f"{controller} is not an option-level controller")
    rows: dict[str, dict[str, int]] = defaultdict(lambda: dict.fromkeys(COLUMNS[1:], 0))
    for seed in episode_seeds(EVAL_SEED_OFFSET, episodes):
        trace = runner.run(seed)
        infos = trace.infos
        speed = np.array([i["robot_speed"] for i in infos])
        s_p = protective_separation(speed, np.array([i["human_speed"] for i in infos]))
        moving = speed >= AT_REST_SPEED
        violation = moving & (np.array([i["min_human_distance"] for i in infos]) < s_p)
        contacts = np.array([i["human_contacts"] for i in infos])
        for d in trace.decisions:
            # a hold is recorded after its step, an option before its steps
            first = d.env_step - d.steps if d.option is None else d.env_step
            steps = slice(first, first + d.steps)
            row = rows[d.option or "hold"]
            violated = int(violation[steps].sum())
            row["steps"] += d.steps
            row["steps_moving"] += int(moving[steps].sum())
            row["sp_violations_moving"] += violated
            row["contacts"] += int(contacts[steps].sum())
            row["decisions"] += 1
            row["decisions_with_violation"] += int(violated > 0)
            shares = d.plan.unsafe_shares
            if d.option is not None and shares is not None and d.plan.chosen is not None:
                row["predicted_safe_but_violated"] += int(
                    violated > 0 and float(shares[d.plan.chosen]) == 0.0)
    return [{"driven_by": k, **v} for k, v in sorted(rows.items())]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--controller", default="dynoplan_safe")
    parser.add_argument("--models", type=Path, default=Path("results/gear/models"))
    parser.add_argument("--episodes", type=int, default=6)
    parser.add_argument("--out", type=Path, default=Path("results/safety/safe_choice.md"))
    args = parser.parse_args()
    rows = tally(args.controller, args.models, args.episodes)
    text = (f"# Where {args.controller}'s S_p violations happen ({args.episodes} unseen-"
            f"behaviour episodes, seed 0, no monitor)\n\n{markdown_table(rows, COLUMNS)}\n")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
