"""One forward model: the residuals a report shows are the residuals of the model ``mle`` fitted.

A noise-free simulated Panda session whose accelerometers drift (0.05 m/s^2 over the session) and whose
dataset states gravity 0.1 % too high: ``mle`` fits the drift and the gravity factor, the result
carries them in ``UnitResult.imu``, and the report's prediction (:mod:`skincal.calib.residuals`) uses
them through :mod:`skincal.calib.model`, the code the solver evaluates.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from skincal.calib.api import METHODS, calibrate_unit
from skincal.calib.mle import method as mle
from skincal.calib.mle.problem import arrange
from skincal.calib.mle.solver import State, accel_rows
from skincal.calib.model import link_specific_force, predict_specific_force
from skincal.calib.preprocess import JointInterpolator
from skincal.calib.timing import motion_instants
from skincal.data.result import CalibrationResult, read_result, write_result
from skincal.kinematics import panda
from skincal.protocol import ProtocolConfig, build_trajectory
from skincal.sim import faults
from skincal.sim.analytic import simulate
from skincal.skin.imu import get_imu_model
from skincal.skin.placement import random_placement

CONFIG = ProtocolConfig(n_poses=8, amplitude=1.2, excite_duration=2.0, rest_duration=1.0, static_duration=0.5)
STATED_GRAVITY = 1.001
"""The dataset states gravity this many times the simulation's."""


@pytest.fixture(scope="module")
def fitted():
    """The dataset, one unit's result (through a result file) and the problem ``mle`` solved for it."""
    chain = panda()
    rng = np.random.default_rng(2)
    placement = random_placement(chain, 2, rng)
    ds = simulate(chain, placement, build_trajectory(chain, CONFIG, rng), get_imu_model("none"), rng)
    ds = faults.drift_bias(ds, 0.05, directions={name: [1.0, -2.0, 0.5] for name in ds.units})
    ds = replace(ds, gravity=np.asarray(ds.gravity, dtype=float) * STATED_GRAVITY)
    name = next(iter(ds.units))
    captured = {}
    spec = METHODS["mle"]

    def run_unit(problem):
        captured["problem"] = problem
        return spec.run_unit(problem)

    interp = JointInterpolator(ds.joints)
    unit = calibrate_unit(
        ds, name, replace(spec, run_unit=run_unit), link=None, rng=np.random.default_rng(0), interpolator=interp
    )
    return ds, name, unit, captured["problem"], interp


def _method_residuals(unit, problem):
    """``mle``'s own accelerometer residuals (the solver's rows, static first) at the parameters the
    result reports, and the arranged data: the solver's state rebuilt from ``unit.pose`` and
    ``unit.imu`` alone (the result holds the whole model)."""
    imu = unit.imu
    p = arrange(problem, unit.pose.link)
    d = 1e-6 * imu.clock_drift_ppm
    # time_offset_s is at time_reference_s and includes the coarse offset; the solver's tau is at t_c
    tau = imu.time_offset_s - d * (imu.time_reference_s - p.data.t_c) - problem.time_offset_s
    assert imu.accel_bias_reference_s == p.data.t_c
    state = State(
        R=unit.pose.R_link_su,
        p=unit.pose.p_link_su,
        b=imu.accel_bias_mps2,
        E=imu.accel_scale_misalignment - np.eye(3),
        tau=tau,
        d=d,
        bg=imu.gyro_bias_rps,
        c=imu.accel_bias_drift_mps3,
        k=imu.gravity_mps2 / np.linalg.norm(problem.gravity) - 1.0,
    )
    r, _ = accel_rows(state, mle.fit_blocks(problem, p), p.linearise(tau, d), p.data.rows)
    return r, p, state


def test_the_result_carries_the_fitted_drift_and_gravity(fitted):
    ds, name, unit, _, _ = fitted
    imu = unit.imu
    drift = ds.truth_sensor[name]["accel_bias_drift_mps2"]
    t0, t1 = faults.session_span(ds)
    np.testing.assert_allclose(imu.accel_bias_drift_mps3, drift / (t1 - t0), atol=1e-6)
    # the data support the simulation's gravity, not the stated one (the scale matrix shares it)
    assert imu.gravity_mps2 < np.linalg.norm(ds.gravity) - 1e-5 and imu.gravity_std_mps2 > 0
    assert "accel_bias_drift_mps3" not in unit.extras and "gravity_mps2" not in unit.extras


def test_report_residuals_vanish_at_rest_and_equal_the_methods_own(fitted, tmp_path: Path):
    """At rest the model is exact (no estimated joint acceleration): the report's residuals are below
    1e-6 m/s^2 there, as the solver's own static rows are. Where the solver uses moving samples, the
    report's residual at the same instant equals the solver's (which evaluates the link signals from
    a 125 Hz table: they agree to its interpolation error, 1e-5 m/s^2). Old code: the report left out
    the bias drift and the gravity factor (up to 0.025 m/s^2 at rest here), and read extras keys."""
    from skincal.calib.residuals import unit_residuals

    ds, name, unit, problem, interp = fitted
    path = tmp_path / "result.json"
    write_result(CalibrationResult("mle", ds.robot.name, "", 0.0, {name: unit}), path)
    unit = read_result(path).units[name]  # what a report reads
    r, p, state = _method_residuals(unit, problem)
    S = len(p.data.rows.static_u)
    assert np.max(np.linalg.norm(r[:S], axis=1)) < 1e-6  # the solver's own rest rows

    shown = unit_residuals(ds, name, unit, interp)
    rest = shown.kind == 0
    assert rest.sum() >= 400  # 8 static poses of 0.5 s
    assert np.max(np.linalg.norm(shown.residual[rest], axis=1)) < 1e-6

    # the solver's moving rows, matched by their motion instant
    stamps = p.data.moving_t  # on the joint clock after the coarse offset
    s = motion_instants(stamps, state.tau, state.d, p.data.t_c)
    i = np.clip(np.searchsorted(shown.t, s), 1, len(shown.t) - 1)
    i = np.where(np.abs(shown.t[i - 1] - s) < np.abs(shown.t[i] - s), i - 1, i)
    same = np.abs(shown.t[i] - s) < 1e-7
    assert same.mean() > 0.99
    mine = shown.residual[i[same]]  # measured - predicted
    theirs = -r[S:][same]  # the solver's rows are predicted - measured
    assert np.max(np.abs(mine - theirs)) < 2e-5
    assert np.sqrt(np.mean(np.sum(mine**2, axis=1))) < 1e-5

    # without the drift and gravity terms (what the report computed before) the rest residuals show
    for leave_out, above in (({"accel_bias_drift_mps3": None}, 5e-3), ({"gravity_mps2": None}, 1e-5)):
        stripped = replace(unit, imu=replace(unit.imu, **leave_out))
        old = unit_residuals(ds, name, stripped, interp)
        assert np.max(np.linalg.norm(old.residual[old.kind == 0], axis=1)) > above, leave_out


def test_model_pieces_compose():
    """``predict_specific_force`` = A R^T (u + K p + k u_g) + b + c t, written out; at rest (K None)
    ``v = (1 + k) u``."""
    rng = np.random.default_rng(4)
    u, K, ug = rng.normal(size=(5, 3)), rng.normal(size=(5, 3, 3)), rng.normal(size=(5, 3))
    R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    p, b, c, t = rng.normal(size=3), rng.normal(size=3), rng.normal(size=3), rng.normal(size=5)
    A = np.eye(3) + 0.01 * rng.normal(size=(3, 3))
    want = np.array([A @ R.T @ (u[m] + K[m] @ p + 0.002 * ug[m]) + b + c * t[m] for m in range(5)])
    got = predict_specific_force(R, p, A, b, u, K, ug=ug, gravity_scale=0.002, c=c, t_rel=t)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    np.testing.assert_allclose(link_specific_force(u, None, p, gravity_scale=0.002), 1.002 * u, rtol=0, atol=1e-15)
    s = motion_instants(np.array([10.0, 20.0]), 0.015, 1e-4, 10.0)
    np.testing.assert_allclose(s, [10.0 - 0.015, 20.0 - 0.015 - 1e-3], rtol=0, atol=1e-12)


def test_result_json_of_the_fit_has_the_documented_keys(fitted, tmp_path: Path):
    """The per-unit fields stay where docs/interfaces.md lists them (nothing renamed or dropped)."""
    ds, name, unit, _, _ = fitted
    path = tmp_path / "r.json"
    write_result(CalibrationResult("mle", ds.robot.name, "", 0.0, {name: unit}), path)
    entry = json.loads(path.read_text())["units"][name]
    for key in (
        "accel_bias_mps2", "accel_bias_std_mps2", "accel_scale_misalignment", "accel_scale_misalignment_std",
        "accel_scale", "accel_misalignment_sym", "time_offset_s", "time_offset_std_s", "time_offset_coarse_s",
        "time_reference_s", "clock_drift_ppm", "clock_drift_std_ppm", "gyro_bias_rps", "gyro_bias_std_rps",
        "gyro_residual_std_rps", "accel_bias_drift_mps3", "accel_bias_drift_std_mps3", "gravity_mps2",
        "gravity_std_mps2", "accel_bias_reference_s",
    ):  # fmt: skip
        assert key in entry, key
    assert np.shape(entry["accel_scale_misalignment"]) == (3, 3) and isinstance(entry["time_offset_s"], float)


def test_report_follows_a_clock_that_re_syncs_periodically(tmp_path: Path):
    """A unit clock re-synced every 2.51 s (drifting -440 ppm in between, ``driver``): ``mle`` removes
    the sawtooth from the stamps before the fit; the report's instants must do the same, or its
    residuals show a time error growing to 0.1 s (old code: RMS 0.25 m/s^2 against 0.018 m/s^2 for
    the same session on an ideal clock, the samples at acceleration steps, which the fit leaves out)."""
    from skincal.calib import calibrate
    from skincal.calib.residuals import unit_residuals
    from skincal.skin.clock import get_clock_model

    chain = panda()
    rms = {}
    for clock in ("ideal", "driver"):
        rng = np.random.default_rng(3)
        placement = dict(list(random_placement(chain, 2, rng).items())[:1])
        trajectory = build_trajectory(chain, CONFIG, rng)
        ds = simulate(chain, placement, trajectory, get_imu_model("none"), rng, clock_model=get_clock_model(clock))
        path = tmp_path / f"{clock}.json"
        write_result(calibrate(ds, "mle"), path)
        ((name, unit),) = read_result(path).units.items()
        assert (unit.imu.clock_resync_steps or 0) > (50 if clock == "driver" else -1)
        shown = unit_residuals(ds, name, unit, JointInterpolator(ds.joints))
        assert np.max(np.linalg.norm(shown.residual[shown.kind == 0], axis=1)) < 1e-6
        rms[clock] = shown.rms
    assert rms["driver"] == pytest.approx(rms["ideal"], rel=1e-3), rms
