"""IMU-only unit-to-unit calibration (issue 18): poses in a reference unit's frame without joints."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skincal.calib import calibrate_relative, compare_with_joint_result
from skincal.calib.imu_only import coarse_offset
from skincal.cli import main
from skincal.data.hdf5 import write_dataset
from skincal.data.result import CalibrationResult, UnitResult, read_result, result_from_dict, result_to_dict
from skincal.errors import DatasetError
from skincal.sim.rigid_body import HandMotion, simulate_rigid_bodies
from skincal.skin.clock import get_clock_model
from skincal.skin.imu import get_imu_model
from skincal.skin.pose import SkinUnitPose

T_J = np.eye(4)
T_J[:3, :3] = Rotation.from_rotvec([0.3, -0.5, 2.0]).as_matrix()
T_J[:3, 3] = [0.2, 0.0, 0.0]


def _dataset(seed: int, preset: str = "datasheet", duration: float = 25.0, clock: str = "ideal", **motion):
    rng = np.random.default_rng(seed)
    motions = {"hand": HandMotion.random(rng, **motion), "other": HandMotion.random(rng)}
    units = {"su1": ("hand", np.eye(4)), "su2": ("hand", T_J), "su3": ("other", np.eye(4))}
    return simulate_rigid_bodies(
        units, motions, duration, get_imu_model(preset), rng, clock_model=get_clock_model(clock)
    )  # fmt: skip


def _errors(unit: UnitResult) -> tuple[float, float]:
    p_err = 1e3 * float(np.linalg.norm(unit.pose.p_link_su - T_J[:3, 3]))
    rot = Rotation.from_matrix(T_J[:3, :3].T @ unit.pose.R_link_su).magnitude()
    return p_err, float(np.degrees(rot))


@pytest.mark.parametrize("seed", [0, 1])
def test_recovers_the_pose_of_a_unit_on_the_same_body(seed):
    ds = _dataset(seed)
    result = calibrate_relative(ds, "su1", units=["su1", "su2"])
    assert result.extras["reference"] == "su1" and result.method == "imu-only"
    ref = result.units["su1"]
    assert ref.pose.link == 0 and np.array_equal(ref.pose.R_link_su, np.eye(3)) and not ref.pose.p_link_su.any()
    unit = result.units["su2"]
    p_err, r_err = _errors(unit)
    assert unit.observable and p_err < 1.0 and r_err < 0.1
    assert np.all(unit.position_std_m < 1e-3) and np.all(unit.position_std_m > 1e-6)


def test_unit_on_another_body_is_reported_not_forced():
    result = calibrate_relative(_dataset(0), "su1")
    assert "su3" not in result.units and set(result.units) == {"su1", "su2"}
    assert "another rigid body" in result.extras["failed_units"]["su3"]


def test_rotation_about_one_axis_names_the_unobservable_direction():
    axis = np.array([0.0, 0.0, 1.0])
    ds = _dataset(3, rotation_axes=axis)
    unit = calibrate_relative(ds, "su1", units=["su2"]).units["su2"]
    assert not unit.observable
    text = " ".join(unit.warnings)
    assert "one axis" in text and "undetermined" in text
    # the named axis is the body's rotation axis seen from su1 (identity on the body): z up to sign
    named = np.array([float(x) for x in text.split("[")[1].split("]")[0].split()])
    assert abs(abs(named @ axis) - 1.0) < 0.02
    assert np.isnan(unit.position_std_m[2]) and np.all(np.isfinite(unit.position_std_m[:2]))


def test_time_offset_between_units_is_found():
    ds = _dataset(2, preset="realistic", clock="wifi")
    truth = ds.truth_sensor["su2"]["time_offset_s"] - ds.truth_sensor["su1"]["time_offset_s"]
    unit = calibrate_relative(ds, "su1", units=["su2"]).units["su2"]
    assert abs(unit.extras["time_offset_to_reference_s"] - truth) < 2e-3
    assert abs(truth) > 5e-3  # the units' clocks do disagree


def test_coarse_offset_sign():
    t = np.arange(0, 20, 0.01)
    w = np.stack([np.sin(3 * t) * np.sin(0.7 * t), np.cos(2.1 * t), 0 * t], axis=1)
    # unit j's stamps run 0.13 s late: its sample stamped t + 0.13 saw the reference's instant t
    assert coarse_offset(t, w, t + 0.13, w, 1.0) == pytest.approx(0.13, abs=0.011)


def test_relative_result_round_trips_with_link_zero(tmp_path):
    result = calibrate_relative(_dataset(0, duration=10.0), "su1", units=["su1", "su2"])
    doc = result_to_dict(result)
    assert doc["reference"] == "su1" and doc["units"]["su2"]["link"] == 0
    back = result_from_dict(json.loads(json.dumps(doc)))
    np.testing.assert_allclose(back.units["su2"].pose.p_link_su, result.units["su2"].pose.p_link_su)
    del doc["reference"]
    with pytest.raises(DatasetError, match="link must be a positive integer"):
        result_from_dict(doc)


@pytest.mark.adversarial
def test_reference_must_be_a_listed_unit():
    doc = result_to_dict(calibrate_relative(_dataset(0, duration=5.0), "su1", units=["su1"]))
    doc["reference"] = "ghost"
    with pytest.raises(DatasetError, match="reference names unit 'ghost'"):
        result_from_dict(doc)


def test_comparison_with_a_joint_based_result():
    R_link_ref = Rotation.from_rotvec([0.1, 0.2, -0.3]).as_matrix()
    p_link_ref = np.array([0.05, 0.1, 0.0])
    T_link_j = np.eye(4)
    T_link_j[:3, :3], T_link_j[:3, 3] = R_link_ref @ T_J[:3, :3], R_link_ref @ T_J[:3, 3] + p_link_ref
    joint = CalibrationResult("mle", "panda", "", 0.0, {
        "su1": UnitResult(SkinUnitPose(3, R_link_ref, p_link_ref)),
        "su2": UnitResult(SkinUnitPose(3, T_link_j[:3, :3], T_link_j[:3, 3] + [0.002, 0, 0])),
        "su3": UnitResult(SkinUnitPose(4, np.eye(3), np.zeros(3))),
    })  # fmt: skip
    relative = CalibrationResult("imu-only", "panda", "", 0.0, {
        "su1": UnitResult(SkinUnitPose(0, np.eye(3), np.zeros(3))),
        "su2": UnitResult(SkinUnitPose(0, T_J[:3, :3], T_J[:3, 3])),
        "su3": UnitResult(SkinUnitPose(0, np.eye(3), np.zeros(3))),
    }, {"reference": "su1"})  # fmt: skip
    diff = compare_with_joint_result(relative, joint)
    assert set(diff) == {"su2"}  # su3 is on another link
    assert diff["su2"][0] == pytest.approx(2.0, abs=1e-9) and diff["su2"][1] == pytest.approx(0.0, abs=1e-6)


def test_cli_calibrate_with_reference(tmp_path, capsys):
    data = tmp_path / "hand.h5"
    write_dataset(_dataset(1, duration=15.0), data)
    before = data.read_bytes()
    out = tmp_path / "rel.json"
    assert main(["calibrate", str(data), "--reference", "su1", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "another rigid body" in printed and "su3" in printed
    result = read_result(out)
    assert result.extras["reference"] == "su1" and "su3" in result.extras["failed_units"]
    assert _errors(result.units["su2"])[0] < 2.0
    assert data.read_bytes() == before
    assert main(["calibrate", str(data), "--reference", "su1", "-o", str(out)]) == 2  # not clobbered
    assert main(["calibrate", str(data), "--reference", "nobody", "-o", str(tmp_path / "x.json")]) == 2
    assert "reference unit 'nobody' is not in the dataset" in capsys.readouterr().err


def test_real_preset_errors_are_covered_by_the_reported_std():
    """``real`` IMUs: the reference accelerometer's scale (3 %) is the positions' gauge; with its size
    given, the std covers the error, and the rotation meets the 0.1 deg target."""
    from skincal.workflows.handheld import handheld_dataset, relative_errors

    ds = handheld_dataset(units=3, duration_s=30.0, imu="real", clock="driver", seed=7)
    result = calibrate_relative(ds, "su1", reference_scale_std=0.03, reference_misalignment_std=0.01)
    errors = relative_errors(result, ds)
    assert set(errors) == {"su2", "su3"}
    for e in errors.values():
        assert np.all(np.abs(e["position_error_m"]) < 4 * e["position_std_m"])
        assert np.degrees(np.linalg.norm(e["rotation_error_rad"])) < 0.1
        assert np.all(np.abs(np.degrees(e["rotation_error_rad"])) < 4 * e["rotation_std_deg"])
    assert "scale of su1's accelerometer" in result.units["su2"].extras["notes"][0]


def test_handheld_session_with_a_second_body():
    from skincal.workflows.handheld import handheld_dataset

    ds = handheld_dataset(units=2, duration_s=10.0, imu="datasheet", clock="ideal", seed=1, other_body=1)
    assert ds.truth_body["su3"].body == "other" and ds.truth_body["su2"].body == "hand"
    result = calibrate_relative(ds, "su2")
    assert set(result.units) == {"su1", "su2"} and "another rigid body" in result.extras["failed_units"]["su3"]


@pytest.mark.slow
def test_benchmark_targets_over_20_runs():
    """The issue's figures (simulated): 60 s, two units 0.2 m apart, ``real`` preset, 20 runs. The
    rotation and the std calibration meet their targets; the position error is the reference
    accelerometer's scale (median ~4 mm, see README), so only its calibration is asserted."""
    from skincal.workflows.handheld import bench_relative

    doc = bench_relative(runs=20)
    assert doc["rotation_error_deg_max"] <= 0.1
    assert 0.5 <= doc["position_error_over_std_rms"] <= 2.0 and 0.5 <= doc["rotation_error_over_std_rms"] <= 2.0
    assert doc["position_error_mm_max"] < 0.06 * 200  # 3 % scale std of the reference, 2 sigma
    calibrated = bench_relative(runs=20, scale_free=True)  # the reference accelerometer's scale known
    assert calibrated["position_error_mm_max"] <= 1.0 and calibrated["rotation_error_deg_max"] <= 0.1
    assert 0.5 <= calibrated["position_error_over_std_rms"] <= 2.0


def test_cli_simulate_handheld_then_calibrate_with_options(tmp_path, capsys):
    data = tmp_path / "hand.h5"
    args = ["simulate", "--handheld", "--units", "2", "--spacing", "0.15", "--duration", "12", "--noise", "real"]
    assert main([*args, "--other-body", "1", "-o", str(data)]) == 0
    assert "no joints" in capsys.readouterr().out
    out = tmp_path / "rel.json"
    opts = ["--option", "reference_scale_std=0.03", "--option", "reference_misalignment_std=0.01"]
    assert main(["calibrate", str(data), "--reference", "su2", "-o", str(out), *opts]) == 0
    result = read_result(out)
    assert set(result.units) == {"su1", "su2"}
    p, std = result.units["su1"].pose.p_link_su, result.units["su1"].position_std_m
    assert np.linalg.norm(p) == pytest.approx(0.15, abs=8e-3)  # su1 seen from su2: 0.15 m away, any direction
    assert np.linalg.norm(std) > 0.15 * 0.01  # the reference's scale and misalignment std are in it


@pytest.mark.adversarial
@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--option", "scale=false"], "--option scale: not an option of --reference"),
        (["--option", "reference_scale_std=big"], "expected a number"),
        (["--option", "reference_scale_std=nan"], "non-negative number"),
        (["--compare-with", "{tmp}/missing.json"], "missing.json"),
    ],
)
def test_cli_reference_refuses_bad_options(tmp_path, capsys, extra, message):
    data = tmp_path / "hand.h5"
    write_dataset(_dataset(0, duration=5.0), data)
    extra = [x.replace("{tmp}", str(tmp_path)) for x in extra]
    assert main(["calibrate", str(data), "--reference", "su1", "-o", str(tmp_path / "r.json"), *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "r.json").exists()


def test_cross_check_with_mle_on_a_robot(tmp_path, capsys):
    """Units of one Panda link: the IMU-only poses (joints ignored) agree with mle's and with the truth."""
    from skincal.kinematics import get_robot
    from skincal.workflows.session import simulate_dataset

    ds = simulate_dataset(get_robot("panda"), "random", 14, "realistic", "fast", 1, "analytic")
    units = [u for u, pose in ds.truth.items() if pose.link == 3]
    assert len(units) == 3
    data, mle, rel = tmp_path / "panda.h5", tmp_path / "mle.json", tmp_path / "rel.json"
    write_dataset(ds, data)
    unit_args = [x for u in units for x in ("--unit", u)]
    assert main(["calibrate", str(data), "-o", str(mle), "--use-truth-links", *unit_args]) == 0
    capsys.readouterr()
    args = ["calibrate", str(data), "--reference", units[0], "-o", str(rel), "--compare-with", str(mle), *unit_args]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert printed.count("IMU-only vs mle differ by") == 2
    diff = compare_with_joint_result(read_result(rel), read_result(mle))
    assert set(diff) == set(units[1:]) and all(mm < 2.0 and deg < 0.1 for mm, deg in diff.values())
    ref = ds.truth[units[0]]
    for u in units[1:]:
        p_true = ref.R_link_su.T @ (ds.truth[u].p_link_su - ref.p_link_su)
        assert np.linalg.norm(read_result(rel).units[u].pose.p_link_su - p_true) < 2e-3


def test_cli_evaluate_a_relative_result(tmp_path, capsys):
    data, out = tmp_path / "hand.h5", tmp_path / "rel.json"
    write_dataset(_dataset(1, duration=15.0), data)
    assert main(["calibrate", str(data), "--reference", "su1", "-o", str(out)]) == 0
    capsys.readouterr()
    assert main(["evaluate", str(out), "--truth", str(data), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["reference"] == "su1" and doc["units"]["su1"]["position_error_mm"] == 0.0
    assert doc["units"]["su2"]["same_body"] and doc["units"]["su2"]["position_error_mm"] < 1.0
    assert doc["mean_position_error_mm"] == doc["units"]["su2"]["position_error_mm"]
    assert "su3" not in doc["units"]  # not calibrated: on the other body


@pytest.mark.parametrize("seed", [0, 1])
def test_real_imus_with_a_calibrated_reference_meet_the_targets(seed):
    """``real`` IMUs and clocks, 25 s, the accelerometers' scale known: <= 1 mm and <= 0.1 deg."""
    from skincal.workflows.handheld import handheld_dataset, relative_errors

    ds = handheld_dataset(units=2, duration_s=25.0, imu="real", clock="driver", seed=seed, scale_free=True)
    errors = relative_errors(calibrate_relative(ds, "su1"), ds)["su2"]
    assert np.linalg.norm(errors["position_error_m"]) <= 1e-3
    assert np.degrees(np.linalg.norm(errors["rotation_error_rad"])) <= 0.1
