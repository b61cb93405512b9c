"""A unit's IMU samples gathered for a calibration: each tagged with its protocol segment
(:func:`tag_segments`), the joint states at its instant (:func:`unit_samples`, :class:`UnitSamples`),
and the static segments averaged (:func:`static_means`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skincal.calib.preprocess.interpolate import JointInterpolator
from skincal.calib.preprocess.screening import GYRO_RAIL_MAX_SHARE, check_accel_units, screen_channels
from skincal.data.dataset import DYNAMIC, STATIC, Dataset, Segments
from skincal.errors import CalibrationError
from skincal.kinematics.transforms import FloatArray


@dataclass(frozen=True)
class SampleAccount:
    """What :func:`unit_samples` dropped from a unit's stream before any method saw it (counts of
    IMU samples) and what the screening said.

    Attributes:
        n_total: samples in the stream.
        n_nonfinite: samples with a non-finite accelerometer reading.
        n_outside: samples whose (shifted) instant lies outside the joint stream.
        n_saturated: samples dropped at a saturating extreme of the accelerometer.
        n_gyro_saturated: samples kept whose gyroscope reading is at a rail (NaN in
            :attr:`UnitSamples.gyro`: every consumer leaves that reading out).
        n_stuck: samples where an accelerometer axis had stopped updating.
        saturated_t: ``(K,)`` instants of the saturated samples (shifted to the joint clock), s.
        warnings: the screening's and the unit check's warnings.
        unit_warnings: the unit check's alone (:func:`check_accel_units`: a stream whose magnitude is
            not gravity's); :func:`skincal.calib.api.calibrate_unit` puts them on every method's result.
    """

    n_total: int
    n_nonfinite: int = 0
    n_outside: int = 0
    n_saturated: int = 0
    n_stuck: int = 0
    n_gyro_saturated: int = 0
    saturated_t: FloatArray | None = None
    warnings: tuple[str, ...] = ()
    unit_warnings: tuple[str, ...] = ()


@dataclass(frozen=True)
class UnitSamples:
    """One unit's IMU samples with the joint states at their instants and their segment tags.

    Attributes:
        unit: unit name.
        t: ``(M,)`` sample instants, s (shifted by ``time_offset_s`` when one was applied).
        accel: ``(M, 3)`` measured specific force in the unit frame, m/s^2.
        gyro: ``(M, 3)`` measured angular rate in the unit frame, rad/s, or ``None``; a row is NaN
            where the reading was at the gyroscope's rail (the accelerometer's reading is kept).
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
    gyro_lost = np.zeros(len(t), dtype=bool) if screen.gyro_saturated is None else screen.gyro_saturated
    extra: tuple[str, ...] = ()
    rail_share = np.count_nonzero(gyro_lost) / max(np.count_nonzero(usable), 1)
    if gyro is not None and rail_share > GYRO_RAIL_MAX_SHARE:
        extra = (f"gyroscope at its rail or stuck in {100 * rail_share:.0f}% of the samples (a register that stopped "
                 "updating, or a range too small for this motion): not used",)  # fmt: skip
        gyro, gyro_lost = None, np.zeros(len(t), dtype=bool)
    elif gyro is not None and gyro_lost.any():
        gyro = np.where(gyro_lost[:, None], np.nan, gyro)
    account = SampleAccount(
        n_total=int(finite.size),
        n_nonfinite=int(np.count_nonzero(~finite)),
        n_outside=int(np.count_nonzero(finite & ~inside_joints)),
        n_saturated=int(np.count_nonzero(screen.saturated)),
        n_stuck=int(np.count_nonzero(~usable & ~screen.saturated)),
        n_gyro_saturated=int(np.count_nonzero(gyro_lost)),
        saturated_t=t[screen.saturated],
        warnings=tuple(unit_warnings) + screen.warnings + extra,
        unit_warnings=tuple(unit_warnings),
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
