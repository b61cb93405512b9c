"""One unit's pose in the reference unit's frame from both IMUs (:func:`fit_relative`, :class:`RelativeFit`):
the time offset of their stamps (:func:`coarse_offset`), the rotation from the gyroscopes, the position
and the accelerometer terms by a robust Gauss-Newton (the package docstring)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.optimize import minimize_scalar
from scipy.signal import savgol_filter

from skincal.calib.closed_form import wahba
from skincal.calib.imu_only.rests import NOISE_FLOOR
from skincal.calib.preprocess import white_noise_std
from skincal.calib.robust import huber_weights, pinv, residual_correlation, robust_sigma
from skincal.calib.timing import normalised_xcorr
from skincal.data.dataset import ImuStream
from skincal.kinematics.transforms import FloatArray, skew

OTHER_BODY_RATIO = 0.2
"""A unit whose gyroscope residual RMS after the best rotation exceeds this fraction of the
reference's rate RMS (centred) moves on another rigid body."""
MIN_AXIS_RATIO = 0.05
"""Rotation about fewer than two axes: the second singular value of the centred rates below this
fraction of the first."""
MIN_MOTION_FACTOR = 3.0
"""The body turned: the reference's centred rate RMS exceeds this multiple of the gyroscope's noise."""


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
    gauge_jacobian: FloatArray | None = None
    """``(3, P)`` derivative of ``r`` with respect to the reference accelerometer's calibration."""


def _uniform_grid(t: FloatArray) -> tuple[FloatArray, float]:
    dt = float(np.median(np.diff(t)))
    return np.arange(t[0], t[-1], dt), dt


def coarse_offset(t_ref: FloatArray, w_ref: FloatArray, t_j: FloatArray, w_j: FloatArray, max_s: float) -> float:
    """Offset ``delta`` s such that unit ``j``'s stamp ``t + delta`` saw the motion of the reference's
    stamp ``t``: the peak of the cross-correlation of ``|w|`` on a uniform grid within ``max_s``
    (:func:`~skincal.calib.timing.normalised_xcorr`, the one cross-correlation)."""
    grid, dt = _uniform_grid(t_ref)
    x = np.interp(grid, t_ref, np.linalg.norm(w_ref, axis=1))
    y = np.interp(grid, t_j, np.linalg.norm(w_j, axis=1))
    size, max_lag = 2 * len(grid), int(max_s / dt)
    values = normalised_xcorr(x, np.conj(np.fft.rfft(y - y.mean(), size)), y, size, max_lag)
    # values[k + max_lag] ~ sum x[i + k] y[i]: y leads x by k samples when the peak is at k, i.e. delta = -k dt
    return float((max_lag - int(np.argmax(values))) * dt)


def _gyro_fit(w_ref: FloatArray, w_j: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Rotation ``R``, bias difference ``c`` and residuals of ``w_ref = R w_j + c`` (centred Wahba)."""
    mr, mj = w_ref.mean(axis=0), w_j.mean(axis=0)
    R = wahba(w_ref - mr, w_j - mj)
    c = mr - R @ mj
    return R, c, w_ref - w_j @ R.T - c


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
    K = skew(dw) + skew(v) @ skew(v)
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
    ref_jacobian: FloatArray | None = None,
) -> RelativeFit | str:
    """Fit one unit against the reference; a reason (str) when it cannot be calibrated.
    ``ref_jacobian`` ``(len(ref.t), 3, P)``: derivative of the reference's accelerations with respect to
    ``P`` calibration parameters (``ref`` calibrated); the fit then returns ``dr/dp`` (``gauge_jacobian``)."""
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
    noise = float(np.linalg.norm(np.maximum(white_noise_std(w_ref, 4), NOISE_FLOOR)))
    if float(np.sqrt(np.mean(np.sum(centred**2, axis=1)))) < MIN_MOTION_FACTOR * noise:
        return "the body did not turn (the reference's angular rates stay at the gyroscope's noise): move and turn it"
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
        sigma = max(robust_sigma(norm), 1e-9)
        weights = huber_weights(norm, sigma) if k > 0 else np.ones(len(t))
        if k == 0:  # first pass: no reference gyro bias (linear in the rest)
            J = J.copy()
            J[:, :, :3] = 0.0
        sw = np.sqrt(weights)[:, None, None]
        Jw = (J * sw).reshape(-1, 18)
        H = Jw.T @ Jw
        g = Jw.T @ (res[:, :, None] * sw).reshape(-1)
        step = -pinv(H) @ g
        theta = theta + step
        if k > 1 and np.max(np.abs(step[3:6])) < 1e-9:
            break
    res, J = _position_rows(theta, a_j, a_ref, w_fused, dw)
    rho = residual_correlation(res)
    sw = np.sqrt(weights)[:, None, None]
    Jw = (J * sw).reshape(-1, 18)
    H_inv = pinv(Jw.T @ Jw)
    cov = H_inv * sigma**2 * rho
    gauge_jacobian = None
    if ref_jacobian is not None:
        # theta minimises sum w |res|^2, res = ... - a_ref: d theta = H^-1 J^T W d a_ref
        dA = (ref_jacobian[inside] * sw).reshape(-1, ref_jacobian.shape[2])
        gauge_jacobian = (H_inv @ (Jw.T @ dA))[3:6]
    # rotation covariance from the gyroscope equation: d(res_g) = [R w_j]x dphi
    sigma_g = float(np.sqrt(np.mean(res_g**2)))
    A = skew(w_j @ R.T - (w_j @ R.T).mean(axis=0))
    rho_g = residual_correlation(res_g)
    rot_cov = pinv(np.einsum("mji,mjk->ik", A, A)) * sigma_g**2 * rho_g
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
        gauge_jacobian=gauge_jacobian,
    )
