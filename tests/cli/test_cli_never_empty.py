"""``skincal calibrate`` never ends without an answer (issue 24): when every unit fails the result is
still written, each unit with its reason and ``observable: false``, and the exit code is 1 (2 stays
for usage and data errors, where nothing is written)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from skincal.cli import main
from skincal.cli.calibrate import NO_UNIT_EXIT
from skincal.data.dataset import STATIC, ImuStream
from skincal.data.hdf5 import write_dataset
from skincal.data.result import read_result
from skincal.sim import simulate
from skincal.workflows.session import make_session


@pytest.fixture(scope="module")
def static_only(tmp_path_factory):
    """A simulated Panda session whose IMUs recorded only in the rests (no gyroscope)."""
    ds = simulate(make_session("panda", "random", 2, "realistic", "fast", 5, links=[3, 5]))
    seg = ds.segments
    rests = [(a, b) for a, b, k in zip(seg.t_start, seg.t_end, seg.kind, strict=True) if k == STATIC]
    imu = {}
    for u, s in ds.imu.items():
        keep = np.any([(s.t >= a) & (s.t <= b) for a, b in rests], axis=0)
        imu[u] = ImuStream(s.t[keep], s.accel[keep], None)
    path = tmp_path_factory.mktemp("static") / "static.h5"
    write_dataset(replace(ds, imu=imu), path)
    return path


def test_every_unit_failed_still_writes_the_result(static_only, tmp_path, capsys):
    out = tmp_path / "om.json"
    code = main(["calibrate", str(static_only), "--out", str(out), "--method", "om"])
    captured = capsys.readouterr()
    assert code == NO_UNIT_EXIT == 1
    doc = json.loads(out.read_text())
    assert set(doc["units"]) == {"su1", "su2"}
    for entry in doc["units"].values():
        assert entry["observable"] is False and entry["position_m"] is None and entry["quaternion_wxyz"] is None
        assert entry["warnings"] and "never excited" in entry["warnings"][0]
    assert set(doc["failed_units"]) == {"su1", "su2"}
    assert "not calibrated" in captured.out and "no unit could be calibrated" in captured.err
    back = read_result(out)
    assert back.units == {} and set(back.failed_units) == {"su1", "su2"}


def test_static_only_writes_rotations_with_null_positions(static_only, tmp_path, capsys):
    out = tmp_path / "mle.json"
    assert main(["calibrate", str(static_only), "--out", str(out)]) == 0
    assert capsys.readouterr().out.count("- (not determined)") == 2  # the table shows no made-up position
    doc = json.loads(out.read_text())
    for name, entry in doc["units"].items():
        assert entry["position_m"] is None and entry["observable"] is False, name
        assert entry["link"] in (3, 5) and len(entry["quaternion_wxyz"]) == 4
        assert any("static poses only" in w for w in entry["warnings"])


def test_a_fleet_whose_results_have_no_unit_exits_1(static_only, tmp_path):
    other = tmp_path / "copy.h5"
    other.write_bytes(static_only.read_bytes())
    folder = tmp_path / "out"
    folder.mkdir()
    assert main(["calibrate", str(static_only), str(other), "--out", str(folder), "--method", "om"]) == NO_UNIT_EXIT
    assert sorted(p.name for p in folder.iterdir()) == ["copy.json", "static.json"]
