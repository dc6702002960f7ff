"""The one order of a run's stages (``run_pipeline`` on a task's ``TaskStages``): each
stage once, in the pipeline's order, given what the last returned, timed on one clock."""

from pathlib import Path

import pytest

from dynoplan import DynoplanError
from dynoplan.envs.gear.pipeline_stages import GearStages
from dynoplan.pipeline import run_pipeline
from dynoplan.pipeline.task import PipelineRun
from test_pipeline import SMALL, line_env, line_options

ORDER = ["prepare", "demonstrations", "option_runs", "fit", "after_fit", "evaluate",
         "report"]


class Recorded:
    """Stages that record which ran, on which run, given what; each is timed by name and
    returns its name with what it was given."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, tuple[object, ...]]] = []
        self.runs: list[PipelineRun] = []

    def _stage(self, name: str, run: PipelineRun, *given: object) -> str:
        self.calls.append((name, given))
        self.runs.append(run)
        return run.clock.stage(name, lambda: f"{name}({', '.join(map(str, given))})")

    def prepare(self, run: PipelineRun) -> None:
        self._stage("prepare", run)

    def demonstrations(self, run: PipelineRun) -> str:
        return self._stage("demonstrations", run)

    def option_runs(self, run: PipelineRun, demos: str) -> str:
        return self._stage("option_runs", run, demos)

    def fit(self, run: PipelineRun, demos: str, runs: str) -> str:
        return self._stage("fit", run, demos, runs)

    def after_fit(self, run: PipelineRun, models: str) -> str:
        return self._stage("after_fit", run, models)

    def evaluate(self, run: PipelineRun, models: str) -> str:
        return self._stage("evaluate", run, models)

    def report(self, run: PipelineRun, evaluation: str) -> dict[str, object]:
        self._stage("report", run, evaluation)
        return {"evaluation": evaluation, "seconds": dict(run.clock.seconds)}


def test_a_tasks_stages_run_once_each_in_order_given_what_the_last_returned(tmp_path: Path):
    stages, said = Recorded(), []
    out = tmp_path / "run"
    result = run_pipeline(stages=stages, out=out, status=said.append, progress=True)

    assert [name for name, _ in stages.calls] == ORDER == said
    given = dict(stages.calls)
    assert given["fit"] == ("demonstrations()", "option_runs(demonstrations())")
    assert given["evaluate"] == ("after_fit(fit(demonstrations(), "
                                 "option_runs(demonstrations())))",)
    assert result["evaluation"] == ("evaluate(after_fit(fit(demonstrations(), "
                                    "option_runs(demonstrations()))))")
    assert list(result["seconds"]) == ORDER  # every stage timed on the one clock
    # one run for every stage, into the output folder, which exists before the first
    assert len({id(run) for run in stages.runs}) == 1
    run = stages.runs[0]
    assert run.out == out and out.is_dir() and run.progress


def test_stages_with_what_the_generic_ones_take_or_neither_are_one_clear_error():
    with pytest.raises(DynoplanError, match="give only out, progress, status and workers"):
        run_pipeline(line_env(), line_options(), stages=Recorded())
    with pytest.raises(DynoplanError, match="give only out, progress, status and workers"):
        run_pipeline(stages=Recorded(), settings=SMALL)
    with pytest.raises(DynoplanError, match="give an environment and options"):
        run_pipeline()


def test_the_gear_stages_need_an_output_folder_before_any_work():
    with pytest.raises(DynoplanError, match="writes into a folder"):
        run_pipeline(stages=GearStages())


def test_the_generic_stages_announce_the_pipelines_order(tmp_path: Path):
    said: list[str] = []
    run_pipeline(line_env(), line_options(), demonstrator=lambda obs: "right",
                 settings=SMALL, status=said.append)
    assert said.index("demonstrations") < said.index("option transitions") < said.index(
        "admissibility") < said.index("evaluation")
