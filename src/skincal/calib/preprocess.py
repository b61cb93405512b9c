"""Shared preprocessing of a dataset for every calibration method.

Real robots report ``q`` and ``qd`` on their own clock; IMUs sample on theirs. This module
estimates joint accelerations, interpolates the joint states to each IMU sample instant, tags
every IMU sample with its protocol segment and averages the static segments.

Frames: accelerometer samples are specific force in the unit frame (``f = R_base_su^T (a - g)``);
joint states are in rad, rad/s, rad/s^2; times in s on the dataset's common clock.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import make_smoothing_spline
from scipy.ndimage import maximum_filter1d, uniform_filter1d
from scipy.signal import savgol_coeffs, savgol_filter

from skincal.data.dataset import DYNAMIC, STATIC, Dataset, JointStates, Segments
from skincal.errors import CalibrationError
from skincal.kinematics.transforms import FloatArray

DEFAULT_QDD_WINDOW_S = 0.05
"""Savitzky-Golay window used to estimate joint accelerations from velocities, s."""


def estimate_qdd(
    joints: JointStates, window_s: float = DEFAULT_QDD_WINDOW_S
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Joint accelerations from the reported velocities by a Savitzky-Golay derivative.

    The joint stream is first put on a uniform grid (its median period) when its sampling is
    uneven. The derivative is a cubic local fit over ``window_s`` (an odd number of samples, at
    least 5): ``qdd(t_i) = d/dt [poly fit of qd over t_i +- window/2]``.

    Returns:
        ``(t, qd, qdd)`` on the (possibly resampled) grid, shapes ``(N,)``, ``(N, n)``, ``(N, n)``.
    """
    t = np.asarray(joints.t, dtype=float)
    qd = np.asarray(joints.qd, dtype=float)
    if t.shape[0] < 7:
        raise CalibrationError(f"joint stream has {t.shape[0]} samples; at least 7 are needed to estimate qdd")
    dt = float(np.median(np.diff(t)))
    if np.max(np.abs(np.diff(t) - dt)) > 0.01 * dt:
        grid = t[0] + dt * np.arange(int(np.floor((t[-1] - t[0]) / dt)) + 1)
        qd = np.column_stack([np.interp(grid, t, qd[:, j]) for j in range(qd.shape[1])])
        t = grid
    window = max(5, int(round(window_s / dt)) | 1)  # odd, at least 5
    if window > t.shape[0]:
        window = t.shape[0] if t.shape[0] % 2 else t.shape[0] - 1
    qdd = savgol_filter(qd, window, polyorder=3, deriv=1, delta=dt, axis=0, mode="interp")
    return t, qd, qdd


@dataclass(frozen=True)
class JointConditioning:
    """What :func:`condition_joint_stream` did to a joint stream.

    Attributes:
        source: ``"velocities"`` (qdd from the reported qd) or ``"positions"`` (qd and qdd from q).
        regularised_stamps: the stamps were replaced by a fitted regular grid.
        stamp_jitter_s: std of the stamps about that grid, s (0 when not tested).
        position_noise: ``(n,)`` noise std of the positions, rad; ``velocity_noise``: of the velocities, rad/s.
        qdd_noise: expected std of the acceleration estimate, rad/s^2, from the chosen source.
    """

    source: str = "velocities"
    regularised_stamps: bool = False
    stamp_jitter_s: float = 0.0
    position_noise: FloatArray | None = None
    velocity_noise: FloatArray | None = None
    qdd_noise: float = 0.0
    unreliable: np.ndarray | None = None
    """``(N,)`` True on the stream's samples where the acceleration estimate is unreliable."""
    qdd_variance: FloatArray | None = None
    """``(N, n)`` variance of the acceleration estimate on the conditioned stream's stamps,
    rad^2/s^4 (m^2/s^4 for a prismatic joint): the interpolation error between a low-rate
    stream's reports (:func:`spline_condition`); ``None`` when the stream resolves its motion
    (the kink test then marks the few places it does not)."""
    report_rate_hz: float = 0.0
    """Median rate of the reported stream, Hz (0 when not measured)."""


LOW_RATE_HZ = 60.0
"""A joint stream reported more slowly than this (median rate) is conditioned by smoothing splines
(:func:`spline_condition`): its samples are too far apart for a local fit over
:data:`DEFAULT_QDD_WINDOW_S` (which then spans only the 5-sample minimum, ~0.1-0.5 s), and the kink
test of such a fit rejects most of a general motion."""
IRREGULAR_SPREAD = 0.25
"""...and so is a stream whose stamps fit no regular grid and whose spacing varies by more than
this fraction of its median (std): resampling it linearly would smear its accelerations."""
FINE_RATE_HZ = 250.0
"""Rate of the uniform grid a spline-conditioned stream is evaluated on, Hz (the link-signal table
then takes every second sample, 125 Hz)."""
ERROR_ORDER_RANGE = (1.0, 4.0)
"""Range of the convergence order ``p`` (:func:`spline_condition`) the acceleration error is
extrapolated with."""


def is_low_rate(t: FloatArray) -> bool:
    """Whether stamps ``t`` ``(N,)`` are those of a low-rate stream (median rate below
    :data:`LOW_RATE_HZ`) or of an irregular one slower than :data:`FINE_RATE_HZ` (spacing std above
    :data:`IRREGULAR_SPREAD` of its median and no regular grid under it, :func:`regular_grid`).
    Judged from the stamps alone."""
    d = np.diff(np.asarray(t, dtype=float))
    dt = float(np.median(d))
    if dt <= 0:
        return False
    if 1.0 / dt < LOW_RATE_HZ:
        return True
    if 1.0 / dt >= FINE_RATE_HZ:  # as fast as the splines' own grid: linear resampling smears nothing they
        return False  # would resolve (a jittered 1 kHz stream took minutes of smoothing splines per block)
    return float(np.std(d)) > IRREGULAR_SPREAD * dt and regular_grid(np.asarray(t, dtype=float)) is None


def spline_condition(joints: JointStates) -> tuple[JointStates, JointConditioning]:
    """A low-rate or irregular joint stream as smoothing splines of its positions, evaluated on a
    uniform :data:`FINE_RATE_HZ` grid, with the variance of the accelerations they give.

    Each joint's positions ``q_j(t_i)`` (the reported velocities of such streams are usually
    differences of the positions and add nothing) are fitted by the cubic smoothing spline
    ``s_j = argmin sum_i (q_j(t_i) - s(t_i))^2 + lam int s''^2`` over the stamps as they are
    (:func:`scipy.interpolate.make_smoothing_spline`, ``lam`` by generalised cross-validation);
    ``q, qd, qdd`` are ``s, s', s''`` on the grid.

    Error of ``s''`` between the reports, from the data themselves: the same fit on every second
    (and every third) report only gives ``s''_2`` (``s''_3``); with an error ``e(h) ~ h^p`` of the
    report spacing ``h``, ``s''_k - s'' ~ (k^p - 1) e(h)``. ``p`` is solved from the ratio of the
    two differences' rms per joint (clipped to :data:`ERROR_ORDER_RANGE`: 1 when the half-rate
    stream no longer resolves the motion, the conservative end) and the local variance is
    ``var(t) = <(s''_2 - s'')^2> / (2^p - 1)^2``, averaged over both half streams and over one
    report spacing. It carries the acceleration the reports do not resolve (corners, stops), the
    stamps' jitter that the spline did not smooth away, and gaps (larger where reports are far apart).
    It is an estimate of the error's size, not a bound: on smooth simulated motion at 13 Hz it is
    within a factor 2 of the true error (``tests/calib/test_real_streams.py``); on the real 14 Hz
    tool-pose streams tried, ``p`` came out at 1 (the half-rate stream no longer resolves the
    motion) and the std at 60-80 % of the accelerations' rms.
    """
    t = np.asarray(joints.t, dtype=float)
    q = np.asarray(joints.q, dtype=float)
    dt_report = float(np.median(np.diff(t)))
    step = 1.0 / FINE_RATE_HZ
    grid = t[0] + step * np.arange(int(np.floor((t[-1] - t[0]) / step)) + 1)
    n = q.shape[1]
    qf, qdf, qddf, var = (np.empty((grid.size, n)) for _ in range(4))
    sigma_q = np.empty(n)
    width = max(1, int(round(dt_report / step)))
    lo, hi = ERROR_ORDER_RANGE
    for j in range(n):
        s = _smoothing_spline(t, q[:, j])
        qf[:, j], qdf[:, j], qddf[:, j] = s(grid), s(grid, 1), s(grid, 2)
        sigma_q[j] = float(np.std(q[:, j] - s(t)))
        if np.ptp(q[:, j]) == 0.0:
            var[:, j] = 0.0
            continue
        d2 = np.mean([(_smoothing_spline(t[k::2], q[k::2, j])(grid, 2) - qddf[:, j]) ** 2 for k in range(2)], axis=0)
        d3 = np.mean([(_smoothing_spline(t[k::3], q[k::3, j])(grid, 2) - qddf[:, j]) ** 2 for k in range(3)], axis=0)
        ratio = float(np.sqrt(np.mean(d3) / max(float(np.mean(d2)), 1e-300)))
        p = _error_order(ratio, lo, hi)
        var[:, j] = uniform_filter1d(d2, width, mode="nearest") / (2.0**p - 1.0) ** 2
    out = JointStates(t=grid, q=qf, qd=qdf, qdd=qddf)
    noise = float(np.sqrt(np.max(np.median(var, axis=0))))
    return out, JointConditioning(
        source="spline",
        position_noise=sigma_q,
        velocity_noise=np.asarray(joint_noise(qf, qdf)[1]),
        qdd_noise=noise,
        qdd_variance=var,
        report_rate_hz=1.0 / dt_report,
    )


SMOOTHING_SPAN = 1.0
"""The smoothing spline's equivalent kernel never spans more than this many report spacings ``h``
(see :func:`_smoothing_spline`): its transfer function is ``1 / (1 + (b w)^4)`` for a bandwidth
``b``, so an eighth of the reports' Nyquist frequency, ``w = pi / (8 h)``, loses at most 2.3 %. A
guard only: on the real 14 Hz tool-pose streams tried, cross-validation chose 0.4-1 spacings by
itself, and a tighter cap (0.4) moved the slow paths' lever arm along the tool axis by up to
0.1 m (the data do not pin it)."""


def _smoothing_spline(t: FloatArray, y: FloatArray):  # noqa: ANN202 - a scipy BSpline
    """The cubic smoothing spline of ``y(t)`` with ``lam`` by generalised cross-validation, but never
    smoother than an equivalent kernel of :data:`SMOOTHING_SPAN` report spacings ``h``: its
    bandwidth is ``(lam h)^(1/4)``, so ``lam <= (SMOOTHING_SPAN h)^4 / h``. Cross-validation on
    nearly noise-free positions can pick an enormous ``lam`` (a straight line through a sine);
    the capped fit is taken whenever it leaves the smaller residual (the smoothing is monotonic in
    ``lam``: GCV chose more than the cap)."""
    h = float(np.median(np.diff(t)))
    gcv = make_smoothing_spline(t, y)
    capped = make_smoothing_spline(t, y, lam=(SMOOTHING_SPAN * h) ** 4 / h)
    r_gcv = float(np.sum((gcv(t) - y) ** 2))
    r_cap = float(np.sum((capped(t) - y) ** 2))
    return capped if r_cap < r_gcv else gcv


def _error_order(ratio: float, lo: float, hi: float) -> float:
    """``p`` with ``(3^p - 1) / (2^p - 1) = ratio`` (the ratio grows with ``p`` from ~1.58 at
    ``p -> 0``), clipped to ``[lo, hi]``; bisection (the function is monotonic)."""
    f = lambda p: (3.0**p - 1.0) / (2.0**p - 1.0)  # noqa: E731
    if ratio <= f(lo):
        return lo
    if ratio >= f(hi):
        return hi
    a, b = lo, hi
    for _ in range(60):
        m = 0.5 * (a + b)
        a, b = (m, b) if f(m) < ratio else (a, m)
    return 0.5 * (a + b)


MAX_REFILL = 4
"""A regularised joint stream's lost samples are refilled (cubic Hermite of q, qd) when no gap is
longer than this many periods; longer gaps keep the stream uneven."""
POSITION_POLYORDER = 5
"""Polynomial order of the position fits. A cubic fit's second derivative is exact only to degree
3 and attenuates a 1 Hz excitation by 0.17 % over 50 ms (measured), enough to shift a unit by
0.7 mm through the link origin's acceleration; order 5 is exact to degree 5 (the error drops to
~1e-6) at a few times the (tiny) encoder noise."""
KINK_FACTOR = 3.0
"""A local fit whose residual exceeds this many noise std (plus a floor) marks a kink (a step of qdd)."""
KINK_FLOOR = {"positions": 1e-6, "velocities": 1e-4}
"""Residual floors of that test: rad (positions) and rad/s (velocities), well below any kink that
matters (a qdd step of ~0.05 rad/s^2 over a 50 ms window)."""


def _kinks(x: FloatArray, window: int, sigma: FloatArray, floor: float) -> np.ndarray:
    """Samples within half a window of a place where ``x`` ``(N, n)`` is not locally cubic: the rms
    residual of the cubic Savitzky-Golay fit over the window exceeds ``KINK_FACTOR sigma + floor``.
    There an acceleration step (a protocol's excitation starting at full acceleration, a stop)
    makes any smoothed derivative wrong for about half a window on each side."""
    r = x - savgol_filter(x, window, 3, axis=0, mode="interp")
    rms = np.sqrt(np.maximum(uniform_filter1d(r * r, window, axis=0, mode="nearest"), 0.0))
    bad = np.any(rms > KINK_FACTOR * sigma + floor, axis=1)
    return maximum_filter1d(bad.astype(np.int8), window, mode="nearest") > 0


NOISE_SAMPLES = 50_000
"""Differences used by :func:`white_noise_std` (evenly strided over the stream): the MAD of 50 000
samples is within 0.5 % of the full stream's."""


def white_noise_std(x: FloatArray, order: int = 2, where: np.ndarray | None = None) -> FloatArray:
    """Robust white-noise std per column of ``x`` ``(N, k)`` from its ``order``-th differences.

    They cancel any polynomial signal of lower degree and have variance ``C(2 order, order)
    sigma^2`` for white noise; the MAD makes the estimate ignore the samples where the signal
    curves more (motion starts and stops): ``sigma = 1.4826 MAD(diff) / sqrt(C(2 order, order))``.
    ``where`` ``(N, k)``: only differences whose samples are all marked count (e.g. a joint while it
    moves: an encoder at rest repeats its count and would read as noise-free).
    """
    x = np.asarray(x, dtype=float)
    if x.shape[0] <= order:
        return np.zeros(x.shape[1:])
    # the differences at evenly strided places only (a median needs no more than NOISE_SAMPLES):
    # d_i = sum_k (-1)^(order-k) C(order, k) x_{i+k}
    i = np.arange(0, x.shape[0] - order, max(1, (x.shape[0] - order) // NOISE_SAMPLES))
    d = sum((-1) ** (order - k) * math.comb(order, k) * x[i + k] for k in range(order + 1))
    if where is None:
        mad = np.median(np.abs(d - np.median(d, axis=0)), axis=0)
    else:
        ok = np.all(np.stack([np.asarray(where)[i + k] for k in range(order + 1)]), axis=0)
        mad = np.array([
            np.median(np.abs(c[m] - np.median(c[m]))) if np.count_nonzero(m) >= 10 else 0.0
            for c, m in zip(d.T, ok.T, strict=True)
        ])
    return 1.4826 * mad / np.sqrt(float(math.comb(2 * order, order)))


def joint_noise(q: FloatArray, qd: FloatArray) -> tuple[FloatArray, FloatArray]:
    """White-noise std per joint of reported positions (rad) and velocities (rad/s), ``(n,)`` each.

    Positions from third differences, velocities from second differences taken where the joint
    moves (an encoder at rest repeats its count, and velocities a driver differentiates from the
    counts are then exactly zero: a MAD over those would read as noise-free). A quantised signal's
    rounding, step / sqrt(12), is the floor of both (velocities differentiated from counts are
    quantised in steps of LSB / dt).
    """
    q = np.asarray(q, dtype=float)
    qd = np.asarray(qd, dtype=float)
    sigma_v = np.maximum(white_noise_std(qd, 2, where=np.abs(qd) > 1e-12), _smallest_step(qd) / np.sqrt(12.0))
    sigma_q = np.maximum(white_noise_std(q, 3), _smallest_step(q) / np.sqrt(12.0))
    return sigma_q, sigma_v


def _smallest_step(x: FloatArray) -> FloatArray:
    """Smallest non-zero change between neighbouring samples per column of ``x`` ``(N, k)`` (the
    quantisation step of a quantised signal; tiny for a smooth one)."""
    d = np.abs(np.diff(np.asarray(x, dtype=float), axis=0))
    return np.array([np.min(c[c > 1e-12]) if np.any(c > 1e-12) else 0.0 for c in d.T])


def _line(x: FloatArray, y: FloatArray) -> tuple[float, float]:
    """Least-squares slope and intercept of ``y = a + b x``."""
    xm, ym = float(x.mean()), float(y.mean())
    b = float(np.dot(x - xm, y - ym) / np.dot(x - xm, x - xm))
    return b, ym - b * xm


def regular_grid(t: FloatArray, chunk: int = 200) -> tuple[FloatArray, float] | None:
    """A regular grid ``a + b k`` fitted to stamps ``t`` that jitter around one (``k`` the sample's
    grid index; dropped samples allowed), and the stamps' std about it; ``None`` when ``t`` is not
    such a stream.

    Indices are assigned chunk by chunk (within ``chunk`` samples the median period cannot drift by
    a period) and chunks are linked through their mean residuals, so that neither a slightly wrong
    period over a long stream nor one strongly jittered neighbour shifts the indices.
    """
    dt = float(np.median(np.diff(t)))
    one = np.diff(t)
    one = one[(one > 0.5 * dt) & (one < 1.5 * dt)]  # single periods only: lost samples lengthen the median
    dt = float(np.mean(one)) if one.size else dt
    k = np.empty(t.size)
    offset, prev_base = 0.0, None
    for a in range(0, t.size, chunk):
        tc = t[a : a + chunk]
        kc = np.rint((tc - tc[0]) / dt)
        base = float(np.mean(tc - dt * kc))  # the chunk's grid origin, jitter averaged out...
        kc = np.rint((tc - base) / dt)  # ...so that each index depends on its own stamp's jitter only
        base = float(np.mean(tc - dt * kc))
        if prev_base is not None:
            offset += float(np.rint((base - prev_base) / dt))
        k[a : a + chunk] = kc + offset
        prev_base = base
    b, a0 = _line(k, t)
    k = np.rint((t - a0) / b)  # with the fitted period, reassign once and refit
    for i in np.flatnonzero(np.diff(k) < 1):  # a stamp jittered past half a period: move the further one
        r0, r1 = t[i] - (a0 + b * k[i]), t[i + 1] - (a0 + b * k[i + 1])
        if abs(r0) > abs(r1):
            k[i] -= 1
        else:
            k[i + 1] += 1
    if np.any(np.diff(k) < 1):
        return None
    b, a0 = _line(k, t)
    grid = a0 + b * k
    jitter = float(np.std(t - grid))
    return (grid, jitter) if jitter < 0.25 * dt else None


def condition_joint_stream(
    joints: JointStates, window_s: float = DEFAULT_QDD_WINDOW_S
) -> tuple[JointStates, JointConditioning]:
    """Put jittered stamps back on their grid and derive ``qd``, ``qdd`` from the positions when
    they are the better source (see :class:`JointInterpolator`).

    Stamps: when they jitter around a regular grid, the positions are compared with the reported
    velocities on both time bases (finite-difference speed minus the mean reported speed of each
    interval); the grid is kept when it agrees better (the controller sampled regularly and only
    the stamps jitter). Source: the expected noise of a cubic Savitzky-Golay acceleration over
    ``window_s`` is ``sigma_v |c_1| / dt`` from the velocities and ``sigma_q |c_2| / dt^2`` from the
    positions (``c_k`` the filter's k-th derivative coefficients; order 5 for positions, see
    :data:`POSITION_POLYORDER`); the smaller wins. Positions'
    noise includes the encoder step's rounding (step / sqrt(12)).
    """
    t = np.asarray(joints.t, dtype=float)
    if t.shape[0] >= 7 and is_low_rate(t):
        return spline_condition(joints)
    q = np.asarray(joints.q, dtype=float)
    qd = np.asarray(joints.qd, dtype=float)
    dt = float(np.median(np.diff(t)))
    regularised, jitter = False, 0.0
    if np.max(np.abs(np.diff(t) - dt)) > 0.01 * dt:
        fitted = regular_grid(t)
        if fitted is not None:
            grid, jitter = fitted
            ref = 0.5 * (qd[1:] + qd[:-1])
            err_t = np.diff(q, axis=0) / np.diff(t)[:, None] - ref
            err_g = np.diff(q, axis=0) / np.diff(grid)[:, None] - ref
            if np.sum(err_g**2) < np.sum(err_t**2):
                t, regularised = grid, True
                dt = float(np.median(np.diff(t)))
    if regularised:  # refill single lost samples of the grid (a few periods at most) from their neighbours
        whole = np.rint(np.diff(t) / dt)
        if 1 < whole.max() <= MAX_REFILL:
            full = t[0] + dt * np.arange(int(whole.sum()) + 1)
            q = cubic_hermite(t, q, qd, full)
            qd = np.column_stack([np.interp(full, t, c) for c in qd.T])
            t = full
    uniform = np.max(np.abs(np.diff(t) - dt)) <= 0.01 * dt
    sigma_q, sigma_v = joint_noise(q, qd)
    window = max(5, int(round(window_s / dt)) | 1)
    window_q = max(window, (POSITION_POLYORDER + 2) | 1)  # an order-5 fit needs 7 samples or more
    noise_v = float(np.max(sigma_v)) * np.linalg.norm(savgol_coeffs(window, 3, deriv=1, delta=dt))
    noise_q = float(np.max(sigma_q)) * np.linalg.norm(
        savgol_coeffs(window_q, POSITION_POLYORDER, deriv=2, delta=dt)
    )
    info = dict(regularised_stamps=regularised, stamp_jitter_s=jitter, position_noise=sigma_q, velocity_noise=sigma_v)
    if t.shape[0] <= window_q:
        return joints, JointConditioning(source="velocities", qdd_noise=noise_v, **info)
    if uniform and noise_q < noise_v:
        qd_q = savgol_filter(q, window_q, POSITION_POLYORDER, deriv=1, delta=dt, axis=0, mode="interp")
        qdd_q = savgol_filter(q, window_q, POSITION_POLYORDER, deriv=2, delta=dt, axis=0, mode="interp")
        out = JointStates(t=t, q=q, qd=qd_q, qdd=qdd_q)
        kinks = _kinks(q, window_q, sigma_q, KINK_FLOOR["positions"])
        return out, JointConditioning(source="positions", qdd_noise=noise_q, unreliable=kinks, **info)
    refilled = t.shape[0] != np.asarray(joints.t).shape[0]
    out = joints if not regularised else JointStates(t=t, q=q, qd=qd, qdd=None if refilled else joints.qdd)
    kinks = _kinks(qd, window, sigma_v, KINK_FLOOR["velocities"])
    return out, JointConditioning(source="velocities", qdd_noise=noise_v, unreliable=kinks, **info)


class JointInterpolator:
    """Joint position, velocity and acceleration at arbitrary instants, built once per dataset.

    ``q`` is a cubic Hermite interpolant of the reported ``(q, qd)``; ``qd`` a cubic Hermite
    interpolant of ``(qd, qdd)``; ``qdd`` linear in the estimated (or, when ``use_dataset_qdd`` and
    the dataset has it, the reported) accelerations. Instants outside the joint stream are an error.

    Real joint streams are conditioned first (:func:`condition_joint_stream`): stamps that jitter
    around a regular grid are put back on it when that makes the positions smoother, and when the
    encoder positions are less noisy than the reported velocities (the usual case: an encoder
    resolves micro-radians, a velocity estimate carries mrad/s of noise), ``qd`` and ``qdd`` are
    the Savitzky-Golay first and second derivatives of the positions instead of the velocities'.
    ``conditioning`` says what was done.
    """

    def __init__(
        self, joints: JointStates, *, use_dataset_qdd: bool = False, qdd_window_s: float = DEFAULT_QDD_WINDOW_S
    ) -> None:
        if np.asarray(joints.t).shape[0] < 7:
            raise CalibrationError(
                f"joint stream has {np.asarray(joints.t).shape[0]} samples; at least 7 are needed to estimate qdd"
            )
        use_reported = use_dataset_qdd and joints.qdd is not None
        joints, self.conditioning = (joints, JointConditioning()) if use_reported else condition_joint_stream(
            joints, qdd_window_s
        )
        tj = np.asarray(joints.t, dtype=float)
        self.t_start, self.t_end = float(tj[0]), float(tj[-1])
        self._tj, self._q, self._qd_j = tj, np.asarray(joints.q, dtype=float), np.asarray(joints.qd, dtype=float)
        self._joints, self._window_s = joints, qdd_window_s
        self._qdd_full: FloatArray | None = None
        self._sg: FloatArray | None = None
        self._qdd_fit: FloatArray | None = None
        self._lock = threading.Lock()
        dt = float(np.median(np.diff(tj)))
        if use_reported or joints.qdd is not None and self.conditioning.source in ("positions", "spline"):
            self._t_acc, self._qd, self._qdd_full = tj, self._qd_j, np.asarray(joints.qdd, dtype=float)
        elif np.max(np.abs(np.diff(tj) - dt)) > 0.01 * dt:  # uneven: resample, estimate everything now
            self._t_acc, self._qd, self._qdd_full = estimate_qdd(joints, qdd_window_s)
        else:
            self._t_acc, self._qd = tj, self._qd_j
            window = min(max(5, int(round(qdd_window_s / dt)) | 1), tj.shape[0] - (1 - tj.shape[0] % 2))
            self._sg = savgol_coeffs(window, 3, deriv=1, delta=dt, use="dot")
        self._uniform = self._t_acc is tj

    @property
    def _qdd(self) -> FloatArray:
        """Full-rate acceleration estimate on the uniform grid (computed once, on first use)."""
        if self._qdd_full is None:
            self._qdd_full = estimate_qdd(self._joints, self._window_s)[2]
        return self._qdd_full

    def warm(self) -> None:
        """Compute the lazily built acceleration estimate now (e.g. before forking workers that share it)."""
        self._qdd_at(np.zeros(1, dtype=np.intp))

    def _qdd_at(self, i: np.ndarray) -> FloatArray:
        """Acceleration estimate at grid indices ``i`` only (the same local fit as :attr:`_qdd`)."""
        if self._qdd_full is not None or self._sg is None:
            return self._qdd[i]
        half = self._sg.size // 2
        with self._lock:  # once per dataset, shared by the units (and their worker threads)
            if self._qdd_fit is None:
                # the local fit at every full window's centre (samples half..N-1-half): a valid-mode
                # convolution per joint, ~0.1 s for ten minutes at 1 kHz
                kernel = self._sg[::-1]
                self._qdd_fit = np.stack([np.convolve(qd, kernel, mode="valid") for qd in self._qd.T], axis=1)
        return self._qdd_fit[np.clip(i, half, self._qd.shape[0] - 1 - half) - half]

    def __call__(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(q, qd, qdd)`` at instants ``t`` (M,), each ``(M, n)``."""
        t = np.asarray(t, dtype=float)
        if t.size and (t.min() < self.t_start - 1e-9 or t.max() > self.t_end + 1e-9):
            raise CalibrationError(
                f"instants {t.min():.3f}..{t.max():.3f} s fall outside the joint stream "
                f"{self.t_start:.3f}..{self.t_end:.3f} s"
            )
        q = cubic_hermite(self._tj, self._q, self._qd_j, t)
        qd = cubic_hermite(self._t_acc, self._qd, self._qdd, t)
        i = np.clip(np.searchsorted(self._t_acc, t) - 1, 0, self._t_acc.size - 2)
        t0, t1 = self._t_acc[i], self._t_acc[i + 1]
        w = ((t - t0) / (t1 - t0))[:, None]
        qdd = (1.0 - w) * self._qdd[i] + w * self._qdd[i + 1]
        return q, qd, qdd


    def reliable(self, t: FloatArray) -> np.ndarray:
        """``(M,)`` False at instants whose acceleration estimate is unreliable (near a kink of the
        joint stream, :func:`condition_joint_stream`); True everywhere for reported accelerations."""
        bad = self.conditioning.unreliable
        t = np.asarray(t, dtype=float)
        if bad is None:
            return np.ones(t.shape, dtype=bool)
        i = np.clip(np.searchsorted(self._tj, t), 0, self._tj.size - 1)
        return ~(bad[i] | bad[np.maximum(i - 1, 0)])

    def qdd_variance(self, t: FloatArray) -> FloatArray | None:
        """``(M, n)`` variance of the joint accelerations at instants ``t`` (M,) (linear in the
        conditioned stream's :attr:`JointConditioning.qdd_variance`), rad^2/s^4; ``None`` when the
        conditioning did not estimate one (a stream that resolves its motion)."""
        var = self.conditioning.qdd_variance
        if var is None:
            return None
        t = np.asarray(t, dtype=float)
        return np.column_stack([np.interp(t, self._tj, c) for c in var.T])

    @property
    def dt(self) -> float:
        """Period of the uniform joint grid, s."""
        return float(self._t_acc[1] - self._t_acc[0])

    def nearest(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(q, qd, qdd)`` of the joint sample nearest to each instant (no interpolation).

        Good enough to tell whether the robot is at rest and where; exact kinematics need
        :meth:`__call__`. Falls back to interpolation for unevenly sampled joint streams.
        """
        if not self._uniform:
            return self(t)
        g = self._t_acc
        i = np.clip(np.rint((np.asarray(t, dtype=float) - g[0]) / self.dt).astype(np.intp), 0, g.size - 1)
        return self._q[i], self._qd_j[i], self._qdd_at(i)

    def on_grid(self, step: int) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Every ``step``-th sample of the (uniform) joint grid: ``(t, q, qd, qdd)``."""
        t = self._t_acc[::step]
        if self._uniform:
            return t, self._q[::step], self._qd_j[::step], self._qdd_at(np.arange(0, t.size * step, step))
        return (t, *self(t))


def cubic_hermite(t_knots: FloatArray, y: FloatArray, dy: FloatArray, t: FloatArray) -> FloatArray:
    """Cubic Hermite interpolation of ``y`` (N, n) with slopes ``dy`` at instants ``t`` (M,).

    Same result as ``scipy.interpolate.CubicHermiteSpline(t_knots, y, dy)(t)`` inside the knots,
    but without building the piecewise-polynomial coefficients of all N knots (0.5 s for a 1 kHz
    recording of ten minutes) when only M << N instants are needed.
    """
    i = np.clip(np.searchsorted(t_knots, t) - 1, 0, t_knots.size - 2)
    h = (t_knots[i + 1] - t_knots[i])[:, None]
    s = (t - t_knots[i])[:, None] / h
    s2, s3 = s * s, s * s * s
    h00, h10, h01, h11 = 2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s, -2 * s3 + 3 * s2, s3 - s2
    return h00 * y[i] + h10 * h * dy[i] + h01 * y[i + 1] + h11 * h * dy[i + 1]


def joint_states_at(
    joints: JointStates,
    t: FloatArray,
    *,
    use_dataset_qdd: bool = False,
    qdd_window_s: float = DEFAULT_QDD_WINDOW_S,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """One-off :class:`JointInterpolator` evaluation at instants ``t`` (M,)."""
    return JointInterpolator(joints, use_dataset_qdd=use_dataset_qdd, qdd_window_s=qdd_window_s)(t)


@dataclass(frozen=True)
class SampleAccount:
    """What :func:`unit_samples` dropped from a unit's stream before any method saw it (counts of
    IMU samples) and what the screening said.

    Attributes:
        n_total: samples in the stream.
        n_nonfinite: samples with a non-finite accelerometer reading.
        n_outside: samples whose (shifted) instant lies outside the joint stream.
        n_saturated: samples at a saturating extreme of some channel (accelerometer or gyroscope).
        n_stuck: samples where an accelerometer axis had stopped updating.
        saturated_t: ``(K,)`` instants of the saturated samples (shifted to the joint clock), s.
        warnings: the screening's and the unit check's warnings.
    """

    n_total: int
    n_nonfinite: int = 0
    n_outside: int = 0
    n_saturated: int = 0
    n_stuck: int = 0
    saturated_t: FloatArray | None = None
    warnings: tuple[str, ...] = ()


@dataclass(frozen=True)
class UnitSamples:
    """One unit's IMU samples with the joint states at their instants and their segment tags.

    Attributes:
        unit: unit name.
        t: ``(M,)`` sample instants, s (shifted by ``time_offset_s`` when one was applied).
        accel: ``(M, 3)`` measured specific force in the unit frame, m/s^2.
        gyro: ``(M, 3)`` measured angular rate in the unit frame, rad/s, or ``None``.
        q, qd, qdd: ``(M, n)`` joint states at ``t``.
        segment: ``(M,)`` index into the dataset's segments, -1 outside every segment.
        kind: ``(M,)`` :data:`STATIC` / :data:`DYNAMIC`, -1 outside every segment.
        joint: ``(M,)`` 0-based excited joint, -1 when static or outside.
        pose: ``(M,)`` 0-based pose index, -1 outside.
        account: what :func:`unit_samples` dropped before (``None`` when built by hand).
    """

    unit: str
    t: FloatArray
    accel: FloatArray
    gyro: FloatArray | None
    q: FloatArray
    qd: FloatArray
    qdd: FloatArray
    segment: np.ndarray
    kind: np.ndarray
    joint: np.ndarray
    pose: np.ndarray
    account: SampleAccount | None = None

    def select(self, mask: np.ndarray) -> UnitSamples:
        """The samples where ``mask`` is true."""
        return UnitSamples(
            self.unit,
            self.t[mask],
            self.accel[mask],
            None if self.gyro is None else self.gyro[mask],
            self.q[mask],
            self.qd[mask],
            self.qdd[mask],
            self.segment[mask],
            self.kind[mask],
            self.joint[mask],
            self.pose[mask],
            self.account,
        )

    @property
    def static(self) -> UnitSamples:
        return self.select(self.kind == STATIC)

    @property
    def dynamic(self) -> UnitSamples:
        return self.select(self.kind == DYNAMIC)


def tag_segments(t: FloatArray, segments: Segments) -> np.ndarray:
    """Index of the segment containing each instant ``t`` (M,), -1 where none does."""
    order = np.argsort(segments.t_start)
    starts = np.asarray(segments.t_start)[order]
    ends = np.asarray(segments.t_end)[order]
    i = np.searchsorted(starts, t, side="right") - 1
    inside = (i >= 0) & (t <= ends[np.clip(i, 0, None)])
    return np.where(inside, order[np.clip(i, 0, None)], -1)


def unit_samples(
    dataset: Dataset,
    unit: str,
    *,
    time_offset_s: float = 0.0,
    interpolator: JointInterpolator | None = None,
    use_dataset_qdd: bool = False,
    exact_joint_states: bool = True,
) -> UnitSamples:
    """Gather one unit's samples with joint states interpolated to its instants.

    ``time_offset_s`` is the IMU's latency: the sample stamped ``t`` measured the motion at
    ``t - time_offset_s``. Samples whose shifted instant lies outside the joint stream are dropped.
    Pass the dataset's ``interpolator`` when gathering several units (it is built once).
    ``exact_joint_states=False`` takes the nearest joint sample instead of interpolating (for
    methods that evaluate the kinematics themselves and only need to know where the robot rests).
    """
    if unit not in dataset.imu:
        raise CalibrationError(f"unknown unit '{unit}' (dataset has: {', '.join(dataset.units)})")
    imu = dataset.imu[unit]
    t = np.asarray(imu.t, dtype=float) - time_offset_s
    accel = np.asarray(imu.accel, dtype=float)
    finite = np.all(np.isfinite(accel), axis=1)
    unit_warnings = check_accel_units(unit, accel[finite], float(np.linalg.norm(dataset.gravity)))
    tj = dataset.joint_states.t
    t0, t1 = float(tj[0]), float(tj[-1])
    if interpolator is not None:  # a conditioned (spline) stream may end a grid step inside the reports
        t0, t1 = max(t0, interpolator.t_start), min(t1, interpolator.t_end)
    inside_joints = (t >= t0) & (t <= t1)
    keep = finite & inside_joints
    t, accel = t[keep], accel[keep]
    gyro = None if imu.gyro is None else np.asarray(imu.gyro, dtype=float)[keep]
    screen = screen_channels(unit, accel, gyro, t)
    usable = screen.keep
    account = SampleAccount(
        n_total=int(finite.size),
        n_nonfinite=int(np.count_nonzero(~finite)),
        n_outside=int(np.count_nonzero(finite & ~inside_joints)),
        n_saturated=int(np.count_nonzero(screen.saturated)),
        n_stuck=int(np.count_nonzero(~usable & ~screen.saturated)),
        saturated_t=t[screen.saturated],
        warnings=tuple(unit_warnings) + screen.warnings,
    )
    t, accel = t[usable], accel[usable]
    gyro = None if gyro is None else gyro[usable]
    if interpolator is None:
        interpolator = JointInterpolator(dataset.joints, use_dataset_qdd=use_dataset_qdd)
    q, qd, qdd = interpolator(t) if exact_joint_states else interpolator.nearest(t)
    segments = dataset.segments if dataset.segments is not None and len(dataset.segments) > 0 else None
    seg = np.full(t.shape, -1, dtype=np.intp) if segments is None else tag_segments(t, segments)
    inside = seg >= 0
    pick = lambda arr, fill: np.where(inside, np.asarray(arr)[np.clip(seg, 0, None)], fill)  # noqa: E731
    return UnitSamples(
        unit=unit,
        t=t,
        accel=accel,
        gyro=gyro,
        q=q,
        qd=qd,
        qdd=qdd,
        segment=seg,
        kind=seg.astype(np.int8) if segments is None else pick(segments.kind, -1).astype(np.int8),
        joint=seg.astype(np.int32) if segments is None else pick(segments.joint, -1).astype(np.int32),
        pose=seg.astype(np.int32) if segments is None else pick(segments.pose, -1).astype(np.int32),
        account=account,
    )


SATURATION_FRACTION = 0.002
"""An axis whose extreme value repeats in more than this fraction of samples is saturating..."""
SATURATION_MIN = 11.0
"""...if that value is beyond this magnitude, m/s^2 (above 1 g plus any bias: a unit at rest
repeats its reading too, but never saturates there)."""


GYRO_SATURATION_MIN = 1.0
"""A gyroscope extreme repeated as often as :data:`SATURATION_FRACTION` says is a rail if it lies
beyond this rate, rad/s (57 deg/s: below every MEMS gyroscope's smallest range, 125 deg/s, and far
above any reading at rest)."""


@dataclass(frozen=True)
class Screening:
    """The outcome of :func:`screen_channels`: ``keep`` ``(M,)`` usable samples, ``saturated``
    ``(M,)`` samples at a channel's rail, and the warnings."""

    keep: np.ndarray
    saturated: np.ndarray
    warnings: tuple[str, ...]


RAIL_BAND = 0.05
"""With ``pile_up``, the samples within this fraction of an extreme are its neighbourhood..."""
RAIL_SHARE = 0.5
"""...of which a rail holds more than this share (a clipped channel piles up at its rail; a
quantised one merely repeats its peak a few times among many readings close to it)."""


def _rails(x: FloatArray, minimum: float, pile_up: bool = False) -> list[tuple[int, float, np.ndarray]]:
    """Per axis of ``x`` ``(M, 3)``: the extremes beyond ``minimum`` in magnitude that repeat exactly
    in more than :data:`SATURATION_FRACTION` of the samples (and more than 3) and, with ``pile_up``,
    hold more than :data:`RAIL_SHARE` of the samples within :data:`RAIL_BAND` of them: ``(axis,
    value, mask)``. A saturating channel clips at its rail and reports the same value every time."""
    out = []
    for k in range(x.shape[1]):
        a = x[:, k]
        fin = a[np.isfinite(a)]
        if fin.size == 0:
            continue
        for extreme in (fin.max(), fin.min()):
            hits = a == extreme
            n_hits = np.count_nonzero(hits)
            if not (abs(extreme) > minimum and hits.mean() > SATURATION_FRACTION and n_hits > 3):
                continue
            if pile_up and n_hits <= RAIL_SHARE * np.count_nonzero(np.abs(fin - extreme) <= RAIL_BAND * abs(extreme)):
                continue
            out.append((k, float(extreme), hits))
    return out


def screen_channels(
    unit: str, accel: FloatArray, gyro: FloatArray | None = None, t: FloatArray | None = None, **stuck: float
) -> Screening:
    """:func:`screen_readings` of the accelerometer, and the same saturation test on the gyroscope
    (rails beyond :data:`GYRO_SATURATION_MIN`): a gyroscope at its rail under-reads the rotation
    exactly when it matters most. ``stuck``: the stuck-axis test's options."""
    keep, warnings = screen_readings(unit, accel, t, **stuck)
    saturated = np.zeros(len(keep), dtype=bool)
    for _, _, hits in _rails(np.asarray(accel, dtype=float), SATURATION_MIN):
        saturated |= hits
    if gyro is not None:
        for k, value, hits in _rails(np.asarray(gyro, dtype=float), GYRO_SATURATION_MIN, pile_up=True):
            keep &= ~hits
            saturated |= hits
            warnings.append(
                f"gyroscope {'xyz'[k]} axis saturates at {value:+.4g} rad/s ({np.degrees(value):+.0f} deg/s) in "
                f"{100 * hits.mean():.1f}% of samples; those samples are ignored"
            )
    return Screening(keep, saturated & ~keep, tuple(warnings))


def screen_readings(
    unit: str,
    accel: FloatArray,
    t: FloatArray | None = None,
    *,
    stuck_min_s: float = 1.0,
    stuck_min_fraction: float = 0.02,
    stuck_others_ptp: float = 0.2,
) -> tuple[np.ndarray, list[str]]:
    """Reject what no method can use: a stuck accelerometer axis and saturated samples. Returns the
    mask of usable samples and the warnings.

    An axis constant over the whole stream is an error. An axis that holds one value from some
    instant on (a register that stopped updating) shows as a run of exactly repeated consecutive
    values that lasts at least ``stuck_min_s`` (needs the stamps ``t`` ``(M,)``, s) or
    ``stuck_min_fraction`` of the samples (at least 10 samples), while another axis of the same
    samples varies by more than ``stuck_others_ptp`` m/s^2 peak to peak: those samples are not
    usable (a unit at rest whose noise stays below one LSB repeats its readings too, but then its
    other axes do not move). A repeated value at the axis' saturating extreme is left to the
    saturation test: samples at an extreme beyond ``SATURATION_MIN`` that repeats in more than
    ``SATURATION_FRACTION`` of the samples are dropped, with a warning.
    """
    accel = np.asarray(accel, dtype=float)
    n = len(accel)
    keep = np.ones(n, dtype=bool)
    warnings: list[str] = []
    t = None if t is None else np.asarray(t, dtype=float)
    min_run = stuck_min_fraction * n
    if t is not None and n > 1:
        dt = float(np.median(np.diff(t)))
        if dt > 0:
            min_run = min(min_run, stuck_min_s / dt)
    min_run = max(min_run, 10.0)
    rows = np.flatnonzero(np.all(np.isfinite(accel), axis=1))  # runs are judged on the complete samples
    fin = accel[rows]
    for k, axis in enumerate("xyz"):
        a = accel[:, k]
        if a.size > 10 and np.ptp(a) < 1e-9:
            raise CalibrationError(f"unit '{unit}': accelerometer {axis} axis is stuck at {a[0]:.4g} m/s^2")
        af, others = fin[:, k], np.delete(fin, k, axis=1)
        same = np.concatenate([[False], af[1:] == af[:-1], [False]])  # same[i]: sample i repeats sample i - 1
        edges = np.flatnonzero(np.diff(same.astype(np.int8)))
        for i0, i1 in zip(edges[::2], edges[1::2], strict=True):
            start, end = int(i0), int(i1) + 1  # finite samples [start, end) hold one value
            value = float(af[start])
            if end - start < min_run:
                continue
            if abs(value) > SATURATION_MIN and value in (af.max(), af.min()):
                continue  # a rail: the saturation test below judges it
            if not np.max(np.ptp(others[start:end], axis=0)) > stuck_others_ptp:
                continue  # the whole unit is still: repeated readings below one LSB of noise
            i, j = rows[start], rows[end - 1]
            keep[i : j + 1] = False
            last = end == rows.size
            if t is None:
                span = f"from sample {i} " + ("to the end" if last else f"to sample {j}")
            else:
                span = f"from {t[i]:.1f} s " + ("to the end" if last else f"to {t[j]:.1f} s")
            warnings.append(
                f"accelerometer {axis} axis stuck at {value:.4g} m/s^2 {span} ({end - start} samples ignored)"
            )
        for extreme in (a.max(), a.min()):
            hits = a == extreme
            if abs(extreme) > SATURATION_MIN and hits.mean() > SATURATION_FRACTION and np.count_nonzero(hits) > 3:
                keep &= ~hits
                warnings.append(
                    f"accelerometer {axis} axis saturates at {extreme:+.4g} m/s^2 in {100 * hits.mean():.1f}% "
                    "of samples; those samples are ignored"
                )
    return keep, warnings


G_UNIT_RANGE = (0.08, 0.125)
"""A median specific-force magnitude this fraction of gravity (1/9.81 = 0.102) is an accelerometer
in g..."""
RAW_COUNT_MIN = 50.0
"""...and one beyond this multiple of gravity a stream of raw counts (an MPU's 16384 LSB/g at
+-2 g is 1670 times gravity in m/s^2)..."""
PLAUSIBLE_G_RANGE = (0.7, 1.4)
"""...while one outside this range of gravity (but neither of the above) is only suspicious."""
MILLI_G_RANGE = (80.0, 125.0)
"""Raw counts whose median is this multiple of gravity (1000 / 9.81 = 102) are named as milli-g."""


def check_accel_units(unit: str, accel: FloatArray, gravity_mps2: float) -> list[str]:
    """The accelerometer's unit from the magnitude of its readings: a robot accelerates its links
    by a fraction of gravity, so the median ``|f|`` over the stream is gravity within tens of
    percent in m/s^2 (:data:`PLAUSIBLE_G_RANGE`). About 1/9.81 of it (:data:`G_UNIT_RANGE`) is a
    stream in g and beyond :data:`RAW_COUNT_MIN` times it raw counts: both are certain and raise a
    one-line :class:`~skincal.errors.DatasetError`; anything else outside the plausible range is a
    warning. Without gravity (``gravity_mps2 < 1``) nothing is checked."""
    from skincal.errors import DatasetError

    accel = np.asarray(accel, dtype=float)
    if gravity_mps2 < 1.0 or accel.shape[0] < 10:
        return []
    m = float(np.median(np.linalg.norm(accel, axis=1)))
    r = m / gravity_mps2
    if G_UNIT_RANGE[0] <= r <= G_UNIT_RANGE[1]:
        raise DatasetError(
            f"unit '{unit}': accelerometer reads |f| = {m:.3g} (median), {r:.3f} of gravity: it is in g, not m/s^2 "
            f"(multiply by {gravity_mps2:.5g})"
        )
    if MILLI_G_RANGE[0] <= r <= MILLI_G_RANGE[1]:
        raise DatasetError(
            f"unit '{unit}': accelerometer reads |f| = {m:.4g} (median), {r:.0f} times gravity: it is in milli-g, "
            f"not m/s^2 (multiply by {gravity_mps2 / 1000:.4g})"
        )
    if r > RAW_COUNT_MIN:
        raise DatasetError(
            f"unit '{unit}': accelerometer reads |f| = {m:.4g} (median), {r:.0f} times gravity: raw counts? "
            "convert them to m/s^2 with the sensor's sensitivity"
        )
    if not PLAUSIBLE_G_RANGE[0] <= r <= PLAUSIBLE_G_RANGE[1]:
        return [
            f"accelerometer reads |f| = {m:.3g} m/s^2 (median), {r:.2f} of gravity: wrong unit or scale? "
            "(the estimated scale/misalignment absorbs a few percent, not this)"
        ]
    return []


DEG_PER_RAD = 180.0 / np.pi
GYRO_SCALE_TOLERANCE = 0.25
"""A gyroscope whose readings are within this fraction of 180/pi times the robot's rotation rate is
in deg/s; within it of 1 the unit is right."""
GYRO_RAW_MIN = 100.0
"""A gyroscope reading more than this many times the rotation rate is raw counts (an MPU's 131
LSB per deg/s is 7506 per rad/s)."""
GYRO_CHECK_MIN_RATE = 0.1
"""The check needs the link to turn at least this fast (rms), rad/s, and..."""
GYRO_CHECK_MIN_CORRELATION = 0.7
"""...the gyroscope's magnitude to follow the link's rotation rate this closely (correlation)."""


def check_gyro_units(unit: str, gyro_speed: FloatArray, link_speed: FloatArray) -> list[str]:
    """The gyroscope's unit from its rate ``|w_meas - b|`` ``(M,)`` against its link's rotation rate
    from the chain ``|w_link|`` ``(M,)`` (rad/s; any frame: magnitudes need no alignment, only the
    time offset), at the same instants. ``s = <|w_meas|, |w_link|> / <|w_link|, |w_link|>`` (least
    squares) is 1 within a consumer part's scale error; ``s ~ 57.3`` (within
    :data:`GYRO_SCALE_TOLERANCE`) is a stream in deg/s and ``s >`` :data:`GYRO_RAW_MIN` raw counts:
    both raise a one-line :class:`~skincal.errors.DatasetError` when the link turns enough and the
    magnitudes correlate (:data:`GYRO_CHECK_MIN_RATE`, :data:`GYRO_CHECK_MIN_CORRELATION`); any
    other ``s`` outside ``1 +- GYRO_SCALE_TOLERANCE`` is a warning."""
    from skincal.errors import DatasetError

    g, w = np.asarray(gyro_speed, dtype=float), np.asarray(link_speed, dtype=float)
    ok = np.isfinite(g) & np.isfinite(w)
    g, w = g[ok], w[ok]
    if g.size < 20 or float(np.sqrt(np.mean(w * w))) < GYRO_CHECK_MIN_RATE or np.std(g) == 0 or np.std(w) == 0:
        return []
    s = float(g @ w / (w @ w))
    rho = float(np.corrcoef(g, w)[0, 1])
    certain = rho >= GYRO_CHECK_MIN_CORRELATION
    if abs(s / DEG_PER_RAD - 1.0) <= GYRO_SCALE_TOLERANCE and certain:
        raise DatasetError(
            f"unit '{unit}': gyroscope reads {s:.1f} times the robot's rotation rate: it is in deg/s, not rad/s "
            f"(multiply by pi/180)"
        )
    if s > GYRO_RAW_MIN and certain:
        raise DatasetError(
            f"unit '{unit}': gyroscope reads {s:.0f} times the robot's rotation rate: raw counts? convert them to "
            "rad/s with the sensor's sensitivity"
        )
    if not certain:
        return [
            f"gyroscope rate follows its link's rotation rate poorly (correlation {rho:.2f}, ratio {s:.2f}): the "
            "joint stream misrepresents the rotation between its reports, or the clock is off"
        ]
    if abs(s - 1.0) > GYRO_SCALE_TOLERANCE:
        return [f"gyroscope reads {s:.2f} times its link's rotation rate (correlation {rho:.2f}): wrong unit or scale?"]
    return []


@dataclass(frozen=True)
class StaticMeans:
    """Per static segment: mean specific force ``(S, 3)`` (unit frame), joint angles ``(S, n)``,
    sample counts ``(S,)`` and the segment indices ``(S,)``."""

    accel: FloatArray
    q: FloatArray
    count: np.ndarray
    segment: np.ndarray


def static_means(samples: UnitSamples, min_samples: int = 1) -> StaticMeans:
    """Average the accelerometer and joint angles over each static segment (paper Sec. II-A)."""
    st = samples.static
    segs, inverse, counts = np.unique(st.segment, return_inverse=True, return_counts=True)
    keep = counts >= min_samples
    sums = np.zeros((segs.size, 3))
    np.add.at(sums, inverse, st.accel)
    qsum = np.zeros((segs.size, st.q.shape[1] if st.q.ndim == 2 else 0))
    np.add.at(qsum, inverse, st.q)
    return StaticMeans(
        accel=(sums / counts[:, None])[keep],
        q=(qsum / counts[:, None])[keep],
        count=counts[keep],
        segment=segs[keep],
    )
