"""The forward model of ``mle``: what a skin unit's accelerometer reads, given its link's motion, its
pose on the link and its IMU calibration. Written once here; the solver (:mod:`skincal.calib.mle.solver`),
the link comparison (:mod:`skincal.calib.mle.method`) and the report's residuals
(:mod:`skincal.calib.residuals`) all evaluate it, so the residuals a report shows are those of the
model that was fitted.

Unit frame ``su``, link frame ``n`` (``R = R_link_su``, ``p = p_link_su`` in m)::

    instant:        s = t - tau - d (t - t_ref)              (the sample stamped t measured the motion at s;
                                                              t with periodic re-sync steps removed)
    link frame:     v(s) = u(s) + K(s) p + k u_g(s)           (specific force at the unit, m/s^2)
    accelerometer:  a = A R^T v(s) + b + c (s - t_b)          (m/s^2, unit frame)

``u``, ``K`` are the link signals of :func:`skincal.calib.signals.link_signals` (specific force of
the link origin and the rigid-body matrix, link frame), ``u_g = -R_base_link^T g`` the part of ``u``
due to the dataset's gravity ``g`` and ``k`` its relative error (the unit's data support gravity
``|g| (1 + k)``). ``A`` is the scale/misalignment matrix, ``b`` the bias (at ``t_b``), ``c`` its
drift (m/s^3), ``tau`` the time offset at ``t_ref`` and ``d`` the clock drift (1e-6 per ppm). In a
result these are the fields of :class:`~skincal.data.imu_calibration.ImuCalibration`.
"""

from __future__ import annotations

import numpy as np

from skincal.calib.timing import find_clock_steps, motion_instants
from skincal.data.imu_calibration import ImuCalibration
from skincal.kinematics.transforms import FloatArray
from skincal.skin.pose import SkinUnitPose


def link_specific_force(
    u: FloatArray, K: FloatArray | None, p: FloatArray, ug: FloatArray | None = None, gravity_scale: float = 0.0
) -> FloatArray:
    """``(M, 3)`` specific force at the unit in link frame, ``v = u + K p + k u_g`` (``ug`` None: no
    gravity correction). ``K`` None: at rest, where ``K = 0`` and ``u = u_g``, so ``v = (1 + k) u``
    (``ug`` is then not needed)."""
    if K is None:
        return (1.0 + gravity_scale) * u
    v = u + (K.reshape(-1, 3) @ p).reshape(-1, 3)  # K_m p of every row: one matrix-vector product
    if ug is not None:
        v = v + gravity_scale * ug
    return v


def sym_from_e(e: FloatArray) -> FloatArray:
    """Symmetric ``(3, 3)`` matrix from its six elements ``e = (xx, yy, zz, xy, xz, yz)`` (the symmetric
    scale/misalignment ``E`` of ``A = I + E``; ``imu_only``'s ellipsoid matrix)."""
    return np.array([[e[0], e[3], e[4]], [e[3], e[1], e[5]], [e[4], e[5], e[2]]])


def accelerometer(
    f: FloatArray, A: FloatArray, b: FloatArray, c: FloatArray | None = None, t_rel: FloatArray | None = None
) -> FloatArray:
    """``(M, 3)`` readings ``A f + b + c t_rel`` of the unit-frame specific force ``f`` ``(M, 3)``
    (``t_rel`` ``(M,)`` s since the bias's reference instant; no drift term when ``c`` is None)."""
    pred = f @ A.T + b
    if c is not None and t_rel is not None:
        pred = pred + np.outer(t_rel, c)
    return pred


def predict_specific_force(
    R: FloatArray,
    p: FloatArray,
    A: FloatArray,
    b: FloatArray,
    u: FloatArray,
    K: FloatArray | None,
    *,
    ug: FloatArray | None = None,
    gravity_scale: float = 0.0,
    c: FloatArray | None = None,
    t_rel: FloatArray | None = None,
) -> FloatArray:
    """``(M, 3)`` accelerometer readings of a unit at ``R = R_link_su``, ``p = p_link_su`` (module
    docstring): :func:`accelerometer` of ``R^T`` :func:`link_specific_force`."""
    return accelerometer(link_specific_force(u, K, p, ug, gravity_scale) @ R, A, b, c, t_rel)


def calibrated_instants(imu: ImuCalibration | None, t: FloatArray) -> FloatArray:
    """:func:`motion_instants` of a unit's stamps ``t`` ``(M,)`` under a result's calibration (no
    offset where ``imu`` is None or gives none; no drift where it gives no drift or no
    ``time_reference_s``). A unit whose clock re-synced periodically (``clock_resync_steps``) has its
    stamps corrected first as ``mle`` corrected them (:func:`~skincal.calib.timing.find_clock_steps`
    on the same stamps); the drift left to apply is then ``clock_drift_ppm`` less the correction's."""
    t = np.asarray(t, dtype=float)
    if imu is None:
        return t
    drift = imu.clock_drift_ppm if imu.clock_drift_ppm is not None and imu.time_reference_s is not None else 0.0
    if imu.clock_resync_steps is not None:
        steps = find_clock_steps(t)
        if steps is not None:
            t = steps.correct(t)
            drift = drift - steps.drift_ppm if drift else 0.0
    return motion_instants(t, imu.time_offset_s or 0.0, 1e-6 * drift, imu.time_reference_s or 0.0)


def predict_calibrated(
    imu: ImuCalibration | None,
    pose: SkinUnitPose,
    u: FloatArray,
    K: FloatArray,
    ug: FloatArray,
    s: FloatArray,
    gravity_mps2: float,
) -> FloatArray:
    """:func:`predict_specific_force` of a unit under a result's pose and IMU calibration at motion
    instants ``s`` ``(M,)`` (for which ``u``, ``K``, ``ug`` were evaluated) with the dataset's
    gravity magnitude ``gravity_mps2``; what ``imu`` does not give (or None) takes the neutral value
    (``A = I``, ``b = 0``, no gravity correction, no bias drift)."""
    if imu is None:
        imu = ImuCalibration()
    k = imu.gravity_mps2 / gravity_mps2 - 1.0 if imu.gravity_mps2 is not None and gravity_mps2 > 0 else 0.0
    c = None if imu.accel_bias_drift_mps3 is None else np.nan_to_num(imu.accel_bias_drift_mps3)
    t_b = imu.accel_bias_reference_s if imu.accel_bias_reference_s is not None else imu.time_reference_s
    t_rel = None if c is None else np.asarray(s, dtype=float) - (t_b or 0.0)
    return predict_specific_force(
        pose.R_link_su, pose.p_link_su, imu.scale_matrix, imu.bias, u, K, ug=ug, gravity_scale=k, c=c, t_rel=t_rel
    )
