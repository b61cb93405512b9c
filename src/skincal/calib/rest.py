"""When is a unit at rest? Rest detection that survives the noise of real joint states and IMUs: the one
home of every rest rule (joint rests, a unit's rest runs cross-checked by its IMU, IMU stillness without
joints :func:`imu_still_mask`, the streaming calibrator's moving/resting split :func:`link_moving`).

A unit on link ``L`` is at rest when joints ``1 .. L`` are (joints after ``L`` may move: they do not
move the unit). Two sources say when a joint rests:

* **the protocol segments** (``/segments``), when the dataset has them: joint ``j`` rests inside a
  static segment and inside a dynamic segment that excites another joint, provided its own data
  (below) agree;
* **the joint positions**, otherwise: over a window of ``REST_WINDOW_S`` the mean speed from the
  position change, ``|q(t + W/2) - q(t - W/2)| / W``, and the mean reported speed must both lie below
  a threshold derived from the stream's own noise (encoder step and velocity noise, estimated from
  second differences, which cancel any smooth motion), never below ``REST_SPEED_FLOOR``.

No constant compares a single sample's ``qd`` or an estimated ``qdd`` with a fixed level: a
controller's velocity noise of a few mrad/s would break that.

Every rest run of a unit is then **cross-checked against the unit's own IMU**: its accelerometer
(and gyroscope) spread inside the run must stay within ``STILL_FACTOR`` times the noise level
measured over all of the unit's runs. A run in which the unit moved (a knock, a misdeclared
segment, a joint that crept) is dropped and named in a warning.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skincal.calib.preprocess import joint_noise, white_noise_std
from skincal.calib.robust import run_correlation
from skincal.data.dataset import DYNAMIC, STATIC, JointStates, Segments
from skincal.kinematics.transforms import FloatArray

REST_WINDOW_S = 0.2
"""Window over which a joint's mean speed is judged, s."""
REST_SPEED_FLOOR = 2e-3
"""Mean joint speed always counted as rest, rad/s (0.1 deg/s: 0.1 mrad in a 50 ms guard)."""
NOISE_FACTOR = 5.0
"""A joint moves when its windowed mean speed exceeds this many standard deviations of its noise."""
GUARD_S = 0.06
"""Samples this close to the edges of a rest run are not used (settling, stamp error), s."""
MIN_RUN_SAMPLES = 5
"""A rest run needs at least this many IMU samples after the guard."""
GAP_FACTOR = 10.0
"""A gap between a unit's stamps longer than this many median sample intervals (and the guard) ends a
rest run: samples recorded only in the rests (a static-only session) must not merge two poses."""
STILL_FACTOR = 4.0
"""A run whose IMU spread exceeds this multiple of the unit's typical rest spread moved."""
STILL_FLOOR_ACCEL = 0.01
"""Spread (std, m/s^2) of the accelerometer inside a run always accepted as still."""
STILL_FLOOR_GYRO = 2e-3
"""Spread (std, rad/s) of the gyroscope inside a run always accepted as still."""
STILL_WINDOW_S = 0.3
"""Window over which a unit is judged still, s."""
STILL_SPREAD_FACTOR = 2.0
"""Still: the rates' and accelerations' std over the window below this multiple of their noise std."""
STILL_MEAN_FACTOR = 4.0
"""Still: the window's mean rate less the gyroscope bias below this many standard errors of the mean."""
STILL_GAP_S = 0.15
"""A still run broken for less than this (a noise excursion of the window's tests) is one rest, s."""
STILL_NOISE_FLOOR = 1e-4
"""Smallest noise std :func:`imu_still_mask` assumes (rad/s, m/s^2): noise-free data still rest."""
MOVING_RPS = 0.02
"""The streaming calibrator's rule (:func:`link_moving`): a sample whose link turns faster than this (rad/s)..."""
MOVING_RPS2 = 0.2
"""...or accelerates its rotation faster than this (rad/s^2) counts as moving."""


def second_difference_noise(x: FloatArray) -> FloatArray:
    """Robust white-noise std per column of ``x`` ``(N, k)`` from its second differences
    (:func:`~skincal.calib.preprocess.white_noise_std` of order 2): ``d_i = x_{i+1} - 2 x_i + x_{i-1}``
    cancels any locally linear signal and has variance ``6 sigma^2`` for white noise."""
    return white_noise_std(x, 2)


@dataclass(frozen=True)
class JointRest:
    """Which joint rests when, on the joint stream's instants.

    Attributes:
        t: ``(N,)`` joint-stream instants, s.
        rest: ``(N, n)`` True where joint ``j`` (0-based column) is at rest.
        source: ``"segments"`` or ``"joint positions"``.
        speed_threshold: ``(n,)`` windowed mean speed above which a joint moves, rad/s.
        velocity_noise: ``(n,)`` estimated white-noise std of the reported velocities, rad/s.
        position_noise: ``(n,)`` estimated noise std of the reported positions (encoder step
            included), rad.
    """

    t: FloatArray
    rest: np.ndarray
    source: str
    speed_threshold: FloatArray
    velocity_noise: FloatArray
    position_noise: FloatArray

    def unit_rest(self, t: FloatArray, link: int) -> np.ndarray:
        """``(M,)`` True where joints ``1 .. link`` all rest at instants ``t`` (nearest joint sample)."""
        tj = self.t
        i = np.clip(np.searchsorted(tj, t), 1, tj.size - 1)
        i -= (t - tj[i - 1]) < (tj[i] - t)
        return np.all(self.rest[i, :link], axis=1)


def _windowed_speed(t: FloatArray, x: FloatArray, window_s: float) -> FloatArray:
    """``|x(t + W/2) - x(t - W/2)| / W`` per column at every instant (ends clamped), ``(N, k)``."""
    lo = np.searchsorted(t, t - window_s / 2)
    hi = np.clip(np.searchsorted(t, t + window_s / 2, side="right") - 1, 0, t.size - 1)
    span = np.maximum(t[hi] - t[lo], 1e-12)[:, None]
    return np.abs(x[hi] - x[lo]) / span


def windowed_mean(t: FloatArray, x: FloatArray, window_s: float) -> tuple[FloatArray, FloatArray]:
    """Mean of ``x`` over ``[t - W/2, t + W/2]`` per column and the sample count, by cumulative sums."""
    lo = np.searchsorted(t, t - window_s / 2)
    hi = np.searchsorted(t, t + window_s / 2, side="right")
    c = np.concatenate([np.zeros((1, x.shape[1])), np.cumsum(x, axis=0)])
    n = np.maximum(hi - lo, 1)
    return (c[hi] - c[lo]) / n[:, None], n


def joint_rest_from_data(
    joints: JointStates, window_s: float = REST_WINDOW_S, noise: tuple[FloatArray, FloatArray] | None = None
) -> JointRest:
    """Rest of each joint from its positions and velocities over windows (module docstring);
    ``noise``: the ``(position, velocity)`` noise std per joint when already known
    (:func:`~skincal.calib.preprocess.joint_noise` otherwise)."""
    t = np.asarray(joints.t, dtype=float)
    q = np.asarray(joints.q, dtype=float)
    qd = np.asarray(joints.qd, dtype=float)
    sigma_q, sigma_v = noise if noise is not None else joint_noise(q, qd)
    speed_from_q = _windowed_speed(t, q, window_s)
    mean_qd, n = windowed_mean(t, qd, window_s)
    # Std of each windowed estimate under pure noise: sqrt(2) sigma_q / W and sigma_v / sqrt(n).
    thr_q = np.maximum(REST_SPEED_FLOOR, NOISE_FACTOR * np.sqrt(2.0) * sigma_q / window_s)
    thr_v = np.maximum(REST_SPEED_FLOOR, NOISE_FACTOR * sigma_v[None, :] / np.sqrt(n)[:, None])
    rest = (speed_from_q < thr_q) & (np.abs(mean_qd) < thr_v)
    return JointRest(t, rest, "joint positions", thr_q, sigma_v, sigma_q)


def joint_rest_from_segments(
    joints: JointStates, segments: Segments, noise: tuple[FloatArray, FloatArray] | None = None
) -> JointRest:
    """Rest of each joint from the protocol segments (module docstring); noise figures ``(position,
    velocity)`` as given (already estimated elsewhere) or from the data."""
    t = np.asarray(joints.t, dtype=float)
    n = np.asarray(joints.q).shape[1]
    rest = np.zeros((t.size, n), dtype=bool)
    kind = np.asarray(segments.kind)
    joint = np.asarray(segments.joint)
    for a, b, k, j in zip(np.asarray(segments.t_start), np.asarray(segments.t_end), kind, joint, strict=True):
        inside = (t >= a) & (t <= b)
        if k == STATIC:
            rest[inside] = True
        elif k == DYNAMIC and 0 <= j < n:
            others = np.ones(n, dtype=bool)
            others[j] = False
            rest[np.ix_(inside, others)] = True
    # A joint the segments declare at rest must also rest in its own data: the reaction of a far
    # joint's excitation can swing a near one by milliradians (a real robot's finite servo stiffness).
    data = joint_rest_from_data(joints, noise=noise)
    return JointRest(t, rest & data.rest, "segments", data.speed_threshold, data.velocity_noise, data.position_noise)


def joint_rest(
    joints: JointStates, segments: Segments | None, noise: tuple[FloatArray, FloatArray] | None = None
) -> JointRest:
    """From the segments when they have a static one, else from the joint data (``noise``: known
    ``(position, velocity)`` noise std per joint)."""
    if segments is not None and np.any(np.asarray(segments.kind) == STATIC):
        return joint_rest_from_segments(joints, segments, noise)
    return joint_rest_from_data(joints, noise=noise)  # no static segment: they cannot say when the robot rests


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """Half-open index ranges ``[start, end)`` of the true runs of a boolean mask."""
    padded = np.concatenate([[False], np.asarray(mask, dtype=bool), [False]])
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


@dataclass(frozen=True)
class RestRuns:
    """A unit's rest runs after the guard and the IMU cross-check.

    Attributes:
        bounds: ``(S, 2)`` half-open sample index ranges into the unit's samples.
        rest: ``(M,)`` True for the samples inside a kept run (guard applied).
        moving: ``(M,)`` True for samples during which some joint ``<= link`` moves.
        dropped: ``(D, 2)`` start/end times (s) of runs dropped because the unit moved in them.
        accel_noise: typical accelerometer std inside a run, m/s^2.
        gyro_noise: typical gyroscope std inside a run, rad/s (0 without a gyroscope).
        warnings: one per dropped run (or a summary when there are many).
        trimmed: how many kept runs lost their start to a unit still settling (no warning).
        accel_correlation: integrated autocorrelation of the accelerometer inside the kept runs
            (:func:`~skincal.calib.robust.residual_correlation` of each run's deviations from its
            mean, the runs end to end; 1 for white noise): a run's mean then varies by about
            ``accel_correlation * accel_noise^2 / n``, not ``accel_noise^2 / n`` (an underestimate
            for short runs, whose own mean takes some of the correlation away).
    """

    bounds: np.ndarray
    rest: np.ndarray
    moving: np.ndarray
    dropped: FloatArray
    accel_noise: float
    gyro_noise: float
    warnings: tuple[str, ...]
    trimmed: int = 0
    accel_correlation: float = 1.0


def _spread(x: FloatArray, a: int, b: int) -> float:
    """Largest per-axis std of the readings ``x[a:b]`` with a value (a gyroscope's at its rail are NaN); 0
    with fewer than two."""
    run = x[a:b]
    ok = np.all(np.isfinite(run), axis=1)
    if not ok.all():
        run = run[ok]
    return float(np.max(np.std(run, axis=0))) if len(run) >= 2 else 0.0


def unit_rest_runs(
    rest_mask: np.ndarray,
    t: FloatArray,
    accel: FloatArray,
    gyro: FloatArray | None,
    guard_s: float = GUARD_S,
    settle_window_s: float = 0.1,
) -> RestRuns:
    """Rest runs of one unit: the joint-derived ``rest_mask`` ``(M,)`` at its instants ``t``, shrunk by
    the guard, then checked against the unit's own accelerometer ``(M, 3)`` and gyroscope.

    A run whose spread exceeds the limit but that moves only at its start (a servo still settling
    after the motion) is trimmed instead of dropped: its first ``settle_window_s`` window must be
    beyond the limit, it starts again after the last window (of ``settle_window_s``, half
    overlapping) that is, and it is kept when at least half of it (and ``MIN_RUN_SAMPLES``) remains
    and that remainder passes the whole-run test too (a slow turn does not show in short windows).
    Such runs are kept silently and counted in ``trimmed``; runs that move later (a knock, a
    misdeclared segment) are dropped and named in a warning.
    """
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.01
    guard = int(np.ceil(guard_s / dt))
    candidates = []
    cuts = np.flatnonzero(np.diff(t) > max(GAP_FACTOR * dt, guard_s)) + 1  # a gap in the stamps ends a run
    for start, end in runs(rest_mask):
        edges = [start, *cuts[(cuts > start) & (cuts < end)].tolist(), end]
        for a, b in zip(np.add(edges[:-1], guard), np.subtract(edges[1:], guard), strict=True):
            if b - a >= MIN_RUN_SAMPLES:
                candidates.append((int(a), int(b)))
    if not candidates:
        empty = np.zeros(t.size, dtype=bool)
        return RestRuns(np.zeros((0, 2), dtype=np.intp), empty, ~rest_mask, np.zeros((0, 2)), 0.0, 0.0, ())
    sa = np.array([_spread(accel, a, b) for a, b in candidates])
    level_a = max(float(np.median(sa)), 1e-12)
    limit_a = max(STILL_FACTOR * level_a, STILL_FLOOR_ACCEL)
    still = sa <= limit_a
    level_g, limit_g = 0.0, np.inf
    if gyro is not None:
        sg = np.array([_spread(gyro, a, b) for a, b in candidates])
        level_g = max(float(np.median(sg)), 1e-12)
        limit_g = max(STILL_FACTOR * level_g, STILL_FLOOR_GYRO)
        still &= sg <= limit_g

    def quiet(a: int, b: int) -> bool:
        return _spread(accel, a, b) <= limit_a and (gyro is None or _spread(gyro, a, b) <= limit_g)

    def settled_start(a: int, b: int) -> int | None:
        """Where a run that only moves at its start becomes still, or None."""
        width = max(MIN_RUN_SAMPLES, int(round(settle_window_s / dt)))
        latest = b - max(MIN_RUN_SAMPLES, int(np.ceil(0.5 * (b - a))))
        if latest <= a or b - a < 2 * width or quiet(a, a + width):
            return None  # too short to trim, or still at its start: it moved later
        step = max(1, width // 2)
        loud = [p for p in range(a, b - width + 1, step) if not quiet(p, p + width)]
        if not quiet(b - width, b):
            return None  # moving at its end
        s = loud[-1] + width
        while s <= latest and not quiet(s, b):
            s += step
        return s if s <= latest else None

    keep, gone, trimmed = [], [], 0
    for (a, b), ok in zip(candidates, still, strict=True):
        s = a if ok else settled_start(a, b)
        if s is None:
            gone.append((a, b))
        else:
            keep.append((s, b))
            trimmed += int(s > a)
    rest = np.zeros(t.size, dtype=bool)
    for a, b in keep:
        rest[a:b] = True
    dropped = np.array([[t[a], t[b - 1]] for a, b in gone]).reshape(-1, 2)
    warnings: list[str] = []
    if gone:
        where = ", ".join(f"{t0:.1f}-{t1:.1f} s" for t0, t1 in dropped[:5]) + (" ..." if len(gone) > 5 else "")
        warnings.append(
            f"static segment moved: {len(gone)} of {len(candidates)} rest period(s) dropped because the unit's "
            f"IMU moved in them ({where}; accelerometer spread above {limit_a:.3g} m/s^2)"
        )
    correlation = run_correlation([accel[a:b] for a, b in keep]) if keep else 1.0
    return RestRuns(
        np.array(keep, dtype=np.intp).reshape(-1, 2),
        rest,
        ~rest_mask,
        dropped,
        level_a,
        level_g,
        tuple(warnings),
        trimmed,
        correlation,
    )


def imu_still_mask(t: FloatArray, gyro: FloatArray, accel: FloatArray, window_s: float = STILL_WINDOW_S) -> np.ndarray:
    """``(M,)`` True where a unit is still: over ``window_s`` around each sample the std of its rates and
    accelerations stays below ``STILL_SPREAD_FACTOR`` times their white-noise std (from 4th differences,
    :func:`~skincal.calib.preprocess.white_noise_std`) and the mean rate less the gyroscope bias (the
    median rate over those samples) below ``STILL_MEAN_FACTOR`` standard errors of the mean."""
    sg = np.maximum(white_noise_std(gyro, 4), STILL_NOISE_FLOOR)
    sa = np.maximum(white_noise_std(accel, 4), STILL_NOISE_FLOOR)
    mg, n = windowed_mean(t, gyro, window_s)
    ma, _ = windowed_mean(t, accel, window_s)
    vg = np.maximum(windowed_mean(t, gyro**2, window_s)[0] - mg**2, 0.0)
    va = np.maximum(windowed_mean(t, accel**2, window_s)[0] - ma**2, 0.0)
    quiet = np.all(vg < (STILL_SPREAD_FACTOR * sg) ** 2, axis=1) & np.all(va < (STILL_SPREAD_FACTOR * sa) ** 2, axis=1)
    if not quiet.any():
        return quiet
    bias = np.median(gyro[quiet], axis=0)
    still = quiet & np.all(np.abs(mg - bias) < STILL_MEAN_FACTOR * sg / np.sqrt(n)[:, None], axis=1)
    bounds = runs(still)
    for (_, end), (start, _) in zip(bounds[:-1], bounds[1:], strict=True):
        if t[start] - t[end - 1] < STILL_GAP_S:
            still[end:start] = True
    return still


def link_moving(w: FloatArray, dw: FloatArray) -> np.ndarray:
    """``(...)`` True where a link moves by the link signals at a sample: ``|w| > MOVING_RPS`` or
    ``|dw| > MOVING_RPS2`` (``w``, ``dw`` ``(..., 3)`` its angular velocity and acceleration, link frame);
    the streaming calibrator's split of samples into a resting and a moving class."""
    return (np.linalg.norm(w, axis=-1) > MOVING_RPS) | (np.linalg.norm(dw, axis=-1) > MOVING_RPS2)
