"""The look-ahead's known answer: DynoPlan on the trap walk at several depths.

Every depth runs on the same episodes (seeds), all episodes side by side
(:func:`~dynoplan.control.batched.run_batched`); ``summary.json`` has one row per depth
(success rate, planning steps, where failed episodes ended, wall time).
"""

import time
from collections import Counter
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from dynoplan import __version__
from dynoplan.control.batched import run_batched
from dynoplan.envs import TRAP_WALK_ID
from dynoplan.envs.trap import CorridorProgress, make_trap_options
from dynoplan.errors import DynoplanError
from dynoplan.io import ensure_writable_dir, write_json
from dynoplan.limits import DEPTH_MAX
from dynoplan.pipeline.evaluate import planning_steps_summary
from dynoplan.planning import SequencePlanner
from dynoplan.seeding import batch_planner_seed, episode_seeds


@dataclass(frozen=True)
class TrapSettings:
    """Everything that defines a trap-walk run (recorded in ``summary.json``)."""

    episodes: int = 1000
    depths: tuple[int, ...] = (1, 2)
    seed: int = 0
    horizon: int = 20
    samples: int = 64
    max_decisions: int = 50

    def validate(self) -> None:
        if self.episodes < 1 or self.horizon < 1 or self.samples < 1 \
                or self.max_decisions < 1:
            raise DynoplanError("--episodes, --horizon, --samples and --max-decisions must "
                                "be >= 1")
        if not self.depths or not all(1 <= d <= DEPTH_MAX for d in self.depths):
            raise DynoplanError(f"every --depth must be in [1, {DEPTH_MAX}], got "
                                f"{list(self.depths)}")


def trap_row(settings: TrapSettings, depth: int) -> dict[str, Any]:
    """DynoPlan at ``depth`` on the settings' episodes: the summary of one row."""
    options = make_trap_options()
    planner = SequencePlanner(options, CorridorProgress(), horizon=settings.horizon,
                              samples=settings.samples, depth=depth, compact=True)
    seeds = episode_seeds(settings.seed, settings.episodes)
    envs = [gym.make(TRAP_WALK_ID) for _ in seeds]
    planner_rng = np.random.default_rng(batch_planner_seed(settings.seed))
    t0, cpu0 = time.perf_counter(), time.process_time()
    traces = run_batched(envs, options, planner, seeds, planner_rng,
                         max_decisions=settings.max_decisions)
    seconds, cpu_seconds = time.perf_counter() - t0, time.process_time() - cpu0
    ends = Counter(tuple(int(v) for v in t.decisions[-1].state_after)
                   for t in traces if not t.success and t.decisions)
    return {"depth": depth, **planning_steps_summary(traces), "seconds": seconds,
            "cpu_seconds": cpu_seconds,
            "failed_ended_at": {f"{x},{lane}": n for (x, lane), n in sorted(ends.items())}}


def run_trap(settings: TrapSettings, out: Path) -> dict[str, Any]:
    """Run every depth, write ``summary.json`` into ``out`` and return the summary."""
    settings.validate()
    out = ensure_writable_dir(out)
    rows = [trap_row(settings, depth) for depth in settings.depths]
    summary = {"experiment": "trap_walk", "dynoplan_version": __version__,
               "settings": {**asdict(settings), "depths": list(settings.depths)},
               "rows": rows}
    write_json(out / "summary.json", summary)
    return summary
