"""Segments of a recording taken from the protocol it executed (``skincal segment --protocol motion.json``).

The recording's joint positions are aligned to the protocol's by the time offset ``tau`` (recording
time = protocol time + ``tau``) that minimises their mean squared difference over the overlap:

1. both are resampled onto a :data:`GRID_S` grid; the squared difference for every lag is
   ``sum a^2 + sum b^2 - 2 a*b`` over the overlap, the cross term by FFT cross-correlation (summed
   over joints), the others by cumulative sums; lags whose overlap is shorter than
   :data:`MIN_OVERLAP` of the protocol are not considered;
2. the best lag is refined below the grid step by a parabola through its neighbours, evaluated
   with the protocol's exact closed form at the recording's own time stamps;
3. the fit is accepted when the RMS position difference is at most ``tolerance`` (rad or m).

The protocol's segments, shifted by ``tau`` and kept where they lie within the recording, become the
dataset's segments.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skincal.data.dataset import Segments
from skincal.errors import DatasetError
from skincal.kinematics.transforms import FloatArray
from skincal.protocol.trajectory import Trajectory

GRID_S = 0.01
"""Resampling step of the coarse alignment, s."""
MIN_OVERLAP = 0.5
"""Smallest overlap of recording and protocol considered, as a fraction of the protocol's duration."""
DEFAULT_TOLERANCE = 0.05
"""Largest accepted RMS joint-position difference after alignment, rad (or m): a controller's
tracking error, not a different motion."""


@dataclass(frozen=True)
class Alignment:
    """Result of :func:`align_to_protocol`: ``offset_s`` (recording time of the protocol's t = 0), the
    ``rms`` position difference over the overlap, the segments kept and how many were dropped
    because they lie (partly) outside the recording."""

    offset_s: float
    rms: float
    segments: Segments
    dropped: int


def _mse(traj: Trajectory, t: FloatArray, q: FloatArray, tau: float) -> float:
    inside = (t - tau >= 0) & (t - tau <= traj.duration)
    if not inside.any():
        return np.inf
    return float(np.mean((q[inside] - traj.evaluate(t[inside] - tau)[0]) ** 2))


def align_to_protocol(
    t: FloatArray, q: FloatArray, traj: Trajectory, tolerance: float = DEFAULT_TOLERANCE
) -> Alignment:
    """Align a recorded joint stream ``t`` ``(N,)`` s, ``q`` ``(N, n)`` to ``traj`` (module docstring).

    Raises :class:`DatasetError` when the joint counts differ, the recording is too short, or the
    best alignment leaves an RMS difference above ``tolerance`` (not a recording of this protocol).
    """
    t = np.asarray(t, dtype=float)
    q = np.asarray(q, dtype=float)
    n = traj.n_joints
    if q.ndim != 2 or q.shape[1] != n:
        raise DatasetError(f"protocol alignment: the recording has {q.shape[-1]} joints, the protocol {n}")
    ok = np.isfinite(t) & np.all(np.isfinite(q), axis=1)
    t, q = t[ok], q[ok]
    if t.size < 3 or t[-1] - t[0] < MIN_OVERLAP * traj.duration:
        raise DatasetError(
            f"protocol alignment: the recording ({t[-1] - t[0] if t.size else 0:.1f} s of joint states) is "
            f"shorter than {MIN_OVERLAP:.0%} of the protocol ({traj.duration:.1f} s)"
        )
    order = np.argsort(t, kind="stable")
    t, q = t[order], q[order]
    grid_a = np.arange(t[0], t[-1], GRID_S)
    a = np.column_stack([np.interp(grid_a, t, q[:, j]) for j in range(n)])
    b = traj.evaluate(np.arange(0.0, traj.duration, GRID_S))[0]
    N, M = a.shape[0], b.shape[0]
    L = 1 << int(np.ceil(np.log2(N + M)))
    cross = np.fft.irfft(np.sum(np.fft.rfft(a, L, axis=0) * np.conj(np.fft.rfft(b, L, axis=0)), axis=1), L)
    d = np.arange(-(M - 1), N)  # recording index = protocol index + d
    c = cross[d % L]
    ca = np.concatenate([[0.0], np.cumsum(np.sum(a**2, axis=1))])
    cb = np.concatenate([[0.0], np.cumsum(np.sum(b**2, axis=1))])
    a_lo, a_hi = np.maximum(d, 0), np.minimum(N, M + d)
    b_lo, b_hi = np.maximum(-d, 0), np.minimum(M, N - d)
    count = a_hi - a_lo
    mse = (ca[a_hi] - ca[a_lo] + cb[b_hi] - cb[b_lo] - 2 * c) / np.maximum(count, 1) / n
    mse[count < MIN_OVERLAP * M] = np.inf
    k = int(np.argmin(mse))
    tau0 = grid_a[0] + d[k] * GRID_S
    # refine below the grid step: parabola through the exact errors at tau0 - dt, tau0, tau0 + dt
    e = np.array([_mse(traj, t, q, tau0 + s * GRID_S) for s in (-1, 0, 1)])
    curvature = e[0] - 2 * e[1] + e[2]
    shift = 0.5 * (e[0] - e[2]) / curvature if curvature > 0 else 0.0
    tau = tau0 + float(np.clip(shift, -1.0, 1.0)) * GRID_S
    err = _mse(traj, t, q, tau)
    if not err <= e[1]:
        tau, err = tau0, e[1]
    rms = float(np.sqrt(err))
    if not rms <= tolerance:
        raise DatasetError(
            f"protocol alignment: the recording does not follow the protocol (RMS joint difference "
            f"{rms:.3g} after the best time offset {tau:.2f} s > {tolerance:g}; another robot, seed or protocol?)"
        )
    seg = traj.segments
    t0, t1 = np.asarray(seg.t_start) + tau, np.asarray(seg.t_end) + tau
    keep = (t0 >= t[0]) & (t1 <= t[-1])
    segments = Segments(
        t_start=t0[keep],
        t_end=t1[keep],
        kind=np.asarray(seg.kind)[keep],
        pose=np.asarray(seg.pose)[keep],
        joint=np.asarray(seg.joint)[keep],
    )
    if len(segments) == 0:
        raise DatasetError("protocol alignment: no segment of the protocol lies within the recording")
    return Alignment(offset_s=float(tau), rms=rms, segments=segments, dropped=int(np.sum(~keep)))
