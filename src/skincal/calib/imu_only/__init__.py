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

The rests are :mod:`~skincal.calib.imu_only.rests`, the accelerometer fitted to them
:mod:`~skincal.calib.imu_only.ellipsoid`, a unit's pose relative to the reference
:mod:`~skincal.calib.imu_only.relative`; this module is the method (:func:`calibrate_relative`) and its
evaluation.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from skincal.calib.imu_only.ellipsoid import (
    MAX_SCALE_STD,
    ORIENTATIONS_ADVISED,
    ORIENTATIONS_DIAGONAL,
    ORIENTATIONS_FULL,
    AccelFit,
    fit_accel_ellipsoid,
    fit_unit_accelerometer,
)
from skincal.calib.imu_only.relative import OTHER_BODY_RATIO, RelativeFit, coarse_offset, fit_relative
from skincal.calib.imu_only.rests import common_rests, distinct_orientations, rest_means
from skincal.data.dataset import Dataset
from skincal.data.imu_calibration import ImuCalibration
from skincal.data.result import REFERENCE_LINK, CalibrationResult, UnitResult
from skincal.errors import ConfigError, DatasetError
from skincal.kinematics.transforms import FloatArray, nearest_rotation
from skincal.names import name_problem, printable
from skincal.parallel import one_blas_thread
from skincal.skin.pose import SkinUnitPose

__all__ = [
    "AccelFit",
    "RelativeOptions",
    "calibrate_relative",
    "coarse_offset",
    "common_rests",
    "compare_with_joint_result",
    "evaluate_relative",
    "fit_accel_ellipsoid",
    "fit_relative",
    "fit_unit_accelerometer",
]


METHOD = "imu-only"


@dataclass(frozen=True)
class RelativeOptions:
    """Options of :func:`calibrate_relative` (``skincal calibrate --reference UNIT --option name=value``),
    parsed by :func:`skincal.calib.options.parse_options` like every method's.

    Attributes:
        max_offset_s: largest time offset between two units' stamps searched, s.
        other_body_ratio: angular-velocity misfit (relative) above which a unit is on another body.
        reference_scale_std, reference_misalignment_std: the reference accelerometer's uncalibrated
            per-axis scale and cross-axis error (used when the rests do not calibrate it).
        consistency: the split check (:mod:`skincal.calib.consistency`: halves in time, alternate
            windows, the calmer and the livelier half by the gyroscopes' speed; std inflated where they
            disagree beyond it).
    """

    max_offset_s: float = field(default=1.0, metadata={"min": 0.0})
    other_body_ratio: float = field(default=OTHER_BODY_RATIO, metadata={"min": 0.0})
    reference_scale_std: float = field(default=0.0, metadata={"min": 0.0, "max": 0.999})
    reference_misalignment_std: float = field(default=0.0, metadata={"min": 0.0, "max": 0.999})
    consistency: bool = True


@one_blas_thread
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
    consistency: bool = True,
    accel_fits: dict[str, AccelFit] | None = None,
) -> CalibrationResult:
    """Poses of ``units`` (default: every unit) in the frame of unit ``reference`` from the IMUs alone.

    When the body rests in enough distinct orientations (module docstring), the reference's accelerometer
    is fitted to the rests and positions come out in metres, with the fit's std in theirs. Otherwise the
    reference accelerometer is the gauge of every position (its scale error ``s`` makes
    ``r_est = (1 + s) r``): ``reference_scale_std`` and ``reference_misalignment_std`` (the size of its
    uncalibrated per-axis scale error and symmetric cross-axis error, e.g. 0.03 and 0.01 for the
    ``real`` IMU preset) add that to the position std; 0 (default) takes the reference as exact. With
    the diagonal fit (6-8 orientations) only ``reference_misalignment_std`` is added. With
    ``consistency`` (default) independent parts of the recording are calibrated the same way and each
    unit's std is inflated where they disagree beyond it (:func:`skincal.calib.consistency.check`; the
    unit's ``consistency`` block). ``accel_fits``: the units' accelerometer fits to the rests to use
    instead of fitting them here (the parts of the split check take the whole recording's, so that
    their positions share its gauge; a part holds too few rests to fit its own).

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
    if accel_fits is None:
        accel_fits = {}
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
    result = CalibrationResult(
        METHOD, robot, dataset_sha256, time.perf_counter() - start, out, {"accel_scale_fit": accel_scale_fit},
        failed_units=failed, reference=reference,
    )  # fmt: skip
    if not consistency:
        return result
    from skincal.calib.consistency import check

    def refit(part: Dataset, links: dict[str, int]) -> CalibrationResult:
        """The same calibration on a part of the recording (the parts' own rests and offsets)."""
        return calibrate_relative(
            part, reference, units=[reference, *(u for u in links if u != reference)], max_offset_s=max_offset_s,
            other_body_ratio=other_body_ratio, reference_scale_std=reference_scale_std,
            reference_misalignment_std=reference_misalignment_std, consistency=False, accel_fits=accel_fits,
        )  # fmt: skip

    checked = check(dataset, result, refit)
    return replace(checked, runtime_s=time.perf_counter() - start)


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
