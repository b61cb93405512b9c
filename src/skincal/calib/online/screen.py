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
    sample's accelerometer reading needs no gyroscope, as in ``mle``): a largest reading that recurs
    exactly (a clipped register) is taken as the range."""
    keep = np.ones(a.shape[0], dtype=bool)
    rail = np.zeros(a.shape[0], dtype=bool)
    for i, x in enumerate((a, g)):
        if x is None or x.size == 0:
            continue
        st.screened[i] += x.shape[0]
        m = np.abs(x)  # a stuck gyroscope's readings are NaN rows (StuckScreen.gyro_masked): never at a rail
        top = float(np.nanmax(m)) if np.isfinite(m).any() else 0.0
        if top < SATURATION_FLOOR[i] and not at_rail_now(st, i):
            continue  # a quantised reading at rest repeats its largest value too: not a range
        if top > st.peak[i]:
            st.peak[i], st.peak_count[i] = top, float((m == top).sum())
        else:
            st.peak_count[i] += float((m == st.peak[i]).sum())
        if at_rail_now(st, i):
            at_rail = np.any(m >= st.peak[i], axis=1)
            if i == 0:
                keep &= ~at_rail
            else:
                rail |= at_rail
    st.saturated += int((~keep).sum())  # samples not absorbed (a gyroscope's rail leaves its reading out only)
    st.gyro_saturated += int((rail & keep).sum())
    if g is not None and rail.any():
        g = np.where(rail[:, None], np.nan, g)
    return keep, g


def at_rail_now(st: UnitState, i: int) -> bool:
    """Whether channel ``i`` (0 accelerometer, 1 gyroscope) has shown a rail so far: its largest reading beyond
    :data:`SATURATION_FLOOR` recurring exactly more than 3 times and in more than
    :data:`~skincal.calib.preprocess.screening.SATURATION_FRACTION` of its samples (the batch screening's
    rule; a consumer IMU's quantised peak recurs twice by chance)."""
    count = st.peak_count[i]
    return bool(st.peak[i] >= SATURATION_FLOOR[i] and count > 3 and count > SATURATION_FRACTION * st.screened[i])


def accel_at_rail(st: UnitState, a: FloatArray) -> np.ndarray:
    """``(M,)`` readings ``a`` at the accelerometer's rail as :func:`unsaturated` found it so far (no update)."""
    if at_rail_now(st, 0):
        return ~np.all(np.abs(a) < st.peak[0], axis=1)
    return np.zeros(a.shape[0], dtype=bool)
