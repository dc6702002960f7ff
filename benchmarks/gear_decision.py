"""Decision latency on the gear assembly: the learned-model planner against the oracle.

Usage::

    .venv/bin/python benchmarks/gear_decision.py --models results/gear/models
    .venv/bin/python benchmarks/gear_decision.py --models DIR --json

Both choosers are DynoPlan's Eq. 1 over the same options (initiation sets, terminations)
and goal heuristic, with the **same** samples and horizon (``--samples``, ``--horizon``):
:class:`~dynoplan.planning.OptionPlanner` rolls the learned dynamics ensembles forward,
:class:`~dynoplan.planning.SimulatorOracle` copies the MuJoCo state and runs
each option's own policy in a scratch simulator. The decision states are those of
``--episodes`` seeded DynoPlan episodes (every ``--every``-th decision where some
option is admissible, after ``--warmup`` such decisions); at each, the two choosers
decide one after the other from the live state, so they see the same machine; the
episode itself runs on the default planner. Reported: p50 / p99 of each, the ratio of
the medians (``oracle / learned``), and the learned planner's p50 at the evaluation's
default settings (``GEAR_CONTROL``).

Targets (issue 6): learned p50 <= 10 ms at the default settings; oracle / learned >= 100.
"""

import argparse
import json
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from dynoplan.envs.gear.controllers import GEAR_CONTROL, gear_oracle
from dynoplan.envs.gear.env import GearAssemblyEnv
from dynoplan.envs.gear.models_folder import load_gear_models
from dynoplan.envs.gear.options.catalog import policy_factories
from dynoplan.envs.gear.pipeline_task import GearTask
from dynoplan.pipeline.evaluate import ControllerRunner
from dynoplan.planning import OptionPlanner
from dynoplan.seeding import episode_seeds


def measure(models_dir: Path, episodes: int, every: int, samples: int, horizon: int,
            seed: int, warmup: int = 4) -> dict[str, Any]:
    models = load_gear_models(models_dir)
    factories = policy_factories(models_dir)
    runner = GearTask().make_runner("dynoplan", models_dir, GEAR_CONTROL)
    assert isinstance(runner, ControllerRunner) and isinstance(runner.env, GearAssemblyEnv)
    env, controller = runner.env, runner.controller
    options = controller.options
    same = OptionPlanner(options, models.goal, horizon=horizon, samples=samples)
    oracle = gear_oracle(env, options, factories, models.goal, horizon, samples)
    timings: dict[str, list[float]] = {"learned": [], "oracle": [], "learned_default": []}
    own = controller.chooser
    rng = np.random.default_rng([seed, 1])
    calls = [0]

    class Timed:
        """The controller's own chooser; every ``every``-th decision with an admissible
        option, the two same-settings choosers decide too, from the live state."""

        option_names = own.option_names

        def choose(self, state: np.ndarray, run_rng: Any, running: int | None = None) -> Any:
            t0 = time.perf_counter()
            plan = own.choose(state, run_rng, running)
            default_ms = 1e3 * (time.perf_counter() - t0)
            calls[0] += 1
            if plan.chosen is not None and calls[0] % every == 0 and calls[0] > warmup:
                timings["learned_default"].append(default_ms)
                for name, fn in (("learned", same.plan), ("oracle", oracle.choose)):
                    t0 = time.perf_counter()
                    fn(state, rng, running)
                    timings[name].append(1e3 * (time.perf_counter() - t0))
            return plan

    controller.chooser = Timed()
    for s in episode_seeds(seed, episodes):
        controller.run(env, s.rng(), seed=s.env_seed)
    env.close()
    p = {name: (float(np.percentile(v, 50)), float(np.percentile(v, 99)))
         for name, v in timings.items()}
    default = GEAR_CONTROL
    return {
        "models": str(models_dir), "episodes": episodes, "decisions": len(timings["learned"]),
        "samples": samples, "horizon": horizon,
        "learned_ms_p50": p["learned"][0], "learned_ms_p99": p["learned"][1],
        "oracle_ms_p50": p["oracle"][0], "oracle_ms_p99": p["oracle"][1],
        "oracle_over_learned": p["oracle"][0] / p["learned"][0],
        "default_samples": default.samples, "default_horizon": default.horizon,
        "learned_default_ms_p50": p["learned_default"][0],
        "learned_default_ms_p99": p["learned_default"][1],
        "torch_threads": torch.get_num_threads(),
        "machine": platform.processor() or platform.machine(),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--models", type=Path, required=True, help="a trained models folder")
    parser.add_argument("--episodes", type=int, default=3)
    parser.add_argument("--every", type=int, default=2, help="time every k-th decision")
    parser.add_argument("--warmup", type=int, default=4, help="decisions not timed first")
    parser.add_argument("--samples", type=int, default=4)
    parser.add_argument("--horizon", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    torch.set_num_threads(1)
    out = measure(args.models, args.episodes, args.every, args.samples, args.horizon, args.seed,
                  args.warmup)
    if args.json:
        print(json.dumps(out))
        return
    for key, value in out.items():
        print(f"{key:24s} {value:.3g}" if isinstance(value, float) else f"{key:24s} {value}")


if __name__ == "__main__":
    main()
