"""The per-item map (:mod:`dynoplan.parallel`): the serial default needs no Ray; on Ray it
gives the serial results, re-raises a task's error, and survives a worker that dies."""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from dynoplan.errors import DynoplanError
from dynoplan.parallel import (
    SERIAL,
    Workers,
    cpu_count,
    imap_unordered,
    parallel_map,
    parse_workers,
    run_in_background,
)


def _setup(context: int) -> dict[str, int]:
    return {"offset": context, "built": 1}


def _square(state: dict[str, int], item: int) -> int:
    return item * item + state["offset"]


def test_serial_map_keeps_order_and_never_imports_ray():
    code = textwrap.dedent("""
        import sys
        from dynoplan.parallel import parallel_map, SERIAL
        out = parallel_map(lambda c: c, lambda s, x: s * x, 3, [1, 2, 3], SERIAL)
        assert out == [3, 6, 9], out
        assert "ray" not in sys.modules
        import dynoplan.cli.main, dynoplan.experiments.gear_run, dynoplan.experiments.sweep
        assert "ray" not in sys.modules
    """)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr


def test_serial_map_builds_once_per_context():
    built = []

    def setup(context: int) -> int:
        built.append(context)
        return context

    tasks = [(1, 0), (1, 1), (2, 2), (2, 3)]
    out = list(imap_unordered(setup, lambda s, x: (s, x), tasks, SERIAL))
    assert out == [(0, (1, 0)), (1, (1, 1)), (2, (2, 2)), (3, (2, 3))]
    assert built == [1, 2]


def test_bad_workers_and_missing_ray_are_one_clear_error(monkeypatch):
    with pytest.raises(DynoplanError, match="--workers must be >= 1"):
        Workers(count=0)
    with pytest.raises(DynoplanError, match="--ray-address must not be empty"):
        Workers(address=" ")
    assert not SERIAL.parallel and Workers(2).parallel and Workers(address="auto").parallel
    monkeypatch.setitem(sys.modules, "ray", None)  # "not installed"
    with pytest.raises(DynoplanError, match=r"need Ray: pip install 'dynoplan\[ray\]'"):
        parallel_map(_setup, _square, 0, [1, 2], Workers(2))


def test_workers_auto_is_one_per_cpu_with_ray_and_serial_without(monkeypatch):
    assert parse_workers("1") == SERIAL and parse_workers(3, "auto") == Workers(3, "auto")
    with pytest.raises(DynoplanError, match="--workers must be 'auto' or a number >= 1"):
        parse_workers("two")
    with pytest.raises(DynoplanError, match="--workers must be >= 1"):
        parse_workers("0")
    monkeypatch.setattr("dynoplan.parallel.ray_available", lambda: True)
    assert parse_workers("auto") == parse_workers(" AUTO ") == Workers(cpu_count())
    monkeypatch.undo()
    monkeypatch.setitem(sys.modules, "ray", None)  # "not installed"
    assert parse_workers("auto") == SERIAL  # no error: serial, and Ray is not needed


def test_gear_run_defaults_to_serial_without_ray_and_never_imports_it():
    code = textwrap.dedent("""
        import sys
        sys.modules["ray"] = None  # "not installed"
        import dynoplan.experiments.gear_run as gear_run
        seen = []
        gear_run.run_gear_pipeline = lambda *a, workers, **k: seen.append(workers) or {
            "results": []}
        from dynoplan.cli.main import main
        sys.argv = ["dynoplan", "gear", "run", "--out", "unused", "--quiet"]
        try:
            main()
        except SystemExit as exc:
            assert exc.code == 0, exc.code
        from dynoplan.parallel import SERIAL
        assert seen == [SERIAL], seen
    """)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr


def test_cli_without_ray_prints_one_error_line(tmp_path: Path):
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "models.json").write_text("{}")
    config = tmp_path / "grid.toml"
    config.write_text('models = "models"\nepisodes = 1\n[grid]\nhorizon = [3]\n')
    code = ("import sys; sys.modules['ray'] = None; from dynoplan.cli.main import main; "
            f"sys.argv = ['dynoplan', 'sweep', {str(config)!r}, '--workers', '2', "
            f"'--out', {str(tmp_path / 'out')!r}]; main()")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("dynoplan: error: ") and "Ray" in lines[0]


@pytest.mark.slow
def test_ray_map_matches_serial_and_retries_a_worker_that_dies(ray_runtime, tmp_path: Path):
    marker, log = tmp_path / "died-once", tmp_path / "completed"

    # defined here, so that Ray ships them by value (the tests folder is not importable)
    def setup(context: int) -> int:
        return context

    def dies_once(offset: int, item: int) -> int:
        if item == 3 and not marker.exists():
            marker.touch()
            os._exit(1)  # the worker process dies mid-item, without a Python exception
        with log.open("a") as f:
            f.write(f"{item}\n")
        return item * item + offset

    items = list(range(8))
    serial = parallel_map(setup, lambda s, x: x * x + s, 5, items, SERIAL)
    parallel = parallel_map(setup, dies_once, 5, items, Workers(2))
    assert parallel == serial
    assert marker.exists()  # it did die once
    assert sorted(int(x) for x in log.read_text().split()) == items  # none lost, none twice


@pytest.mark.slow
def test_ray_map_reraises_a_task_error_without_retrying(ray_runtime, tmp_path: Path):
    attempts = tmp_path / "attempts"

    def fails(state: int, item: int) -> int:
        with attempts.open("a") as f:
            f.write("x")
        raise DynoplanError(f"item {item} is bad")

    with pytest.raises(DynoplanError, match="item 0 is bad"):
        parallel_map(lambda c: c, fails, 0, [0], Workers(2))
    assert attempts.read_text() == "x"


def test_a_background_task_runs_at_once_when_serial():
    ran = []
    wait = run_in_background(lambda x: ran.append(x) or x + 1, (1,), SERIAL)
    assert ran == [1] and wait() == 2


@pytest.mark.slow
def test_a_background_task_runs_beside_a_map_on_ray(ray_runtime, tmp_path: Path):
    def slow_square(x: int) -> int:
        import time

        time.sleep(1.0)
        return x * x

    def fails(x: int) -> int:
        raise DynoplanError(f"{x} is bad")

    wait = run_in_background(slow_square, (7,), Workers(2))
    assert parallel_map(lambda c: c, lambda c, x: x + c, 1, [1, 2, 3], Workers(2)) == [2, 3, 4]
    assert wait() == 49
    failed = run_in_background(fails, (3,), Workers(2))
    with pytest.raises(DynoplanError, match="3 is bad"):
        failed()
