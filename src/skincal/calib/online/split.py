"""The streaming calibrator's split check: its statistics kept per window of the stream as well, so that
independent parts of what it absorbed are solved from their own Grams and compared.

The batch check (:mod:`skincal.calib.consistency`) calibrates parts of a recording apart and inflates a
unit's std where they disagree beyond it; on real 14 Hz tool recordings it is what makes ``mle``'s std
honest, and without it the streaming calibrator's estimates of one mount spread 2-6 times their own std.
A streaming calibrator keeps no samples, but its statistics are sums over samples (:mod:`.stats`), so a
part's Grams are the sum of its windows' Grams. The :class:`Ledger` keeps per window of the stream
(:data:`~skincal.calib.consistency.EXCITATION_WINDOW_S` long on the joint clock, doubled whenever there
would be more than :data:`WINDOWS`: memory stays bounded however long the stream) each candidate link's
Grams, moving samples and summed joint speed. The three splits of the batch check are then formed over
windows (:func:`part_windows`):

* ``time``: windows before and after the middle of the absorbed span;
* ``interleaved``: alternate groups of windows spanning :data:`~skincal.calib.consistency.WINDOW_S`
  (each window once it is that long);
* ``excitation``: windows whose mean joint speed of the unit's chain (``sum_{j <= link} |qd_j|``) is at
  or below the median window's, and the livelier ones.

Each part is solved with the whole stream's noise levels and correlation inflation (:func:`check`), and
the differences are judged by :func:`skincal.calib.consistency.judge`, the batch check's rule. The parts
share the stream's clock mapping and each solves its own residual offset, as a batch part searches its
own. A window's Grams follow every change of the unit's statistics: a clock re-alignment re-expresses
them (:func:`~skincal.calib.online.stats.shift_clock`) or clears them with the rest, a decided link
keeps only its own (:meth:`Ledger.keep_link`), a moved unit's restart rebuilds them from its chunks.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from skincal.calib import consistency
from skincal.calib.online import stats
from skincal.kinematics.transforms import FloatArray, rotation_angle

WINDOWS = 64
"""Most windows a ledger keeps (pairs are merged, doubling the window, beyond): about 1 MB per decided unit, as
much per candidate link of an undecided one."""
MIN_WINDOWS = 2
"""Windows with samples each part needs to be solved."""
MIN_MOVING = 10
"""Moving samples a part needs for its position to be compared (the streaming calibrator's rule for a position)."""
FAR_RAD = np.radians(30.0)
"""A part whose rotation is this far from the whole stream's fell into another basin: not compared."""


@dataclass(frozen=True)
class Piece:
    """The statistics of one absorb call's samples within one window: ``t`` a time inside the window
    (joint clock, s), Grams ``(L, 2, NA, NA)`` and ``(L, 2, NG, NG)`` per candidate link and class, moving
    samples ``(L,)``, summed joint speed ``speed`` ``(L,)`` (rad/s or m/s per sample) and samples ``n``."""

    t: float
    Za: FloatArray
    Zg: FloatArray
    moving: FloatArray
    speed: FloatArray
    n: float

    def link(self, k: int) -> Piece:
        """This piece with candidate link ``k``'s statistics only."""
        return Piece(self.t, self.Za[k : k + 1].copy(), self.Zg[k : k + 1].copy(), self.moving[k : k + 1].copy(),
                     self.speed[k : k + 1].copy(), self.n)  # fmt: skip


def pieces(s: FloatArray, rows_a: FloatArray, rows_g: FloatArray | None, moving: FloatArray, speed: FloatArray,
           t0: float, width: float) -> list[Piece]:  # fmt: skip
    """The absorb call's samples at instants ``s`` ``(M,)`` (rows ``(L, 2, M, 3, NA)`` and ``(L, 2, M, 3, NG)``
    (None: no gyroscope), moving ``(L, M)`` bools, joint speed ``(L, M)``) grouped by window of ``width`` s
    from ``t0`` (samples before ``t0`` join the first)."""
    index = np.maximum(np.floor((s - t0) / width), 0).astype(int)
    L = rows_a.shape[0]
    out = []
    for i in np.unique(index):
        m = index == i
        Za = stats.gram(rows_a[:, :, m])
        Zg = stats.gram(rows_g[:, :, m]) if rows_g is not None else np.zeros((L, 2, stats.NG, stats.NG))
        out.append(Piece(t0 + (i + 0.5) * width, Za, Zg, moving[:, m].sum(axis=1).astype(float),
                         speed[:, m].sum(axis=1), float(m.sum())))  # fmt: skip
    return out


@dataclass
class Ledger:
    """Per window of ``width`` s from ``t0`` (joint clock): Grams ``Za`` ``(W, L, 2, NA, NA)``, ``Zg``
    ``(W, L, 2, NG, NG)``, moving samples ``(W, L)``, summed joint speed ``(W, L)``, samples ``n`` ``(W,)``."""

    t0: float | None = None
    width: float = consistency.EXCITATION_WINDOW_S
    Za: FloatArray | None = None
    Zg: FloatArray | None = None
    moving: FloatArray | None = None
    speed: FloatArray | None = None
    n: FloatArray | None = None

    def start(self, s0: float) -> tuple[float, float]:
        """``(t0, width)`` of the windows, ``t0`` set on the first samples (``s0``: their first instant)."""
        if self.t0 is None:
            self.t0 = float(s0)
        return self.t0, self.width

    def count(self) -> int:
        """The samples absorbed (each in one window; a Gram's ``Z[9, 9]`` sums their robust weights instead)."""
        return 0 if self.n is None else int(round(float(self.n.sum())))

    def add(self, parts: list[Piece], sign: float = 1.0) -> None:
        """Add (``sign`` 1) or take out (-1) ``parts``."""
        for p in parts:
            if self.t0 is None:  # rebuilt from chunks (a moved unit's restart): windows about the first
                self.t0 = p.t - 0.5 * self.width
            i = self._index(p.t)
            assert self.Za is not None and self.Zg is not None and self.moving is not None
            assert self.speed is not None and self.n is not None
            self.Za[i] += sign * p.Za
            self.Zg[i] += sign * p.Zg
            self.moving[i] += sign * p.moving
            self.speed[i] += sign * p.speed
            self.n[i] += sign * p.n

    def _index(self, t: float) -> int:
        assert self.t0 is not None
        i = max(int(np.floor((t - self.t0) / self.width)), 0)
        while i >= WINDOWS:  # merge pairs: the window doubles, memory stays bounded
            self._merge()
            i = max(int(np.floor((t - self.t0) / self.width)), 0)
        if self.Za is None or i >= self.Za.shape[0]:
            self._grow(i + 1)
        return i

    def _grow(self, w: int) -> None:
        assert self.Za is not None, "Ledger.setup() before add()"
        extra = w - self.Za.shape[0]
        for name in ("Za", "Zg", "moving", "speed", "n"):
            x = getattr(self, name)
            setattr(self, name, np.concatenate([x, np.zeros((extra, *x.shape[1:]))]))

    def setup(self, L: int) -> None:
        """Empty windows for ``L`` candidate links (the first absorb call)."""
        if self.Za is None:
            self.Za, self.Zg = np.zeros((0, L, 2, stats.NA, stats.NA)), np.zeros((0, L, 2, stats.NG, stats.NG))
            self.moving, self.speed, self.n = np.zeros((0, L)), np.zeros((0, L)), np.zeros(0)

    def _merge(self) -> None:
        assert self.Za is not None
        w = self.Za.shape[0]
        if w % 2:
            self._grow(w + 1)
        for name in ("Za", "Zg", "moving", "speed", "n"):
            x = getattr(self, name)
            setattr(self, name, x[0::2] + x[1::2])
        self.width *= 2.0

    def shift(self, tau: float, drift: float) -> None:
        """Re-express every window's Grams in the clock mapping composed with ``(tau, drift)``."""
        if self.Za is not None and self.Zg is not None and self.Za.shape[0]:
            self.Za, self.Zg = stats.shift_clock(self.Za, self.Zg, tau, drift)

    def clear(self) -> None:
        """Forget every window (a restart whose older statistics are forgotten)."""
        L = None if self.moving is None else self.moving.shape[1]
        self.t0, self.width, self.Za, self.Zg, self.moving, self.speed, self.n = (
            None, consistency.EXCITATION_WINDOW_S, None, None, None, None, None
        )  # fmt: skip
        if L is not None:
            self.setup(L)

    def keep_link(self, k: int) -> None:
        """Candidate link ``k``'s statistics only (the unit's link is decided)."""
        if self.Za is not None and self.Zg is not None and self.moving is not None and self.speed is not None:
            self.Za, self.Zg = self.Za[:, k : k + 1].copy(), self.Zg[:, k : k + 1].copy()
            self.moving, self.speed = self.moving[:, k : k + 1].copy(), self.speed[:, k : k + 1].copy()


def part_windows(ledger: Ledger, k: int) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``{split: (windows_A, windows_B)}`` boolean over the ledger's windows for candidate link ``k``
    (module docstring); windows without samples are in neither part."""
    assert ledger.n is not None and ledger.speed is not None
    have = ledger.n > 0
    if not have.any():
        return {}
    i = np.arange(ledger.n.size)
    lo, hi = i[have][0], i[have][-1] + 1
    mid = 0.5 * (lo + hi)
    centre = i + 0.5
    group = max(int(round(consistency.WINDOW_S / ledger.width)), 1)
    alternate = (i // group) % 2 == 0
    score = np.where(have, ledger.speed[:, k] / np.maximum(ledger.n, 1.0), 0.0)
    live = score > np.median(score[have])
    return {
        "time": (have & (centre < mid), have & (centre >= mid)),
        "interleaved": (have & alternate, have & ~alternate),
        "excitation": (have & ~live, have & live),
    }


def _std(var: FloatArray) -> FloatArray:
    """Std of variances ``var``; NaN (not compared) where a variance is not positive or not finite (a part whose
    normal matrix is not positive definite there determines nothing)."""
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(var) & (var > 0), np.sqrt(np.abs(var)), np.nan)


Solve = Callable[[FloatArray, FloatArray, float, np.ndarray], "stats.Solution | None"]
"""``solve(Za, Zg, span_s, windows)``: a part's solution from its Grams ``(2, NA, NA)``, ``(2, NG, NG)`` (the
two classes, unweighted), the span of its windows, s, and which of the ledger's windows they are ``(W,)``."""


def check(ledger: Ledger, k: int, full_std: FloatArray, full_R: FloatArray, solve: Solve, kappa: float
          ) -> consistency.Consistency | None:  # fmt: skip
    """The split check of candidate link ``k`` (module docstring): ``full_std`` ``(7,)`` the whole stream's
    pose std (m, rad; position then rotation, link frame) and its time offset's (s), ``full_R`` its rotation
    (a part more than :data:`FAR_RAD` from it is not compared), ``solve`` a part's
    solver, ``kappa`` the stream's variance inflation for correlated residuals (applied to each part's
    covariance too). The time offsets of the parts (each its residual offset ``tau`` of the one mapping)
    are compared too. None when the ledger holds nothing."""
    if ledger.Za is None or ledger.Zg is None or ledger.n is None or not (ledger.n > 0).any():
        return None
    parts: dict[str, tuple[Any, ...]] = {}  # per split: position, rotation, pose std, offset, its std; A then B
    failed: list[str] = []
    for split, sides in part_windows(ledger, k).items():
        got = []
        for side, w in enumerate(sides):
            sol = None
            if int(w.sum()) >= MIN_WINDOWS:
                span = float(np.ptp(np.flatnonzero(w)) + 1) * ledger.width
                sol = solve(ledger.Za[w, k].sum(axis=0), ledger.Zg[w, k].sum(axis=0), span, w)
            if sol is None:
                failed.append(f"{split} part {side + 1}: too little data")
                break
            away = float(rotation_angle(sol.R, full_R))
            if away > FAR_RAD:
                failed.append(f"{split} part {side + 1}: {consistency.ANOTHER_BASIN} ({np.degrees(away):.0f} deg away)")
                break
            std = _std(np.r_[np.diag(sol.pose_covariance()), sol.cov[stats.TAU, stats.TAU]] * kappa)
            if ledger.moving is not None and ledger.moving[w, k].sum() < MIN_MOVING:
                std[:3] = np.nan  # rests only (the calm windows of a unit that mostly rests): no position
            got.append((sol.p, sol.R, std[:6], sol.tau, std[6]))
        if len(got) == 2:
            parts[split] = (*got[0], *got[1])
    z = np.full((len(consistency.SPLITS), 6), np.nan)
    z_offset = np.full(len(consistency.SPLITS), np.nan)
    named: list[str] = []
    limit = consistency.PART_STD_LIMIT * full_std
    for i, split in enumerate(consistency.SPLITS):
        if split in parts:
            pa, Ra, sa, ta, ua, pb, Rb, sb, tb, ub = parts[split]
            d = consistency.pose_difference(pa, Ra, pb, Rb)
            z[i], names = consistency.normalised_difference(split, d, sa, sb, limit[:6])
            named += names
            if max(ua, ub) <= limit[6] and ua + ub > 0:  # the residual offsets: the offset's difference (s)
                z_offset[i] = (tb - ta) / np.hypot(ua, ub)
                if abs(z_offset[i]) > consistency.Z_NAMED:
                    named.append(f"{split}: time offset {1e3 * (ta - tb):+.1f} ms ({abs(z_offset[i]):.1f} std)")
    return consistency.judge(z, named, failed, z_offset)
