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
