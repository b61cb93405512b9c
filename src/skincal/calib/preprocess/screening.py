"""Reading screening of every channel (saturation, stuck rails: :func:`screen_readings`,
:func:`screen_channels`) and the unit checks of a stream (:func:`check_accel_units`: m/s^2, not g,
milli-g or raw counts; :func:`check_gyro_units`: rad/s, not deg/s)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skincal.errors import CalibrationError
from skincal.kinematics.transforms import FloatArray

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
    """The outcome of :func:`screen_channels`: ``keep`` ``(M,)`` usable samples (their accelerometer
    reading), ``saturated`` ``(M,)`` samples dropped at an accelerometer rail, ``gyro_saturated``
    ``(M,)`` kept samples whose gyroscope reading alone is at a rail or stuck (that reading is unusable, the
    accelerometer's is not), and the warnings."""

    keep: np.ndarray
    saturated: np.ndarray
    warnings: tuple[str, ...]
    gyro_saturated: np.ndarray | None = None


STUCK_MIN_S = 1.0
"""A run of exactly repeated consecutive readings of one accelerometer axis lasting this long, s, (or
:data:`STUCK_MIN_FRACTION` of the stream, and at least :data:`STUCK_MIN_SAMPLES` samples)..."""
STUCK_MIN_FRACTION = 0.02
STUCK_MIN_SAMPLES = 10
STUCK_OTHERS_PTP = 0.2
"""...while another axis of the same samples varies by more than this, m/s^2 peak to peak, is a register
that stopped updating (:func:`screen_readings`; streamed: :class:`~skincal.calib.online.stuck.StuckScreen`)."""
GYRO_STUCK_OTHERS_PTP = 0.05
"""The same for a gyroscope axis, whose other axes vary by more than this, rad/s peak to peak (3 deg/s: ten
times a MEMS gyroscope's noise at 100 Hz) (:func:`screen_channels`)."""


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
        for extreme in dict.fromkeys((fin.max(), fin.min())):  # one rail when the axis never leaves it
            hits = a == extreme
            n_hits = np.count_nonzero(hits)
            if not (abs(extreme) > minimum and hits.mean() > SATURATION_FRACTION and n_hits > 3):
                continue
            if pile_up and n_hits <= RAIL_SHARE * np.count_nonzero(np.abs(fin - extreme) <= RAIL_BAND * abs(extreme)):
                continue
            out.append((k, float(extreme), hits))
    return out


GYRO_RAIL_MAX_SHARE = 0.5
"""A gyroscope at its rail in more than this share of its samples is not used at all (not for the clock
search either): its rest readings are gone too (a stuck register), and without them its bias and the
clock's cross-correlation rest on clipped motion alone (a stuck one aligned a unit 0.5 s off)."""


def gyro_lost(gyro: FloatArray, accel: FloatArray, t: FloatArray | None = None) -> tuple[np.ndarray, list[str]]:
    """``(M,)`` samples whose gyroscope reading ``gyro`` ``(M, 3)`` rad/s is unusable, and the warnings: some
    axis at a rail (beyond :data:`GYRO_SATURATION_MIN`, piled up there) or stuck (:func:`stuck_runs`: the
    other gyroscope axes varying by more than :data:`GYRO_STUCK_OTHERS_PTP`, or the accelerometer ``accel``
    ``(M, 3)`` by more than :data:`STUCK_OTHERS_PTP`: a dead gyroscope reading zeros on every axis while the
    unit moves is stuck too). ``t``: the stamps, s (the stuck runs' length)."""
    gyro, accel = np.asarray(gyro, dtype=float), np.asarray(accel, dtype=float)
    lost = np.zeros(len(gyro), dtype=bool)
    warnings = []
    for k, value, hits in _rails(gyro, GYRO_SATURATION_MIN, pile_up=True):
        lost |= hits
        warnings.append(
            f"gyroscope {'xyz'[k]} axis saturates at {value:+.4g} rad/s ({np.degrees(value):+.0f} deg/s) in "
            f"{100 * hits.mean():.1f}% of samples; those gyroscope readings are ignored (the accelerometer's "
            "are kept)"
        )
    min_run = stuck_min_run(len(gyro), t)
    runs = stuck_runs(gyro, t, min_run, GYRO_STUCK_OTHERS_PTP, GYRO_SATURATION_MIN, accel, STUCK_OTHERS_PTP)
    for k, value, i, j, count, span in runs:
        lost[i : j + 1] = True
        warnings.append(f"gyroscope {'xyz'[k]} axis stuck at {value:.4g} rad/s {span} ({count} gyroscope readings "
                        "ignored; the accelerometer's are kept)")  # fmt: skip
    return lost, warnings


def gyro_lost_share(gyro: FloatArray, accel: FloatArray, t: FloatArray | None = None) -> float:
    """The share of the samples whose gyroscope reading is unusable (:func:`gyro_lost`)."""
    return float(gyro_lost(gyro, accel, t)[0].mean()) if len(gyro) else 0.0


def screen_channels(
    unit: str, accel: FloatArray, gyro: FloatArray | None = None, t: FloatArray | None = None
) -> Screening:
    """:func:`screen_readings` of the accelerometer, and the same saturation test on the gyroscope
    (rails beyond :data:`GYRO_SATURATION_MIN`): a gyroscope at its rail under-reads the rotation
    exactly when it matters most, so its reading there is unusable; the sample's accelerometer
    reading is not (it needs no gyroscope), and dropping it too would leave only the slower motion,
    where a joint stream's acceleration estimate errs the most (SO-101's ``fast`` motion with a
    +-245 deg/s gyroscope: 46 mm off, 8 std, when those samples were dropped whole). A stuck
    gyroscope axis (:func:`gyro_lost`) leaves its readings out the same way (one stuck at 0.37 rad/s from
    30 % of a simulated Panda session put ``mle`` on the wrong link, 148 mm off; a dead one reading zeros,
    90 mm off at 4.5 std)."""
    t = None if t is None else np.asarray(t, dtype=float)
    keep, warnings = screen_readings(unit, accel, t)
    saturated = np.zeros(len(keep), dtype=bool)
    for _, _, hits in _rails(np.asarray(accel, dtype=float), SATURATION_MIN):
        saturated |= hits
    gyro_saturated = np.zeros(len(keep), dtype=bool)
    if gyro is not None:
        gyro_saturated, gyro_warnings = gyro_lost(gyro, accel, t)
        warnings += gyro_warnings
    return Screening(keep, saturated & ~keep, tuple(warnings), gyro_saturated & keep)


def stuck_min_run(n: int, t: FloatArray | None, min_s: float = STUCK_MIN_S,
                  min_fraction: float = STUCK_MIN_FRACTION) -> float:  # fmt: skip
    """The samples a run of repeats needs to be a stuck axis in a stream of ``n`` samples stamped ``t`` (s; None:
    unknown): ``min_s`` at the median sample interval or ``min_fraction`` of the stream, whichever is shorter,
    and at least :data:`STUCK_MIN_SAMPLES`."""
    min_run = min_fraction * n
    if t is not None and n > 1:
        dt = float(np.median(np.diff(t)))
        if dt > 0:
            min_run = min(min_run, min_s / dt)
    return max(min_run, float(STUCK_MIN_SAMPLES))


def stuck_runs(
    x: FloatArray,
    t: FloatArray | None,
    min_run: float,
    others_ptp: float,
    rail_min: float,
    also: FloatArray | None = None,
    also_ptp: float = np.inf,
) -> list[tuple[int, float, int, int, int, str]]:
    """The stuck axes of a channel ``x`` ``(M, 3)``: runs of exactly repeated consecutive values of one axis,
    at least ``min_run`` long, while another axis of the same samples varies by more than ``others_ptp`` peak
    to peak (a unit at rest whose noise stays below one LSB repeats its readings too, but then its other axes
    do not move); a run at the axis' extreme beyond ``rail_min`` is a rail, left to the saturation test. Runs
    are judged on the complete (finite) samples. Returns ``(axis, value, first, last, samples, span)`` with
    ``first``/``last`` indices into ``x`` and ``span`` the words "from 30.0 s to 42.0 s" (stamps ``t``, s, or
    sample indices when ``t`` is None; "to the end" for a run that reaches it). ``also`` ``(M, J)``: another
    channel of the same samples whose varying by more than ``also_ptp`` shows the unit moving too."""
    rows = np.flatnonzero(np.all(np.isfinite(x), axis=1))
    fin = x[rows]
    extra = np.zeros((rows.size, 0)) if also is None else np.asarray(also, dtype=float)[rows]
    limit = np.r_[np.full(x.shape[1] - 1, others_ptp), np.full(extra.shape[1], also_ptp)]
    out = []
    for k in range(x.shape[1]):
        af, others = fin[:, k], np.hstack([np.delete(fin, k, axis=1), extra])
        same = np.concatenate([[False], af[1:] == af[:-1], [False]])  # same[i]: sample i repeats sample i - 1
        edges = np.flatnonzero(np.diff(same.astype(np.int8)))
        for i0, i1 in zip(edges[::2], edges[1::2], strict=True):
            start, end = int(i0), int(i1) + 1  # finite samples [start, end) hold one value
            value = float(af[start])
            if end - start < min_run:
                continue
            if abs(value) > rail_min and value in (af.max(), af.min()):
                continue  # a rail: the saturation test judges it
            if not np.any(np.ptp(others[start:end], axis=0) > limit):
                continue  # the whole unit is still
            i, j = int(rows[start]), int(rows[end - 1])
            last = end == rows.size
            if t is None:
                span = f"from sample {i} " + ("to the end" if last else f"to sample {j}")
            else:
                span = f"from {t[i]:.1f} s " + ("to the end" if last else f"to {t[j]:.1f} s")
            out.append((k, value, i, j, end - start, span))
    return out


def screen_readings(
    unit: str,
    accel: FloatArray,
    t: FloatArray | None = None,
    *,
    stuck_min_s: float = STUCK_MIN_S,
    stuck_min_fraction: float = STUCK_MIN_FRACTION,
    stuck_others_ptp: float = STUCK_OTHERS_PTP,
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
    min_run = stuck_min_run(n, t, stuck_min_s, stuck_min_fraction)
    for k, axis in enumerate("xyz"):
        if n > 10 and np.ptp(accel[:, k]) < 1e-9:
            raise CalibrationError(f"unit '{unit}': accelerometer {axis} axis is stuck at {accel[0, k]:.4g} m/s^2")
    for k, value, i, j, count, span in stuck_runs(accel, t, min_run, stuck_others_ptp, SATURATION_MIN):
        keep[i : j + 1] = False
        warnings.append(f"accelerometer {'xyz'[k]} axis stuck at {value:.4g} m/s^2 {span} ({count} samples ignored)")
    for k, axis in enumerate("xyz"):
        a = accel[:, k]
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
