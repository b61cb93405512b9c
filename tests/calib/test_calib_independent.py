"""The default calibrator against data it did not make.

The datasets come from ``tests/independent/generator.py``: its own robots (invented modified-DH
arms), its own DH -> MJCF, MuJoCo physics, its own protocol and a hardware-like recording (a
controller's joint stream, IMUs with bias, scale, non-symmetric misalignment, noise, quantisation,
drops, jitter and latency). Nothing in it comes from skincal. The tests state what the calibrator
must achieve on such data; tolerances are the requirement, not today's performance.

The first tests check the generator itself (MuJoCo's readings against its own forward kinematics,
and its file against skincal's reader and skincal's forward kinematics).
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from skincal.data.hdf5 import read_dataset  # noqa: E402

from independent.generator import (  # noqa: E402
    G_FILE,
    Placement,
    Truth,
    build_model,
    forward_kinematics,
    homogeneous,
    make_dataset,
    mujoco_readings,
    random_rotation,
    robot_spec,
    rotation_log,
)

POSITION_TARGET_MM = 1.0
"""Mean position error over the units on links >= 2, mm."""
ROTATION_TARGET_DEG = 0.1
"""Mean rotation error over the units on links >= 2, deg."""
N_SIGMA = 3.0

# ---------------------------------------------------------------------------------------- datasets
DATASETS: dict[str, dict] = {
    # (a) a controller's joint stream + every IMU fault of the model, with /segments
    "a_arm6": dict(robot="arm6", seed=11, n_units=6),
    "a_arm7": dict(robot="arm7", seed=17, n_units=6),
    # (b) the same recording without /segments
    "b_arm6": dict(robot="arm6", seed=11, n_units=6, segments=False),
    # (c) a 0.4 s latency on every unit
    "c_arm7": dict(robot="arm7", seed=12, n_units=6, time_offset_s=0.4),
    # (d) one unit (u1) on link 1
    "d_arm6": dict(robot="arm6", seed=13, n_units=5, units_on_link1=1),
    # (e) faults outside the calibrator's model
    "e_bias_drift": dict(robot="arm6", seed=14, n_units=6, bias_drift=0.05),
    "e_clock_drift": dict(robot="arm6", seed=15, n_units=6, clock_drift_ppm=100.0),
    "e_gravity": dict(robot="arm7", seed=16, n_units=6, gravity_true=9.796),
    # baseline: no joint noise, no IMU faults, no latency
    "ideal_arm7": dict(robot="arm7", seed=18, n_units=6, joint_noise=False, imu_faults=False, time_offset_s=0.0),
}


@dataclass
class Case:
    truth: Truth
    path: Path
    _result: object = None

    @property
    def dataset(self):
        return read_dataset(self.path)

    def result(self):
        """``calibrate(dataset)`` with the default method (computed once per case)."""
        if self._result is None:
            from skincal.calib import calibrate

            self._result = calibrate(self.dataset)
        return self._result


@pytest.fixture(scope="module")
def cases(tmp_path_factory):
    root = tmp_path_factory.mktemp("independent")
    made: dict[str, Case] = {}

    def get(name: str) -> Case:
        if name not in made:
            path = root / f"{name}.h5"
            truth = make_dataset(path, **DATASETS[name])
            print(f"generated {name}: {truth.duration_s:.0f} s of motion in {truth.generation_s:.2f} s")
            made[name] = Case(truth, path)
        return made[name]

    return get


# ---------------------------------------------------------------------------------------- checking
def unit_errors(result, truth: Truth, name: str) -> tuple[np.ndarray, np.ndarray]:
    """Position error (link frame, mm) and rotation error (rotation vector about the link axes, deg)."""
    est = result.units[name].pose
    ut = truth.units[name]
    dp = (est.p_link_su - ut.position) * 1e3
    dr = np.degrees(rotation_log(est.R_link_su @ ut.R.T))
    return dp, dr


def _std(value) -> np.ndarray:
    return np.full(3, np.nan) if value is None else np.array([np.nan if v is None else v for v in value], float)


def within_sigma(result, truth: Truth, name: str) -> tuple[bool, str]:
    """Is every axis of the pose error within N_SIGMA reported std? (A missing std is not.)"""
    u = result.units[name]
    dp, dr = unit_errors(result, truth, name)
    sp = _std(u.position_std_m) * 1e3
    sr = _std(u.rotation_std_deg)
    with np.errstate(invalid="ignore"):
        ok = bool(np.all(np.abs(dp) <= N_SIGMA * sp) and np.all(np.abs(dr) <= N_SIGMA * sr))
    text = (
        f"{name} (link {truth.units[name].link} -> {u.pose.link}): dp {np.round(dp, 3)} mm (std {np.round(sp, 3)}), "
        f"dr {np.round(dr, 4)} deg (std {np.round(sr, 4)}), warnings {list(u.warnings)}"
    )
    return ok, text


def report(result, truth: Truth) -> str:
    lines = [within_sigma(result, truth, u)[1] for u in truth.units if u in result.units]
    failed = result.failed_units
    lines += [f"{u}: FAILED ({why})" for u, why in failed.items()]
    return "\n".join(lines)


def check_calibration(result, truth: Truth, *, fault_keywords: tuple[str, ...] | None = None) -> list[str]:
    """The requirements on a calibration of an independent dataset; returns the violations.

    * every unit gets a result;
    * units on links >= 2 get the right link, and their mean errors meet the targets (unless
      ``fault_keywords`` is given: a fault outside the model need not be absorbed);
    * per unit, every axis within N_SIGMA reported std, warnings or not (with ``fault_keywords``, a
      fault outside the model: within N_SIGMA or else a warning containing one of them, i.e. naming the
      problem).
    """
    problems = []
    failed = result.failed_units
    for name in truth.units:
        if name not in result.units:
            problems.append(f"{name}: no result ({failed.get(name, 'missing')})")
    units = [u for u in truth.units if u in result.units and truth.units[u].link >= 2]
    pos, rot = [], []
    for name in units:
        unit = result.units[name]
        ok, text = within_sigma(result, truth, name)
        link_ok = unit.pose.link == truth.units[name].link
        if fault_keywords is None:
            if not link_ok:
                problems.append(f"wrong link: {text}")
            if not ok:  # a warning does not excuse it: the std is what the warning says accounts for the problem
                problems.append(f"error beyond {N_SIGMA:g} std: {text}")
        else:
            named = any(k in w.lower() for w in unit.warnings for k in fault_keywords)
            if not (ok and link_ok) and not named:
                problems.append(f"silent error (no warning naming {'/'.join(fault_keywords)}): {text}")
        if link_ok:
            dp, dr = unit_errors(result, truth, name)
            pos.append(np.linalg.norm(dp))
            rot.append(np.linalg.norm(dr))
    if fault_keywords is None and units:
        mp = float(np.mean(pos)) if pos else np.inf
        mr = float(np.mean(rot)) if rot else np.inf
        if not mp <= POSITION_TARGET_MM:
            problems.append(f"mean position error {mp:.3f} mm > {POSITION_TARGET_MM} mm")
        if not mr <= ROTATION_TARGET_DEG:
            problems.append(f"mean rotation error {mr:.4f} deg > {ROTATION_TARGET_DEG} deg")
    return problems


def assert_meets(result, truth: Truth, **kw) -> None:
    problems = check_calibration(result, truth, **kw)
    print(report(result, truth))
    assert not problems, "\n".join(problems) + "\n--- all units:\n" + report(result, truth)


# ---------------------------------------------------------------------------------------- the generator
def _random_placements(spec, rng, k=4):
    out = []
    for i in range(k):
        d = rng.normal(size=3)
        out.append(Placement(f"s{i}", int(rng.integers(1, spec.n + 1)), d / np.linalg.norm(d) * rng.uniform(0.02, 0.15),
                             random_rotation(rng)))
    return out


def test_generator_does_not_use_skincal():
    """The generator imports nothing from skincal (a fresh interpreter, generator only)."""
    import subprocess

    code = (
        "import sys; sys.path.insert(0, sys.argv[1]); import independent.generator; "
        "bad = sorted(m for m in sys.modules if m == 'skincal' or m.startswith('skincal.')); "
        "assert not bad, bad"
    )
    proc = subprocess.run([sys.executable, "-c", code, str(Path(__file__).resolve().parents[1])],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr


@pytest.mark.parametrize("robot", ["arm6", "arm7"])
@pytest.mark.parametrize("gravity", [G_FILE, 9.796])
def test_generator_static_accelerometer_is_gravity_from_own_dh(robot, gravity):
    """At rest MuJoCo's accelerometer reads R^T (0, 0, g), R from the generator's own DH kinematics."""
    rng = np.random.default_rng(1)
    spec = robot_spec(robot)
    placements = _random_placements(spec, rng)
    model = build_model(spec, placements, gravity=gravity)
    q = rng.uniform(spec.lower, spec.upper)
    frames = forward_kinematics(spec.dh, q)
    for p in placements:
        f, w = mujoco_readings(model, p.name, q[None], np.zeros((1, spec.n)), np.zeros((1, spec.n)))
        R = frames[p.link][:3, :3] @ p.R_site
        np.testing.assert_allclose(f[0], R.T @ [0.0, 0.0, gravity], atol=1e-10)
        np.testing.assert_allclose(w[0], 0.0, atol=1e-12)


@pytest.mark.parametrize("robot", ["arm6", "arm7"])
def test_generator_moving_readings_match_own_dh(robot):
    """In motion: MuJoCo's accelerometer = R^T (x'' - g) and gyro = R^T omega, with x'' and omega
    differentiated numerically from the generator's own DH kinematics along q + qd t + qdd t^2/2."""
    rng = np.random.default_rng(2)
    spec = robot_spec(robot)
    placements = _random_placements(spec, rng)
    model = build_model(spec, placements)
    q, qd, qdd = rng.uniform(spec.lower, spec.upper), rng.uniform(-1.5, 1.5, spec.n), rng.uniform(-5, 5, spec.n)
    h = 1e-4

    def site(p, t):
        T = forward_kinematics(spec.dh, q + qd * t + 0.5 * qdd * t * t)[p.link] @ homogeneous(p.R_site, p.position)
        return T[:3, 3], T[:3, :3]

    for p in placements:
        f, w = mujoco_readings(model, p.name, q[None], qd[None], qdd[None])
        (x0, R0), (xp, Rp), (xm, Rm) = site(p, 0.0), site(p, h), site(p, -h)
        acc = (xp - 2 * x0 + xm) / h**2
        omega = rotation_log(Rp @ Rm.T) / (2 * h)  # base frame
        np.testing.assert_allclose(f[0], R0.T @ (acc - [0.0, 0.0, -G_FILE]), atol=1e-4)
        np.testing.assert_allclose(w[0], R0.T @ omega, atol=1e-6)


def test_generator_file_reads_back_and_frames_agree_with_skincal(tmp_path):
    """skincal reads the generator's file; its forward kinematics (dataset.robot.link_frames) puts
    every unit's site where MuJoCo has it, and the truth reads back as written."""
    path = tmp_path / "small.h5"
    truth = make_dataset(path, robot="arm7", seed=3, n_units=4, units_on_link1=1, n_poses=2)
    ds = read_dataset(path)
    spec = truth.robot
    assert ds.robot.convention == "modified"
    np.testing.assert_array_equal(ds.robot.dh, spec.dh)
    np.testing.assert_array_equal(ds.robot.joint_lower, spec.lower)
    np.testing.assert_array_equal(ds.robot.joint_upper, spec.upper)
    np.testing.assert_array_equal(ds.robot.velocity_limit, spec.velocity_limit)
    np.testing.assert_array_equal(ds.gravity, [0.0, 0.0, -9.81])
    assert ds.joints.qdd is None
    assert ds.segments is not None and len(ds.segments) == len(truth.segments)
    assert set(ds.units) == set(truth.units)
    for name, ut in truth.units.items():
        pose = ds.truth[name]
        assert pose.link == ut.link
        np.testing.assert_allclose(pose.p_link_su, ut.position, atol=1e-15)
        np.testing.assert_allclose(pose.R_link_su, ut.R, atol=1e-12)
        stream = ds.imu[name]
        rate = 1.0 / np.median(np.diff(stream.t))
        assert 99.0 < rate < 101.0 and stream.gyro is not None

    model = build_model(spec, truth.placements)
    data = mujoco.MjData(model)
    rng = np.random.default_rng(4)
    for q in [ds.joints.q[0], ds.joints.q[len(ds.joints.t) // 2], rng.uniform(spec.lower, spec.upper)]:
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        frames = ds.robot.link_frames(q)[0]
        np.testing.assert_allclose(frames, forward_kinematics(spec.dh, q), atol=1e-12)
        for p in truth.placements:
            sid = model.site(p.name).id
            T = frames[p.link] @ homogeneous(p.R_site, p.position)
            np.testing.assert_allclose(data.site_xpos[sid], T[:3, 3], atol=1e-12)
            np.testing.assert_allclose(data.site_xmat[sid].reshape(3, 3), T[:3, :3], atol=1e-12)
    # the body of link i is DH frame {i} too
    for i in range(1, spec.n + 1):
        bid = model.body(f"link{i}").id
        np.testing.assert_allclose(data.xpos[bid], frames[i][:3, 3], atol=1e-12)


def test_ideal_independent_data_is_calibrated_exactly(cases):
    """Baseline: with exact joint states and ideal IMUs the calibration is exact (conventions agree)."""
    case = cases("ideal_arm7")
    result = case.result()
    print(report(result, case.truth))
    assert set(result.units) == set(case.truth.units)
    for name, ut in case.truth.units.items():
        dp, dr = unit_errors(result, case.truth, name)
        assert result.units[name].pose.link == ut.link
        assert np.linalg.norm(dp) < 0.02 and np.linalg.norm(dr) < 0.005, within_sigma(result, case.truth, name)[1]


# ---------------------------------------------------------------------------------------- requirements
def test_a_controller_joints_and_imu_faults(cases):
    """(a) Controller joint stream + IMU faults, /segments present: every unit, right links, mean
    errors <= 1 mm / 0.1 deg, each unit within 3 reported std per axis or warned."""
    case = cases("a_arm6")
    assert_meets(case.result(), case.truth)


@pytest.mark.slow
def test_a_controller_joints_and_imu_faults_arm7(cases):
    """(a) on the 7-joint arm."""
    case = cases("a_arm7")
    assert_meets(case.result(), case.truth)


def test_b_without_segments(cases):
    """(b) The recording of (a) without /segments: the calibrator finds the rests itself."""
    case = cases("b_arm6")
    assert case.dataset.segments is None
    assert_meets(case.result(), case.truth)


def test_c_time_offset_0p4s(cases):
    """(c) Every IMU lags by 0.4 s (+ 1 ms jitter): the offset is found within 1 ms and poses meet the targets."""
    case = cases("c_arm7")
    result = case.result()
    wrong = []
    for name, ut in case.truth.units.items():
        if name not in result.units:
            continue
        imu = result.units[name].imu
        found = None if imu is None else imu.time_offset_s
        want = ut.mean_time_offset(case.truth.duration_s)
        if found is None or not abs(float(found) - want) <= 1e-3:
            wrong.append(f"{name}: time_offset_s {found} vs true {want:.4f}")
    print("\n".join(wrong))
    assert not wrong, "\n".join(wrong) + "\n" + report(result, case.truth)
    assert_meets(result, case.truth)


def test_d_unit_on_link1_result_file(cases, tmp_path):
    """(d) A unit on link 1: observable false, null in the undetermined std components (its offset
    along and yaw about the joint-1 axis, z of link frame 1) in the result file, which reads back;
    the other units are unaffected."""
    from skincal.data.result import read_result, write_result

    case = cases("d_arm6")
    result = case.result()
    l1 = [u for u, ut in case.truth.units.items() if ut.link == 1]
    assert l1 == ["u1"]
    assert "u1" in result.units, result.failed_units
    unit = result.units["u1"]
    assert unit.pose.link == 1
    assert unit.observable is False
    assert unit.warnings, "an unobservable unit must say why"

    path = tmp_path / "result.json"
    write_result(result, path)
    doc = json.loads(path.read_text())["units"]["u1"]
    assert doc["observable"] is False
    assert doc["position_std_m"] is not None and doc["position_std_m"][2] is None
    assert doc["rotation_std_deg"] is not None and doc["rotation_std_deg"][2] is None
    assert all(v is not None for v in doc["rotation_std_deg"][:2]), doc["rotation_std_deg"]
    # x and y of the position turn with the undetermined yaw: null, or (if given) honest
    dp, _ = unit_errors(result, case.truth, "u1")
    for k in (0, 1):
        sd = doc["position_std_m"][k]
        assert sd is None or abs(dp[k]) <= N_SIGMA * 1e3 * sd, within_sigma(result, case.truth, "u1")[1]
    back = read_result(path)
    b = back.units["u1"]
    assert b.observable is False and b.pose.link == 1 and b.warnings == unit.warnings
    np.testing.assert_allclose(b.pose.p_link_su, unit.pose.p_link_su)
    np.testing.assert_allclose(b.pose.R_link_su, unit.pose.R_link_su, atol=1e-12)
    np.testing.assert_array_equal(np.isnan(_std(b.position_std_m)), np.isnan(_std(unit.position_std_m)))
    for name in case.truth.units:
        if name != "u1":
            assert back.units[name].pose.link == result.units[name].pose.link
    assert_meets(result, case.truth)  # the others: links >= 2 only


def test_d_unit_on_link1_partial_pose(cases):
    """(d) The determinable part of the link-1 unit's pose is right: its distance from the joint-1
    axis (mm) and the direction of the joint-1 axis in the unit frame (deg); the rest is a
    plausible best guess (no coordinate beyond 2 m)."""
    case = cases("d_arm6")
    result = case.result()
    assert "u1" in result.units, result.failed_units
    est, ut = result.units["u1"].pose, case.truth.units["u1"]
    radius_err = 1e3 * abs(np.linalg.norm(est.p_link_su[:2]) - np.linalg.norm(ut.position[:2]))
    z_est, z_true = est.R_link_su.T @ [0, 0, 1.0], ut.R.T @ [0, 0, 1.0]
    tilt_err = np.degrees(np.arccos(np.clip(z_est @ z_true, -1, 1)))
    print(f"u1: radius error {radius_err:.3f} mm, axis direction error {tilt_err:.4f} deg, position {est.p_link_su} m")
    assert radius_err <= POSITION_TARGET_MM and tilt_err <= ROTATION_TARGET_DEG
    # the undetermined offset along the axis is left at a plausible value (the unit is on the robot)
    assert np.all(np.abs(est.p_link_su) < 2.0), est.p_link_su


@pytest.mark.slow
@pytest.mark.parametrize(
    ("name", "keywords"),
    [
        ("e_bias_drift", ("bias", "drift")),
        ("e_clock_drift", ("clock", "drift", "time offset", "timing")),
        ("e_gravity", ("gravity",)),
    ],
)
def test_e_faults_outside_the_model_are_never_silent(cases, name, keywords):
    """(e) Bias drift of 0.05 m/s^2 over the session; a 100 ppm IMU clock drift; true gravity 9.796
    with 9.81 in the file: each unit within 3 std, or a warning naming the problem."""
    case = cases(name)
    assert_meets(case.result(), case.truth, fault_keywords=keywords)


@pytest.mark.slow
def test_cli_calibrate_and_evaluate(cases, tmp_path, capsys):
    """The user path on the (a) recording: ``skincal calibrate`` then ``skincal evaluate --json``."""
    from skincal.cli import main

    case = cases("a_arm6")
    out = tmp_path / "r.json"
    assert main(["calibrate", str(case.path), "--out", str(out), "--workers", "1"]) == 0
    capsys.readouterr()
    assert main(["evaluate", str(out), "--truth", str(case.path), "--json"]) == 0
    ev = json.loads(capsys.readouterr().out)
    print(json.dumps({k: v for k, v in ev.items() if k != "units"}))
    assert ev["links_correct"] == ev["units_total"] == len(case.truth.units)
    assert ev["mean_position_error_mm"] <= POSITION_TARGET_MM
    assert ev["mean_rotation_error_deg"] <= ROTATION_TARGET_DEG
