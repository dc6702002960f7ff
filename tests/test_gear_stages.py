"""The stage commands (``gear demos``, ``collect``, ``train``, ``figures``) chained as
``docs/gear-options.md`` shows them write the files of ``gear run`` for the same seed."""

import hashlib
import json
import re
import shlex
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from safetensors import safe_open
from typer.testing import CliRunner

from dynoplan.cli.main import app
from dynoplan.envs.gear.learning.settings import QUICK_SETTINGS
from dynoplan.envs.gear.options.catalog import gear_option_names, network_files

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "gear-options.md"
CHAIN_MARK = "<!-- the stage chain"
FOLDER = "results/gear-stages"


def documented_chain() -> list[list[str]]:
    """The ``dynoplan ...`` commands of the bash block after the stage-chain mark in the
    doc, each split into its arguments (``\\`` continuations joined)."""
    text = DOC.read_text(encoding="utf-8")
    block = re.search(r"```bash\n(.*?)```", text[text.index(CHAIN_MARK):], re.S)
    assert block is not None, f"{DOC}: no bash block after {CHAIN_MARK!r}"
    lines = block.group(1).replace("\\\n", " ").splitlines()
    return [shlex.split(line) for line in lines if line.startswith("dynoplan ")]


def test_the_documented_chain_is_every_stage_into_one_folder():
    chain = documented_chain()
    assert [c[1:3] for c in chain] == [["gear", "demos"], ["gear", "demos"],
                                       ["gear", "collect"], ["gear", "train"],
                                       ["gear", "figures"], ["gear", "outcomes"]]
    assert "--heldout" in chain[1] and "--heldout" not in chain[0]
    for command in chain:
        assert all(a.startswith(FOLDER) for a in command if "/" in a), command


def _without_seconds(value: Any) -> Any:
    """JSON ``value`` without the entries that time the run (``*seconds*``)."""
    if isinstance(value, dict):
        return {k: _without_seconds(v) for k, v in value.items() if "seconds" not in k}
    if isinstance(value, list):
        return [_without_seconds(v) for v in value]
    return value


def _safetensors(path: Path) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Every tensor of the file, and its metadata (JSON values parsed) without timings."""
    with safe_open(str(path), "np") as f:
        tensors = {k: f.get_tensor(k) for k in f.keys()}  # noqa: SIM118 (no __iter__)
        meta = {k: json.loads(v) if v[:1] in "{[" else v for k, v in (f.metadata() or {}).items()}
    return tensors, _without_seconds(meta)


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _paths_and_times_removed(value: Any) -> Any:
    """``metrics.json`` or ``figures.json`` without where the inputs were and timings."""
    value = _without_seconds(value)
    if isinstance(value, dict):
        return {k: _paths_and_times_removed(v) for k, v in value.items()
                if k not in ("data", "file", "heldout", "models")}
    if isinstance(value, list):
        return [_paths_and_times_removed(v) for v in value]
    return value


@pytest.mark.slow
def test_stage_commands_chained_as_documented_give_gear_runs_models(quick_gear_run: Path,
                                                                     tmp_path: Path):
    """The doc's chain with ``--quick`` (about a minute and a half on one core: the option
    networks, 20 operator demonstrations, 16 collection runs, quick fits) against the
    session's ``gear run --quick`` (same seed, 0): the same datasets, the same model
    files (the option networks' tensors and metadata, their training time aside) and
    manifest, the same metrics and figures."""
    run = quick_gear_run
    out = tmp_path / "stages"
    for command in documented_chain():
        args = [a.replace(FOLDER, str(out)) for a in command[1:]]
        args += ["--quick", "--quiet"] + (["--workers", "1"] if args[1] != "figures" else [])
        result = CliRunner().invoke(app, args)
        assert result.exit_code == 0, f"{shlex.join(args)}\n{result.output}"

    for dataset in ("demos", "heldout", "transitions"):
        for file in sorted((run / dataset).rglob("*.hdf5")):
            mine = out / dataset / file.relative_to(run / dataset)
            assert mine.read_bytes() == file.read_bytes(), mine

    theirs = sorted(p.name for p in (run / "models").iterdir() if p.is_file())
    assert sorted(p.name for p in (out / "models").iterdir() if p.is_file()) == theirs
    manifest = json.loads((out / "models" / "models.json").read_text())
    assert manifest == json.loads((run / "models" / "models.json").read_text())
    assert manifest["option_names"] == list(gear_option_names())
    # gear run --quick's fits (JSON has lists where the settings have tuples)
    assert manifest["report"]["settings"] == json.loads(json.dumps(asdict(QUICK_SETTINGS)))
    for name in theirs:
        if name in network_files().values():  # their metadata holds the training time
            tensors, meta = _safetensors(out / "models" / name)
            expected, expected_meta = _safetensors(run / "models" / name)
            assert tensors.keys() == expected.keys() and meta == expected_meta, name
            for key, tensor in expected.items():
                np.testing.assert_array_equal(tensors[key], tensor, err_msg=f"{name}: {key}")
        elif name not in ("metrics.json", "initiation.json"):  # the goal, the regions,
            # the dynamics, the learned initiation, models.json
            assert _sha256(out / "models" / name) == _sha256(run / "models" / name), name
    for file in sorted((run / "outcomes").rglob("*.hdf5")):  # the outcome runs
        mine = out / "outcomes" / file.relative_to(run / "outcomes")
        assert mine.read_bytes() == file.read_bytes(), mine
    for name in ("models/metrics.json", "models/initiation.json", "figures/figures.json"):
        mine_json = json.loads((out / name).read_text())
        assert _paths_and_times_removed(mine_json) == _paths_and_times_removed(
            json.loads((run / name).read_text())), name
