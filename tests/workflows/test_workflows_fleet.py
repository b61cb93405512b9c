"""Calibrating a fleet: many datasets on the sweep runner, one result each, one failure never
stopping the others."""

from __future__ import annotations

import json

import numpy as np
import pytest

from skincal.calib import calibrate
from skincal.cli import main
from skincal.data.hdf5 import write_dataset
from skincal.data.result import read_result
from skincal.workflows.session import simulate_dataset


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    root = tmp_path_factory.mktemp("fleet")
    paths = []
    for k, robot in enumerate(("panda", "ur5e")):
        ds = simulate_dataset(robot, "random", 2, "none", "fast", seed=k)
        paths.append(root / f"{robot}.h5")
        write_dataset(ds, paths[-1])
    (root / "broken.h5").write_bytes(b"not an HDF5 file")
    return root, paths


def test_every_dataset_gets_its_result_and_a_broken_one_is_named(fleet, capsys):
    root, paths = fleet
    out = root / "results"
    out.mkdir()
    code = main(["calibrate", *map(str, paths), str(root / "broken.h5"), "-o", str(out), "--workers", "2"])
    err = capsys.readouterr().err
    assert code == 2 and "1 of 3 datasets could not be calibrated" in err
    assert sorted(p.name for p in out.iterdir()) == ["panda.json", "ur5e.json"]
    for path in paths:  # the same numbers as calibrating the dataset alone
        from skincal.data.hdf5 import read_dataset

        alone = calibrate(read_dataset(path), "mle", workers=1)
        res = read_result(out / f"{path.stem}.json")
        for name, unit in alone.units.items():
            np.testing.assert_allclose(res.units[name].pose.T_link_su, unit.pose.T_link_su, atol=1e-12)


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--unit", "su1"], "--unit selects units of one dataset"),
        (["--option", "scale=maybe"], "option scale expects true or false"),
        (["--method", "nope"], "unknown method 'nope'"),
    ],
)
def test_fleet_mistakes_are_refused_before_any_work(fleet, capsys, extra, message):
    root, paths = fleet
    out = root / "refused"
    out.mkdir(exist_ok=True)
    assert main(["calibrate", *map(str, paths), "-o", str(out), *extra]) == 2
    assert message in capsys.readouterr().err and not any(out.iterdir())


def test_two_datasets_with_one_name_or_a_file_as_folder_are_refused(fleet, tmp_path, capsys):
    root, paths = fleet
    twin = tmp_path / "panda.h5"
    twin.write_bytes(paths[0].read_bytes())
    assert main(["calibrate", str(paths[0]), str(twin), "-o", str(tmp_path)]) == 2
    assert "would both write" in capsys.readouterr().err
    assert main(["calibrate", str(paths[0]), str(paths[0]), "-o", str(tmp_path)]) == 2
    assert "is given twice" in capsys.readouterr().err
    assert main(["calibrate", *map(str, paths), "-o", str(tmp_path / "r.json")]) == 2
    assert "--out is a folder that exists" in capsys.readouterr().err


def test_a_method_option_reaches_the_method(fleet, tmp_path):
    _, paths = fleet
    assert main(["calibrate", str(paths[0]), "-o", str(tmp_path / "r.json"), "--option", "gyro=false"]) == 0
    doc = json.loads((tmp_path / "r.json").read_text())
    assert all("gyro_bias_rps" not in unit for unit in doc["units"].values())
