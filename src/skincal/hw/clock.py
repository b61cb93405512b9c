"""Device clock -> host clock: offset and drift from one-sided delayed timestamp pairs.

Model: a sample stamped ``d`` (s, device clock) and received at host time ``h`` (s) satisfies

    h = d + offset + drift * (d - d_ref) + delay,     delay >= 0,

with ``drift`` dimensionless (1e-6 = 1 ppm; ``drift = 1 / (1 + e) - 1`` for a device clock that runs
``1 + e`` times as fast as the host's) and ``d_ref`` the first device time seen. Since delays are
one-sided, the line is the *lower envelope* of ``y = h - d`` over ``d``: the line below every point
that is closest to them on average,

    maximise  n * a + b * sum(x_i)   subject to   a + b * x_i <= y_i,   x_i = d_i - d_ref

(a linear programme solved with :func:`scipy.optimize.linprog`; its optimum touches the lower convex
hull at the mean of ``x``). The minimum network delay is absorbed into ``offset``: mapped times are
host times at the fastest observed delivery. Memory stays bounded: points are binned by device time
and only the lowest point of each bin is kept (bins double in width when there are too many).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import linprog

from skincal.errors import ConfigError

MAX_DRIFT = 0.01
"""Largest clock drift fitted, dimensionless (10,000 ppm; crystals drift < 100 ppm): the fitted mapping
always increases with device time, whatever timestamps a sender makes up."""


@dataclass(frozen=True)
class ClockFit:
    """``host_s = device_s + offset_s + drift * (device_s - device_ref_s)`` (all in seconds).

    ``n_points``: lower-envelope points used; ``span_s``: device-time span they cover.
    """

    offset_s: float
    drift: float
    device_ref_s: float
    n_points: int = 0
    span_s: float = 0.0

    @property
    def drift_ppm(self) -> float:
        return self.drift * 1e6

    def to_host(self, device_s: ArrayLike) -> np.ndarray:
        """Map device times ``(N,)`` s to host times ``(N,)`` s."""
        d = np.asarray(device_s, dtype=float)
        return d + self.offset_s + self.drift * (d - self.device_ref_s)


class ClockEstimator:
    """Incremental lower-envelope fit of one device clock against the host clock.

    Args:
        bin_s: initial bin width in device time, s (one envelope point per bin).
        max_bins: bins kept before their width doubles.
        min_span_s: device-time span below which only the offset is fitted (drift 0): over a
            short span the slope is dominated by delay noise (0.3 ms of scheduling noise over 1 s
            is 300 ppm, more than a crystal's drift), so drift is estimated from 10 s on by default.
    """

    def __init__(self, bin_s: float = 0.1, max_bins: int = 4096, min_span_s: float = 10.0) -> None:
        if bin_s <= 0 or max_bins < 2 or min_span_s < 0:
            raise ConfigError("clock estimator: bin_s must be > 0 s, max_bins >= 2, min_span_s >= 0 s")
        self.bin_s = float(bin_s)
        self.max_bins = int(max_bins)
        self.min_span_s = float(min_span_s)
        self.device_ref_s: float | None = None
        self._bins: dict[int, tuple[float, float]] = {}  # bin -> (x, y) with the lowest y
        self._fit: ClockFit | None = None

    def add(self, host_s: ArrayLike, device_s: ArrayLike) -> None:
        """Add pairs of host receive times ``(N,)`` s and device timestamps ``(N,)`` s."""
        h = np.atleast_1d(np.asarray(host_s, dtype=float))
        d = np.atleast_1d(np.asarray(device_s, dtype=float))
        if h.shape != d.shape or h.ndim != 1:
            raise ConfigError(
                f"clock estimator: host and device times must be equal-length 1-D arrays, got {h.shape}, {d.shape}"
            )
        if h.size == 0:
            return
        if self.device_ref_s is None:
            self.device_ref_s = float(d[0])
        x = d - self.device_ref_s
        y = h - d
        keys = np.floor(x / self.bin_s).astype(np.int64)
        order = np.lexsort((y, keys))  # per bin, lowest y first
        keys, x, y = keys[order], x[order], y[order]
        first = np.r_[True, keys[1:] != keys[:-1]]
        changed = False
        for k, xi, yi in zip(keys[first].tolist(), x[first].tolist(), y[first].tolist(), strict=True):
            old = self._bins.get(k)
            if old is None or yi < old[1]:
                self._bins[k] = (xi, yi)
                changed = True
        while len(self._bins) > self.max_bins:
            self._merge()
        if changed:
            self._fit = None

    def _merge(self) -> None:
        self.bin_s *= 2.0
        merged: dict[int, tuple[float, float]] = {}
        for k, (xi, yi) in self._bins.items():
            old = merged.get(k // 2)
            if old is None or yi < old[1]:
                merged[k // 2] = (xi, yi)
        self._bins = merged

    def envelope(self) -> tuple[np.ndarray, np.ndarray]:
        """The kept lower-envelope points: device times ``x`` (s, relative to ``device_ref_s``) and
        ``y = h - d`` (s), sorted by ``x``."""
        if not self._bins:
            return np.empty(0), np.empty(0)
        pts = np.array(sorted(self._bins.values()))
        return pts[:, 0], pts[:, 1]

    def fit(self) -> ClockFit | None:
        """Current fit, or ``None`` before the first sample (cached until new envelope points)."""
        if self._fit is None and self._bins:
            x, y = self.envelope()
            self._fit = fit_lower_envelope(x, y, self.device_ref_s or 0.0, self.min_span_s)
        return self._fit


def fit_lower_envelope(x: np.ndarray, y: np.ndarray, device_ref_s: float = 0.0, min_span_s: float = 0.0) -> ClockFit:
    """Line ``a + b x`` below all points ``(x_i, y_i)`` maximising ``sum(a + b x_i)`` (see module doc).

    ``x``: ``(N,)`` device time minus ``device_ref_s``, s; ``y``: ``(N,)`` host minus device time, s.
    Fits the offset only (``b = 0``, ``a = min y``) when the span of ``x`` is below ``min_span_s``;
    ``|b|`` is at most :data:`MAX_DRIFT`.
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    span = float(x.max() - x.min()) if x.size else 0.0
    if x.size < 2 or span <= max(min_span_s, 0.0):
        return ClockFit(float(y.min()), 0.0, device_ref_s, int(x.size), span)
    xm = float(x.mean())
    xc = x - xm  # centred for conditioning: a_c = a + b * xm
    res = linprog(
        c=[-1.0, 0.0],  # maximise a_c (sum(xc) = 0)
        A_ub=np.column_stack([np.ones_like(xc), xc]),
        b_ub=y,
        bounds=[(None, None), (-MAX_DRIFT, MAX_DRIFT)],
        method="highs",
    )
    if res.status != 0:  # cannot happen for >= 2 distinct x; keep the offset-only fit
        return ClockFit(float(y.min()), 0.0, device_ref_s, int(x.size), span)
    a_c, b = (float(v) for v in res.x)
    # the slope is not unique when the optimum is a vertex; the LP picks a supporting line at xm
    return ClockFit(a_c - b * xm, b, device_ref_s, int(x.size), span)
