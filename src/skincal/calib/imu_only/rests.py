"""The rests of a rigid body seen by its IMUs alone: the common rests of the units on the reference's body
(:func:`common_rests`), each unit's mean reading per rest (:func:`rest_means`) and how many distinct
orientations they hold (:func:`distinct_orientations`)."""

from __future__ import annotations

import math

import numpy as np

from skincal.calib.rest import imu_still_mask, runs
from skincal.data.dataset import ImuStream
from skincal.kinematics.transforms import FloatArray

NOISE_FLOOR = 1e-4
"""Smallest noise std assumed for the rest tests (rad/s, m/s^2): noise-free data still rest, and the
windowed variances' round-off (sums of squares of ~10 m/s^2) stays far below the limits."""
REST_GUARD_S = 0.05
"""Cut from both ends of a rest (beyond the window's reach: the units' stamp offsets), s."""
MIN_REST_S = 0.4
"""Shortest rest used for the accelerometers, s (after the guard)."""
DISTINCT_DEG = 15.0
"""Rests whose gravity directions are closer than this count as one orientation, deg."""


def common_rests(streams: dict[str, ImuStream], reference: str) -> FloatArray:
    """``(S, 2)`` start and end (reference stamps, s) of the rests of the body: where the reference is
    still (``rest.imu_still_mask``) and so is every other unit that is still for at least half of that time
    (the units on the reference's body; a unit on another body moves on), less ``REST_GUARD_S`` at both
    ends, at least ``MIN_REST_S`` long."""
    ref = streams[reference]
    assert ref.gyro is not None
    common = imu_still_mask(ref.t, ref.gyro, ref.accel)
    total = max(int(common.sum()), 1)
    for name, stream in streams.items():
        if name == reference or stream.gyro is None or len(stream.t) < 10:
            continue
        mine = imu_still_mask(stream.t, stream.gyro, stream.accel)
        i = np.clip(np.searchsorted(stream.t, ref.t), 1, len(stream.t) - 1)
        i -= (ref.t - stream.t[i - 1]) < (stream.t[i] - ref.t)
        at_ref = mine[i]
        if np.count_nonzero(at_ref & common) >= 0.5 * total:
            common &= at_ref
    out = []
    for a, b in runs(common):
        t0, t1 = ref.t[a] + REST_GUARD_S, ref.t[b - 1] - REST_GUARD_S
        if t1 - t0 >= MIN_REST_S:
            out.append((t0, t1))
    return np.array(out, dtype=float).reshape(-1, 2)


def rest_means(stream: ImuStream, rests: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Per rest ``(S, 2)``: the mean acceleration ``(S, 3)``, the sample count ``(S,)`` and the
    within-rest variance ``(S, 3)`` of one unit."""
    means, counts, var = [], [], []
    for t0, t1 in rests:
        a = stream.accel[(stream.t >= t0) & (stream.t <= t1)]
        if len(a) < 3:
            a = np.full((3, 3), np.nan)
        means.append(a.mean(axis=0))
        counts.append(len(a))
        var.append(a.var(axis=0, ddof=1))
    return np.array(means).reshape(-1, 3), np.array(counts, dtype=float), np.array(var).reshape(-1, 3)


def distinct_orientations(directions: FloatArray, deg: float = DISTINCT_DEG) -> int:
    """How many of the gravity directions ``(S, 3)`` differ by more than ``deg`` from each other
    (greedy: each direction joins the first earlier one within ``deg``)."""
    unit = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    kept: list[FloatArray] = []
    for u in unit:
        if all(float(u @ v) < math.cos(math.radians(deg)) for v in kept):
            kept.append(u)
    return len(kept)
