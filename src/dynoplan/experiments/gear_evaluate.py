"""``dynoplan gear evaluate``: controllers on trained models only, timed.

The same seeded episodes as ``dynoplan gear run`` for the same seed (its evaluation
stage without the training stages), so a run on several workers can be compared with a
run on one: the metrics agree, the wall time (``summary.json``'s ``wall_s``) does not.
"""

import time
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

from dynoplan.envs.gear.controllers import GEAR_CONTROL, VARIANTS
from dynoplan.envs.gear.evaluation import ORACLE_FIRST, controller_rows, evaluation_seeds
from dynoplan.envs.gear.flat_policy import FLAT_POLICY
from dynoplan.envs.gear.pipeline_task import GearTask
from dynoplan.envs.gear.reports.results import evaluation_markdown, results_rows, write_results
from dynoplan.errors import DynoplanError
from dynoplan.io import ensure_writable_dir, write_json, write_text
from dynoplan.parallel import SERIAL, Workers, ray_session
from dynoplan.pipeline.control_settings import ControllerSettings
from dynoplan.pipeline.jobs import evaluate_rows


def run_gear_evaluation(models: Path, out: Path, controllers: Sequence[str], episodes: int,
                        seed: int = 0, planner: ControllerSettings = GEAR_CONTROL,
                        flat_folder: Path | None = None, workers: Workers = SERIAL,
                        progress: bool = True,
                        task: GearTask = GearTask()) -> dict[str, Any]:
    """Evaluate ``controllers`` (of :data:`VARIANTS` and ``flat_ppo``) on ``episodes``
    seeded episodes each; write ``results.csv``, ``results.md``, ``episodes.json`` and
    ``summary.json`` (with ``wall_s``, Ray's start included) into ``out``; return the
    summary. ``task``: the gear as the episodes see it: the human behaviours they draw
    from (``results.md`` has the success by behaviour) and the runtime monitor.

    Raises:
        DynoplanError: an unknown controller, ``episodes < 1``, unreadable models, or
            ``flat_ppo`` without ``flat_folder``.
    """
    from dynoplan.envs.gear.flat_policy import read_flat_policy
    from dynoplan.envs.gear.models_folder import load_gear_models

    known = (*VARIANTS, FLAT_POLICY)
    unknown = [c for c in controllers if c not in known]
    if unknown or not controllers:
        raise DynoplanError(f"unknown controller(s) {', '.join(unknown) or '(none given)'}; "
                            f"expected some of {', '.join(known)}")
    if FLAT_POLICY in controllers and flat_folder is None:
        raise DynoplanError(f"{FLAT_POLICY} needs the flat policy's folder")
    if episodes < 1:
        raise DynoplanError(f"--episodes must be >= 1, got {episodes}")
    planner.validate()  # horizon, samples, ...
    ensure_writable_dir(out)
    load_gear_models(models)  # one clear error here rather than one per worker
    if FLAT_POLICY in controllers and flat_folder is not None:
        read_flat_policy(flat_folder)
    rows = controller_rows(models, evaluation_seeds(seed, episodes), planner,
                           [c for c in controllers if c != FLAT_POLICY],
                           flat_folder if FLAT_POLICY in controllers else None, task)
    t0 = time.perf_counter()
    with ray_session(workers):
        per_episode = evaluate_rows(rows, workers, f"evaluate ({len(rows)} controllers)",
                                    progress, ORACLE_FIRST)
    wall = time.perf_counter() - t0
    table = results_rows(per_episode)
    summary = {"models": str(models), "seed": seed, "episodes": episodes,
               "human": list(task.human) if task.human is not None else None,
               "shield": task.shield,
               "planner": asdict(planner), "workers": asdict(workers),
               "wall_s": round(wall, 2), "results": table}
    write_results(out, table, per_episode)
    write_text(out / "results.md", evaluation_markdown(summary))
    write_json(out / "summary.json", summary)
    return summary


__all__ = ["run_gear_evaluation"]
