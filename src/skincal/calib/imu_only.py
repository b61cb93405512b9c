"""Unit-to-unit calibration from the IMUs alone: the pose of each unit in a reference unit's frame.

No joint states are needed: units fixed on one rigid body (a hand-held patch, a link of a robot
without encoders) see the same angular velocity and accelerations that differ only by the
rigid-body terms. For the reference unit ``ref`` and another unit ``j`` with pose
``T_ref_j = (R, r)``:

* gyroscopes: ``w_ref - b_ref = R (w_j - b_j)``. The rotation is Wahba's problem on the centred
  rates (:func:`skincal.calib.closed_form.wahba`); only the difference ``c = b_ref - R b_j`` of the
  biases is seen by this equation. The time offset between the two units' stamps comes first: a
  cross-correlation of ``|w|`` and a refinement that minimises the gyroscope residual.
* accelerometers: ``R f_j - f_ref = ([dw]x + [w]x^2) r`` with ``w`` the fused angular velocity
  (both gyroscopes, ``- b_ref``) and ``dw`` its Savitzky-Golay derivative. With affine accelerometer
  models the equation becomes ``M a_j + d - K(w_ref - b_ref, dw) r = a_ref``; ``M`` (3x3: the rotation
  times unit ``j``'s scale and misalignment relative to the reference's), ``d`` (both biases),
  ``r`` and the reference gyroscope bias ``b_ref`` (seen through the centripetal term) are found by
  a robust Gauss-Newton. The reference accelerometer is the gauge: its scale errors carry over to
  ``r`` (a common scale of both accelerometers scales ``r``, and the equation cannot see it).

The covariance is the normal matrix's inverse times the robust residual variance, inflated by the
residuals' autocorrelation (the functions of :mod:`skincal.calib.mle.solver`). A unit whose rates
disagree with the reference's beyond ``other_body_ratio`` of their RMS after the best rotation is on
another rigid body and is reported as failed; rotation about fewer than two axes leaves the rotation
about, and the position along, the one axis undetermined (``observable = False``, named).

Result convention (``docs/interfaces.md``): ``extras["reference"]`` names the reference unit, every
unit's pose is ``T_ref_su`` with ``link = 0`` meaning "the reference unit's frame" (the reference
itself: identity, std 0).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.optimize import minimize_scalar
from scipy.signal import savgol_filter

from skincal.calib.closed_form import wahba
from skincal.calib.mle.solver import _huber, _pinv, _residual_correlation, _robust_sigma
from skincal.data.dataset import Dataset, ImuStream
from skincal.data.names import name_problem, printable
from skincal.data.result import REFERENCE, REFERENCE_LINK, CalibrationResult, UnitResult
from skincal.errors import ConfigError, DatasetError
from skincal.kinematics.transforms import FloatArray
from skincal.skin.pose import SkinUnitPose

METHOD = "imu-only"
OTHER_BODY_RATIO = 0.2
"""A unit whose gyroscope residual RMS after the best rotation exceeds this fraction of the
reference's rate RMS (centred) moves on another rigid body."""
MIN_AXIS_RATIO = 0.05
"""Rotation about fewer than two axes: the second singular value of the centred rates below this
fraction of the first."""


@dataclass(frozen=True)
class RelativeFit:
    """One unit's fit against the reference (all in the reference unit's frame)."""

    R: FloatArray
    r: FloatArray
    offset_s: float
    gyro_bias_diff: FloatArray
    gyro_bias_ref: FloatArray
    M: FloatArray
    d: FloatArray
    position_cov: FloatArray
    rotation_cov: FloatArray
    gyro_ratio: float
    accel_sigma: float
    gyro_sigma: float
    correlation: float
    null_axis: FloatArray | None


def _uniform_grid(t: FloatArray) -> tuple[FloatArray, float]:
    dt = float(np.median(np.diff(t)))
    return np.arange(t[0], t[-1], dt), dt


def coarse_offset(t_ref: FloatArray, w_ref: FloatArray, t_j: FloatArray, w_j: FloatArray, max_s: float) -> float:
    """Offset ``delta`` s such that unit ``j``'s stamp ``t + delta`` saw the motion of the reference's
    stamp ``t``: the peak of the cross-correlation of ``|w|`` on a uniform grid within ``max_s``."""
    grid, dt = _uniform_grid(t_ref)
    x = np.interp(grid, t_ref, np.linalg.norm(w_ref, axis=1))
    y = np.interp(grid, t_j, np.linalg.norm(w_j, axis=1))
    x, y = x - x.mean(), y - y.mean()
    n = len(grid)
    lags = np.arange(-int(max_s / dt), int(max_s / dt) + 1)
    spectrum = np.fft.rfft(x, 2 * n) * np.conj(np.fft.rfft(y, 2 * n))
    cc = np.fft.irfft(spectrum, 2 * n)
    values = cc[lags % (2 * n)]
    # cc[k] = sum x[i + k] y[i]: y leads x by k samples when the peak is at k, i.e. delta = -k dt
    return float(-lags[int(np.argmax(values))] * dt)


def _gyro_fit(w_ref: FloatArray, w_j: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Rotation ``R``, bias difference ``c`` and residuals of ``w_ref = R w_j + c`` (centred Wahba)."""
    mr, mj = w_ref.mean(axis=0), w_j.mean(axis=0)
    R = wahba(w_ref - mr, w_j - mj)
    c = mr - R @ mj
    return R, c, w_ref - w_j @ R.T - c


def _skew(v: FloatArray) -> FloatArray:
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2], S[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    S[..., 1, 0], S[..., 2, 0], S[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return S


def rate_derivative(t: FloatArray, w: FloatArray, window_s: float = 0.12) -> FloatArray:
    """Angular acceleration ``(M, 3)`` at stamps ``t``: a quintic Savitzky-Golay derivative on a uniform
    grid (the rates resampled by a cubic spline), read back at ``t``."""
    grid, dt = _uniform_grid(t)
    window = max(7, int(round(window_s / dt)) | 1)
    wg = CubicSpline(t, w, axis=0)(grid)
    dwg = savgol_filter(wg, window, 5, deriv=1, delta=dt, axis=0, mode="interp")
    return CubicSpline(grid, dwg, axis=0)(t)


def _position_rows(
    theta: FloatArray, a_j: FloatArray, a_ref: FloatArray, w: FloatArray, dw: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Residual ``(N, 3)`` and Jacobian ``(N, 3, 18)`` of ``M a_j + d - K(w - b) r - a_ref`` for
    ``theta = [b (3), r (3), M (9, row-major), d (3)]``."""
    b, r, M, d = theta[:3], theta[3:6], theta[6:15].reshape(3, 3), theta[15:18]
    v = w - b
    K = _skew(dw) + _skew(v) @ _skew(v)
    res = a_j @ M.T + d - K @ r - a_ref
    n = len(a_j)
    J = np.zeros((n, 3, 18))
    # d/dv of [v]x^2 r = v (v.r) - |v|^2 r  is  (v.r) I + v r^T - 2 r v^T; d/db = -d/dv, and res has -K r
    vr = v @ r
    J[:, :, :3] = (
        vr[:, None, None] * np.eye(3) + v[:, :, None] * r[None, None, :] - 2 * r[None, :, None] * v[:, None, :]
    )
    J[:, :, 3:6] = -K
    for i in range(3):
        J[:, i, 6 + 3 * i : 9 + 3 * i] = a_j
    J[:, :, 15:18] = np.eye(3)
    return res, J


def fit_relative(
    ref: ImuStream,
    unit: ImuStream,
    *,
    max_offset_s: float = 1.0,
    iterations: int = 20,
    other_body_ratio: float = OTHER_BODY_RATIO,
) -> RelativeFit | str:
    """Fit one unit against the reference; a reason (str) when it cannot be calibrated."""
    if ref.gyro is None or unit.gyro is None:
        return "no gyroscope stream (the IMU-only calibration needs both units' angular rates)"
    if len(unit.t) < 50 or len(ref.t) < 50:
        return "fewer than 50 IMU samples"
    delta0 = coarse_offset(ref.t, ref.gyro, unit.t, unit.gyro, max_offset_s)
    spline_w = CubicSpline(unit.t, unit.gyro, axis=0)
    spline_a = CubicSpline(unit.t, unit.accel, axis=0)
    margin = max_offset_s + 0.1
    inside = (ref.t + delta0 - margin / 10 > unit.t[0]) & (ref.t + delta0 + margin / 10 < unit.t[-1])
    inside &= (ref.t > ref.t[0] + 0.25) & (ref.t < ref.t[-1] - 0.25)
    if inside.sum() < 50:
        return "the two streams overlap by fewer than 50 samples"
    t = ref.t[inside]
    w_ref, a_ref = ref.gyro[inside], ref.accel[inside]
    dt = float(np.median(np.diff(ref.t)))

    def gyro_cost(delta: float) -> float:
        return float(np.mean(_gyro_fit(w_ref, spline_w(t + delta))[2] ** 2))

    found = minimize_scalar(gyro_cost, bounds=(delta0 - 2 * dt, delta0 + 2 * dt), method="bounded",
                            options={"xatol": 1e-6})  # fmt: skip
    delta = float(found.x)
    w_j, a_j = spline_w(t + delta), spline_a(t + delta)
    R, c, res_g = _gyro_fit(w_ref, w_j)
    centred = w_ref - w_ref.mean(axis=0)
    ratio = float(np.sqrt(np.mean(res_g**2) / max(np.mean(centred**2), 1e-300)))
    if ratio > other_body_ratio:
        return (
            f"on another rigid body: its angular rates disagree with the reference's by {100 * ratio:.0f} % of "
            f"their RMS after the best rotation (same body: a few %)"
        )
    _, s, Vt = np.linalg.svd(centred, full_matrices=False)
    null_axis = Vt[0] if s[1] < MIN_AXIS_RATIO * s[0] else None
    # fused rate (both gyroscopes, reference frame, reference bias not yet removed) and its derivative
    w_fused = 0.5 * (w_ref + w_j @ R.T + c)
    dw = rate_derivative(t, w_fused)
    # linear start (b = 0), then robust Gauss-Newton with the reference gyroscope bias
    theta = np.zeros(18)
    theta[:3] = np.median(w_fused, axis=0) if null_axis is not None else 0.0
    theta[6:15] = R.ravel()
    weights = np.ones(len(t))
    sigma = 1.0
    H = np.eye(18)
    for k in range(iterations):
        res, J = _position_rows(theta, a_j, a_ref, w_fused, dw)
        norm = np.linalg.norm(res, axis=1)
        sigma = max(_robust_sigma(norm), 1e-9)
        weights = _huber(norm, sigma) if k > 0 else np.ones(len(t))
        if k == 0:  # first pass: no reference gyro bias (linear in the rest)
            J = J.copy()
            J[:, :, :3] = 0.0
        sw = np.sqrt(weights)[:, None, None]
        Jw = (J * sw).reshape(-1, 18)
        H = Jw.T @ Jw
        g = Jw.T @ (res[:, :, None] * sw).reshape(-1)
        step = -_pinv(H) @ g
        theta = theta + step
        if k > 1 and np.max(np.abs(step[3:6])) < 1e-9:
            break
    res, J = _position_rows(theta, a_j, a_ref, w_fused, dw)
    rho = _residual_correlation(res)
    sw = np.sqrt(weights)[:, None, None]
    Jw = (J * sw).reshape(-1, 18)
    cov = _pinv(Jw.T @ Jw) * sigma**2 * rho
    # rotation covariance from the gyroscope equation: d(res_g) = [R w_j]x dphi
    sigma_g = float(np.sqrt(np.mean(res_g**2)))
    A = _skew(w_j @ R.T - (w_j @ R.T).mean(axis=0))
    rho_g = _residual_correlation(res_g)
    rot_cov = _pinv(np.einsum("mji,mjk->ik", A, A)) * sigma_g**2 * rho_g
    return RelativeFit(
        R=R,
        r=theta[3:6],
        offset_s=delta,
        gyro_bias_diff=c,
        gyro_bias_ref=theta[:3],
        M=theta[6:15].reshape(3, 3),
        d=theta[15:18],
        position_cov=cov[3:6, 3:6],
        rotation_cov=rot_cov,
        gyro_ratio=ratio,
        accel_sigma=sigma,
        gyro_sigma=sigma_g,
        correlation=rho,
        null_axis=null_axis,
    )


def _closest_rotation(R: FloatArray) -> FloatArray:
    U, _, Vt = np.linalg.svd(R)
    return U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt


def calibrate_relative(
    dataset: Dataset,
    reference: str,
    *,
    units: list[str] | None = None,
    max_offset_s: float = 1.0,
    other_body_ratio: float = OTHER_BODY_RATIO,
    reference_scale_std: float = 0.0,
    reference_misalignment_std: float = 0.0,
    dataset_sha256: str = "",
) -> CalibrationResult:
    """Poses of ``units`` (default: every unit) in the frame of unit ``reference`` from the IMUs alone.

    The reference accelerometer is the gauge of every position (its scale error ``s`` makes
    ``r_est = (1 + s) r``): ``reference_scale_std`` and ``reference_misalignment_std`` (the size of its
    uncalibrated per-axis scale error and symmetric cross-axis error, e.g. 0.03 and 0.01 for the
    ``real`` IMU preset) add that to the position std; 0 (default) takes the reference as exact.

    Returns a :class:`~skincal.data.result.CalibrationResult` with ``method = "imu-only"``,
    ``extras["reference"] = reference`` and per unit ``T_ref_su`` at ``link = 0``; units on another
    rigid body (or without a gyroscope) are in ``extras["failed_units"]`` with the reason.
    """
    start = time.perf_counter()
    problem = name_problem(reference)
    if problem is not None:
        raise ConfigError(f"--reference: {problem}")
    if reference not in dataset.imu:
        known = ", ".join(printable(u) for u in dataset.units)
        raise DatasetError(f"reference unit '{printable(reference)}' is not in the dataset (units: {known})")
    names = list(units) if units else dataset.units
    if not (0.0 <= reference_scale_std < 1.0 and 0.0 <= reference_misalignment_std < 1.0):
        raise ConfigError("reference_scale_std and reference_misalignment_std must be in [0, 1)")
    for name in names:
        if name not in dataset.imu:
            raise DatasetError(f"unit '{printable(name)}' is not in the dataset")
    ref = dataset.imu[reference]
    if ref.gyro is None:
        raise DatasetError(f"reference unit '{printable(reference)}' has no gyroscope stream")
    out: dict[str, UnitResult] = {}
    failed: dict[str, str] = {}
    for name in names:
        if name == reference:
            out[name] = UnitResult(
                SkinUnitPose(REFERENCE_LINK, np.eye(3), np.zeros(3)),
                position_std_m=np.zeros(3),
                rotation_std_deg=np.zeros(3),
                extras={"link_name": f"{reference} (reference)"},
            )
            continue
        fit = fit_relative(ref, dataset.imu[name], max_offset_s=max_offset_s, other_body_ratio=other_body_ratio)
        if isinstance(fit, str):
            failed[name] = fit
            continue
        r2 = fit.r**2
        gauge = reference_scale_std**2 * r2 + reference_misalignment_std**2 * (r2.sum() - r2)
        fit = replace(fit, position_cov=fit.position_cov + np.diag(gauge))
        out[name] = _unit_result(fit, reference)
    robot = dataset.robot.name if dataset.robot is not None else "none"
    extras: dict = {REFERENCE: reference}
    if failed:
        extras["failed_units"] = failed
    return CalibrationResult(METHOD, robot, dataset_sha256, time.perf_counter() - start, out, extras)


def _unit_result(fit: RelativeFit, reference: str) -> UnitResult:
    pos_std = np.sqrt(np.maximum(np.diag(fit.position_cov), 0.0))
    rot_std = np.degrees(np.sqrt(np.maximum(np.diag(fit.rotation_cov), 0.0)))
    warnings: list[str] = []
    notes = [f"position in the scale of {reference}'s accelerometer (its scale error carries over to the position)"]
    observable = True
    if fit.null_axis is not None:
        observable = False
        axis = " ".join(f"{x:+.2f}" for x in fit.null_axis)
        warnings.append(
            f"rotation about one axis only ([{axis}] in {reference}'s frame): the rotation about it and the "
            "position along it are undetermined; move about a second axis"
        )
        undetermined = np.abs(fit.null_axis) > 0.3
        pos_std = np.where(undetermined, math.nan, pos_std)
        rot_std = np.where(undetermined, math.nan, rot_std)
    extras = {
        "link_name": f"{reference} (reference)",
        "time_offset_to_reference_s": fit.offset_s,
        "gyro_bias_difference_rps": fit.gyro_bias_diff,
        "reference_gyro_bias_rps": fit.gyro_bias_ref,
        "accel_relative_matrix": fit.M,
        "accel_relative_offset_mps2": fit.d,
        "gyro_disagreement_ratio": fit.gyro_ratio,
        "residual_std_mps2": fit.accel_sigma,
        "gyro_residual_std_rps": fit.gyro_sigma,
        "residual_correlation": fit.correlation,
        "notes": notes,
    }
    return UnitResult(
        SkinUnitPose(REFERENCE_LINK, _closest_rotation(fit.R), fit.r),
        observable=observable,
        position_std_m=pos_std,
        rotation_std_deg=rot_std,
        warnings=tuple(warnings),
        extras=extras,
    )


def compare_with_joint_result(relative: CalibrationResult, joint: CalibrationResult) -> dict[str, tuple[float, float]]:
    """Disagreement of an IMU-only result with a joint-based one (e.g. ``mle``) of the same units:
    unit -> ``(position mm, rotation deg)`` of ``T_ref_su`` against ``T_link_ref^-1 T_link_su`` from
    ``joint``, for the units that ``joint`` puts on the reference unit's link (others: not comparable)."""
    reference = relative.extras.get(REFERENCE)
    if not isinstance(reference, str) or reference not in joint.units:
        return {}
    ref_pose = joint.units[reference].pose
    out: dict[str, tuple[float, float]] = {}
    for name, unit in relative.units.items():
        other = joint.units.get(name)
        if name == reference or other is None or other.pose.link != ref_pose.link:
            continue
        R_joint = ref_pose.R_link_su.T @ other.pose.R_link_su
        p_joint = ref_pose.R_link_su.T @ (other.pose.p_link_su - ref_pose.p_link_su)
        # rotation angle from the chord ||R1 - R2||_F = 2 sqrt(2) sin(angle / 2): exact near 0, unlike acos
        chord = min(float(np.linalg.norm(R_joint - unit.pose.R_link_su)) / math.sqrt(8.0), 1.0)
        out[name] = (1e3 * float(np.linalg.norm(unit.pose.p_link_su - p_joint)), math.degrees(2 * math.asin(chord)))
    return out


def evaluate_relative(result: CalibrationResult, dataset: Dataset) -> dict:
    """Errors of a relative result against a simulated dataset's truth: per unit on the reference's body
    (``truth_body``) or link (``truth``), ``position_error_mm`` and ``rotation_error_deg`` of ``T_ref_su``;
    means over observable units. Units whose truth is on another body or link are listed as such."""
    reference = result.extras.get(REFERENCE)
    if not isinstance(reference, str):
        raise ConfigError("evaluate_relative: the result has no reference unit (not an IMU-only result)")
    truth: dict[str, tuple[str, FloatArray]] = {}
    for name, body in dataset.truth_body.items():
        truth[name] = (f"body {body.body}", np.asarray(body.T_body_su, dtype=float))
    for name, pose in dataset.truth.items():
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = pose.R_link_su, pose.p_link_su
        truth.setdefault(name, (f"link {pose.link}", T))
    if reference not in truth:
        raise DatasetError(f"the dataset has no true pose of the reference unit '{printable(reference)}'")
    where, T_ref = truth[reference]
    units: dict[str, dict] = {}
    for name, unit in result.units.items():
        if name not in truth:
            continue
        on, T = truth[name]
        if on != where:
            units[name] = {"same_body": False, "observable": unit.observable}
            continue
        T_rel = np.linalg.inv(T_ref) @ T
        chord = min(float(np.linalg.norm(T_rel[:3, :3] - unit.pose.R_link_su)) / math.sqrt(8.0), 1.0)
        units[name] = {
            "same_body": True,
            "observable": unit.observable,
            "position_error_mm": 1e3 * float(np.linalg.norm(unit.pose.p_link_su - T_rel[:3, 3])),
            "rotation_error_deg": math.degrees(2 * math.asin(chord)),
        }
    scored = [u for name, u in units.items() if u.get("same_body") and u["observable"] and name != reference]
    return {
        "reference": reference,
        "units": units,
        "mean_position_error_mm": float(np.mean([u["position_error_mm"] for u in scored])) if scored else None,
        "mean_rotation_error_deg": float(np.mean([u["rotation_error_deg"] for u in scored])) if scored else None,
    }
