"""Which link is a unit on? The activity matrix of Mittendorfer & Cheng (2012).

A unit fixed to link ``n`` moves when any joint ``j <= n`` moves and stays still when a joint
``j > n`` moves. For every excited joint ``j`` the activity is the largest, over that joint's
dynamic segments, RMS deviation of the measured specific force from its segment mean; the noise
floor is the median RMS deviation over static segments. The link is the last joint whose
activity stands clearly above the floor. When angular rates are available (``use_gyro``) the
same statistic on the gyroscope, whose reading is zero for every joint after the unit's link, is
used as well: it is immune to the one blind spot of accelerometers, a joint axis through the
unit that stays vertical.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skincal.calib.preprocess import UnitSamples
from skincal.kinematics.transforms import FloatArray

ABSOLUTE_FLOOR_ACCEL = 0.02
"""Smallest accelerometer activity (RMS deviation, m/s^2) ever taken as motion (~2 mg)."""
ABSOLUTE_FLOOR_GYRO = 0.02
"""Smallest gyroscope activity (RMS, rad/s) ever taken as motion (~1 deg/s)."""
ACTIVITY_RATIO = 8.0
"""Activity must exceed this multiple of the noise floor to count as excitation."""


@dataclass(frozen=True)
class LinkAssignment:
    """Result of link discovery for one unit.

    Attributes:
        link: 1-based link, or 0 when no joint excites the unit.
        confidence: in [0, 1]; how clearly the assigned joint's activity exceeds the threshold
            while the next joint's stays below it.
        activity: ``(n,)`` activity per joint divided by the threshold (>= 1 means "moves").
        warnings: human-readable notes (ambiguity, unexcited joints).
    """

    link: int
    confidence: float
    activity: FloatArray
    warnings: tuple[str, ...] = ()


def _rms_per_segment(values: FloatArray, segment: np.ndarray) -> tuple[np.ndarray, FloatArray]:
    segs, inverse, counts = np.unique(segment, return_inverse=True, return_counts=True)
    sums = np.zeros((segs.size, values.shape[1]))
    np.add.at(sums, inverse, values)
    dev = values - (sums / counts[:, None])[inverse]
    sq = np.zeros(segs.size)
    np.add.at(sq, inverse, np.sum(dev * dev, axis=1))
    return segs, np.sqrt(sq / counts)


def _activity(samples: UnitSamples, values: FloatArray, absolute_floor: float, n_joints: int) -> FloatArray:
    finite = np.all(np.isfinite(values), axis=1)  # a gyroscope's readings at its rail are NaN
    if not finite.all():
        samples, values = samples.select(finite), values[finite]
    static = samples.kind == 0
    floor = absolute_floor
    if np.any(static):
        _, rms_static = _rms_per_segment(values[static], samples.segment[static])
        floor = max(absolute_floor, ACTIVITY_RATIO * float(np.median(rms_static)))
    activity = np.zeros(n_joints)
    for j in range(n_joints):
        m = (samples.kind == 1) & (samples.joint == j)
        if np.count_nonzero(m) >= 3:
            _, rms = _rms_per_segment(values[m], samples.segment[m])
            activity[j] = float(rms.max()) / floor
        else:
            activity[j] = np.nan
    return activity


def discover_link(samples: UnitSamples, n_joints: int, *, use_gyro: bool = False) -> LinkAssignment:
    """Assign a unit to the last joint whose motion excites it (see module docstring)."""
    activity = _activity(samples, samples.accel, ABSOLUTE_FLOOR_ACCEL, n_joints)
    source = "accelerometer"
    if use_gyro and samples.gyro is not None:
        activity = np.fmax(activity, _activity(samples, samples.gyro, ABSOLUTE_FLOOR_GYRO, n_joints))
        source = "accelerometer and gyroscope"
    warnings: list[str] = []
    unexcited = [j + 1 for j in range(n_joints) if np.isnan(activity[j])]
    if unexcited:
        warnings.append(f"joints {unexcited} were never excited; link discovery cannot consider them")
    moving = np.flatnonzero(np.nan_to_num(activity) >= 1.0)
    if moving.size == 0:
        return LinkAssignment(0, 0.0, activity, (*warnings, f"no joint motion excites this unit ({source})"))
    link = int(moving[-1]) + 1
    a_link = float(activity[link - 1])
    later = np.nan_to_num(activity[link:], nan=0.0)
    a_next = float(later.max()) if later.size else 0.0
    # Confidence: margin of the assigned joint above 1 and of the later joints below 1, on a log scale.
    margin = min(np.log10(a_link), -np.log10(max(a_next, 1e-12)))
    confidence = float(np.clip(margin / np.log10(ACTIVITY_RATIO), 0.0, 1.0))
    if confidence < 0.5:
        warnings.append(
            f"link {link} is ambiguous: joint {link} activity {a_link:.2f}x threshold"
            + (f", next joint {a_next:.2f}x" if later.size else "")
        )
    return LinkAssignment(link, confidence, activity, tuple(warnings))


GYRO_ROTATES = 0.05
"""A gyroscope whose bias-corrected rate exceeds this (rms over the unit's samples), rad/s (3 deg/s),
rotates: its link's chain must rotate it."""
GYRO_MISMATCH = 0.5
"""A link whose rotation rate misses the gyroscope's rate by more than this fraction (rms of the
difference over rms of the rate) cannot carry the unit."""


@dataclass(frozen=True)
class GyroLinks:
    """Which links can carry a unit whose gyroscope turns (:func:`gyro_rules_out`).

    Attributes:
        rotates: the gyroscope turns (rms rate above :data:`GYRO_ROTATES`).
        mismatch: ``(n,)`` per link ``k``: ``rms(|w_meas| - |w_k|) / rms(|w_meas|)``.
        allowed: ``(n,)`` True for the links not ruled out (all True when the gyroscope does not turn).
        rate_rms: rms of the gyroscope's rate, rad/s; ``link_rms``: ``(n,)`` of each link's.
    """

    rotates: bool
    mismatch: FloatArray
    allowed: np.ndarray
    rate_rms: float
    link_rms: FloatArray

    def note(self) -> str | None:
        """Words for the links ruled out, or ``None`` when none is."""
        out = [int(k) + 1 for k in np.flatnonzero(~self.allowed)]
        if not out:
            return None
        parts = ", ".join(f"{k} ({self.link_rms[k - 1]:.2g})" for k in out)
        return (
            f"links {out} ruled out by the gyroscope: it turns at {self.rate_rms:.2g} rad/s rms, unlike their "
            f"chain (link rate rms in rad/s: {parts})"
        )


def gyro_rules_out(gyro_rate: FloatArray, link_rate: FloatArray) -> GyroLinks:
    """Links a turning gyroscope rules out, from magnitudes alone.

    A gyroscope on link ``k`` reads ``w_meas = R_link_su^T w_k + b + noise``, so its rate
    ``|w_meas - b|`` ``(M,)`` equals the link's rotation rate from the chain ``|w_k|`` ``(M, n)`` at
    the same instants, whatever the unit's rotation (a scale error of a few percent aside). A link
    whose rate misses it by more than :data:`GYRO_MISMATCH` (relative rms) is ruled out: a
    translation-only chain (prismatic joints) cannot turn the unit at all, and a link before the
    wrist turns it differently. Never rules out every link (a gyroscope in another unit, or a clock
    far off, would; the caller's checks name those): if none is left, all are allowed.
    """
    g = np.asarray(gyro_rate, dtype=float)
    w = np.asarray(link_rate, dtype=float)
    ok = np.isfinite(g) & np.all(np.isfinite(w), axis=1)
    g, w = g[ok], w[ok]
    n = w.shape[1]
    rate_rms = float(np.sqrt(np.mean(g * g))) if g.size else 0.0
    link_rms = np.sqrt(np.mean(w * w, axis=0)) if g.size else np.zeros(n)
    if rate_rms < GYRO_ROTATES:
        return GyroLinks(False, np.zeros(n), np.ones(n, dtype=bool), rate_rms, link_rms)
    mismatch = np.sqrt(np.mean((w - g[:, None]) ** 2, axis=0)) / rate_rms
    allowed = mismatch <= GYRO_MISMATCH
    if not allowed.any():
        allowed = np.ones(n, dtype=bool)
    return GyroLinks(True, mismatch, allowed, rate_rms, link_rms)


def activity_in(samples: UnitSamples, mask: np.ndarray, *, use_gyro: bool = False) -> float:
    """The unit's activity over the samples ``mask`` ``(M,)`` (e.g. general motion no segment
    tags) as :func:`discover_link` measures it per joint: the RMS deviation of the readings from
    their mean over those samples divided by the threshold (noise floor of the static segments
    times :data:`ACTIVITY_RATIO`, at least the absolute floor); the larger of accelerometer and
    gyroscope with ``use_gyro``. NaN with fewer than 3 samples."""
    if np.count_nonzero(mask) < 3:
        return float("nan")
    channels = [(samples.accel, ABSOLUTE_FLOOR_ACCEL)]
    if use_gyro and samples.gyro is not None:
        channels.append((samples.gyro, ABSOLUTE_FLOOR_GYRO))
    static = samples.kind == 0
    out = 0.0
    for values, absolute_floor in channels:
        finite = np.all(np.isfinite(values), axis=1)  # a gyroscope's readings at its rail are NaN
        floor = absolute_floor
        if np.any(static & finite):
            _, rms_static = _rms_per_segment(values[static & finite], samples.segment[static & finite])
            floor = max(absolute_floor, ACTIVITY_RATIO * float(np.median(rms_static)))
        v = values[mask & finite]
        if len(v) < 3:
            continue
        out = max(out, float(np.sqrt(np.mean(np.sum((v - v.mean(axis=0)) ** 2, axis=1)))) / floor)
    return out
