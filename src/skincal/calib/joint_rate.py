"""What a low-rate joint stream's report spacing does to the estimate, measured on the fit itself.

A joint stream reported every ``h`` seconds (a robot's 14 Hz pose reports) gives the link's
accelerations only through an interpolation between reports (:func:`~skincal.calib.preprocess.spline_condition`),
which cuts the motion's corners and flattens its peaks. The error this leaves in the estimate is
*systematic*: every part of the recording uses the same joint stream, so no split of the IMU samples
(:mod:`skincal.calib.consistency`) and no sandwich of the residuals can see it, yet on real 14 Hz
tool-pose recordings it moves the lever arm along the tool axis by centimetres.

Richardson's argument, applied to the calibration as a whole: with an error ``theta_h - theta* ~ c h^p``
of the report spacing, the same calibration on every second report (``theta_2h``: both phases, averaged)
and on every third (``theta_3h``: all three phases) gives::

    theta_2h - theta_h ~ (2^p - 1) c h^p,   theta_3h - theta_h ~ (3^p - 1) c h^p
    r = |theta_2h - theta_h| / |theta_3h - theta_h| = (2^p - 1) / (3^p - 1)      (p = 2: r = 0.375)
    b = (theta_2h - theta_h) / (2^p - 1)     the full fit's own error theta_h - theta*

``p`` is solved from ``r`` (the shifts normalised by the full fit's std, pose components only) and
clipped to :data:`ORDER_RANGE`. The argument holds only where the error converges like a power of
``h``: a ratio of :data:`RATIO_MAX` (``p = 1``) or more says the thinned streams no longer resolve the
motion (a simulated 14 Hz Panda running the ``fast`` protocol, whose single-joint moves last about as
long as two reports: ratios 0.5-2.2, the thinned fits off by 0.1-0.5 m while the full fit is within
2 mm and honest), and the unit is then left as it was, with a note. On the real ABB tool recordings
(smooth multi-joint paths, 14 Hz) the ratio came out at about 0.37 (``p = 2``) on most, the full
fit's lever arm along the tool axis moving 10-35 mm.

The estimate is not corrected (``b`` is itself uncertain); the pose covariance (``x, y, z, rx, ry, rz``
in the link frame, m and rad) gains ``b b^T`` and the std the matching terms in quadrature::

    Sigma' = Sigma + b b^T,     s_i' = sqrt(s_i^2 + b_i^2)

and a unit whose term exceeds its std on some component is warned. A stream at or above
:data:`~skincal.calib.preprocess.LOW_RATE_HZ` (a robot controller's 100-1000 Hz) is left alone: its
interpolation error is negligible beside the noise, and the check would only cost time.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy.optimize import brentq

from skincal.calib.consistency import pose_difference, pose_vector
from skincal.data.dataset import Dataset, JointStates
from skincal.data.result import CalibrationResult, UnitResult
from skincal.kinematics.transforms import FloatArray

ORDER_RANGE = (1.0, 4.0)
"""Range of the convergence order ``p`` the full fit's error is extrapolated with."""
RATIO_MAX = 0.5
"""A shift ratio ``r`` at or above this (``p <= 1``, or thinned fits that jump rather than converge)
is outside Richardson's regime: the check is not applied."""
MIN_THINNED_REPORTS = 30
"""A thinned stream with fewer reports than this is not calibrated (the check is then skipped)."""
THINNINGS = (2, 3)
"""The stream is refitted on every ``k``-th report for each ``k`` here, once per phase (``k`` refits)."""


def thinnings(t: np.ndarray) -> tuple[int, ...]:
    """The thinnings :func:`check` refits a joint stream stamped ``t`` with: those of :data:`THINNINGS` that keep
    :data:`MIN_THINNED_REPORTS` reports (one refit per phase, ``k`` for every ``k``-th report)."""
    return tuple(every for every in THINNINGS if len(t) // every >= MIN_THINNED_REPORTS)


AXES = ("x", "y", "z")

Refit = Callable[[Dataset, dict[str, int]], CalibrationResult]
"""``refit(thinned, links)``: the method, run from scratch on a dataset whose joint stream is thinned,
with the units' links given."""


@dataclass(frozen=True)
class JointRateTerm:
    """One unit's report-spacing check (module docstring).

    Attributes:
        report_rate_hz: median rate of the reported joint stream, Hz.
        order: the convergence order ``p`` used (clipped to :data:`ORDER_RANGE`).
        ratio: the measured shift ratio ``r`` (below :data:`RATIO_MAX`).
        bias_position_m: ``(3,)`` the full fit's estimated error ``b``, position, link frame, m.
        bias_rotation_deg: ``(3,)`` the same for the rotation (rotation vector about the link axes), deg.
        fits: how many thinned calibrations entered (2 + 3).
    """

    report_rate_hz: float
    order: float
    ratio: float
    bias_position_m: tuple[float, float, float]
    bias_rotation_deg: tuple[float, float, float]
    fits: int

    def to_json(self) -> dict[str, Any]:
        def num(x: float) -> float | None:
            return float(x) if np.isfinite(x) else None

        return {
            "report_rate_hz": num(self.report_rate_hz),
            "order": num(self.order),
            "ratio": num(self.ratio),
            "bias_position_m": [num(v) for v in self.bias_position_m],
            "bias_rotation_deg": [num(v) for v in self.bias_rotation_deg],
            "fits": self.fits,
        }


def thinned(dataset: Dataset, every: int, phase: int) -> Dataset:
    """``dataset`` with its joint stream reduced to every ``every``-th report from ``phase`` on."""
    j = dataset.joints
    assert j is not None
    pick = slice(phase, None, every)
    return replace(
        dataset,
        joints=JointStates(j.t[pick], j.q[pick], j.qd[pick], None if j.qdd is None else j.qdd[pick]),
    )


def order_from_ratio(ratio: float) -> float:
    """The order ``p`` with ``(2^p - 1) / (3^p - 1) = ratio``, clipped to :data:`ORDER_RANGE` (the
    function falls from 0.5 at ``p = 0`` towards 0 as ``p`` grows; a ratio of 0.5 or more gives the
    lower end, a non-finite one too)."""
    lo, hi = ORDER_RANGE

    def f(p: float) -> float:
        return (2.0**p - 1.0) / (3.0**p - 1.0) - ratio

    if not np.isfinite(ratio) or f(lo) <= 0.0:
        return lo
    if f(hi) >= 0.0:
        return hi
    return float(brentq(f, lo, hi, xtol=1e-6))


def _shift(full: UnitResult, fits: list[UnitResult]) -> FloatArray | None:
    """``(6,)`` mean over ``fits`` of their pose minus the full result's (position m, rotation vector of
    ``R_fit R_full^T`` about the link axes, rad); None when a fit put the unit on another link."""
    p0, R0, _ = pose_vector(full)
    rows = []
    for f in fits:
        if f.pose.link != full.pose.link:
            return None
        p, R, _ = pose_vector(f)
        rows.append(pose_difference(p0, R0, p, R))
    return np.mean(rows, axis=0)


def _std(unit: UnitResult) -> FloatArray:
    """``(6,)`` the reported std (m, rad); NaN where undetermined or absent."""
    p = np.full(3, np.nan) if unit.position_std_m is None else np.asarray(unit.position_std_m, dtype=float)
    r = np.full(3, np.nan)
    if unit.rotation_std_deg is not None:
        r = np.radians(np.asarray(unit.rotation_std_deg, dtype=float))
    return np.r_[p, r]


def term(
    full: UnitResult, half: list[UnitResult], third: list[UnitResult], rate_hz: float
) -> tuple[JointRateTerm | None, str]:
    """The unit's :class:`JointRateTerm` from its full result and the thinned fits (module docstring), or
    None and why not: a thinned fit missing or on another link, or a ratio outside Richardson's regime."""
    d2 = _shift(full, half) if len(half) == 2 else None
    d3 = _shift(full, third) if len(third) == 3 else None
    if d2 is None or d3 is None:
        return None, "the thinned joint streams could not be calibrated on this unit's link"
    s = pose_vector(full)[2]  # NaN where undetermined or zero
    ok = np.isfinite(s)
    if not np.any(ok):
        return None, "no pose component has a std"
    n2, n3 = np.linalg.norm(d2[ok] / s[ok]), np.linalg.norm(d3[ok] / s[ok])
    ratio = float(n2 / n3) if n3 > 0 else np.inf
    if not ratio < RATIO_MAX:
        return None, (
            f"the thinned joint streams do not resolve the motion (shift ratio {ratio:.2f}, at least {RATIO_MAX}): "
            "the report spacing's error cannot be extrapolated"
        )
    p = order_from_ratio(ratio)
    b = d2 / (2.0**p - 1.0)  # (theta_2h - theta_h) / (2^p - 1) = theta_h - theta*
    return JointRateTerm(float(rate_hz), p, ratio, tuple(b[:3]), tuple(np.degrees(b[3:])), 5), ""  # type: ignore[arg-type]


def apply(unit: UnitResult, t: JointRateTerm) -> UnitResult:
    """``unit`` with the term in its std and covariance (module docstring), ``extras["joint_rate"]`` and,
    where the term exceeds the std of a component, a warning naming it."""
    b = np.r_[np.asarray(t.bias_position_m), np.radians(np.asarray(t.bias_rotation_deg))]
    s = _std(unit)
    big = [i for i in range(6) if np.isfinite(s[i]) and abs(b[i]) > s[i]]
    with np.errstate(invalid="ignore"):
        s_new = np.sqrt(s**2 + b**2)  # NaN (undetermined) stays NaN
    pos = None if unit.position_std_m is None else s_new[:3]
    rot = None if unit.rotation_std_deg is None else np.degrees(s_new[3:])
    cov = unit.pose_covariance
    if cov is not None:
        cov = np.asarray(cov, dtype=float) + np.outer(b, b)
    warnings = list(unit.warnings)
    if big:
        named = ", ".join(
            f"position {AXES[i]} {1e3 * b[i]:+.1f} mm" if i < 3
            else f"rotation {AXES[i - 3]} {np.degrees(b[i]):+.2f} deg"
            for i in big
        )
        warnings.append(
            f"the joint stream's {t.report_rate_hz:.0f} Hz reports limit this pose (fits on every second and third "
            f"report move it; estimated error {named}): std raised to include it"
        )
    extras = {**unit.extras, "joint_rate": t.to_json()}
    return replace(unit, position_std_m=pos, rotation_std_deg=rot, pose_covariance=cov, warnings=tuple(warnings),
                   extras=extras)  # fmt: skip


def check(dataset: Dataset, result: CalibrationResult, refit: Refit) -> CalibrationResult:
    """``result`` with each unit's report-spacing term (module docstring) when ``dataset``'s joint stream
    is low-rate; ``refit`` runs the method on a thinned dataset. Where the term cannot be had (a thinned
    fit failed, or the ratio is outside Richardson's regime) the unit is left as it was and a note says why."""
    from skincal.calib.preprocess import is_low_rate

    j = dataset.joints
    if j is None or not result.units or not is_low_rate(j.t):
        return result
    links = {name: int(u.pose.link) for name, u in result.units.items() if u.observable}
    if not links:
        return result
    rate_hz = 1.0 / float(np.median(np.diff(j.t)))
    fits: dict[int, list[CalibrationResult]] = {every: [] for every in THINNINGS}
    for every in thinnings(j.t):
        for phase in range(every):
            try:
                fits[every].append(refit(thinned(dataset, every, phase), links))
            except Exception:  # noqa: BLE001 - a thinned stream the method cannot take leaves the check out
                continue
    units = dict(result.units)
    for name in links:
        half = [r.units[name] for r in fits[2] if name in r.units]
        third = [r.units[name] for r in fits[3] if name in r.units]
        t, why = term(units[name], half, third, rate_hz)
        if t is None:
            unit = units[name]
            units[name] = replace(unit, notes=(*unit.notes, f"joint-rate check not applied: {why}"))
            continue
        units[name] = apply(units[name], t)
    return replace(result, units=units)
