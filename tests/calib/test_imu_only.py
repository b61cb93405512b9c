"""IMU-only unit-to-unit calibration (issue 18): poses in a reference unit's frame without joints."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skincal.calib import calibrate_relative, compare_with_joint_result
from skincal.calib.imu_only import coarse_offset, common_rests, fit_accel_ellipsoid
from skincal.calib.model import sym_from_e
from skincal.calib.rest import imu_still_mask as still_mask
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
    assert result.reference == "su1" and result.method == "imu-only"
    ref = result.units["su1"]
    assert ref.pose.link == 0 and np.array_equal(ref.pose.R_link_su, np.eye(3)) and not ref.pose.p_link_su.any()
    unit = result.units["su2"]
    p_err, r_err = _errors(unit)
    assert unit.observable and p_err < 1.0 and r_err < 0.1
    assert np.all(unit.position_std_m < 1e-3) and np.all(unit.position_std_m > 1e-6)


def test_unit_on_another_body_is_reported_not_forced():
    result = calibrate_relative(_dataset(0), "su1")
    assert "su3" not in result.units and set(result.units) == {"su1", "su2"}
    assert "another rigid body" in result.failed_units["su3"]


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
    }, reference="su1")  # fmt: skip
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
    assert result.reference == "su1" and "su3" in result.failed_units
    assert _errors(result.units["su2"])[0] < 2.0
    assert data.read_bytes() == before
    assert main(["calibrate", str(data), "--reference", "su1", "-o", str(out)]) == 2  # not clobbered
    assert main(["calibrate", str(data), "--reference", "nobody", "-o", str(tmp_path / "x.json")]) == 2
    assert "reference unit 'nobody' is not in the dataset" in capsys.readouterr().err


def test_real_preset_without_rests_keeps_the_reference_gauge():
    """``real`` IMUs, a motion without holds: no rests, so the reference accelerometer's scale (3 %) is
    the positions' gauge; with its size given, the std covers the error, a note says what is missing,
    and the rotation meets the 0.1 deg target."""
    from skincal.workflows.handheld import handheld_dataset, relative_errors

    ds = handheld_dataset(units=3, duration_s=30.0, imu="real", clock="driver", seed=7, holds=0)
    result = calibrate_relative(ds, "su1", reference_scale_std=0.03, reference_misalignment_std=0.01)
    errors = relative_errors(result, ds)
    assert set(errors) == {"su2", "su3"}
    for e in errors.values():
        assert np.all(np.abs(e["position_error_m"]) < 4 * e["position_std_m"])
        assert np.linalg.norm(e["position_std_m"]) > 0.01 * np.linalg.norm(ds.truth_body["su2"].T_body_su[:3, 3])
        assert np.degrees(np.linalg.norm(e["rotation_error_rad"])) < 0.1
        assert np.all(np.abs(np.degrees(e["rotation_error_rad"])) < 4 * e["rotation_std_deg"])
    notes = result.units["su2"].notes
    assert "scale of su1's accelerometer" in notes[0]
    assert "0 rest(s)" in notes[1] and "in 12 more" in notes[1]
    assert result.extras["accel_scale_fit"]["model"] == "none" and result.units["su2"].imu is None


def test_too_few_orientations_say_how_many_more():
    """Four holds: the rests are found, but four orientations cannot fit a scale (6 unknowns at least):
    positions stay in the reference's scale (its std in the position std) and the note asks for 8 more."""
    from skincal.workflows.handheld import handheld_dataset

    ds = handheld_dataset(units=2, duration_s=30.0, imu="real", clock="driver", seed=2, holds=4)
    free = calibrate_relative(ds, "su1", units=["su2"])
    result = calibrate_relative(ds, "su1", units=["su2"], reference_scale_std=0.03)
    fit = result.extras["accel_scale_fit"]
    assert fit["model"] == "none" and fit["rests"] == 4 and fit["orientations"] == 4
    assert "4 rest(s) in 4 distinct orientation(s)" in fit["note"] and "in 8 more" in fit["note"]
    assert result.units["su2"].notes[1] == fit["note"]
    r = np.linalg.norm(result.units["su2"].pose.p_link_su)
    assert (
        np.linalg.norm(result.units["su2"].position_std_m)
        > 0.03 * r
        > 5 * np.linalg.norm(free.units["su2"].position_std_m)
    )


@pytest.mark.parametrize("seed", [0, 1])
def test_real_imus_with_rests_meet_the_targets(seed):
    """``real`` IMUs and clocks on a 30 s "turn it over" motion (11 holds of 1.5 s): the reference's
    accelerometer scale is fitted from the rests, so positions come out in metres: <= 1 mm, <= 0.1 deg,
    errors within the reported std, which carries the fitted scale's std."""
    from skincal.workflows.handheld import handheld_dataset, relative_errors

    ds = handheld_dataset(units=2, duration_s=30.0, imu="real", clock="driver", seed=seed)
    result = calibrate_relative(ds, "su1", reference_scale_std=0.03, reference_misalignment_std=0.01)
    errors = relative_errors(result, ds)["su2"]
    assert np.linalg.norm(errors["position_error_m"]) <= 1e-3
    assert np.degrees(np.linalg.norm(errors["rotation_error_rad"])) <= 0.1
    assert np.all(np.abs(errors["position_error_m"]) < 4 * errors["position_std_m"])
    assert np.all(errors["position_std_m"] < 1e-3)  # the 3 % given for the reference is not used
    fit = result.extras["accel_scale_fit"]
    assert fit["model"] == "symmetric" and fit["rests"] == fit["orientations"] == 11
    assert "position in metres" in result.units["su2"].notes[0]
    # each unit's accelerometer, fitted to the rests, against the truth
    for name in ("su1", "su2"):
        truth, imu = ds.truth_sensor[name], result.units[name].imu
        assert imu is not None and imu.accel_scale_misalignment is not None and imu.accel_bias_mps2 is not None
        A = np.diag(truth["accel_scale"]) @ truth["accel_misalignment"]
        assert np.max(np.abs(imu.accel_scale_misalignment - A)) < 0.004  # the scale errors are ~0.03
        assert np.all(np.abs(imu.accel_bias_mps2 - truth["accel_bias"]) < 4 * imu.accel_bias_std_mps2 + 1e-3)


def _sphere(n: int) -> np.ndarray:
    k = np.arange(n) + 0.5
    z = 1 - 2 * k / n
    phi = np.pi * (1 + np.sqrt(5)) * k
    return np.stack([np.sqrt(1 - z**2) * np.cos(phi), np.sqrt(1 - z**2) * np.sin(phi), z], axis=1)


def test_ellipsoid_fit_recovers_a_known_accelerometer():
    """Exact rest means ``a = A u g + b`` in 12 directions: the fit gives ``b`` and ``C = (A A^T)^(-1/2)``
    (``C A`` a rotation: the part an ellipsoid cannot see); the diagonal model recovers a diagonal ``A``;
    with noise the errors are within the reported std."""
    g = 9.81
    A = np.diag([1.03, 0.97, 1.01]) @ (np.eye(3) + np.array([[0, 0.01, -0.02], [0.01, 0, 0.005], [-0.02, 0.005, 0]]))
    b = np.array([0.3, -0.2, 0.1])
    means = g * _sphere(12) @ A.T + b
    counts, noise = np.full(12, 100.0), np.full(3, 0.01)
    fit = fit_accel_ellipsoid(means, counts, noise, g)
    assert fit is not None and fit.model == "symmetric" and fit.orientations == 12
    np.testing.assert_allclose(fit.b, b, atol=1e-9)
    w, V = np.linalg.eigh(A @ A.T)
    np.testing.assert_allclose(fit.C, (V / np.sqrt(w)) @ V.T, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(fit.apply(means), axis=1), g, atol=1e-9)
    Q = fit.C @ A
    np.testing.assert_allclose(Q @ Q.T, np.eye(3), atol=1e-9)
    D = np.diag([1.03, 0.97, 1.01])
    diag = fit_accel_ellipsoid(g * _sphere(7) @ D + b, np.full(7, 100.0), noise, g, "diagonal")
    assert diag is not None and diag.model == "diagonal"
    np.testing.assert_allclose(diag.C, np.linalg.inv(D), atol=1e-9)
    assert np.all(diag.cov[3:6] == 0)  # cross-axis terms not fitted
    rng = np.random.default_rng(3)
    z = []
    for _ in range(40):
        noisy = means + rng.normal(0, np.sqrt(0.01 / 100), means.shape)
        f = fit_accel_ellipsoid(noisy, counts, noise, g)
        assert f is not None
        p = np.concatenate([np.diag(f.C), [f.C[0, 1], f.C[0, 2], f.C[1, 2]], f.b])
        p0 = np.concatenate([np.diag(fit.C), [fit.C[0, 1], fit.C[0, 2], fit.C[1, 2]], b])
        z.append((p - p0) / np.sqrt(np.diag(f.cov)))
    assert 0.6 < np.sqrt(np.mean(np.square(z))) < 1.6
    assert fit_accel_ellipsoid(means[:8], counts[:8], noise, g) is None  # 8 equations, 9 unknowns


def test_rests_are_found_from_the_gyroscopes():
    """The holds of the motion are found (all units agreeing), inside the true holds; a unit on another
    body that never rests does not veto them."""
    from skincal.workflows.handheld import handheld_dataset

    ds = handheld_dataset(units=2, duration_s=30.0, imu="real", clock="driver", seed=4, other_body=1)
    rests = common_rests(ds.imu, "su1")
    assert len(rests) == 11
    # the hold times of the preset: 11 holds of 1.5 s evenly spaced (stamps run ~15 ms late)
    move = (30.0 - 11 * 1.5) / 12
    starts = move + np.arange(11) * (1.5 + move)
    assert np.all(rests[:, 0] > starts - 0.05) and np.all(rests[:, 1] < starts + 1.55)
    assert np.all(rests[:, 1] - rests[:, 0] > 1.0)
    stream = ds.imu["su1"]
    assert stream.gyro is not None
    assert not still_mask(stream.t, stream.gyro, stream.accel)[(stream.t > 0.2) & (stream.t < move - 0.4)].any()


def test_position_std_carries_the_fitted_scale():
    """``dr/dp`` of the position with respect to the reference accelerometer's calibration (what the
    std propagates) against re-fits with a perturbed calibration."""
    from dataclasses import replace as dc_replace

    from skincal.calib.imu_only import AccelFit, fit_relative, fit_unit_accelerometer
    from skincal.workflows.handheld import handheld_dataset

    ds = handheld_dataset(units=2, duration_s=20.0, imu="real", clock="driver", seed=5)
    ref, unit = ds.imu["su1"], ds.imu["su2"]
    acc, _ = fit_unit_accelerometer(ref, common_rests(ds.imu, "su1"), 9.81)
    assert acc is not None
    base = fit_relative(dc_replace(ref, accel=acc.apply(ref.accel)), unit, ref_jacobian=acc.jacobian(ref.accel))
    assert not isinstance(base, str) and base.gauge_jacobian is not None
    p = np.concatenate([np.diag(acc.C), [acc.C[0, 1], acc.C[0, 2], acc.C[1, 2]], acc.b])
    for k in (0, 4, 7):
        h = 1e-4
        step = np.zeros(9)
        step[k] = h
        q = p + step
        moved = AccelFit(sym_from_e(q[:6]), q[6:], acc.cov, acc.model, acc.rests, acc.orientations, 0.0)
        other = fit_relative(dc_replace(ref, accel=moved.apply(ref.accel)), unit)
        assert not isinstance(other, str)
        numeric, linear = (other.r - base.r) / h, base.gauge_jacobian[:, k]
        assert np.linalg.norm(numeric - linear) <= 0.05 * np.linalg.norm(linear) + 1e-4  # Huber weights move too
    # a common scale of the reference's accelerometer scales r (the sum of the diagonal entries' columns)
    np.testing.assert_allclose(base.gauge_jacobian[:, :3].sum(axis=1), base.r, atol=0.01)
    assert np.all(np.abs(base.gauge_jacobian[:, 6:]) < 1e-6)  # a bias goes into the offset d


def test_handheld_session_with_a_second_body():
    from skincal.workflows.handheld import handheld_dataset

    ds = handheld_dataset(units=2, duration_s=10.0, imu="datasheet", clock="ideal", seed=1, other_body=1)
    assert ds.truth_body["su3"].body == "other" and ds.truth_body["su2"].body == "hand"
    result = calibrate_relative(ds, "su2")
    assert set(result.units) == {"su1", "su2"} and "another rigid body" in result.failed_units["su3"]


@pytest.mark.slow
def test_benchmark_targets_over_20_runs():
    """The issue's figures (simulated): 60 s "turn it over" motion with 12 holds, two units 0.2 m apart,
    ``real`` preset, 20 runs: 1 mm, 0.1 deg and the std's calibration; without holds the position error
    is the reference accelerometer's scale (median ~4 mm, see README), so only its calibration is asserted."""
    from skincal.bench.handheld import bench_relative

    doc = bench_relative(runs=20)
    assert doc["position_error_mm_max"] <= 1.0 and doc["rotation_error_deg_max"] <= 0.1
    assert 0.5 <= doc["position_error_over_std_rms"] <= 2.0 and 0.5 <= doc["rotation_error_over_std_rms"] <= 2.0
    no_rests = bench_relative(runs=20, holds=0)
    assert no_rests["position_error_mm_max"] < 0.06 * 200  # 3 % scale std of the reference, 2 sigma
    assert 0.5 <= no_rests["position_error_over_std_rms"] <= 2.0
    calibrated = bench_relative(runs=20, scale_free=True, holds=0)  # the reference accelerometer's scale known
    assert calibrated["position_error_mm_max"] <= 1.0 and calibrated["rotation_error_deg_max"] <= 0.1
    assert 0.5 <= calibrated["position_error_over_std_rms"] <= 2.0


def test_cli_simulate_handheld_then_calibrate_with_options(tmp_path, capsys):
    data = tmp_path / "hand.h5"
    args = ["simulate", "--handheld", "--units", "2", "--spacing", "0.15", "--duration", "12", "--noise", "real"]
    assert main([*args, "--other-body", "1", "-o", str(data)]) == 0
    assert "no joints" in " ".join(capsys.readouterr().out.split())  # (rich may wrap a long path)
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
        (["--option", "scale=false"], "unknown option(s) scale for method 'imu-only'"),
        (["--option", "reference_scale_std=big"], "option reference_scale_std expects a number"),
        (["--option", "reference_scale_std=nan"], "option reference_scale_std must be finite"),
        (["--option", "reference_scale_std=-1"], "option reference_scale_std must be in"),
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

    ds = handheld_dataset(units=2, duration_s=25.0, imu="real", clock="driver", seed=seed, scale_free=True, holds=0)
    errors = relative_errors(calibrate_relative(ds, "su1"), ds)["su2"]
    assert np.linalg.norm(errors["position_error_m"]) <= 1e-3
    assert np.degrees(np.linalg.norm(errors["rotation_error_rad"])) <= 0.1


def test_cli_handheld_with_holds_prints_the_scale_fit_and_round_trips(tmp_path, capsys):
    """``simulate --handheld`` (30 s: 11 holds) then ``calibrate --reference``: the note on the positions'
    scale is printed, and the fitted accelerometers and ``accel_scale_fit`` survive the result file."""
    data, out = tmp_path / "hand.h5", tmp_path / "rel.json"
    args = ["simulate", "--handheld", "--units", "2", "--duration", "30", "--noise", "real", "-o", str(data)]
    assert main(args) == 0
    capsys.readouterr()
    assert main(["calibrate", str(data), "--reference", "su1", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "note: accelerometer scale fitted from 11 rest(s) in 11 distinct orientation(s)" in printed
    result = read_result(out)
    assert result.extras["accel_scale_fit"]["model"] == "symmetric" and result.extras["accel_scale_fit"]["rests"] == 11
    for name in ("su1", "su2"):
        imu = result.units[name].imu
        assert imu is not None and imu.accel_scale_misalignment is not None
        assert np.all(np.abs(np.diag(imu.accel_scale_misalignment) - 1) < 0.15)
    assert np.linalg.norm(result.units["su2"].pose.p_link_su) == pytest.approx(0.2, abs=1e-3)


@pytest.mark.adversarial
def test_a_body_that_never_moves_is_named_not_called_another_body():
    from dataclasses import replace as dc_replace

    rng = np.random.default_rng(0)
    motion = HandMotion.random(rng)
    motion = dc_replace(motion, amp_rot=0 * motion.amp_rot, amp_pos=0 * motion.amp_pos)
    ds = simulate_rigid_bodies({"su1": ("hand", np.eye(4)), "su2": ("hand", T_J)}, {"hand": motion}, 10.0,
                               get_imu_model("real"), rng)  # fmt: skip
    result = calibrate_relative(ds, "su1")
    assert "did not turn" in result.failed_units["su2"]
    fit = result.extras["accel_scale_fit"]
    assert fit["rests"] == 1 and fit["orientations"] == 1 and "in 11 more" in fit["note"]


@pytest.mark.adversarial
def test_a_rest_counts_only_where_every_unit_on_the_body_is_still():
    """A knock on su2 in the middle of a hold (its data only): that part is no rest of the body."""
    from dataclasses import replace as dc_replace

    from skincal.workflows.handheld import handheld_dataset

    ds = handheld_dataset(units=2, duration_s=30.0, imu="real", clock="driver", seed=4)
    clean = common_rests(ds.imu, "su1")
    t0 = float(clean[5].mean())
    su2 = ds.imu["su2"]
    assert su2.gyro is not None
    knock = np.exp(-(((su2.t - t0) / 0.05) ** 2))[:, None] * np.array([0.5, -0.3, 0.2])
    knocked = dict(ds.imu, su2=dc_replace(su2, accel=su2.accel + 20 * knock, gyro=su2.gyro + 2 * knock))
    rests = common_rests(knocked, "su1")
    assert not np.any((rests[:, 0] < t0) & (rests[:, 1] > t0))
    assert len(rests) >= len(clean) - 1 and len(clean) == 11


def _knocked(ds, unit: str, angle_deg: float):
    """``ds`` with ``unit`` turned by ``angle_deg`` about its z axis from the recording's middle on (a unit
    that slipped: the rigid-body model does not carry it)."""
    from dataclasses import replace

    s = ds.imu[unit]
    late = s.t >= 0.5 * (s.t[0] + s.t[-1])
    R = Rotation.from_rotvec([0.0, 0.0, np.radians(angle_deg)]).as_matrix()
    accel, gyro = s.accel.copy(), s.gyro.copy()
    accel[late], gyro[late] = accel[late] @ R.T, gyro[late] @ R.T
    return replace(ds, imu={**ds.imu, unit: replace(s, accel=accel, gyro=gyro)})


@pytest.mark.parametrize("seed", [0, 1])
def test_split_check_leaves_honest_std_alone_and_catches_a_slipped_unit(seed):
    """The IMU-only fit's split check (issue 24: "the same for --reference"): on a clean simulated
    "turn it over" session with ``real`` IMUs the halves, alternate windows and calm/lively parts agree
    within their std (the parts share the whole recording's accelerometer gauge: without it the lively
    half, holding no rest, disagreed by 8 std in position); with the unit turned by 2 deg halfway, which
    the model does not carry, the time split disagrees by tens of std and the rotation std is inflated
    with a warning."""
    from skincal.workflows.handheld import handheld_dataset

    ds = handheld_dataset(units=2, duration_s=30.0, imu="real", clock="driver", seed=seed)
    clean = calibrate_relative(ds, "su1").units["su2"]
    c = clean.extras["consistency"]
    assert c["failed"] == [] and c["dof_position"] == c["dof_rotation"] == 9
    assert c["inflation_position"] == 1.0 and c["chi2_position"] < 2.5 * 9
    assert c["inflation_rotation"] < 1.7  # seed 1: 1.60 ('real' gyroscopes' scale errors are not in the model)
    off = calibrate_relative(_knocked(ds, "su2", 2.0), "su1").units["su2"]
    k = off.extras["consistency"]
    assert k["inflation_rotation"] > 10.0 and any(d.startswith("time: rotation") for d in k["disagrees"])
    assert any("independent parts of the recording disagree" in w for w in off.warnings)
    unchecked = calibrate_relative(_knocked(ds, "su2", 2.0), "su1", consistency=False).units["su2"]
    assert "consistency" not in unchecked.extras
    grown = off.rotation_std_deg / unchecked.rotation_std_deg
    assert np.all(grown >= 1.0 - 1e-12) and grown.max() > 10.0
