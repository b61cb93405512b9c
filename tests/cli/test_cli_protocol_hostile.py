"""``skincal protocol --out`` onto what exists (found by the new-user/attacker review)."""

from __future__ import annotations

import pytest

from skincal.cli import main


@pytest.mark.adversarial
@pytest.mark.parametrize("force", [[], ["--force"]])
def test_an_existing_bag_folder_is_named_as_such_and_kept(tmp_path, capsys, force):
    """It used to say "is a folder; give a file name", though a folder is what a ROS 2 bag is."""
    out = tmp_path / "motion"
    out.mkdir()
    (out / "keep.db3").write_bytes(b"mine")
    code = main(["protocol", "--robot", "panda", "--rate", "10", "--out", str(out), *force])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert "exists; a ROS 2 bag folder is never overwritten" in err
    assert [p.name for p in out.iterdir()] == ["keep.db3"] and (out / "keep.db3").read_bytes() == b"mine"


@pytest.mark.adversarial
def test_an_existing_dataset_is_not_a_protocol_output(tmp_path, capsys):
    data = tmp_path / "data.h5"
    data.write_bytes(b"dataset")
    code = main(["protocol", "--robot", "panda", "--out", str(data), "--force"])
    assert code == 2 and "unknown trajectory format '.h5'" in capsys.readouterr().err
    assert data.read_bytes() == b"dataset"
