"""Joint-stream conditioning: jittered stamps put back on their grid (:func:`regular_grid`), ``qd``/``qdd``
from the encoder positions when they are less noisy, kinks, the noise levels (:func:`joint_noise`,
:func:`white_noise_std`); a low-rate (< 60 Hz) or irregular stream as smoothing splines of its positions
with the per-sample variance of its accelerations (:func:`spline_condition`).
The cubic Hermite interpolation of positions with their velocities is :func:`skincal.calib.hermite.hermite`."""

from __future__ import annotations

import hashlib
import math
import threading
from dataclasses import dataclass, replace

import numpy as np
from scipy.ndimage import correlate1d, maximum_filter1d, uniform_filter1d
from scipy.signal import savgol_coeffs, savgol_filter

from skincal.calib.hermite import hermite
from skincal.calib.preprocess.gcv import gcv_lambda, smoothing_spline, spline_bands
from skincal.data.dataset import JointStates
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
    (the kink test then marks the few places it does not) or when it was not estimated
    (``spline_condition(..., error_estimate=False)``, the default: ask
    :meth:`~skincal.calib.preprocess.JointInterpolator.qdd_variance`)."""
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
SPLINE_MIN_REPORTS = 5
"""Fewest reports a smoothing spline is fitted to (SciPy's ``make_smoothing_spline`` needs 5)."""
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


def spline_condition(joints: JointStates, error_estimate: bool = False) -> tuple[JointStates, JointConditioning]:
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
    motion) and the std at 60-80 % of the accelerations' rms. Those five further fits per joint are
    made only with ``error_estimate`` (:func:`with_spline_error`; :meth:`JointInterpolator.qdd_variance`
    makes them on first use): no calibrator reads the variance, and they were five sixths of the
    conditioning's time (the streaming calibrator conditions every block of a slow stream).
    """
    t = np.asarray(joints.t, dtype=float)
    q = np.asarray(joints.q, dtype=float)
    dt_report = float(np.median(np.diff(t)))
    step = 1.0 / FINE_RATE_HZ
    grid = t[0] + step * np.arange(int(np.floor((t[-1] - t[0]) / step)) + 1)
    n = q.shape[1]
    qf, qdf, qddf = (np.empty((grid.size, n)) for _ in range(3))
    sigma_q = np.empty(n)
    for j in range(n):
        s = _smoothing_spline(t, q[:, j])
        qf[:, j], qdf[:, j], qddf[:, j] = s(grid), s(grid, 1), s(grid, 2)
        sigma_q[j] = float(np.std(q[:, j] - s(t)))
    out = JointStates(t=grid, q=qf, qd=qdf, qdd=qddf)
    noise_qd = np.asarray(joint_noise(qf, qdf)[1])
    cond = JointConditioning(
        source="spline", position_noise=sigma_q, velocity_noise=noise_qd, report_rate_hz=1.0 / dt_report
    )
    return out, with_spline_error(cond, joints, out) if error_estimate else cond


def _thinned_shift(t: FloatArray, q: FloatArray, grid: FloatArray, qdd: FloatArray, every: int) -> FloatArray:
    """``(G,)`` mean over the ``every`` phases of the squared change of the acceleration on ``grid`` when one
    joint's positions ``q`` at stamps ``t`` are fitted on every ``every``-th report only (``qdd``: the full fit's)."""
    fits = [_smoothing_spline(t[k::every], q[k::every])(grid, 2) for k in range(every)]
    return np.mean([(f - qdd) ** 2 for f in fits], axis=0)


def with_spline_error(cond: JointConditioning, joints: JointStates, out: JointStates) -> JointConditioning:
    """``cond`` of a spline-conditioned stream with its acceleration error estimated
    (:func:`spline_condition`: ``qdd_variance`` on ``out``'s stamps and ``qdd_noise``) from the reported
    ``joints``."""
    t, q = np.asarray(joints.t, dtype=float), np.asarray(joints.q, dtype=float)
    grid, qddf = np.asarray(out.t, dtype=float), np.asarray(out.qdd, dtype=float)
    width = max(1, int(round(float(np.median(np.diff(t))) * FINE_RATE_HZ)))
    lo, hi = ERROR_ORDER_RANGE
    var = np.empty_like(qddf)
    for j in range(q.shape[1]):
        if np.ptp(q[:, j]) == 0.0:
            var[:, j] = 0.0
            continue
        if t.size < 2 * SPLINE_MIN_REPORTS:  # too few reports for a thinned fit (a short block of a slow stream):
            var[:, j] = qddf[:, j] ** 2  # the accelerations' own size, the conservative end
            continue

        d2 = _thinned_shift(t, q[:, j], grid, qddf[:, j], 2)
        p = lo  # every third report too few for a fit: the conservative end of the order
        if t.size >= 3 * SPLINE_MIN_REPORTS:
            d3 = _thinned_shift(t, q[:, j], grid, qddf[:, j], 3)
            p = _error_order(float(np.sqrt(np.mean(d3) / max(float(np.mean(d2)), 1e-300))), lo, hi)
        var[:, j] = uniform_filter1d(d2, width, mode="nearest") / (2.0**p - 1.0) ** 2
    return replace(cond, qdd_noise=float(np.sqrt(np.max(np.median(var, axis=0)))), qdd_variance=var)


SMOOTHING_SPAN = 1.0
"""The smoothing spline's equivalent kernel never spans more than this many report spacings ``h``
(see :func:`_smoothing_spline`): its transfer function is ``1 / (1 + (b w)^4)`` for a bandwidth
``b``, so an eighth of the reports' Nyquist frequency, ``w = pi / (8 h)``, loses at most 2.3 %. A
guard only: on the real 14 Hz tool-pose streams tried, cross-validation chose 0.4-1 spacings by
itself, and a tighter cap (0.4) moved the slow paths' lever arm along the tool axis by up to
0.1 m (the data do not pin it)."""


SPLINE_MEMO_SIZE = 4096
"""How many smoothing parameters :func:`_smoothing_spline` remembers (FIFO; a few floats per joint and
thinned stream of a recording)."""
_spline_lam: dict[bytes, float] = {}
_spline_lock = threading.Lock()


def _smoothing_spline(t: FloatArray, y: FloatArray):  # noqa: ANN202 - a scipy BSpline
    """The cubic smoothing spline of ``y(t)`` with ``lam`` by generalised cross-validation, but never
    smoother than an equivalent kernel of :data:`SMOOTHING_SPAN` report spacings ``h``: its
    bandwidth is ``(lam h)^(1/4)``, so ``lam <= (SMOOTHING_SPAN h)^4 / h``. Cross-validation on
    nearly noise-free positions can pick an enormous ``lam`` (a straight line through a sine);
    the capped fit is taken whenever it leaves the smaller residual (the smoothing is monotonic in
    ``lam``: GCV chose more than the cap).

    The ``lam`` chosen is remembered by the bytes of ``(t, y)``: the same stream fitted again (a report
    stream's every second report, fitted for the error estimate of the full stream and again as the thinned
    stream of the report-spacing check, :mod:`skincal.calib.joint_rate`) gets the same spline without its
    cross-validation (bit-identical: the same arithmetic on the same numbers)."""
    t = np.ascontiguousarray(t, dtype=float)
    y = np.ascontiguousarray(y, dtype=float)
    key = hashlib.blake2b(t.tobytes() + b"|" + y.tobytes(), digest_size=20).digest()
    bands = spline_bands(t)
    lam = _spline_lam.get(key)
    if lam is not None:
        return smoothing_spline(t, y, lam, bands)
    h = float(np.median(np.diff(t)))
    lam_gcv = gcv_lambda(t, y, bands)  # SciPy's own GCV choice, found faster
    lam_cap = (SMOOTHING_SPAN * h) ** 4 / h
    gcv = smoothing_spline(t, y, lam_gcv, bands)
    capped = smoothing_spline(t, y, lam_cap, bands)
    r_gcv = float(np.sum((gcv(t) - y) ** 2))
    r_cap = float(np.sum((capped(t) - y) ** 2))
    with _spline_lock:  # units calibrated in threads share it
        if len(_spline_lam) >= SPLINE_MEMO_SIZE:
            del _spline_lam[next(iter(_spline_lam))]
        _spline_lam[key] = lam_cap if r_cap < r_gcv else lam_gcv
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
STEP_FACTOR = 5.0
"""A qdd step estimated at a sample (:func:`_qdd_steps`) beyond this many of its own std (plus
:data:`STEP_FLOOR`) marks a kink."""
STEP_POLYORDER = 7
"""The smooth motion beside a step is a polynomial of this order over twice the estimate's window
(measured, 500 Hz, 18-bit encoder: steps from 2.2 rad/s^2 found, a 3 Hz, 1 rad swing reads 0.002;
order 5 over that window reads 0.27 for it, and over the estimate's own window finds only steps
beyond 6.6 rad/s^2)."""
STEP_FLOOR = 0.05
"""rad/s^2: a qdd step below this spoils no acceleration estimate that matters (0.025 rad/s^2 for
half a window), however clean the positions."""
KINK_FLOOR = {"positions": 1e-6, "velocities": 1e-4}
"""Residual floors of that test: rad (positions) and rad/s (velocities), well below any kink that
matters (a qdd step of ~0.05 rad/s^2 over a 50 ms window)."""


def _kinks(
    x: FloatArray, window: int, sigma: FloatArray, floor: float, polyorder: int = 3, dt: float | None = None
) -> np.ndarray:
    """Samples within half a window of a place where ``x`` ``(N, n)`` is not locally a polynomial of
    ``polyorder`` (the order of the fit whose derivative gives qdd): the rms residual of that
    Savitzky-Golay fit over the window exceeds ``KINK_FACTOR sigma + floor``, or (positions, ``dt``
    given) a step of qdd is found there (:func:`_qdd_steps`). There an acceleration step (a
    protocol's excitation starting at full acceleration, a stop) makes any smoothed derivative
    wrong for about half a window on each side.

    The residual test alone must be of the estimate's own order: a cubic's residual over a fast
    smooth motion (a 2 Hz, 1 rad swing: 3.4e-5 rad over 50 ms) looks like a qdd step of 8 rad/s^2,
    and it flagged 73 % of a 9 rad/s motion that the order-5 estimate follows to 0.01 rad/s^2."""
    r = x - savgol_filter(x, window, polyorder, axis=0, mode="interp")
    rms = np.sqrt(np.maximum(uniform_filter1d(r * r, window, axis=0, mode="nearest"), 0.0))
    bad = np.any(rms > KINK_FACTOR * sigma + floor, axis=1)
    if dt is not None:
        bad |= _qdd_steps(x, window, sigma, dt)
    return maximum_filter1d(bad.astype(np.int8), window, mode="nearest") > 0


def qdd_steps(q: FloatArray, window: int, dt: float, polyorder: int = 5) -> tuple[FloatArray, float]:
    """The qdd step at each sample, by the matched filter of a step: ``(N, n)`` estimates, rad/s^2,
    and their std per unit of white position noise, (rad/s^2) / rad.

    Over the window around sample ``c`` (``k = -h..h``), a qdd step ``D`` at ``c`` adds
    ``D phi(k)``, ``phi(k) = (k dt)^2 / 2`` for ``k > 0`` and 0 before, to a smooth motion. Its
    least-squares estimate beside a polynomial of ``polyorder`` is ``D_c = phi_perp . q[c-h..c+h] /
    |phi_perp|^2`` with ``phi_perp`` the part of ``phi`` no such polynomial explains; white position
    noise ``sigma`` gives it the std ``sigma / |phi_perp|``."""
    h = window // 2
    k = np.arange(-h, h + 1, dtype=float)
    phi = np.where(k > 0, 0.5 * (k * dt) ** 2, 0.0)
    basis = np.vander(k / h, polyorder + 1)
    perp = phi - basis @ np.linalg.lstsq(basis, phi, rcond=None)[0]
    norm2 = float(perp @ perp)
    return correlate1d(np.asarray(q, dtype=float), perp / norm2, axis=0, mode="nearest"), 1.0 / math.sqrt(norm2)


def _qdd_steps(q: FloatArray, window: int, sigma: FloatArray, dt: float) -> np.ndarray:
    """``(N,)`` samples at which some joint's acceleration steps: :func:`qdd_steps` over twice the
    estimate's ``window`` beside an order :data:`STEP_POLYORDER` polynomial, ``|D_c| > STEP_FACTOR
    sigma / |phi_perp| + STEP_FLOOR``."""
    wide = 2 * window - 1
    if q.shape[0] < wide:
        return np.zeros(q.shape[0], dtype=bool)
    step, per_sigma = qdd_steps(q, wide, dt, STEP_POLYORDER)
    h = wide // 2
    step[:h], step[-h:] = 0.0, 0.0  # no whole window there: the padding's flat ends are no steps of the motion
    return np.any(np.abs(step) > STEP_FACTOR * np.asarray(sigma) * per_sigma + STEP_FLOOR, axis=1)


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


QUANTUM_DIVISORS = 8
"""A quantised signal's step is sought down to its smallest change over this many (a joint that turns fast
enough never changes by one count between samples: its smallest change is several counts)."""


def _smallest_step(x: FloatArray) -> FloatArray:
    """The quantisation step per column of ``x`` ``(N, k)``: the smallest non-zero change ``d_min`` between
    neighbouring samples, divided by the smallest ``m <= QUANTUM_DIVISORS`` for which every change is an
    integer multiple of ``d_min / m`` (a window in which the joint moves 3 or 4 counts per sample has
    ``d_min`` = 3 counts and the step ``d_min / 3``); ``d_min`` when no ``m`` fits (a signal that is not
    quantised; tiny for a smooth one)."""
    d = np.abs(np.diff(np.asarray(x, dtype=float), axis=0))
    out = np.zeros(d.shape[1])
    for j, c in enumerate(d.T):
        c = c[c > 1e-12]
        if not c.size:
            continue
        out[j] = step = float(np.min(c))
        for m in range(1, QUANTUM_DIVISORS + 1):
            units = c * (m / step)
            if np.all(np.abs(units - np.rint(units)) < 1e-3):
                out[j] = step / m
                break
    return out


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


OUTPUT_REACH = 4
"""Windows (of the acceleration estimate) a conditioned stream's outputs reach back: the position fit, its
residual's running mean, the qdd-step filter over two windows and the unreliable mask's widening each look at
most a window or two to each side (:func:`condition_joint_stream` with ``outputs_from``)."""


def condition_joint_stream(
    joints: JointStates, window_s: float = DEFAULT_QDD_WINDOW_S, outputs_from: float | None = None
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

    ``outputs_from`` (s): the stream is conditioned for the instants from then on only (a streaming block
    after its lookback): the decisions (stamps, noise levels, source) are taken on the whole stream; with
    the positions as the source (a uniform stream) the filtered states and the unreliable mask returned
    start :data:`OUTPUT_REACH` windows before it. From ``outputs_from`` on, the states are the whole
    stream's bit for bit (the Savitzky-Golay fits are local); the mask's running mean of the fit residual
    is a running sum, equal to rounding, so the mask is the same unless a residual sits at its threshold
    to the last bit. Other sources are returned whole (their interpolator derives the sample interval
    from the stream it is given).
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
            q = hermite(t, q, qd, full)[0]
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
        if outputs_from is not None:  # the position filters only where the instants asked for need them
            i0 = max(0, int(np.searchsorted(t, outputs_from)) - OUTPUT_REACH * window_q)
            t, q = t[i0:], q[i0:]
        qd_q = savgol_filter(q, window_q, POSITION_POLYORDER, deriv=1, delta=dt, axis=0, mode="interp")
        qdd_q = savgol_filter(q, window_q, POSITION_POLYORDER, deriv=2, delta=dt, axis=0, mode="interp")
        out = JointStates(t=t, q=q, qd=qd_q, qdd=qdd_q)
        kinks = _kinks(q, window_q, sigma_q, KINK_FLOOR["positions"], POSITION_POLYORDER, dt)
        return out, JointConditioning(source="positions", qdd_noise=noise_q, unreliable=kinks, **info)
    refilled = t.shape[0] != np.asarray(joints.t).shape[0]
    out = joints if not regularised else JointStates(t=t, q=q, qd=qd, qdd=None if refilled else joints.qdd)
    kinks = _kinks(qd, window, sigma_v, KINK_FLOOR["velocities"])
    return out, JointConditioning(source="velocities", qdd_noise=noise_v, unreliable=kinks, **info)
