"""How fast does ``dynoplan/GearAssembly-v0`` step? Steps per second and realtime factor.

Usage::

    .venv/bin/python benchmarks/gear_step.py            # a table
    .venv/bin/python benchmarks/gear_step.py --json     # one JSON object

Two workloads, each from ``reset(seed)``:

- ``env.step``: the arms sweep slowly around their home pose (sinusoidal joint targets,
  the gripper opening and closing) while a human crosses the workspace; only the time
  inside ``env.step`` is counted;
- ``expert``: the scripted expert's episodes, timing ``env.step`` and the expert's
  decisions separately.

The realtime factor is simulated time divided by wall time (50 ms of simulated time per
step); the target is at least 10.
"""

import argparse
import json
import platform
import time
from typing import Any

import mujoco
import numpy as np

from dynoplan.envs.gear.env import CONTROL_DT, HOME_Q, SUBSTEPS, GearAssemblyEnv
from dynoplan.envs.gear.expert import GearExpert


def bench_env_step(steps: int, seed: int) -> dict[str, Any]:
    """Time ``env.step`` under a smooth, contact-rich motion."""
    env = GearAssemblyEnv(max_episode_steps=steps + 1)
    env.reset(seed=seed, options={"human_mode": "cross"})
    phases = np.linspace(0.0, np.pi, 12)
    elapsed = 0.0
    for k in range(steps):
        t = k * CONTROL_DT
        action = np.concatenate([HOME_Q + 0.15 * np.sin(0.8 * t + phases),
                                 [0.5 + 0.5 * np.sin(0.5 * t)]])
        t0 = time.perf_counter()
        env.step(action)
        elapsed += time.perf_counter() - t0
    # Bare physics for comparison: the same number of mj_step calls, no Python around them.
    m, d = env.model, env.data
    t0 = time.perf_counter()
    mujoco.mj_step(m, d, nstep=steps * SUBSTEPS)
    physics = time.perf_counter() - t0
    env.close()
    return {
        "steps": steps,
        "steps_per_second": steps / elapsed,
        "ms_per_step": 1e3 * elapsed / steps,
        "realtime_factor": steps * CONTROL_DT / elapsed,
        "physics_only_realtime_factor": steps * CONTROL_DT / physics,
    }


def bench_expert(episodes: int, seed: int) -> dict[str, Any]:
    """Time the expert's episodes: ``env.step`` and the expert's decisions separately."""
    env = GearAssemblyEnv()
    expert = GearExpert(env)
    step_time = decide_time = 0.0
    steps = 0
    for i in range(episodes):
        obs, info = env.reset(seed=seed + i)
        expert.reset()
        done = False
        while not done:
            t0 = time.perf_counter()
            decision = expert.act(obs, info)
            t1 = time.perf_counter()
            obs, _, terminated, truncated, info = env.step(decision.action)
            step_time += time.perf_counter() - t1
            decide_time += t1 - t0
            steps += 1
            done = terminated or truncated
    env.close()
    return {
        "episodes": episodes,
        "steps": steps,
        "env_realtime_factor": steps * CONTROL_DT / step_time,
        "env_ms_per_step": 1e3 * step_time / steps,
        "expert_ms_per_decision": 1e3 * decide_time / steps,
        "realtime_factor_with_expert": steps * CONTROL_DT / (step_time + decide_time),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000, help="env.step calls to time")
    parser.add_argument("--episodes", type=int, default=5, help="expert episodes to time")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args()
    result = {
        "env_step": bench_env_step(args.steps, args.seed),
        "expert": bench_expert(args.episodes, args.seed),
        "control_dt": CONTROL_DT,
        "substeps": SUBSTEPS,
        "mujoco": mujoco.__version__,
        "python": platform.python_version(),
    }
    if args.json:
        print(json.dumps(result))
        return
    e, x = result["env_step"], result["expert"]
    print(f"env.step: {e['steps_per_second']:.0f} steps/s, {e['ms_per_step']:.2f} ms/step, "
          f"{e['realtime_factor']:.1f}x real time "
          f"(bare physics {e['physics_only_realtime_factor']:.1f}x)")
    print(f"expert:   env.step {x['env_realtime_factor']:.1f}x real time, "
          f"{x['expert_ms_per_decision']:.2f} ms per decision, "
          f"{x['realtime_factor_with_expert']:.1f}x real time with the expert")


if __name__ == "__main__":
    main()
