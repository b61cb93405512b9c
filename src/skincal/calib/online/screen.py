"""The streaming calibrator's screening of a unit's samples, as ``mle``'s
(:mod:`~skincal.calib.preprocess.screening`): a stuck axis (:func:`admit`, through the unit's
:class:`~skincal.calib.online.stuck.StuckScreen`) and the channels' rails (:func:`unsaturated`)."""

from __future__ import annotations

import numpy as np

from skincal.calib.online.unit import UnitState, keep_pending
from skincal.calib.preprocess.screening import GYRO_SATURATION_MIN, SATURATION_FRACTION, SATURATION_MIN
from skincal.kinematics.transforms import FloatArray

SATURATION_FLOOR = (SATURATION_MIN, GYRO_SATURATION_MIN)
"""A recurring largest reading is taken as the sensor's range only beyond the batch screening's floors
(m/s^2, rad/s: :data:`~skincal.calib.preprocess.screening.SATURATION_MIN` and
:data:`~skincal.calib.preprocess.screening.GYRO_SATURATION_MIN`), so both calibrators leave out the same
readings."""


def admit(st: UnitState, t: FloatArray, a: FloatArray, g: FloatArray | None, final: bool = False) -> None:
    """New finite samples of the unit through its stuck-axis test into its pending ones (``final``: the data's
    end, every held sample released)."""
    keep_pending(st, *st.stuck.push(t, a, g, final))


def unsaturated(st: UnitState, a: FloatArray, g: FloatArray | None) -> tuple[np.ndarray, FloatArray | None]:
    """``(M,)`` samples whose accelerometer is below its saturation, and the gyroscope's readings with NaN
    rows where it is at its rail (:func:`~skincal.calib.online.stats.gyro_rows` leaves them out; the
    sample's accelerometer reading needs no gyroscope, as in ``mle``): each axis' largest and smallest reading
    that recurs exactly (a clipped register) is taken as that side's range, as the batch screening takes it
    per axis and extreme (a real MPU6050 clips at +19.56 and -19.67 m/s^2 on one axis)."""
    keep = np.ones(a.shape[0], dtype=bool)
    rail = np.zeros(a.shape[0], dtype=bool)
    for i, x in enumerate((a, g)):
        if x is None or x.size == 0:
            continue
        st.screened[i] += x.shape[0]
        v = _signed(x)
        top = v.max(axis=0)
        rails = at_rail_now(st, i)
        if np.all(top < SATURATION_FLOOR[i]) and not rails.any():
            continue  # a quantised reading at rest repeats its largest value too: not a range
        higher = top > st.peak[i]
        st.peak_count[i] = np.where(higher, (v == top).sum(axis=0), st.peak_count[i] + (v == st.peak[i]).sum(axis=0))
        st.peak[i] = np.maximum(st.peak[i], top)
        rails = at_rail_now(st, i)
        if rails.any():
            at_rail = np.any((v >= st.peak[i]) & rails, axis=1)
            if i == 0:
                keep &= ~at_rail
            else:
                rail |= at_rail
    st.saturated += int((~keep).sum())  # samples not absorbed (a gyroscope's rail leaves its reading out only)
    st.gyro_saturated += int((rail & keep).sum())
    if g is not None and rail.any():
        g = np.where(rail[:, None], np.nan, g)
    return keep, g


def _signed(x: FloatArray) -> FloatArray:
    """``(M, 6)`` readings ``x`` ``(M, 3)`` and their negatives (each axis' two rails as largest values; a stuck
    gyroscope's NaN rows, :meth:`~skincal.calib.online.stuck.StuckScreen.gyro_masked`, never at one)."""
    v = np.hstack([x, -x])
    return np.where(np.isnan(v), -np.inf, v)


def at_rail_now(st: UnitState, i: int) -> np.ndarray:
    """``(6,)`` which of channel ``i``'s (0 accelerometer, 1 gyroscope) extremes (largest x, y, z; smallest x, y,
    z) have shown a rail so far: beyond :data:`SATURATION_FLOOR` in magnitude and recurring exactly more than 3
    times and in more than :data:`~skincal.calib.preprocess.screening.SATURATION_FRACTION` of the channel's
    samples (the batch screening's rule; a consumer IMU's quantised peak recurs twice by chance)."""
    count = st.peak_count[i]
    return (st.peak[i] >= SATURATION_FLOOR[i]) & (count > 3) & (count > SATURATION_FRACTION * st.screened[i])


def accel_at_rail(st: UnitState, a: FloatArray) -> np.ndarray:
    """``(M,)`` readings ``a`` at the accelerometer's rails as :func:`unsaturated` found them so far (no update)."""
    rails = at_rail_now(st, 0)
    if rails.any():
        return np.any((_signed(a) >= st.peak[0]) & rails, axis=1)
    return np.zeros(a.shape[0], dtype=bool)
