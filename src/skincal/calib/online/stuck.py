"""The stuck-axis test of :func:`~skincal.calib.preprocess.screening.screen_channels`, streamed
(:class:`StuckScreen`): an axis whose register stopped updating repeats one value exactly while the unit moves.
A stuck accelerometer axis makes its samples wrong (a frozen z axis put the unit's position 0.5 mm off at 10x
its std, and without a word, in a simulated Panda session): they are dropped. A stuck gyroscope axis makes its
readings wrong (one stuck at 0.37 rad/s turned the streamed rotation 4.3 deg): they are left out, the
accelerometer's kept.

The rule is the batch one (:func:`~skincal.calib.preprocess.screening.stuck_runs`): a run of exactly repeated
consecutive readings of one axis that lasts :data:`~skincal.calib.preprocess.screening.STUCK_MIN_S` (at least
:data:`~skincal.calib.preprocess.screening.STUCK_MIN_SAMPLES` samples) while another axis of the same channel
varies by more than :data:`~skincal.calib.preprocess.screening.STUCK_OTHERS_PTP` peak to peak (gyroscope:
another of its axes by more than :data:`~skincal.calib.preprocess.screening.GYRO_STUCK_OTHERS_PTP` or the
accelerometer by more than ``STUCK_OTHERS_PTP``: a dead gyroscope reading zeros while the unit moves is
stuck); a run at the axis' extreme
beyond the channel's rail floor is a rail, left to the saturation screening. Streamed, a run cannot be judged
before it is long enough, so the samples from the start of a run of repeats still too short to judge are held
back (at most ``STUCK_MIN_S`` of one unit's stream) and released once the run ends or is judged; a stream's
last sample alone is not held (a register's last update is a true reading: the batch test drops it with the
run, streamed it is dropped only when its repeat arrived with it). Two more differences from the batch test,
both for a stream whose length is unknown: the run's length threshold is ``STUCK_MIN_S`` only (not also a
fraction of the stream), the extremes are those so far, and a long run judged still (the other axes quiet: a
unit at rest below one LSB of noise) is released; should the other axes move later in that run, its samples
from then on are left out, the released ones stay.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from skincal.calib.preprocess.screening import (
    GYRO_SATURATION_MIN,
    GYRO_STUCK_OTHERS_PTP,
    SATURATION_MIN,
    STUCK_MIN_S,
    STUCK_MIN_SAMPLES,
    STUCK_OTHERS_PTP,
)
from skincal.kinematics.transforms import FloatArray


@dataclass
class _Run:
    """One axis' run of repeated readings at the end of the released samples: its value and length, the
    other axes' smallest and largest readings over it, and the index of its stuck span (-1: not stuck)."""

    value: float = float("nan")
    length: int = 0
    lo: FloatArray = field(default_factory=lambda: np.full(5, np.inf))  # (2,) accelerometer, (5,) gyroscope
    hi: FloatArray = field(default_factory=lambda: np.full(5, -np.inf))
    span: int = -1


@dataclass
class Span:
    """A stretch of readings with an axis stuck: channel (0 accelerometer: the samples dropped; 1 gyroscope:
    its readings left out), axis (0, 1, 2 = x, y, z), value (m/s^2 or rad/s), first and last stamp (s, the
    unit's clock) and the number of samples."""

    channel: int
    axis: int
    value: float
    t0: float
    t1: float
    n: int


INTERVALS = 256
"""The stream's sample interval is the median of its last this many stamp intervals (a first push of two
bunched stamps would otherwise set the 1 s run length for good)."""

CHANNELS = (
    (np.full(2, STUCK_OTHERS_PTP), SATURATION_MIN),
    (np.r_[np.full(2, GYRO_STUCK_OTHERS_PTP), np.full(3, STUCK_OTHERS_PTP)], GYRO_SATURATION_MIN),
)
"""Per channel (accelerometer, gyroscope) how much each of the other readings of a run's samples must vary
(the accelerometer: its other two axes, m/s^2; the gyroscope: its other two axes, rad/s, then the
accelerometer's three, m/s^2), and beyond what value a run at the axis' extreme is a rail (the batch
screening's constants, :func:`~skincal.calib.preprocess.screening.gyro_lost`)."""


_OTHER_COLUMNS = [np.array(c) for c in ([1, 2], [0, 2], [0, 1], [4, 5, 0, 1, 2], [3, 5, 0, 1, 2], [3, 4, 0, 1, 2])]
"""Per axis (accelerometer x, y, z, gyroscope x, y, z) the columns of ``[accel, gyro]`` that :func:`_others` takes."""


def _others(c: int, k: int, a: FloatArray, g: FloatArray | None) -> FloatArray:
    """The readings that show the unit moving during a run of axis ``k`` of channel ``c`` (:data:`CHANNELS`)."""
    if c == 0:
        return np.delete(a, k, axis=1)
    assert g is not None
    return np.hstack([np.delete(g, k, axis=1), a])


class StuckScreen:
    """One unit's streamed stuck-axis test: :meth:`push` takes samples in stamp order and returns those
    released, without those whose accelerometer is stuck; :meth:`push` with ``final`` releases everything
    held; :meth:`gyro_masked` leaves out the readings of a stuck gyroscope axis.

    Attributes:
        spans: the stuck stretches found, in order.
        dropped: samples dropped (accelerometer), and ``gyro_dropped`` gyroscope readings found stuck.
        t_end: the newest stamp released, s.
    """

    def __init__(self) -> None:
        self._held: tuple[FloatArray, FloatArray, FloatArray | None] | None = None
        self._runs = [[_Run() for _ in range(3)] for _ in CHANNELS]
        self._flat_runs = [r for runs in self._runs for r in runs]  # accelerometer x, y, z, gyroscope x, y, z
        self._lo = [np.full(3, np.inf) for _ in CHANNELS]  # each axis' extremes so far (a rail's value is one)
        self._hi = [np.full(3, -np.inf) for _ in CHANNELS]
        self._dt = float("nan")
        self._intervals: deque[float] = deque(maxlen=INTERVALS)
        self._t_seen = float("-inf")
        self.spans: list[Span] = []
        self.dropped = 0
        self.gyro_dropped = 0
        self.t_end = float("-inf")
        self.quick = True  # False: every push through the per-axis path (the reference the quick one is tested on)
        self.quick_pushes = 0  # pushes in which no run could be judged, screened all axes at once

    def min_run(self) -> float:
        """The samples a run needs to be judged: ``STUCK_MIN_S`` at the stream's median sample interval
        (at least ``STUCK_MIN_SAMPLES``)."""
        return max(float(STUCK_MIN_SAMPLES), STUCK_MIN_S / self._dt) if self._dt > 0 else float(STUCK_MIN_SAMPLES)

    def held(self) -> int:
        """Samples held back, waiting for their run to be judged."""
        return 0 if self._held is None else int(self._held[0].size)

    def push(
        self, t: FloatArray, a: FloatArray, g: FloatArray | None, final: bool = False
    ) -> tuple[FloatArray, FloatArray, FloatArray | None]:
        """Screen the new samples ``t`` ``(M,)`` s, ``a`` ``(M, 3)`` m/s^2, ``g`` ``(M, 3)`` rad/s or None (finite
        readings) after the held ones: the samples released (stuck accelerometer ones left out), ``g`` None
        when ``g`` is."""
        if t.size:  # the stream's sample interval: the median of its recent intervals, across pushes
            d = np.diff(np.r_[self._t_seen, t]) if np.isfinite(self._t_seen) else np.diff(t)
            self._intervals.extend(d[d > 0].tolist())
            self._t_seen = max(self._t_seen, float(t[-1]))
            if self._intervals:
                self._dt = float(np.median(self._intervals))
        if self._held is not None:
            ht, ha, hg = self._held
            t, a = np.concatenate([ht, t]), np.concatenate([ha, a])
            g = None if g is None or hg is None else np.concatenate([hg, g])
            self._held = None
        n = t.size
        if n == 0:
            return t, a, g
        min_run = self.min_run()
        if self.quick and (out := self._release_unjudged(t, a, g, min_run, final)) is not None:
            self.quick_pushes += 1
            return out
        judged, release = [], n
        for c, x in enumerate((a, g)):
            if x is None:
                continue
            lo, hi = np.minimum(self._lo[c], x.min(axis=0)), np.maximum(self._hi[c], x.max(axis=0))
            for k in range(3):
                s, bad = self._judge(c, k, x, _others(c, k, a, g), min_run, lo[k], hi[k])
                length = int(self._length(c, k, x, s)[-1])  # the last run's, its released part included
                if not final and 1 < length < min_run and not bad[-1]:
                    release = min(release, int(s[-1]))  # a repeat too short to judge yet: held from its start
                judged.append((c, k, x, s, bad))
        keep = np.ones(release, dtype=bool)
        gyro_stuck = np.zeros(release, dtype=bool)
        for c, k, x, s, bad in judged:
            self._release(c, k, t, x, _others(c, k, a, g), s, bad, release, keep if c == 0 else gyro_stuck)
        if release:
            for c, x in enumerate((a, g)):
                if x is not None:
                    self._lo[c] = np.minimum(self._lo[c], x[:release].min(axis=0))
                    self._hi[c] = np.maximum(self._hi[c], x[:release].max(axis=0))
            self.t_end = max(self.t_end, float(t[release - 1]))
        if release < n:
            self._held = (t[release:], a[release:], None if g is None else g[release:])
        self.dropped += int((~keep).sum())
        self.gyro_dropped += int((gyro_stuck & keep).sum())
        t, a = t[:release][keep], a[:release][keep]
        return t, a, None if g is None else g[:release][keep]

    def _release_unjudged(
        self, t: FloatArray, a: FloatArray, g: FloatArray | None, min_run: float, final: bool
    ) -> tuple[FloatArray, FloatArray, FloatArray | None] | None:
        """:meth:`push` when no run can be judged (None otherwise): no axis' run in the samples can reach
        ``min_run`` (each axis' repeated neighbours plus one, plus the released run it may continue, fall short:
        the usual case of a chunk shorter than a second). Then nothing is stuck; the samples from the start of
        the newest run of repeats (longer than one sample) on any axis are held, unless ``final``; each axis' run
        at the end of the released samples is carried over. All axes at once: the same state as the per-axis
        path, bit for bit (minima and maxima only)."""
        x = a if g is None else np.hstack([a, g])
        n, m = x.shape
        runs = self._flat_runs[:m]
        same = x[1:] == x[:-1]
        carried = np.array([bool(r.length) and x[0, j] == r.value for j, r in enumerate(runs)])
        carried_length = np.array([r.length for r in runs]) * carried
        if np.any(np.count_nonzero(same, axis=0) + 1 + carried_length >= min_run):
            return None
        changed = np.vstack([np.ones((1, m), dtype=bool), ~same])  # (n, m): a run starts here
        row = np.arange(n)[:, None]
        last_start = np.where(changed, row, 0).max(axis=0)  # each axis' newest run start
        length = n - last_start + np.where(last_start == 0, carried_length, 0)
        release = n if final or not np.any(length > 1) else int(np.min(last_start[length > 1]))
        if release:
            start = np.where(changed[:release], row[:release], 0).max(axis=0)  # each axis' run at the release
            lo = np.minimum.accumulate(x[release - 1 :: -1], axis=0)[::-1]  # lo[i]: smallest of rows i..release-1
            hi = np.maximum.accumulate(x[release - 1 :: -1], axis=0)[::-1]
            for j, run in enumerate(runs):
                i0, cols = int(start[j]), _OTHER_COLUMNS[j]
                if i0 == 0 and carried[j]:
                    run.length += release
                    run.lo, run.hi = np.minimum(run.lo, lo[0, cols]), np.maximum(run.hi, hi[0, cols])
                else:
                    run.value, run.length = float(x[i0, j]), release - i0
                    run.lo, run.hi = lo[i0, cols], hi[i0, cols]
                run.span = -1
            for c in range(m // 3):
                self._lo[c] = np.minimum(self._lo[c], lo[0, 3 * c : 3 * c + 3])
                self._hi[c] = np.maximum(self._hi[c], hi[0, 3 * c : 3 * c + 3])
            self.t_end = max(self.t_end, float(t[release - 1]))
        if release < n:
            self._held = (t[release:], a[release:], None if g is None else g[release:])
        return t[:release], a[:release], None if g is None else g[:release]

    def _length(self, c: int, k: int, x: FloatArray, s: np.ndarray) -> np.ndarray:
        """The lengths of axis ``k``'s runs (starts ``s``) in ``x`` of channel ``c``, the released run included."""
        length = np.diff(np.r_[s, x.shape[0]])
        run = self._runs[c][k]
        if run.length and x[0, k] == run.value:
            length[0] += run.length
        return length

    def _judge(
        self, c: int, k: int, x: FloatArray, others: FloatArray, min_run: float, lo: float, hi: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Axis ``k`` of channel ``c``'s runs in ``x``: their starts and which are stuck (``others``: the readings
        that show the unit moving; ``lo``, ``hi``: the axis' extremes so far, a run at one beyond the channel's
        rail floor is a rail)."""
        ptp, rail = CHANNELS[c]
        col = x[:, k]
        s = np.flatnonzero(np.r_[True, col[1:] != col[:-1]])
        rlo, rhi = np.minimum.reduceat(others, s, axis=0), np.maximum.reduceat(others, s, axis=0)
        run = self._runs[c][k]
        if run.length and col[0] == run.value:  # the first run continues the released samples' last one
            rlo[0], rhi[0] = np.minimum(rlo[0], run.lo), np.maximum(rhi[0], run.hi)
        v = col[s]
        at_rail = (np.abs(v) > rail) & ((v == lo) | (v == hi))
        return s, (self._length(c, k, x, s) >= min_run) & np.any(rhi - rlo > ptp, axis=1) & ~at_rail

    def _release(self, c: int, k: int, t: FloatArray, x: FloatArray, o: FloatArray, s: np.ndarray, bad: np.ndarray,
                 release: int, mark: np.ndarray) -> None:  # fmt: skip
        """Axis ``k`` of channel ``c``'s stuck runs (starts ``s``, ``bad``) among the samples ``[0, release)``:
        marked in ``mark`` (accelerometer: ``False`` in the kept mask; gyroscope: ``True``) and recorded as spans;
        its run at the end of the released samples carried over (``o``: the readings that show the unit moving)."""
        if release == 0:
            return
        run = self._runs[c][k]
        ends = np.r_[s[1:], t.size]
        carried = bool(run.length) and x[0, k] == run.value
        inside = np.flatnonzero(s < release)
        for j in inside[bad[inside]]:
            i0, i1 = int(s[j]), min(int(ends[j]), release)
            mark[i0:i1] = c == 1
            if j == 0 and carried and run.span >= 0:  # the stuck span the released samples ended in goes on
                span = self.spans[run.span]
                span.t1, span.n = float(t[i1 - 1]), span.n + (i1 - i0)
            else:
                self.spans.append(Span(c, k, float(x[i0, k]), float(t[i0]), float(t[i1 - 1]), i1 - i0))
                if j == inside[-1]:
                    run.span = len(self.spans) - 1
        last = int(inside[-1])
        i0 = int(s[last])
        others = o[i0:release]
        if last == 0 and carried:
            run.length += release
            run.lo, run.hi = np.minimum(run.lo, others.min(axis=0)), np.maximum(run.hi, others.max(axis=0))
        else:
            run.value, run.length = float(x[i0, k]), release - i0
            run.lo, run.hi = others.min(axis=0), others.max(axis=0)
        if not bad[last]:
            run.span = -1

    def gyro_masked(self, t: FloatArray, g: FloatArray | None) -> FloatArray | None:
        """``g`` with NaN rows at the stamps ``t`` inside a stuck gyroscope span (those readings are left out of the
        statistics, as at a rail; the accelerometer's stay)."""
        if g is None:
            return None
        out = g
        for sp in self.spans:
            if sp.channel == 1:
                inside = (t >= sp.t0) & (t <= sp.t1)
                if inside.any():
                    out = np.where(inside[:, None], np.nan, out)
        return out

    def warnings(self) -> list[str]:
        """The batch screening's warning for each stuck stretch (``to the end``: up to the newest stamp released)."""
        out = []
        for sp in self.spans:
            end = "to the end" if sp.t1 >= self.t_end else f"to {sp.t1:.1f} s"
            if sp.channel == 0:
                out.append(f"accelerometer {'xyz'[sp.axis]} axis stuck at {sp.value:.4g} m/s^2 from {sp.t0:.1f} s "
                           f"{end} ({sp.n} samples ignored)")  # fmt: skip
            else:
                out.append(f"gyroscope {'xyz'[sp.axis]} axis stuck at {sp.value:.4g} rad/s from {sp.t0:.1f} s {end} "
                           f"({sp.n} gyroscope readings ignored; the accelerometer's are kept)")  # fmt: skip
        return out
