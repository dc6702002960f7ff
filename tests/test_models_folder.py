"""The models folder's manifest: a refitted initiation replaces the recorded one."""

import pytest

from dynoplan.errors import DynoplanError
from dynoplan.models.folder import read_manifest, set_initiation, write_manifest


def _folder(tmp_path):
    for name, data in (("goal.safetensors", b"goal"), ("dynamics-a.safetensors", b"a"),
                       ("initiation.safetensors", b"first fit")):
        (tmp_path / name).write_bytes(data)
    write_manifest(tmp_path, task="toy", state_dim=2, option_names=["a"], stride=1,
                   use_regions=False, goal=("goal.safetensors", None), regions=None,
                   dynamics={"a": "dynamics-a.safetensors"},
                   initiation=("initiation.safetensors", None))
    return tmp_path


def test_a_refitted_initiation_is_recorded_over_the_old_one(tmp_path):
    folder = _folder(tmp_path)
    (folder / "initiation.safetensors").write_bytes(b"second fit")  # what a refit writes
    with pytest.raises(DynoplanError, match=r"does not match models\.json"):
        read_manifest(folder)
    set_initiation(folder, "initiation.safetensors", "relative")
    manifest = read_manifest(folder)
    assert manifest.initiation is not None and manifest.initiation.features == "relative"


def test_replacing_the_initiation_still_checks_every_other_file(tmp_path):
    folder = _folder(tmp_path)
    (folder / "goal.safetensors").write_bytes(b"tampered")
    with pytest.raises(DynoplanError, match=r"goal\.safetensors: does not match"):
        set_initiation(folder, "initiation.safetensors")
