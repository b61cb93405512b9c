"""What the streaming calibrator keeps of the joint stream: the joint states received, merged in stamp order
only when a block is conditioned (:class:`JointBuffer`), and the link-signal grid of the conditioned blocks
with its time derivatives, kept up to date block by block (:class:`GridHistory`)."""

from __future__ import annotations

import numpy as np

from skincal.calib.online.unit import Grid
from skincal.kinematics.transforms import FloatArray

KINEMATIC = slice(12, 15)
"""The columns of :attr:`Grid.y` whose derivative (``dw``) comes from the kinematics, not from differences."""


MERGE_EVERY = 256
"""Chunks of joint states :class:`JointBuffer` holds unmerged at most (the merge is the same whenever it runs)."""


class JointBuffer:
    """Joint states ``(t, q, qd)`` as received (any order, repeats allowed), merged when :meth:`arrays` is asked:
    sorted by stamp (stable: of repeated stamps the first received is kept), ``qd`` from the positions
    (``np.gradient`` over each received chunk) where it was not sent."""

    def __init__(self) -> None:
        self._t: list[FloatArray] = []
        self._q: list[FloatArray] = []
        self._qd: list[FloatArray | None] = []
        self._merged: tuple[FloatArray, FloatArray, FloatArray] | None = None
        self.newest = float("-inf")
        """The latest stamp received, s."""

    def add(self, t: FloatArray, q: FloatArray, qd: FloatArray | None) -> None:
        """One chunk of finite joint states: ``t`` ``(N,)`` s, ``q`` ``(N, n)`` rad, ``qd`` ``(N, n)`` rad/s or None."""
        self._t.append(t)
        self._q.append(q)
        self._qd.append(qd)
        self.newest = max(self.newest, float(np.max(t)))
        if len(self._t) >= MERGE_EVERY:  # a stream whose stamps stop advancing (a driver repeating its last
            self.arrays()  # state) reaches no block: merged now, its repeats go and the memory stays bounded

    def arrays(self) -> tuple[FloatArray, FloatArray, FloatArray] | None:
        """The kept states merged in stamp order (None: none received)."""
        if self._t:
            kept = [] if self._merged is None else [self._merged]
            qd_new = [
                np.gradient(q, t, axis=0) if qd is None and t.size > 1 else (np.zeros_like(q) if qd is None else qd)
                for t, q, qd in zip(self._t, self._q, self._qd, strict=True)
            ]
            t = np.concatenate([m[0] for m in kept] + self._t)
            order = np.argsort(t, kind="stable")
            t = t[order]
            keep = np.r_[True, np.diff(t) > 0]
            q = np.concatenate([m[1] for m in kept] + self._q)[order][keep]
            qd = np.concatenate([m[2] for m in kept] + qd_new)[order][keep]
            self._merged = (t[keep], q, qd)
            self._t, self._q, self._qd = [], [], []
        return self._merged

    def forget_before(self, t0: float) -> None:
        """Drop the merged states stamped before ``t0`` (no block needs them any more)."""
        if self._merged is not None:
            t, q, qd = self._merged
            keep = t >= t0
            if not keep.all():
                self._merged = (t[keep], q[keep], qd[keep])


def _gradient(t: FloatArray, y: FloatArray) -> FloatArray:
    """``dy/dt`` along axis 0 for ``t`` ``(G,)``, ``G >= 2``: three-point differences for unevenly spaced
    instants inside, one-sided at both ends (``np.gradient``'s non-uniform formula, ``edge_order=1``),

        dy_i = -h2 / (h1 (h1 + h2)) y_{i-1} + (h2 - h1) / (h1 h2) y_i + h1 / (h2 (h1 + h2)) y_{i+1},

    ``h1 = t_i - t_{i-1}``, ``h2 = t_{i+1} - t_i``. Written out rather than ``np.gradient`` of each block's rows:
    that takes its equal-spacing formula whenever the rows it is given happen to be evenly spaced to the bit,
    and a block's rows would then differ in the last bits from the same rows of the whole grid."""
    out = np.empty_like(y)
    h = np.diff(t)
    shape = (-1,) + (1,) * (y.ndim - 1)
    out[0] = (y[1] - y[0]) / h[0]
    out[-1] = (y[-1] - y[-2]) / h[-1]
    if t.size > 2:
        h1, h2 = h[:-1], h[1:]
        a = (-h2 / (h1 * (h1 + h2))).reshape(shape)
        b = ((h2 - h1) / (h1 * h2)).reshape(shape)
        c = (h1 / (h2 * (h1 + h2))).reshape(shape)
        out[1:-1] = a * y[:-2] + b * y[1:-1] + c * y[2:]
    return out


class GridHistory:
    """The conditioned blocks' link signals and the derivatives of the whole table along the kept grid:
    three-point differences continuous across blocks, one-sided at the kept grid's two ends, ``dw`` from the
    kinematics. Each block's are computed when it comes (and its predecessor's last row again, and when the
    oldest block goes its successor's first row), not the whole grid's at every block; the rows live in
    buffers with room to grow, :meth:`whole` a view of them (a new buffer when full: a view taken before
    keeps its rows, but for the two end rows' derivatives, which become central or one-sided in place)."""

    def __init__(self) -> None:
        self._spans: list[tuple[int, int, float]] = []  # per kept block: first row, end row, resolved_rps
        self._buf: list[np.ndarray] = []  # t, y, dy, ok, speed
        self._whole: Grid | None = None

    def __bool__(self) -> bool:
        return bool(self._spans)

    def _room(self, block: Grid) -> int:
        """The buffers' row at which ``block`` goes (moved to new buffers, twice the kept rows' room, when full)."""
        start = self._spans[0][0] if self._spans else 0
        end = self._spans[-1][1] if self._spans else 0
        G = block.t.size
        if self._buf and end + G <= self._buf[0].shape[0]:
            return end
        rows = 2 * (end - start + G) + 64
        parts = (block.t, block.y, block.y, block.ok, block.speed)
        new = [np.empty((rows, *x.shape[1:]), dtype=x.dtype) for x in parts]
        for old, buf in zip(self._buf, new if self._buf else (), strict=True):
            buf[: end - start] = old[start:end]
        self._buf = new
        self._spans = [(a - start, b - start, r) for a, b, r in self._spans]
        return end - start

    def append(self, block: Grid) -> None:
        """A new block (its instants after the kept ones'; ``block.dy`` its ``dw`` ``(G, n, 3)``, ``G >= 2``)."""
        i = self._room(block)
        t, y, dy, ok, speed = self._buf
        j = i + block.t.size
        t[i:j], y[i:j], ok[i:j], speed[i:j] = block.t, block.y, block.ok, block.speed
        if self._spans:  # the previous last row, one-sided before, now central
            d = _gradient(t[i - 2 : j], y[i - 2 : j])
            d[1, ..., KINEMATIC] = dy[i - 1, ..., KINEMATIC]
            dy[i - 1], dy[i:j] = d[1], d[2:]
        else:
            dy[i:j] = _gradient(block.t, block.y)
        dy[i:j, ..., KINEMATIC] = block.dy
        self._spans.append((i, j, block.resolved_rps))
        self._whole = None

    def forget_before(self, horizon: float) -> None:
        """Drop the blocks that end before ``horizon`` (the new oldest block's first row one-sided again)."""
        t, y, dy = self._buf[:3] if self._buf else (None, None, None)
        dropped = False
        while self._spans and t is not None and t[self._spans[0][1] - 1] < horizon:
            self._spans.pop(0)
            dropped = True
        if dropped:
            self._whole = None
            if self._spans and t is not None and y is not None and dy is not None:
                i = self._spans[0][0]
                row = (y[i + 1] - y[i]) / (t[i + 1] - t[i])
                row[..., KINEMATIC] = dy[i, ..., KINEMATIC]
                dy[i] = row

    def whole(self) -> Grid | None:
        """The kept blocks as one :class:`Grid` whose ``dy`` is the whole table's (None: no block yet)."""
        if not self._spans:
            return None
        if self._whole is None:
            a, b = self._spans[0][0], self._spans[-1][1]
            t, y, dy, ok, speed = (x[a:b] for x in self._buf)
            self._whole = Grid(t, y, dy, ok, speed, min(r for _, _, r in self._spans))
        return self._whole
