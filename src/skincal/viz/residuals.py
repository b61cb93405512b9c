"""Accelerometer residuals of a calibration result and the data coverage, for plots and reports.

The model is the one ``mle`` fits, evaluated by the same code (:mod:`skincal.calib.model`): the
sample stamped ``t`` measured the motion at ``s = t - tau - d (t - t_ref)``, and

    f_pred = A R_link_su^T (u(s) + K(s) p_link_su + k u_g(s)) + b + c (s - t_b),

with ``u``, ``K``, ``u_g`` the link signals of :func:`skincal.calib.signals.link_signals` and the
unit's :class:`~skincal.data.imu_calibration.ImuCalibration` (``UnitResult.imu``; what it does not
give takes the neutral value: ``A`` identity, ``b``, ``c``, ``k``, ``tau``, ``d`` zero). Residual
``e = f_meas - f_pred`` in the unit frame, m/s^2. (``mle`` measures the bias drift's time from its
coarsely aligned stamps, here from ``s``: the two differ by the refined offset, a few ms, which moves
the prediction by ``c`` times that, below 1e-6 m/s^2 for any drift it reports as plausible.)
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from skincal.calib.links import discover_link
from skincal.calib.model import calibrated_instants, predict_calibrated
from skincal.calib.preprocess import JointInterpolator, unit_samples
from skincal.calib.signals import link_signals
from skincal.data.dataset import Dataset
from skincal.data.result import UnitResult
from skincal.kinematics.transforms import FloatArray

CHUNK = 8192
"""Samples whose prediction is computed at once (bounds the memory of a long recording's residuals)."""
PLOT_POINTS = 2000
"""Samples per residual curve in the report's plots (:meth:`UnitResiduals.thinned`): a picture, not the data."""


@dataclass(frozen=True)
class UnitResiduals:
    """One unit's measured and predicted specific force.

    Attributes:
        unit: unit name.
        t: ``(M,)`` motion instants ``t_stamp - tau``, s.
        measured, predicted, residual: ``(M, 3)`` in the unit frame, m/s^2.
        segment: ``(M,)`` segment index, -1 outside every segment.
        kind: ``(M,)`` 0 static, 1 dynamic, -1 outside.
        joint: ``(M,)`` 0-based excited joint, -1 when static or outside.
        segment_rms: ``(S,)`` RMS residual norm per dataset segment, m/s^2 (NaN: no samples).
        rms_mps2: RMS residual norm over every sample when the arrays are a thinned copy
            (:meth:`thinned`), else None (computed from ``residual``).
        n_samples: samples before thinning, None when not thinned.
    """

    unit: str
    t: FloatArray
    measured: FloatArray
    predicted: FloatArray
    residual: FloatArray
    segment: np.ndarray
    kind: np.ndarray
    joint: np.ndarray
    segment_rms: FloatArray
    rms_mps2: float | None = None
    n_samples: int | None = None

    @property
    def rms(self) -> float:
        """RMS residual norm over every sample (of the full data, also for a thinned copy), m/s^2."""
        if self.rms_mps2 is not None:
            return self.rms_mps2
        return float(np.sqrt(np.mean(np.sum(self.residual**2, axis=1)))) if len(self.t) else float("nan")

    def thinned(self, max_points: int = PLOT_POINTS) -> UnitResiduals:
        """A copy with at most ``max_points`` samples for plotting (:func:`envelope_indices` of the
        residual: each component's minimum and maximum in every time bucket are kept, so spikes stay
        visible); ``rms``, ``segment_rms`` and ``n_samples`` still describe the full data."""
        n = len(self.t) if self.n_samples is None else self.n_samples
        idx = envelope_indices(self.residual, max_points)
        if len(idx) == len(self.t):
            return replace(self, rms_mps2=self.rms, n_samples=n)
        return UnitResiduals(
            self.unit, self.t[idx], self.measured[idx], self.predicted[idx], self.residual[idx], self.segment[idx],
            self.kind[idx], self.joint[idx], self.segment_rms, self.rms, n,
        )


def envelope_indices(values: FloatArray, max_points: int = PLOT_POINTS) -> np.ndarray:
    """Sorted indices of at most ``max_points`` rows of ``values`` ``(M,)`` or ``(M, k)`` that keep
    the envelope: the rows are cut into equal time buckets and, per bucket, the rows of each column's
    minimum and maximum are kept (plus the first and last row). NaN is never chosen over a number."""
    v = np.asarray(values, dtype=float).reshape(len(values), -1)
    m, k = v.shape
    if m <= max(max_points, 2):
        return np.arange(m)
    n_buckets = max(1, (max_points - 2) // (2 * k))
    size = -(-m // n_buckets)
    pad = n_buckets * size - m
    lo = np.pad(np.where(np.isnan(v), np.inf, v), ((0, pad), (0, 0)), constant_values=np.inf)
    hi = np.pad(np.where(np.isnan(v), -np.inf, v), ((0, pad), (0, 0)), constant_values=-np.inf)
    base = (np.arange(n_buckets) * size)[:, None]
    i_min = base + np.argmin(lo.reshape(n_buckets, size, k), axis=1)
    i_max = base + np.argmax(hi.reshape(n_buckets, size, k), axis=1)
    idx = np.unique(np.concatenate([i_min.ravel(), i_max.ravel(), [0, m - 1]]))
    return idx[idx < m]


def unit_residuals(
    dataset: Dataset, name: str, unit: UnitResult, interpolator: JointInterpolator | None = None
) -> UnitResiduals:
    """Residuals of one unit (module docstring). Pass one ``interpolator`` for several units."""
    if interpolator is None:
        interpolator = JointInterpolator(dataset.joints)
    if unit.imu is not None:  # the stamps put on the motion's clock (offset and drift)
        imu = dataset.imu[name]
        # a dataset of this unit alone: the others' streams are not read (a lazily read file streams them)
        dataset = replace(dataset, imu={name: replace(imu, t=calibrated_instants(unit.imu, imu.t))})
    s = unit_samples(dataset, name, interpolator=interpolator)
    pose, gravity = unit.pose, np.asarray(dataset.gravity, dtype=float)
    g0 = float(np.linalg.norm(gravity))
    predicted = np.empty_like(s.accel)
    for i in range(0, len(s.t), CHUNK):  # the kinematics' temporaries grow with the samples: bound them
        j = slice(i, i + CHUNK)
        sig = link_signals(dataset.robot, pose.link, s.q[j], s.qd[j], s.qdd[j], gravity)
        predicted[j] = predict_calibrated(unit.imu, pose, sig.u, sig.K, sig.u_g, s.t[j], g0)
    residual = s.accel - predicted
    n_seg = len(dataset.segments) if dataset.segments is not None else 0
    inside = s.segment >= 0
    sq = np.bincount(s.segment[inside], weights=np.einsum("ij,ij->i", residual[inside], residual[inside]),
                     minlength=n_seg)[:n_seg]
    count = np.bincount(s.segment[inside], minlength=n_seg)[:n_seg].astype(float)
    with np.errstate(invalid="ignore", divide="ignore"):
        seg_rms = np.where(count > 0, np.sqrt(sq / np.maximum(count, 1.0)), np.nan)
    return UnitResiduals(name, s.t, s.accel, predicted, residual, s.segment, s.kind, s.joint, seg_rms)


def activity_matrix(dataset: Dataset, units: list[str], interpolator: JointInterpolator | None = None) -> FloatArray:
    """Data coverage: ``(len(units), n)`` activity of each joint on each unit, as a multiple of the
    motion threshold of :func:`skincal.calib.links.discover_link` (>= 1: the joint moved the unit;
    NaN: joint never excited). Uses the gyroscope too when the dataset has it."""
    if interpolator is None:
        interpolator = JointInterpolator(dataset.joints)
    rows = [unit_activity(dataset, name, interpolator) for name in units]
    return np.array(rows).reshape(len(units), dataset.robot.n_joints)


def unit_activity(dataset: Dataset, name: str, interpolator: JointInterpolator | None = None) -> FloatArray:
    """One row of :func:`activity_matrix`: ``(n,)`` activity of each joint on unit ``name``."""
    if interpolator is None:
        interpolator = JointInterpolator(dataset.joints)
    # the activity uses the readings and their segment tags only: no need to interpolate the joints
    s = unit_samples(dataset, name, interpolator=interpolator, exact_joint_states=False)
    return discover_link(s, dataset.robot.n_joints, use_gyro=True).activity

