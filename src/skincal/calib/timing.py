"""Time alignment of a unit's IMU stream with the robot's joint stream: the one clock model and the one
cross-correlation of the calibrators (``mle`` and the streaming calibrator).

The clock model (:func:`motion_instants`, :class:`ClockSteps`): a sample stamped ``t`` by the unit's
clock measured the motion at ``s = t' - tau - d (t' - t_ref)`` on the joint clock, with ``t'`` the
stamp with periodic re-sync steps removed (:meth:`ClockSteps.correct`), ``tau`` the time offset at
``t_ref`` and ``d`` the clock drift (dimensionless, 1e-6 per ppm).

A unit stamped by its own clock (WiFi skin without time sync, a driver's buffering) can be off by
a large fraction of a second. Gauss-Newton on the time offset converges only within about a
quarter period of the excitation, so a **coarse search** runs first: the cross-correlation, over
lags up to ``+-max_offset_s``, of a rotation-invariant motion signal measured by the unit with the
same signal predicted from the joint states for each candidate link ``k``:

* with a gyroscope: ``m(t) = |w_meas(t) - b|`` (``b`` the median reading, the bias at rest) against
  ``p_k(t) = |w_k(t)|``, the angular speed of link frame ``k`` (forward kinematics; independent of
  the unit's unknown pose);
* accelerometer only: ``m(t)`` = the accelerometer's spread over a short window against
  ``p_k(t) = sum_{j <= k} |qd_j(t)|``.

Both speeds are clipped at the angular speed the joint stream resolves (:func:`resolved_speed`: a
14 Hz stream of reported poses cannot follow a wrist turning at 8 rad/s, and its predicted spin,
wrong in shape, would otherwise dominate the correlation: on real recordings of an industrial robot it
moved the peak by 250-300 ms), then mean-removed and compared on a uniform grid by FFT; the lag of the
highest normalised correlation (refined by a parabola through its neighbours) is the offset, the link
whose signal correlates best a hint for link discovery.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skincal.calib.preprocess.screening import GYRO_RAIL_MAX_SHARE, gyro_lost_share
from skincal.kinematics.transforms import FloatArray

MAX_OFFSET_S = 0.5
"""Largest time offset searched, s, unless its peak lies at this edge..."""
WIDE_OFFSET_S = 5.0
"""...or a peak up to this offset, s, correlates better by :data:`WIDE_MARGIN` (a unit stamped 2 s off was
aligned at 0.37 s, correlation 0.29 against 0.99 at 2.0 s, without a word: the streaming calibrator put it on
the wrong link, 423 mm off, and ``mle`` 192 mm off). Within half the joint stream's span at most, and with a
gyroscope only: the accelerometer's spread signal aliases at wide lags (a simulated protocol of repeated
moves: a peak 3 s off at 0.92 against the true one's 0.70)."""
WIDE_MARGIN = 0.1
"""See :data:`WIDE_OFFSET_S` (normalised correlation). At 0.2 a UR5e ``fast`` session stamped 1.0-1.6 s late
had one unit aligned on the protocol's 1.4 s repetition inside the usual search (correlation 0.80 against 0.99
at the true offset, SIMULATED), without a word; the true peaks there correlate at 0.97-1.00, the repetitions
at most 0.79."""
CLOCK_DRIFT_MIN_SPAN_S = 60.0
"""The clock drift is estimated when the unit's samples span at least this long, s (moving samples in
``mle``; the absorbed stream in the streaming calibrator, which holds it near 0 before,
:data:`~skincal.calib.online.stats.DRIFT_SHORT_PRIOR`): a drift fitted on 10-20 s of a low-rate stream took
up model errors as -8000 ppm on a real recording."""
RESOLVED_TURN_RAD = 0.3
"""A joint stream resolves a link's angular speed up to this turn per report interval, rad (``0.3 / dt``:
4 rad/s at 14 Hz, 150 rad/s at 500 Hz, i.e. no limit for a controller's stream)."""
SPREAD_WINDOW_S = 0.1
"""Window of the accelerometer-spread signal (no gyroscope), s."""


def motion_instants(t: FloatArray, time_offset_s: float, drift: float = 0.0, t_ref: float = 0.0) -> FloatArray:
    """``(M,)`` instants ``s = t - tau - d (t - t_ref)`` (s) at which samples stamped ``t`` measured the
    motion (``drift`` dimensionless: 1e-6 per ppm)."""
    t = np.asarray(t, dtype=float)
    if drift:
        return t - drift * (t - t_ref) - time_offset_s
    return t - time_offset_s


def compose_clock(
    time_offset_s: float, drift: float, residual_offset_s: float, residual_drift: float
) -> tuple[float, float]:
    """The clock mapping ``(tau', d')`` (same ``t_ref``) after a residual ``(tau_r, d_r)``: samples mapped
    by ``(tau, d)`` to ``s`` measured the motion at ``s + tau_r + d_r (s - t_ref)``, exactly the
    mapping ``tau' = (1 + d_r) tau - tau_r``, ``d' = d - d_r + d_r d`` (:func:`motion_instants`)."""
    return (1.0 + residual_drift) * time_offset_s - residual_offset_s, drift - residual_drift + residual_drift * drift


@dataclass(frozen=True)
class MotionProfile:
    """Predicted motion signals of every link on a uniform grid (computed once per dataset), with
    their mean-removed spectra for the correlation (computed once, shared by every unit).

    Attributes:
        t: ``(G,)`` grid instants, s (uniform).
        angular_speed: ``(G, n)`` ``|w_k|`` of link frame ``k`` (column ``k - 1``), rad/s.
        joint_speed: ``(G, n)`` cumulative ``sum_{j <= k} |qd_j|``, rad/s.
        fft_size: length of the zero-padded transforms (room for every lag searched).
        spectra: ``{"gyroscope": (F, n), "accelerometer": (F, n)}`` conjugate real FFTs of the two
            predicted signals.
    """

    t: FloatArray
    angular_speed: FloatArray
    joint_speed: FloatArray
    fft_size: int
    spectra: dict[str, FloatArray]
    resolved_rps: float = float("inf")
    """The angular speed the joint stream resolves (:func:`resolved_speed`), rad/s: ``angular_speed`` is
    clipped at it, and so is the gyroscope's measured speed in :func:`coarse_time_offset`."""


def resolved_speed(joint_t: FloatArray) -> float:
    """The angular speed a joint stream stamped ``joint_t`` ``(N,)`` resolves, rad/s:
    ``RESOLVED_TURN_RAD / median(diff(joint_t))`` (``inf`` for fewer than two stamps)."""
    t = np.asarray(joint_t, dtype=float)
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    return RESOLVED_TURN_RAD / dt if dt > 0 else float("inf")


def motion_profile(
    t: FloatArray, angular_speed: FloatArray, joint_speed: FloatArray, resolved_rps: float = float("inf")
) -> MotionProfile:
    """:class:`MotionProfile` from predicted signals on a uniform grid ``t`` ``(G,)``, the angular speeds
    clipped at ``resolved_rps`` (:func:`resolved_speed` of the joint stream)."""
    angular_speed = np.minimum(angular_speed, resolved_rps)
    size = 1 << int(np.ceil(np.log2(2 * t.size)))
    spectra = {
        name: np.conj(np.fft.rfft(x - x.mean(axis=0), size, axis=0))
        for name, x in (("gyroscope", angular_speed), ("accelerometer", joint_speed))
    }
    return MotionProfile(t, angular_speed, joint_speed, size, spectra, float(resolved_rps))


@dataclass(frozen=True)
class OffsetSearch:
    """Outcome of :func:`coarse_time_offset`.

    Attributes:
        offset_s: the IMU latency found: the sample stamped ``t`` measured the motion at ``t - offset_s``.
        link: the 1-based link whose predicted signal correlates best.
        correlation: ``(n,)`` peak normalised correlation per candidate link.
        sharpness: peak correlation minus the best correlation more than ``0.25 s`` away from it
            (small: the offset is uncertain).
        source: ``"gyroscope"`` or ``"accelerometer"``.
        widened: the gyroscope's peak within ``+-max_offset_s`` lay at its edge or a peak beyond, up to
            ``+-``:data:`WIDE_OFFSET_S`, correlated clearly better: the offset was taken from there (a
            clock further off than the usual latencies).
    """

    offset_s: float
    link: int
    correlation: FloatArray
    sharpness: float
    source: str
    widened: bool = False


def normalised_xcorr(m: FloatArray, spectrum: FloatArray, p: FloatArray, size: int, max_lag: int) -> FloatArray:
    """Normalised correlation ``c[L]`` of ``m(t)`` with ``p(t - L)`` for ``L = -max_lag .. max_lag``
    (``spectrum`` the conjugate FFT of the mean-removed ``p``)."""
    m = m - m.mean()
    full = np.fft.irfft(np.fft.rfft(m, size) * spectrum, size)
    lags = np.arange(-max_lag, max_lag + 1)
    c = full[lags % size]
    denom = np.linalg.norm(m) * np.linalg.norm(p - p.mean())
    return c / denom if denom > 0 else np.zeros_like(c)


def parabola_peak(c: FloatArray, i: int) -> float:
    """The fractional index of the vertex of the parabola through ``c[i - 1], c[i], c[i + 1]`` (a peak's
    sub-sample position); ``i`` itself at an end of ``c`` or where the three points are not concave."""
    if 0 < i < c.size - 1:
        den = c[i - 1] - 2 * c[i] + c[i + 1]
        if den < 0:
            return float(i + 0.5 * (c[i - 1] - c[i + 1]) / den)
    return float(i)


def _spread_signal(t: FloatArray, accel: FloatArray, window_s: float) -> FloatArray:
    lo = np.searchsorted(t, t - window_s / 2)
    hi = np.searchsorted(t, t + window_s / 2, side="right")
    c1 = np.concatenate([np.zeros((1, 3)), np.cumsum(accel, axis=0)])
    c2 = np.concatenate([np.zeros((1, 3)), np.cumsum(accel * accel, axis=0)])
    n = np.maximum(hi - lo, 1)[:, None]
    mean = (c1[hi] - c1[lo]) / n
    var = np.maximum((c2[hi] - c2[lo]) / n - mean * mean, 0.0)
    return np.sqrt(var.sum(axis=1))


def widened_note(offset_s: float) -> str:
    """What a result notes of a coarse offset found beyond the usual search (:attr:`OffsetSearch.widened`)."""
    return (f"clock far off the robot's: coarse time offset {offset_s * 1e3:+.0f} ms, beyond the usual "
            f"+-{MAX_OFFSET_S * 1e3:.0f} ms (searched up to +-{WIDE_OFFSET_S:.0f} s)")  # fmt: skip


def coarse_time_offset(
    profile: MotionProfile,
    t: FloatArray,
    accel: FloatArray,
    gyro: FloatArray | None,
    links: range | list[int] | None = None,
    max_offset_s: float = MAX_OFFSET_S,
) -> OffsetSearch:
    """Coarse IMU time offset by cross-correlation (module docstring).

    Args:
        profile: the dataset's :class:`MotionProfile`.
        t: ``(M,)`` the unit's stamps, s; ``accel`` ``(M, 3)`` m/s^2, ``gyro`` ``(M, 3)`` rad/s or ``None``.
        links: candidate 1-based links (default: all).
    """
    g = profile.t
    n = profile.angular_speed.shape[1]
    candidates = list(range(1, n + 1)) if links is None else list(links)
    if gyro is not None and gyro_lost_share(gyro, accel, t) > GYRO_RAIL_MAX_SHARE:
        gyro = None  # at its rail or stuck throughout: it shows no motion to align on; the accelerometer does
    if gyro is not None:
        b = np.median(gyro, axis=0)
        measured = np.minimum(np.linalg.norm(gyro - b, axis=1), profile.resolved_rps)
        predicted = profile.angular_speed
        source = "gyroscope"
    else:
        measured = _spread_signal(t, accel, SPREAD_WINDOW_S)
        predicted = profile.joint_speed
        source = "accelerometer"
    # The unit's signal on the grid (zero-order where it has gaps: dropped samples are rare).
    inside = (g >= t[0]) & (g <= t[-1])
    m = np.zeros(g.size)
    m[inside] = np.interp(g[inside], t, measured)
    m[~inside] = np.median(measured)
    dt = float(g[1] - g[0])
    max_lag = max(1, int(np.ceil(max_offset_s / dt)))
    wide_lag = max(max_lag, min(int(np.ceil(WIDE_OFFSET_S / dt)), g.size // 2))
    spectra = profile.spectra[source]
    every = {k: normalised_xcorr(m, spectra[:, k - 1], predicted[:, k - 1], profile.fft_size, wide_lag)
             for k in candidates}  # fmt: skip

    def peak_within(lag: int) -> tuple[float, float, int, FloatArray, FloatArray, int]:
        best = (-np.inf, 0.0, candidates[0], np.zeros(0), np.full(n, np.nan), 0)
        corr = np.full(n, np.nan)
        for k, full in every.items():
            c = full[wide_lag - lag : wide_lag + lag + 1]
            i = int(np.argmax(c))
            corr[k - 1] = float(c[i])
            if c[i] > best[0]:
                best = (float(c[i]), (parabola_peak(c, i) - lag) * dt, k, c, corr, i)
        return (*best[:4], corr, best[5])

    peak, offset, link, c, corr, i = peak_within(max_lag)
    widened = False
    if wide_lag > max_lag and source == "gyroscope":  # at the edge, or far weaker than a peak beyond it
        wide = peak_within(wide_lag)
        widened = i in (0, c.size - 1) or wide[0] > peak + WIDE_MARGIN
        if widened:
            peak, offset, link, c, corr, _ = wide
    lags = (np.arange(c.size) - (c.size - 1) // 2) * dt
    far = np.abs(lags - offset) > 0.25
    sharpness = peak - float(c[far].max()) if np.any(far) else peak
    return OffsetSearch(float(offset), int(link), corr, float(sharpness), source, widened)


STEP_SIGMAS = 8.0
"""An interval longer than the stream's whole periods by this many stamp-jitter std is a clock step..."""
STEP_MIN_S = 20e-6
"""...and by at least this much, s."""
MIN_STEPS = 3
"""Fewer steps than this are not taken as periodic re-syncs."""


@dataclass(frozen=True)
class ClockSteps:
    """Periodic re-sync steps found in a unit's stamps (:func:`find_clock_steps`).

    A sensor clock that runs at ``1 + drift`` of the true rate, with stamps re-synchronised to the
    host every ``period_s``, makes stamps that are regular between re-syncs and jump by
    ``-drift * period`` at each: a sawtooth ``tau(t) = offset + drift (t - t_sync)``.

    Attributes:
        n_steps: steps found.
        period_s: mean interval between them, s.
        mean_step_s: mean step, s (positive: stamps jump forward, the sensor clock is slow).
        drift_ppm: ``-mean_step / period`` in ppm.
        sync_stamps: ``(n_steps,)`` the first stamp after each step, s.
    """

    n_steps: int
    period_s: float
    mean_step_s: float
    drift_ppm: float
    sync_stamps: FloatArray
    interval_s: float = float("nan")
    """The stream's median sample interval, s (for :meth:`extend`)."""
    threshold_s: float = float("nan")
    """Smallest deviation from whole intervals taken as a step, s (for :meth:`extend`)."""
    step_sum_s: float = float("nan")
    """Sum of the steps found, s (for :meth:`extend`)."""

    def extend(self, t_prev: float, t: FloatArray) -> ClockSteps:
        """The steps with those of newer stamps ``t`` ``(M,)`` (increasing, after ``t_prev``, the last
        stamp already seen) added, found as :func:`find_clock_steps` finds them (same interval and
        threshold; same sign as the steps so far): the streaming form of the search."""
        t = np.asarray(t, dtype=float)
        if t.size == 0 or not np.isfinite(self.interval_s) or t[0] <= t_prev:
            return self
        dt = np.diff(np.r_[t_prev, t])
        resid = dt - np.maximum(np.rint(dt / self.interval_s), 1.0) * self.interval_s
        idx = np.flatnonzero((np.abs(resid) > self.threshold_s) & (np.sign(resid) == np.sign(self.mean_step_s)))
        if idx.size == 0:
            return self
        syncs = np.r_[self.sync_stamps, t[idx]]
        n = self.n_steps + int(idx.size)
        total = self.step_sum_s + float(resid[idx].sum())
        period = float(np.median(np.diff(syncs)))
        mean_step = total / n
        drift_ppm = -mean_step / period * 1e6
        return ClockSteps(n, period, mean_step, drift_ppm, syncs, self.interval_s, self.threshold_s, total)

    def correct(self, t: FloatArray) -> FloatArray:
        """Stamps with the sawtooth removed: ``t - drift (t - t_sync)`` (the last re-sync at or before
        each stamp; one period before the first step for the stamps before it), s."""
        syncs = np.concatenate([[self.sync_stamps[0] - self.period_s], self.sync_stamps])
        i = np.clip(np.searchsorted(syncs, t, side="right") - 1, 0, syncs.size - 1)
        return t - 1e-6 * self.drift_ppm * (t - syncs[i])


def find_clock_steps(t: FloatArray) -> ClockSteps | None:
    """Periodic re-sync steps of a stamp stream ``t`` ``(M,)`` s, or ``None`` when the stamps show none.

    Each interval is compared with its nearest whole number of median periods (dropped samples
    leave whole periods); what is left is stamp jitter, except at a re-sync, where it stands out by
    :data:`STEP_SIGMAS` (robust jitter std) and :data:`STEP_MIN_S`. Steps must share their sign and
    recur at least :data:`MIN_STEPS` times; with jittery stamps (a millisecond) the steps of a few
    hundred ppm cannot be seen and ``None`` is returned.
    """
    dt = np.diff(np.asarray(t, dtype=float))
    if dt.size < 10:
        return None
    P = float(np.median(dt))
    whole = np.maximum(np.rint(dt / P), 1.0)
    resid = dt - whole * P
    jitter = 1.4826 * float(np.median(np.abs(resid - np.median(resid))))
    threshold = max(STEP_SIGMAS * jitter, STEP_MIN_S)
    idx = np.flatnonzero(np.abs(resid) > threshold)
    if idx.size < MIN_STEPS:
        return None
    steps = resid[idx]
    if not (np.all(steps > 0) or np.all(steps < 0)):
        return None
    syncs = t[idx + 1]
    period = float(np.median(np.diff(syncs)))
    if period <= 0:
        return None
    mean_step = float(np.mean(steps))
    return ClockSteps(
        int(idx.size), period, mean_step, -mean_step / period * 1e6, syncs, P, threshold, float(np.sum(steps))
    )


GAP_MIN_S = 0.2
"""A stamp interval longer than this (s)..."""
GAP_INTERVALS = 10.0
"""...and than this many median intervals is a gap, after which the unit's clock may have stepped."""
PIECE_MIN_S = 4.0
"""A piece between gaps is aligned on its own only when it spans this long, s."""
GAP_STEP_MIN_S = 0.005
"""A piece's offset that differs from the first piece's by more than this (s)..."""
GAP_STEP_SHARPNESS = 0.05
"""...with a correlation peak at least this distinct, is a one-off clock step at the gap."""
GAP_STEP_CORRECT_S = 0.05
"""Steps beyond this (s) are corrected in the stamps; smaller ones are named only: the robust fit of one
offset copes with them better than the pieces' coarse offsets (about 1-2 ms each) would correct them
(simulated ``host-gaps`` clocks: steps of N(0, 20 ms))."""


@dataclass(frozen=True)
class GapSteps:
    """One-off clock steps at stamp gaps (:func:`find_gap_steps`): a sensor that lost its link and
    re-synchronised (or a host that re-stamped after a pause) shifts its clock once at the gap.

    Attributes:
        gap_start_s, gap_end_s: ``(K,)`` the last stamp before and the first after each gap, s.
        step_s: ``(K,)`` the step at each gap (the offset after it minus before it), s; 0 where none was seen.
    """

    gap_start_s: FloatArray
    gap_end_s: FloatArray
    step_s: FloatArray

    @property
    def corrected(self) -> np.ndarray:
        """``(K,)`` the steps :meth:`correct` removes (beyond :data:`GAP_STEP_CORRECT_S`)."""
        return np.abs(self.step_s) > GAP_STEP_CORRECT_S

    def correct(self, t: FloatArray) -> FloatArray:
        """Stamps with the large steps removed: each stamp after gap ``k`` less the corrected steps of gaps
        ``<= k``, s."""
        t = np.asarray(t, dtype=float)
        k = np.searchsorted(self.gap_end_s, t, side="right")  # gaps at or before each stamp
        cum = np.r_[0.0, np.cumsum(np.where(self.corrected, self.step_s, 0.0))]
        return t - cum[k]

    def describe(self) -> str:
        parts = [
            f"{s * 1e3:+.0f} ms after the {e - b:.2f} s gap at {b:.1f} s"
            for b, e, s in zip(self.gap_start_s, self.gap_end_s, self.step_s, strict=True)
            if s != 0.0
        ]
        how = "corrected" if self.corrected.any() else "not corrected"
        return "clock stepped at stamp gaps: " + ", ".join(parts) + f" (found by cross-correlation, {how})"


def find_gaps(t: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``(start, end)`` stamps ``(K,)`` of the gaps in ``t`` (:data:`GAP_MIN_S`, :data:`GAP_INTERVALS`)."""
    t = np.asarray(t, dtype=float)
    if t.size < 10:
        return np.zeros(0), np.zeros(0)
    dt = np.diff(t)
    big = np.flatnonzero(dt > max(GAP_MIN_S, GAP_INTERVALS * float(np.median(dt))))
    return t[big], t[big + 1]


def find_gap_steps(
    profile: MotionProfile, t: FloatArray, accel: FloatArray, gyro: FloatArray | None
) -> GapSteps | None:
    """One-off clock steps at the gaps of a unit's stamps ``t`` ``(M,)`` (readings ``accel``/``gyro``
    ``(M, 3)``): each piece between gaps spanning :data:`PIECE_MIN_S` is aligned on its own by
    :func:`coarse_time_offset`; a piece whose offset differs from the previous aligned piece's by more
    than :data:`GAP_STEP_MIN_S` with a distinct peak makes a step at the gap before it. None without gaps
    or steps."""
    start, end = find_gaps(t)
    if start.size == 0:
        return None
    edges = np.r_[t[0], end]
    stops = np.r_[start, t[-1]]
    offsets: list[float | None] = []
    for a, b in zip(edges, stops, strict=True):
        m = (t >= a) & (t <= b)
        if b - a < PIECE_MIN_S or m.sum() < 50:
            offsets.append(None)
            continue
        s = coarse_time_offset(profile, t[m], accel[m], None if gyro is None else gyro[m])
        offsets.append(s.offset_s if s.sharpness >= GAP_STEP_SHARPNESS else None)
    steps = np.zeros(start.size)
    last = offsets[0]
    for k in range(start.size):
        o = offsets[k + 1]
        if o is not None and last is not None and abs(o - last) > GAP_STEP_MIN_S:
            steps[k] = o - last
        if o is not None:
            last = o
    if not np.any(steps):
        return None
    return GapSteps(start, end, steps)
