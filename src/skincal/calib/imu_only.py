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

**The absolute scale from rests.** When the body was held still in enough orientations (the
"turn it over" motion of :meth:`skincal.sim.rigid_body.HandMotion.turn_over`), every unit's
accelerometer is fitted to its rests first (:func:`fit_accel_ellipsoid`: ``|C (a - b)| = |g|``, ``C``
symmetric 3x3, i.e. scale and cross-axis terms, and the bias ``b``; 9 unknowns, one equation per
orientation, so 9 distinct orientations at least; 6 give the diagonal scale and the bias). Rests are
found from the gyroscopes (``rest.imu_still_mask``: over a window the rates' spread and their mean less the
bias within noise-derived limits, all units on the body agreeing, :func:`common_rests`). The
reference's calibrated specific force ``C (a_ref - b)`` then replaces ``a_ref`` in the position
equation, so positions come out in metres, and the fit's covariance is carried into the position's
(linearised at the solution). Without enough rests the reference's accelerometer stays the gauge and
a note says how many more orientations are needed.

The covariance is the normal matrix's inverse times the robust residual variance, inflated by the
residuals' autocorrelation (the functions of :mod:`skincal.calib.mle.solver`). A unit whose rates
disagree with the reference's beyond ``other_body_ratio`` of their RMS after the best rotation is on
another rigid body and is reported as failed; rotation about fewer than two axes leaves the rotation
about, and the position along, the one axis undetermined (``observable = False``, named).

Result convention (``docs/interfaces.md``): ``CalibrationResult.reference`` names the reference unit, every
unit's pose is ``T_ref_su`` with ``link = 0`` meaning "the reference unit's frame" (the reference
itself: identity, std 0).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.optimize import minimize_scalar
from scipy.signal import savgol_filter

from skincal.calib.closed_form import wahba
from skincal.calib.model import sym_from_e
from skincal.calib.preprocess import white_noise_std
from skincal.calib.rest import imu_still_mask, runs
from skincal.calib.robust import huber_weights, pinv, residual_correlation, robust_sigma
from skincal.data.dataset import Dataset, ImuStream
from skincal.data.imu_calibration import ImuCalibration
from skincal.data.result import REFERENCE_LINK, CalibrationResult, UnitResult
from skincal.errors import ConfigError, DatasetError
from skincal.kinematics.transforms import FloatArray, nearest_rotation, skew
from skincal.names import name_problem, printable
from skincal.skin.pose import SkinUnitPose

METHOD = "imu-only"
OTHER_BODY_RATIO = 0.2
"""A unit whose gyroscope residual RMS after the best rotation exceeds this fraction of the
reference's rate RMS (centred) moves on another rigid body."""
MIN_AXIS_RATIO = 0.05
"""Rotation about fewer than two axes: the second singular value of the centred rates below this
fraction of the first."""
MIN_MOTION_FACTOR = 3.0
"""The body turned: the reference's centred rate RMS exceeds this multiple of the gyroscope's noise."""
NOISE_FLOOR = 1e-4
"""Smallest noise std assumed for the rest tests (rad/s, m/s^2): noise-free data still rest, and the
windowed variances' round-off (sums of squares of ~10 m/s^2) stays far below the limits."""
REST_GUARD_S = 0.05
"""Cut from both ends of a rest (beyond the window's reach: the units' stamp offsets), s."""
MIN_REST_S = 0.4
"""Shortest rest used for the accelerometers, s (after the guard)."""
DISTINCT_DEG = 15.0
"""Rests whose gravity directions are closer than this count as one orientation, deg."""
ORIENTATIONS_FULL = 9
"""Distinct orientations needed for the symmetric (scale and cross-axis) fit: 6 + 3 unknowns."""
ORIENTATIONS_DIAGONAL = 6
"""Distinct orientations needed for the diagonal scale and the bias: 3 + 3 unknowns."""
ORIENTATIONS_ADVISED = 12
"""Distinct orientations a user is asked for (the symmetric fit's 9 and a margin for its conditioning)."""
MAX_SCALE_STD = 0.01
"""A fit whose scale or cross-axis std exceeds this (orientations too alike) is not used."""


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


@dataclass(frozen=True)
class AccelFit:
    """One accelerometer fitted to its rests: the specific force is ``C (a - b)``.

    Attributes:
        C: ``(3, 3)`` symmetric correction (the inverse of the scale and cross-axis matrix, up to a
            rotation that an ellipsoid cannot see; identity-like), ``b``: ``(3,)`` bias, m/s^2.
        cov: ``(9, 9)`` covariance of ``p = [C11, C22, C33, C12, C13, C23, b1, b2, b3]`` (zero rows
            for the cross-axis terms of the diagonal model).
        model: ``"symmetric"`` or ``"diagonal"``.
        rests, orientations: rests used and how many distinct gravity directions they have.
        residual_std: RMS of ``|C (a - b)| - |g|`` over the rests, m/s^2.
    """

    C: FloatArray
    b: FloatArray
    cov: FloatArray
    model: str
    rests: int
    orientations: int
    residual_std: float

    def apply(self, accel: FloatArray) -> FloatArray:
        """Calibrated specific force ``(M, 3)`` of raw readings ``accel`` ``(M, 3)``."""
        return (accel - self.b) @ self.C.T

    def jacobian(self, accel: FloatArray) -> FloatArray:
        """``(M, 3, 9)`` derivative of :meth:`apply` with respect to ``p``."""
        y = accel - self.b
        J = np.zeros((len(y), 3, 9))
        for i in range(3):
            J[:, i, i] = y[:, i]
        for k, (i, j) in enumerate(_OFF_DIAGONAL):
            J[:, i, 3 + k] = y[:, j]
            J[:, j, 3 + k] = y[:, i]
        J[:, :, 6:] = -self.C
        return J

    @property
    def scale_std(self) -> float:
        """Largest std of the entries of ``C`` (dimensionless)."""
        return float(np.sqrt(np.max(np.diag(self.cov)[:6])))

    def imu_calibration(self) -> ImuCalibration:
        """As :class:`~skincal.data.imu_calibration.ImuCalibration`: ``A = C^-1`` and the bias."""
        bias_std = np.sqrt(np.maximum(np.diag(self.cov)[6:], 0.0))
        return ImuCalibration(accel_bias_mps2=self.b.copy(), accel_bias_std_mps2=bias_std,
                              accel_scale_misalignment=np.linalg.inv(self.C))  # fmt: skip


_OFF_DIAGONAL = ((0, 1), (0, 2), (1, 2))


def common_rests(streams: dict[str, ImuStream], reference: str) -> FloatArray:
    """``(S, 2)`` start and end (reference stamps, s) of the rests of the body: where the reference is
    still (``rest.imu_still_mask``) and so is every other unit that is still for at least half of that time
    (the units on the reference's body; a unit on another body moves on), less ``REST_GUARD_S`` at both
    ends, at least ``MIN_REST_S`` long."""
    ref = streams[reference]
    assert ref.gyro is not None
    common = imu_still_mask(ref.t, ref.gyro, ref.accel)
    total = max(int(common.sum()), 1)
    for name, stream in streams.items():
        if name == reference or stream.gyro is None or len(stream.t) < 10:
            continue
        mine = imu_still_mask(stream.t, stream.gyro, stream.accel)
        i = np.clip(np.searchsorted(stream.t, ref.t), 1, len(stream.t) - 1)
        i -= (ref.t - stream.t[i - 1]) < (stream.t[i] - ref.t)
        at_ref = mine[i]
        if np.count_nonzero(at_ref & common) >= 0.5 * total:
            common &= at_ref
    out = []
    for a, b in runs(common):
        t0, t1 = ref.t[a] + REST_GUARD_S, ref.t[b - 1] - REST_GUARD_S
        if t1 - t0 >= MIN_REST_S:
            out.append((t0, t1))
    return np.array(out, dtype=float).reshape(-1, 2)


def rest_means(stream: ImuStream, rests: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Per rest ``(S, 2)``: the mean acceleration ``(S, 3)``, the sample count ``(S,)`` and the
    within-rest variance ``(S, 3)`` of one unit."""
    means, counts, var = [], [], []
    for t0, t1 in rests:
        a = stream.accel[(stream.t >= t0) & (stream.t <= t1)]
        if len(a) < 3:
            a = np.full((3, 3), np.nan)
        means.append(a.mean(axis=0))
        counts.append(len(a))
        var.append(a.var(axis=0, ddof=1))
    return np.array(means).reshape(-1, 3), np.array(counts, dtype=float), np.array(var).reshape(-1, 3)


def distinct_orientations(directions: FloatArray, deg: float = DISTINCT_DEG) -> int:
    """How many of the gravity directions ``(S, 3)`` differ by more than ``deg`` from each other
    (greedy: each direction joins the first earlier one within ``deg``)."""
    unit = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    kept: list[FloatArray] = []
    for u in unit:
        if all(float(u @ v) < math.cos(math.radians(deg)) for v in kept):
            kept.append(u)
    return len(kept)


def _ellipsoid_start(means: FloatArray, gravity: float, model: str) -> tuple[FloatArray, FloatArray] | None:
    """Algebraic fit of ``(a - b)^T Q (a - b) = g^2`` (linear in ``Q``, ``-2 Q b``, a constant; the
    smallest singular vector), ``C = Q^(1/2)``; None when the quadric is no ellipsoid."""
    a = means
    quad = [a[:, 0] ** 2, a[:, 1] ** 2, a[:, 2] ** 2]
    if model == "symmetric":
        quad += [2 * a[:, i] * a[:, j] for i, j in _OFF_DIAGONAL]
    D = np.column_stack([*quad, a, np.ones(len(a))])
    scale = np.linalg.norm(D, axis=0)
    z = np.linalg.svd(D / scale, full_matrices=False)[2][-1] / scale
    nq = len(quad)
    Q = sym_from_e(np.concatenate([z[:nq], np.zeros(6 - nq)]))
    L, k = z[nq : nq + 3], z[-1]
    eig = np.linalg.eigvalsh(Q)
    if eig[0] * eig[-1] <= 0:
        return None
    if eig[0] < 0:
        Q, L, k = -Q, -L, -k
    b = -0.5 * np.linalg.solve(Q, L)
    denom = float(b @ Q @ b - k)
    if denom <= 0:
        return None
    w, V = np.linalg.eigh(Q * gravity**2 / denom)
    return (V * np.sqrt(w)) @ V.T, b


def fit_accel_ellipsoid(
    means: FloatArray,
    counts: FloatArray,
    noise_var: FloatArray,
    gravity: float,
    model: str = "symmetric",
    iterations: int = 30,
) -> AccelFit | None:
    """Fit ``|C (m_k - b)| = gravity`` to rest means ``m_k`` ``(S, 3)`` (``counts`` ``(S,)`` samples,
    per-axis sample noise variance ``noise_var`` ``(3,)``): the algebraic start, then Gauss-Newton
    weighted by each mean's std along gravity; ``model`` ``"symmetric"`` (``C`` 3x3 symmetric) or
    ``"diagonal"``. The covariance is the weighted normal matrix's inverse, inflated by the reduced
    chi-square when it exceeds 1 and there are 3 or more redundant rests. None without an ellipsoid."""
    need = ORIENTATIONS_FULL if model == "symmetric" else ORIENTATIONS_DIAGONAL
    ok = np.all(np.isfinite(means), axis=1)
    means, counts = means[ok], counts[ok]
    if len(means) < need:
        return None
    start = _ellipsoid_start(means, gravity, model)
    if start is None:
        return None
    C, b = start
    free = np.ones(9, dtype=bool)
    if model == "diagonal":
        free[3:6] = False
        C = np.diag(np.diag(C))
    p = np.concatenate([np.diag(C), [C[i, j] for i, j in _OFF_DIAGONAL], b])
    H = np.eye(9)
    e = np.zeros(len(means))
    for _ in range(iterations):
        fit = AccelFit(sym_from_e(p[:6]), p[6:], np.zeros((9, 9)), model, len(means), 0, 0.0)
        f = fit.apply(means)
        norm = np.linalg.norm(f, axis=1)
        n = f / norm[:, None]
        e = norm - gravity
        sigma2 = np.einsum("si,ij,sj->s", n @ fit.C, np.diag(noise_var), n @ fit.C) / counts
        J = np.einsum("si,sip->sp", n, fit.jacobian(means))[:, free]
        Jw = J / np.sqrt(sigma2)[:, None]
        H = Jw.T @ Jw
        step = -np.linalg.lstsq(Jw, e / np.sqrt(sigma2), rcond=None)[0]
        p[free] += step
        if np.max(np.abs(step)) < 1e-12:
            break
    dof = len(means) - int(free.sum())
    chi2 = float(np.sum(e**2 / sigma2))
    inflate = max(1.0, chi2 / dof) if dof >= 3 else 1.0
    cov = np.zeros((9, 9))
    cov[np.ix_(free, free)] = pinv(H) * inflate
    return AccelFit(sym_from_e(p[:6]), p[6:], cov, model, len(means), distinct_orientations(means),
                    float(np.sqrt(np.mean(e**2))))  # fmt: skip


def fit_unit_accelerometer(stream: ImuStream, rests: FloatArray, gravity: float) -> tuple[AccelFit | None, int]:
    """The best identifiable accelerometer fit of one unit over ``rests`` (symmetric with
    ``ORIENTATIONS_FULL`` distinct orientations, diagonal with ``ORIENTATIONS_DIAGONAL``, none below; a
    fit whose scale std exceeds ``MAX_SCALE_STD`` is refused) and the number of distinct orientations."""
    means, counts, var = rest_means(stream, rests)
    ok = np.all(np.isfinite(means), axis=1)
    if not ok.any():
        return None, 0
    distinct = distinct_orientations(means[ok])
    noise_var = np.maximum(np.median(var[ok], axis=0), NOISE_FLOOR**2)
    for model, need in (("symmetric", ORIENTATIONS_FULL), ("diagonal", ORIENTATIONS_DIAGONAL)):
        if distinct < need:
            continue
        fit = fit_accel_ellipsoid(means, counts, noise_var, gravity, model)
        if fit is not None and fit.scale_std <= MAX_SCALE_STD:
            return fit, distinct
    return None, distinct


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


@dataclass(frozen=True)
class RelativeOptions:
    """Options of :func:`calibrate_relative` (``skincal calibrate --reference UNIT --option name=value``),
    parsed by :func:`skincal.calib.options.parse_options` like every method's.

    Attributes:
        max_offset_s: largest time offset between two units' stamps searched, s.
        other_body_ratio: angular-velocity misfit (relative) above which a unit is on another body.
        reference_scale_std, reference_misalignment_std: the reference accelerometer's uncalibrated
            per-axis scale and cross-axis error (used when the rests do not calibrate it).
    """

    max_offset_s: float = field(default=1.0, metadata={"min": 0.0})
    other_body_ratio: float = field(default=OTHER_BODY_RATIO, metadata={"min": 0.0})
    reference_scale_std: float = field(default=0.0, metadata={"min": 0.0, "max": 0.999})
    reference_misalignment_std: float = field(default=0.0, metadata={"min": 0.0, "max": 0.999})


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

    When the body rests in enough distinct orientations (module docstring), the reference's accelerometer
    is fitted to the rests and positions come out in metres, with the fit's std in theirs. Otherwise the
    reference accelerometer is the gauge of every position (its scale error ``s`` makes
    ``r_est = (1 + s) r``): ``reference_scale_std`` and ``reference_misalignment_std`` (the size of its
    uncalibrated per-axis scale error and symmetric cross-axis error, e.g. 0.03 and 0.01 for the
    ``real`` IMU preset) add that to the position std; 0 (default) takes the reference as exact. With
    the diagonal fit (6-8 orientations) only ``reference_misalignment_std`` is added.

    Returns a :class:`~skincal.data.result.CalibrationResult` with ``method = "imu-only"``,
    ``reference``, ``extras["accel_scale_fit"]`` (the rests' fit of the reference's
    accelerometer: model, rests, distinct orientations, a note) and per unit ``T_ref_su`` at ``link = 0``
    (with ``imu``: its accelerometer fitted to the rests, when they allow it); units on another rigid
    body (or without a gyroscope) are in ``failed_units`` with the reason.
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
    gravity = float(np.linalg.norm(dataset.gravity))
    streams = {name: dataset.imu[name] for name in dict.fromkeys([reference, *names])}
    rests = common_rests(streams, reference) if len(ref.t) >= 50 else np.zeros((0, 2))
    accel_fits: dict[str, AccelFit] = {}
    for name, stream in streams.items():
        fit_a, _ = fit_unit_accelerometer(stream, rests, gravity)
        if fit_a is not None:
            accel_fits[name] = fit_a
    ref_fit = accel_fits.get(reference)
    ref_distinct = distinct_orientations(rest_means(ref, rests)[0]) if len(rests) else 0
    gauge = _gauge_notes(reference, ref_fit, len(rests), ref_distinct, gravity)
    ref_jacobian = None
    if ref_fit is not None:
        ref_jacobian = ref_fit.jacobian(ref.accel)
        ref = replace(ref, accel=ref_fit.apply(ref.accel))
    out: dict[str, UnitResult] = {}
    failed: dict[str, str] = {}
    for name in names:
        imu = accel_fits[name].imu_calibration() if name in accel_fits else None
        if name == reference:
            out[name] = UnitResult(
                SkinUnitPose(REFERENCE_LINK, np.eye(3), np.zeros(3)),
                position_std_m=np.zeros(3),
                rotation_std_deg=np.zeros(3),
                extras={"link_name": f"{reference} (reference)"},
                imu=imu,
            )
            continue
        fit = fit_relative(
            ref, dataset.imu[name], max_offset_s=max_offset_s, other_body_ratio=other_body_ratio,
            ref_jacobian=ref_jacobian,
        )  # fmt: skip
        if isinstance(fit, str):
            failed[name] = fit
            continue
        r2 = fit.r**2
        if ref_fit is None:  # the reference accelerometer is the gauge
            extra = np.diag(reference_scale_std**2 * r2 + reference_misalignment_std**2 * (r2.sum() - r2))
        else:
            assert fit.gauge_jacobian is not None
            extra = fit.gauge_jacobian @ ref_fit.cov @ fit.gauge_jacobian.T
            if ref_fit.model == "diagonal":  # cross-axis terms not fitted
                extra = extra + np.diag(reference_misalignment_std**2 * (r2.sum() - r2))
        fit = replace(fit, position_cov=fit.position_cov + extra)
        out[name] = _unit_result(fit, reference, gauge, imu)
    robot = dataset.robot.name if dataset.robot is not None else "none"
    accel_scale_fit = {
        "model": ref_fit.model if ref_fit is not None else "none",
        "rests": int(len(rests)),
        "orientations": int(ref_distinct),
        "note": gauge[-1],
    }
    return CalibrationResult(
        METHOD, robot, dataset_sha256, time.perf_counter() - start, out, {"accel_scale_fit": accel_scale_fit},
        failed_units=failed, reference=reference,
    )  # fmt: skip


def _gauge_notes(reference: str, fit: AccelFit | None, rests: int, distinct: int, gravity: float) -> list[str]:
    """What sets the positions' scale, and (last) what the rests gave or what is missing."""
    found = f"{rests} rest(s) in {distinct} distinct orientation(s)"
    if fit is not None and fit.model == "symmetric":
        return [
            f"position in metres: {reference}'s accelerometer scale and cross-axis terms fitted to {found} "
            f"(|g| = {gravity:.4g} m/s^2; scale std {100 * fit.scale_std:.2g} %)",
            f"accelerometer scale fitted from {found}",
        ]
    more_full = max(ORIENTATIONS_FULL - distinct, 1)
    if fit is not None:
        return [
            f"position in metres: {reference}'s accelerometer scale fitted to {found}, its cross-axis terms "
            "not (their size, reference_misalignment_std, is in the std)",
            f"accelerometer scale fitted from {found}; {more_full} more orientation(s) would fit the cross-axis "
            "terms too",
        ]
    more = max(ORIENTATIONS_ADVISED - distinct, 1)
    if distinct >= ORIENTATIONS_DIAGONAL:
        missing = (
            f"{found}: too few or too alike to fit the accelerometer's scale to {100 * MAX_SCALE_STD:g} %; hold the "
            f"body still for 1-2 s in {more} more orientation(s), spread over the sphere (face up, face down, on "
            "each edge)"
        )
    else:
        missing = (
            f"{found}: the accelerometer's scale needs {ORIENTATIONS_FULL} (at least {ORIENTATIONS_DIAGONAL}) "
            f"distinct orientations; hold the body still for 1-2 s in {more} more, spread over the sphere "
            "(face up, face down, on each edge)"
        )
    return [
        f"position in the scale of {reference}'s accelerometer (its scale error carries over to the position)",
        missing,
    ]


def _unit_result(fit: RelativeFit, reference: str, notes: list[str], imu: ImuCalibration | None) -> UnitResult:
    pos_std = np.sqrt(np.maximum(np.diag(fit.position_cov), 0.0))
    rot_std = np.degrees(np.sqrt(np.maximum(np.diag(fit.rotation_cov), 0.0)))
    warnings: list[str] = []
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
    }
    return UnitResult(
        SkinUnitPose(REFERENCE_LINK, nearest_rotation(fit.R), fit.r),
        observable=observable,
        position_std_m=pos_std,
        rotation_std_deg=rot_std,
        warnings=tuple(warnings),
        extras=extras,
        imu=imu,
        notes=tuple(notes),
    )


def compare_with_joint_result(relative: CalibrationResult, joint: CalibrationResult) -> dict[str, tuple[float, float]]:
    """Disagreement of an IMU-only result with a joint-based one (e.g. ``mle``) of the same units:
    unit -> ``(position mm, rotation deg)`` of ``T_ref_su`` against ``T_link_ref^-1 T_link_su`` from
    ``joint``, for the units that ``joint`` puts on the reference unit's link (others: not comparable)."""
    reference = relative.reference
    if reference is None or reference not in joint.units:
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
    reference = result.reference
    if reference is None:
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
