"""``skincal benchmark robustness``: the quick command end to end, the silent-error rule, pairing of cells."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from skincal.bench import robustness as rb
from skincal.cli import app, main
from skincal.data.result import UnitResult
from skincal.skin.pose import SkinUnitPose
from skincal.workflows.sweep import map_local

CELL_FIELDS = {
    "robot", "backend", "fault", "seeds", "mean_position_error_mm", "max_position_error_mm",
    "mean_rotation_error_deg", "max_rotation_error_deg", "links_correct", "units_total", "units_calibrated",
    "z_rms", "warned", "beyond_3sigma", "silent", "silent_units", "targets", "failed_targets", "pass",
}


def test_quick_cli_writes_every_cell(tmp_path):
    out = tmp_path / "rob.json"
    args = ["benchmark", "robustness", "--quick", "--robots", "panda", "--backends", "analytic",
            "--faults", "qd-3e-3,knock", "--out", str(out)]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output
    assert "robustness" in res.output and "knock" in res.output and "wrote" in res.output
    doc = json.loads(out.read_text())
    assert doc["config"]["protocol"] == "fast" and doc["config"]["seeds"] == 1
    assert "silent_error" in doc["config"] and doc["wall_time_s"] > 0
    assert [c["fault"] for c in doc["cells"]] == ["qd-3e-3", "knock"]
    for cell in doc["cells"]:
        assert CELL_FIELDS <= set(cell)
        assert cell["units_total"] == 6 and cell["links_correct"] == 6
    base, knock = doc["cells"]
    assert base["mean_position_error_mm"] < 0.3 and base["targets"]["mean_position_error_mm"] == 0.3
    assert knock["targets"]["mean_position_error_mm"] is None
    assert len(doc["records"]) == 2
    rec = next(r for r in doc["records"] if r["fault"] == "knock")
    hit = rec["units"][rec["affected"]["knocked_unit"]]
    # knocked 3 cm / 10 deg at 2/3 of the session: found, named, and calibrated from the part before it
    assert any("moved on its link" in w for w in hit["warnings"]) and hit["position_error_mm"] < 1.0
    # an existing file is kept unless --force
    before = out.read_text()
    assert main(args) == 2 and out.read_text() == before
    assert main([*args[:-4], "--faults", "gravity", "--out", str(out), "--force"]) == 0
    assert [c["fault"] for c in json.loads(out.read_text())["cells"]] == ["gravity"]


def test_unknown_fault_is_one_line_error(capsys):
    assert main(["benchmark", "robustness", "--quick", "--faults", "knock,nope"]) == 2
    err = capsys.readouterr().err.strip()
    assert "unknown fault(s) nope" in err and "\n" not in err


def _unit(p, std, warnings=(), link=3):
    return UnitResult(SkinUnitPose(link, np.eye(3), p), position_std_m=std, warnings=warnings)


def test_silent_rule():
    truth = SkinUnitPose(3, np.eye(3), [0.1, 0.0, 0.05])
    ev = {"position_error_mm": 0.0, "rotation_error_deg": 0.0}
    std = np.array([1e-4, 1e-4, 1e-4])
    judge = lambda unit: rb.judge_unit(unit, truth, ev)  # noqa: E731
    assert not judge(_unit([0.1 + 2.9e-4, 0.0, 0.05], std))["silent"]  # 2.9 sigma on one axis
    ok = judge(_unit([0.1 + 3.1e-4, 0.0, 0.05], std))
    assert ok["silent"] and ok["z"][0] == pytest.approx(3.1)  # 3.1 sigma on x
    # the normalised norm: sum z^2 > chi2_3(0.9973) = 14.16 with every axis under 3 sigma
    assert rb.silent_chi2(3) == pytest.approx(14.16, abs=0.01)
    assert judge(_unit([0.1 + 2.5e-4, 2.5e-4, 0.05 + 2.5e-4], std))["silent"]  # sum z^2 = 18.75
    assert not judge(_unit([0.1 + 2.0e-4, 2.0e-4, 0.05 + 2.0e-4], std))["silent"]  # 12
    assert judge(_unit([0.1 + 3.05e-4, 0.0, 0.05], np.array([1e-4, 1e-4, np.nan])))["silent"]
    assert not judge(_unit([0.1 + 3.1e-4, 0.0, 0.05], std, warnings=("poor fit",)))["silent"]  # warned: loud
    assert judge(_unit([0.1, 0.0, 0.05], std, link=4))["silent"]  # wrong link, no warning
    assert judge(_unit([0.1 + 1e-6, 0.0, 0.05], None))["silent"]  # no std claims none
    nan_axis = judge(_unit([0.1, 0.5, 0.05], np.array([1e-4, np.nan, 1e-4])))
    assert not nan_axis["silent"] and nan_axis["z"][1] is None  # an undetermined axis is not judged


def test_cells_share_placements_and_choices():
    base, _ = rb.build_dataset(rb.Job("ur5e", "analytic", "qd-3e-3", 4, "fast"))
    grav, picked = rb.build_dataset(rb.Job("ur5e", "analytic", "gravity", 4, "fast"))
    knock, picked_k = rb.build_dataset(rb.Job("ur5e", "analytic", "knock", 4, "fast"))
    assert picked == picked_k and picked.stuck_unit != picked.knocked_unit
    for name in base.units:
        np.testing.assert_array_equal(base.truth[name].T_link_su, grav.truth[name].T_link_su)
        np.testing.assert_array_equal(base.truth[name].T_link_su, knock.truth[name].T_link_su)
        np.testing.assert_array_equal(base.imu[name].t, grav.imu[name].t)
    assert np.linalg.norm(grav.gravity) == pytest.approx(9.81)
    assert np.linalg.norm(grav.truth_sensor["su1"]["gravity_true_mps2"]) == pytest.approx(9.796)
    np.testing.assert_array_equal(base.imu[picked.stuck_unit].accel, knock.imu[picked.stuck_unit].accel)
    assert not np.array_equal(base.imu[picked.knocked_unit].accel, knock.imu[picked.knocked_unit].accel)


def test_jobs_and_local_runner_order():
    config = rb.RobustnessConfig.quick(robots=("panda",), faults=("qd-3e-3", "knock"))
    todo = rb.jobs(config)
    assert len(todo) == 4 and todo[0].backend == "mujoco" and todo[0].fault == "knock"
    seen = []
    assert map_local(abs, [-3, 1, -2], workers=2, progress=seen.append) == [3, 1, 2]
    assert sorted(seen) == [1, 2, 3]


def test_dask_cluster_on_loopback_repeats_local_run(tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    job = rb.Job("sawyer", "analytic", "clock-offset", 0, "fast")
    local = rb.run_job(job)
    out = tmp_path / "dask.json"
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=1, processes=False, protocol="tcp", host="127.0.0.1", dashboard_address=None
    ) as cluster:
        assert main(["benchmark", "robustness", "--quick", "--robots", "sawyer", "--backends", "analytic",
                     "--faults", "clock-offset", "--dask", cluster.scheduler_address, "--out", str(out)]) == 0
    (rec,) = json.loads(out.read_text())["records"]
    for name, unit in local["units"].items():
        assert rec["units"][name]["position_error_mm"] == pytest.approx(unit["position_error_mm"])
