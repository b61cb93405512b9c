"""A user with a URDF and no DH table: simulate, calibrate, evaluate and export through the CLI
with the robot's own link names, on a maker's URDF from a registry package."""

from __future__ import annotations

import json
import shutil

import pytest

from skincal.cli import main
from skincal.data.hdf5 import read_dataset

from registry_robots import registry_urdf


@pytest.mark.parametrize("robot", ["ur5", "xarm7"])
def test_urdf_robot_from_simulation_to_export(tmp_path, capsys, robot):
    urdf = tmp_path / f"{robot}.urdf"
    shutil.copy(registry_urdf(robot), urdf)
    ds, res = tmp_path / "ds.h5", tmp_path / "r.json"
    args = ["--placement", "random", "--units", "3", "--protocol", "fast", "--seed", "2"]
    assert main(["simulate", "--robot", str(urdf), *args, "-o", str(ds)]) == 0
    chain = read_dataset(ds).robot
    assert chain.convention == "urdf" and chain.source == urdf.read_text()
    assert main(["calibrate", str(ds), "-o", str(res)]) == 0
    doc = json.loads(res.read_text())
    for unit in doc["units"].values():
        assert unit["link_name"] == chain.link_names[unit["link"]]
    capsys.readouterr()
    assert main(["evaluate", str(res), "--truth", str(ds), "--json"]) == 0
    ev = json.loads(capsys.readouterr().out)
    assert ev["links_correct"] == 3 and ev["mean_position_error_mm"] <= 0.01  # noise-free: <= 0.01 mm
    out = tmp_path / "units.urdf"
    assert main(["export", str(res), "-f", "urdf", "-o", str(out), "--robot", str(urdf)]) == 0
    assert all(f'name="{unit}"' in out.read_text() for unit in doc["units"])
