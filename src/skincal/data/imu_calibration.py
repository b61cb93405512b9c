"""The calibration of a skin unit's IMU, as a result carries it (:attr:`UnitResult.imu
<skincal.data.result.UnitResult>`).

In the result file these are per-unit fields next to the contract's (``docs/interfaces.md``,
"per-unit extras": ``accel_bias_mps2``, ``time_offset_s``, ...); :mod:`skincal.data.result` reads
them into one :class:`ImuCalibration` and writes them from it, under the same keys. Every field is
optional (``None``: the method did not estimate it, ``null`` or absent in the file); a unit whose
entry has none of the keys gets ``imu = None``.

Frames and the model the numbers belong to (:mod:`skincal.calib.model`): vectors are in the unit
frame ``su``; the accelerometer reads ``a = A f + b + c (t - t_b)`` for the unit frame's specific
force ``f``; the sample stamped ``t`` measured the motion at
``t - time_offset_s - 1e-6 clock_drift_ppm (t - time_reference_s)``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from skincal.kinematics.transforms import FloatArray

_SHAPES: dict[str, tuple[int, ...]] = {
    "accel_bias_mps2": (3,),
    "accel_bias_std_mps2": (3,),
    "accel_scale_misalignment": (3, 3),
    "accel_scale_misalignment_std": (3, 3),
    "time_offset_s": (),
    "time_offset_std_s": (),
    "time_reference_s": (),
    "clock_drift_ppm": (),
    "clock_drift_std_ppm": (),
    "gyro_bias_rps": (3,),
    "gyro_bias_std_rps": (3,),
    "accel_bias_drift_mps3": (3,),
    "accel_bias_drift_std_mps3": (3,),
    "accel_bias_reference_s": (),
    "gravity_mps2": (),
    "gravity_std_mps2": (),
    "clock_resync_steps": (),
    "clock_resync_period_s": (),
    "clock_resync_step_s": (),
}
INTEGER_KEYS = frozenset({"clock_resync_steps"})
"""Fields of :class:`ImuCalibration` that are whole numbers (the others of shape ``()`` are floats)."""


@dataclass(frozen=True)
class ImuCalibration:
    """Estimated errors of one unit's IMU (SI units, unit frame ``su``; ``None``: not estimated).

    Attributes:
        accel_bias_mps2: ``(3,)`` accelerometer bias ``b``, m/s^2 (at ``accel_bias_reference_s``
            when a drift is estimated).
        accel_bias_std_mps2: ``(3,)`` its std, m/s^2.
        accel_scale_misalignment: ``(3, 3)`` the matrix ``A`` of ``a = A f + b`` (scale on the
            diagonal, misalignment off it; dimensionless; ``None`` reads as the identity).
        accel_scale_misalignment_std: ``(3, 3)`` element-wise std of ``A`` (``None``: ``A`` was not
            estimated).
        time_offset_s: the IMU's latency, s, at ``time_reference_s``: the sample stamped ``t``
            measured the motion at ``t - time_offset_s - 1e-6 clock_drift_ppm (t - time_reference_s)``.
        time_offset_std_s: its std, s.
        time_reference_s: the instant (joint clock, s) ``time_offset_s`` refers to.
        clock_drift_ppm: the unit clock's drift relative to the robot's, ppm.
        clock_drift_std_ppm: its std, ppm.
        gyro_bias_rps: ``(3,)`` gyroscope bias, rad/s.
        gyro_bias_std_rps: ``(3,)`` its std, rad/s.
        accel_bias_drift_mps3: ``(3,)`` linear drift ``c`` of the accelerometer bias, m/s^2 per s.
        accel_bias_drift_std_mps3: ``(3,)`` its std, m/s^3.
        accel_bias_reference_s: the instant (joint clock, s) ``accel_bias_mps2`` refers to when the
            bias drifts (``t_b`` of the model; ``None`` reads as ``time_reference_s``).
        gravity_mps2: the gravity magnitude the unit's data support, m/s^2.
        gravity_std_mps2: its std, m/s^2.
        clock_resync_steps: periodic re-sync steps found in the unit's stamps (count; ``None``: none
            found). The stamps were then corrected before the fit (the sawtooth between re-syncs
            removed, :meth:`skincal.calib.timing.ClockSteps.correct`), and ``clock_drift_ppm`` is the
            drift between re-syncs (what the correction removed plus what the fit found).
        clock_resync_period_s: their mean period, s.
        clock_resync_step_s: their mean step, s (positive: the stamps jump forward).
    """

    accel_bias_mps2: FloatArray | None = None
    accel_bias_std_mps2: FloatArray | None = None
    accel_scale_misalignment: FloatArray | None = None
    accel_scale_misalignment_std: FloatArray | None = None
    time_offset_s: float | None = None
    time_offset_std_s: float | None = None
    time_reference_s: float | None = None
    clock_drift_ppm: float | None = None
    clock_drift_std_ppm: float | None = None
    gyro_bias_rps: FloatArray | None = None
    gyro_bias_std_rps: FloatArray | None = None
    accel_bias_drift_mps3: FloatArray | None = None
    accel_bias_drift_std_mps3: FloatArray | None = None
    accel_bias_reference_s: float | None = None
    gravity_mps2: float | None = None
    gravity_std_mps2: float | None = None
    clock_resync_steps: int | None = None
    clock_resync_period_s: float | None = None
    clock_resync_step_s: float | None = None

    def __post_init__(self) -> None:
        for name, shape in _SHAPES.items():
            value = getattr(self, name)
            if value is None:
                continue
            if name in INTEGER_KEYS:
                object.__setattr__(self, name, int(value))
                continue
            if shape == ():
                number = float(value)
                object.__setattr__(self, name, number if math.isfinite(number) else None)
                continue
            arr = np.array(value, dtype=float)
            if arr.shape != shape:
                raise ValueError(f"ImuCalibration.{name} must have shape {shape}, got {arr.shape}")
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @property
    def scale_matrix(self) -> FloatArray:
        """``A`` ``(3, 3)``: the estimate, or the identity where none is given or it is not finite."""
        A = self.accel_scale_misalignment
        return np.eye(3) if A is None or not np.all(np.isfinite(A)) else np.array(A)

    @property
    def bias(self) -> FloatArray:
        """``b`` ``(3,)`` m/s^2: the estimate with undetermined (NaN) components 0, or zeros."""
        b = self.accel_bias_mps2
        return np.zeros(3) if b is None else np.nan_to_num(np.array(b))


IMU_KEYS: tuple[str, ...] = tuple(f.name for f in fields(ImuCalibration))
"""The per-unit result fields an :class:`ImuCalibration` holds (its attribute names, in file order)."""
IMU_SHAPES: Mapping[str, tuple[int, ...]] = _SHAPES
"""Shape of each of :data:`IMU_KEYS`: ``()`` a number, ``(3,)`` a vector, ``(3, 3)`` a matrix."""


ALWAYS_WRITTEN: tuple[str, ...] = (
    "accel_bias_mps2",
    "accel_bias_std_mps2",
    "accel_scale_misalignment",
    "time_offset_s",
    "time_offset_std_s",
    "time_reference_s",
    "clock_drift_ppm",
    "clock_drift_std_ppm",
)
"""Fields a result file holds for every unit with an :class:`ImuCalibration`, ``null`` when not
estimated (bias and its std, scale/misalignment, time offset and its std and reference, clock drift
and its std, as ``mle`` always wrote them); the others are left out when not estimated."""


def imu_to_fields(imu: ImuCalibration) -> dict[str, Any]:
    """The result-file fields of ``imu`` (``None`` for a field of :data:`ALWAYS_WRITTEN` not estimated;
    arrays stay arrays)."""
    return {k: getattr(imu, k) for k in IMU_KEYS if k in ALWAYS_WRITTEN or getattr(imu, k) is not None}
