"""The one stage timer of ``gear run`` and ``run_pipeline``."""

import itertools

import pytest

import dynoplan.timing
from dynoplan.parallel import SERIAL
from dynoplan.timing import StageClock


@pytest.fixture
def ticks(monkeypatch):
    """``time.perf_counter`` as seen by the timer: 0, 1, 2, ... seconds, one per call."""
    counter = itertools.count()
    monkeypatch.setattr(dynoplan.timing, "perf_counter", lambda: float(next(counter)))


def test_switch_times_each_stage_until_the_next_and_adds_a_repeated_name(ticks):
    said: list[str] = []
    clock = StageClock(said.append)  # t=0
    clock.switch("fit")  # t=1: nothing current
    clock.switch("evaluate")  # t=2: fit 1 s
    clock.switch("fit")  # t=3: evaluate 1 s
    clock.switch("")  # t=4: fit 1 s more
    assert clock.seconds == {"fit": 2.0, "evaluate": 1.0}
    assert said == ["fit", "evaluate", "fit"]  # "" ends the stage without a message


def test_stage_returns_the_result_and_leaves_gaps_untimed(ticks):
    said: list[str] = []
    clock = StageClock(said.append, "[{}]")
    assert clock.stage("demos", lambda: 7) == 7  # t=1 .. t=2
    clock.switch("")  # t=3: no stage was running
    assert clock.stage("train", lambda: "done") == "done"  # t=4 .. t=5
    assert clock.seconds == {"demos": 1.0, "train": 1.0}
    assert said == ["[demos]", "[train]"]


def test_a_started_stage_runs_at_once_when_serial_and_records_its_own_duration(ticks):
    said: list[str] = []
    clock = StageClock(said.append, "[{}]")
    ran: list[int] = []
    wait = clock.start("video", lambda x: ran.append(x) or x + 1, 4, workers=SERIAL)
    assert ran == [4] and "video" not in clock.seconds  # recorded when waited for
    assert wait() == 5
    assert clock.seconds == {"video": 1.0}
    assert said == ["[video]"]


def test_rounded_rounds_every_stage():
    clock = StageClock()
    clock.seconds.update(fit=1.23456, evaluate=0.0049)
    assert clock.rounded(2) == {"fit": 1.23, "evaluate": 0.0}
