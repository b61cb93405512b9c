"""Each unit's clock in the streaming calibrator: its coarse alignment on the motion (:func:`align`),
the mapping of its stamps to joint-clock instants (:func:`instants`, re-sync steps tracked by
:func:`track_steps`) and its re-alignment when the fitted residual clock error grows
(:func:`clock_off`, :func:`realign`); the clock model itself is :mod:`skincal.calib.timing`'s."""

from __future__ import annotations

from collections import deque

import numpy as np

from skincal.calib import rest
from skincal.calib.online import stats
from skincal.calib.online.options import OnlineOptions
from skincal.calib.online.unit import Grid, UnitState, undecide
from skincal.calib.timing import (
    OffsetSearch,
    coarse_time_offset,
    compose_clock,
    find_clock_steps,
    motion_instants,
    motion_profile,
    widened_note,
)
from skincal.kinematics.transforms import FloatArray

ALIGN_SHARPNESS = 0.1
"""A unit's clock is aligned once the cross-correlation peak stands out by this much (correlation units)...
"""
ALIGN_WAIT_FRACTION = 0.8
"""...or once its pending stream spans this fraction of the history (then with a warning in the result)."""
REALIGN_S = 0.004
"""A decided unit whose residual clock error (offset and drift, at either end of its data) exceeds this (s)
is re-aligned (its clock mapping composed with the residual, :func:`~skincal.calib.timing.compose_clock`)
and its statistics restarted: the first-order clock model holds for a few ms only."""
RECHECK_GROWTH = 2.0
"""An aligned unit's coarse offset is searched again once its kept stream spans this many times the stream
it was last searched on, and at the data's end (:func:`recheck`)..."""
RECHECK_S = 0.02
"""...and taken when its distinct peak lies further than this from the current mapping, s (beyond what the
fine fit's re-alignments, :data:`REALIGN_S` at a time, reach reliably)."""
ALIGN_RETRY_S = 2.0
"""A unit not yet aligned tries again after this much more of its stream, s."""
MAX_REALIGN = 6
"""Re-alignments allowed per unit."""
AGEING_S = 5.0
"""Samples this close (s) to the start of the grid's history are about to be lost unaligned: judged then."""
REST_ONLY_DENSITY = 0.3
"""A unit's stream whose samples fall in the robot's moves at under this fraction of the moves' share of
time was recorded in the rests only (:func:`holds_motion`)."""


def align(st: UnitState, grid: Grid, t: FloatArray, a: FloatArray, g: FloatArray | None, o: OnlineOptions,
          final: bool = False) -> None:  # fmt: skip
    """Find the unit's coarse time offset on the grid's motion (:func:`~skincal.calib.timing.coarse_time_offset`)
    once its samples ``t, a, g`` span ``o.align_s`` with motion and the peak is distinct (or the history is
    nearly full, or the data ended: ``final``, whatever they span, as ``mle`` searches a short recording);
    else leave ``st.offset`` None."""
    tg = grid.t
    inside = (t >= tg[0]) & (t <= tg[-1])
    if inside.sum() < 20:
        return
    ti = t[inside]
    short = ti[-1] - ti[0] < o.align_s
    # about to leave the grid unaligned (a full history): was it recorded in the rests only, judged up to the
    # grid's end? (At a stream's start every sample is near the grid's start: a real recording whose first second
    # was a rest was judged "static poses only" there and never searched.)
    ageing = bool(ti[0] < tg[0] + AGEING_S and tg[-1] - tg[0] >= o.history_s - AGEING_S)
    if short and not (ageing or final):
        return
    if holds_motion(grid, ti, end=tg[-1] if short and not final else ti[-1]) is False:
        # the robot moved while the unit recorded nothing (static poses only): nothing determines its
        # clock, and a search would shift the rest samples into the moves
        if st.offset is None:  # the stamps as they are, aligned again once it records in motion
            st.offset, st.offset_sharpness, st.clock_provisional = 0.0, 0.0, True
            st.t_ref, st.steps, st.t_seen = float(ti[0]), find_clock_steps(t), float(t[-1])
        return
    if short and not final:
        return
    search = search_span(grid, ti, a[inside], None if g is None else g[inside])
    if search is None:
        return  # no motion to align on yet
    span = ti[-1] - ti[0]
    if search.sharpness < ALIGN_SHARPNESS and span < ALIGN_WAIT_FRACTION * o.history_s and not final:
        return  # the peak is not distinct yet: wait for more motion (the samples stay pending)
    st.offset, st.offset_sharpness, st.clock_provisional = float(search.offset_s), float(search.sharpness), False
    st.t_ref, st.searched_span, st.clock_widened = float(ti[0]), float(span), search.widened
    st.steps = find_clock_steps(t)
    st.t_seen = float(t[-1])


def search_span(grid: Grid, t: FloatArray, a: FloatArray, g: FloatArray | None) -> OffsetSearch | None:
    """The coarse offset search (:func:`~skincal.calib.timing.coarse_time_offset`) of samples stamped ``t``
    (inside the grid) on the grid's predicted motion over their span, clipped at what the joint stream
    resolves; None when a link turns too little there to align on."""
    lo, hi = np.searchsorted(grid.t, [t[0], t[-1]])
    ang = np.linalg.norm(grid.y[lo:hi, :, 12:15], axis=2)
    if ang.shape[0] < 20 or float(ang.max()) < 5 * rest.MOVING_RPS:
        return None
    profile = motion_profile(grid.t[lo:hi], ang, grid.speed[lo:hi], grid.resolved_rps)
    return coarse_time_offset(profile, t, a, g)


def kept_with(st: UnitState, t: FloatArray | None, a: FloatArray | None,
              g: FloatArray | None) -> tuple[FloatArray, FloatArray, FloatArray | None]:  # fmt: skip
    """The unit's kept raw samples followed by the new ones ``t, a, g`` (``t`` None: none): stamps, accel and
    gyro (None when some part has none)."""
    parts = [r[:3] for r in st.raw] + ([] if t is None or not len(t) else [(t, a, g)])
    T = np.concatenate([p[0] for p in parts])
    A = np.concatenate([p[1] for p in parts])
    return T, A, None if any(p[2] is None for p in parts) else np.concatenate([p[2] for p in parts])


def holds_motion(grid: Grid, t: FloatArray, end: float | None = None) -> bool | None:
    """Whether the unit recorded while the robot moved: the share of its stamps ``t`` (taken as
    joint-clock instants) that fall where a link turns (faster than ``5 rest.MOVING_RPS`` on the grid)
    is at least :data:`REST_ONLY_DENSITY` of the share of the grid's time from ``t[0]`` to ``end``
    (default ``t[-1]``) that moves. A stream recorded in the rests only (static poses) has samples in
    the moves only where its unknown clock offset pushes a rest's edge over (a few % of each move); a
    continuous stream has about the grid's own share. ``None`` when nothing tells (no stamp inside the
    grid, or the robot did not move over the span)."""
    t = t[(t >= grid.t[0]) & (t <= grid.t[-1])]
    if t.size == 0:
        return None
    lo, hi = np.searchsorted(grid.t, [t[0], t[-1] if end is None else end], side="right")
    lo = max(lo - 1, 0)
    ang = np.linalg.norm(grid.y[lo:hi, :, 12:15], axis=2).max(axis=1)
    moving = ang >= 5 * rest.MOVING_RPS
    if not moving.any():
        return None
    k = np.clip(np.searchsorted(grid.t[lo:hi], t), 0, hi - lo - 1)
    return bool(moving[k].mean() >= REST_ONLY_DENSITY * moving.mean())


def track_steps(st: UnitState, t: FloatArray) -> None:
    """Search the unit's stamps ``t`` newer than any seen for further re-sync steps."""
    if st.steps is not None:
        new = t > st.t_seen
        if new.any():
            st.steps = st.steps.extend(st.t_seen, t[new])
            st.t_seen = float(t[new][-1])


def instants(st: UnitState, t: FloatArray) -> FloatArray:
    """Joint-clock instants of the unit's stamps ``t`` under its clock mapping (:mod:`skincal.calib.timing`:
    re-sync steps removed, then offset and drift)."""
    assert st.offset is not None
    if st.steps is not None:
        t = st.steps.correct(t)
    return motion_instants(t, st.offset, st.drift, st.t_ref)


def realign(st: UnitState, tau: float, drift: float) -> None:
    """Compose the unit's clock mapping with the residual offset ``tau`` (s) and drift and absorb its kept
    raw samples again under the new mapping; the statistics of the samples no longer kept (older than the
    history) are carried over to the new mapping's unknowns (:func:`~skincal.calib.online.stats.shift_clock`)
    instead of being dropped: a re-alignment late in a long session no longer discards all but its last
    ``history_s`` of data."""
    assert st.offset is not None
    st.offset, st.drift = compose_clock(st.offset, st.drift, tau, drift)
    st.realigned += 1
    raw = list(st.raw)
    if st.steps is None and raw:  # re-sync steps seen since the alignment
        st.steps = find_clock_steps(np.concatenate([r[0] for r in raw]))
        st.t_seen = float(raw[-1][0][-1])
    restart(st, (tau, drift))


def align_on_motion(st: UnitState, grid: Grid, t: FloatArray, a: FloatArray, g: FloatArray | None,
                    o: OnlineOptions, final: bool = False) -> bool:  # fmt: skip
    """A unit whose clock is provisional (:func:`align` saw it record in the rests only) aligned on its
    kept and new samples ``t, a, g`` once they hold motion (``final``: the data's end, whatever they span);
    on success (``True``) its statistics are restarted and every kept sample (then the new ones) is absorbed
    again under the found clock."""
    if not holds_motion(grid, t):  # the new samples: still in the rests, or nothing tells
        return False
    T, A, G = kept_with(st, t, a, g)
    st.offset = None
    align(st, grid, T, A, G, o, final)
    if st.offset is None or st.clock_provisional:  # no distinct peak yet: the stamps as they are, for now
        st.offset, st.clock_provisional = 0.0, True
        return False
    restart(st)
    return True


def recheck(st: UnitState, grid: Grid, t: FloatArray | None, a: FloatArray | None, g: FloatArray | None,
            o: OnlineOptions, final: bool = False) -> bool:  # fmt: skip
    """Search an aligned unit's coarse offset again on its kept and new samples ``t, a, g`` (``t`` None: none)
    once they span :data:`RECHECK_GROWTH` times what it was last searched on, or more at the data's end
    (``final``): the first ``align_s`` of a stream can hold a distinct but wrong peak (a real 14 Hz recording:
    365 ms on its first 11 s, 108 ms on all 39 s, where ``mle`` finds 112 ms). A distinct peak further than
    :data:`RECHECK_S` from the current mapping's offset replaces the mapping (as :func:`align` sets it, no
    drift) and the statistics restart from the kept samples (``True``: they are pending again; those older
    than the history, taken under the wrong clock, are forgotten)."""
    if st.offset is None or st.clock_provisional or not st.raw:
        return False
    last = t[-1] if t is not None and len(t) else st.raw[-1][0][-1]  # kept_with's last and first stamps
    span = float(last - st.raw[0][0][0])
    if span < RECHECK_GROWTH * st.searched_span and not (final and span > 1.05 * st.searched_span):
        return False
    st.searched_span = span
    T, A, G = kept_with(st, t, a, g)
    inside = (T >= grid.t[0]) & (T <= grid.t[-1])  # searched on the stamps as align searches them
    if inside.sum() < 20:
        return False
    Ti = T[inside]
    search = search_span(grid, Ti, A[inside], None if G is None else G[inside])
    now = float(np.median(Ti - instants(st, Ti)))  # the current mapping's offset over these samples
    if search is None or search.sharpness < ALIGN_SHARPNESS or abs(search.offset_s - now) <= RECHECK_S:
        return False
    st.recheck_shift_s = float(search.offset_s) - now
    st.offset, st.drift, st.t_ref = float(search.offset_s), 0.0, float(Ti[0])
    st.offset_sharpness, st.clock_widened = float(search.sharpness), search.widened
    st.rechecked, st.realigned = st.rechecked + 1, 0  # a new coarse mapping: the fine re-alignments start over
    restart(st)
    if st.decided and st.candidates:  # decided under the wrong clock: decided again under the new one
        undecide(st)
    return True


def notes(st: UnitState) -> list[str]:
    """What the result should say about the unit's clock: a search skipped (rests only) or run again."""
    out = []
    if st.clock_provisional:
        out.append("coarse clock search skipped: the unit's samples hold no motion (static poses only), so nothing "
                   "determines the clock offset; the stamps taken as they are")  # fmt: skip
    if st.clock_widened and st.offset is not None:
        out.append(widened_note(st.offset))
    if st.rechecked:
        out.append(f"coarse clock offset searched again on a longer stream ({st.rechecked} time(s)): the first "
                   f"seconds' peak was elsewhere, the offset moved by {1e3 * st.recheck_shift_s:+.0f} ms")  # fmt: skip
    return out


def restart(st: UnitState, shift: tuple[float, float] | None = None) -> None:
    """Put the unit's kept raw samples back in front of its pending ones and take their part out of its
    statistics; the rest (samples older than the history) carried over to the clock mapping composed with
    ``shift = (tau, drift)`` (:func:`~skincal.calib.online.stats.shift_clock`), or forgotten (``None``)."""
    raw = list(st.raw)
    st.raw = deque()
    Za, Zg, moving = st.Za.copy(), st.Zg.copy(), st.moving.copy()
    for *_, chunk in raw:  # what is absorbed again below
        if chunk is not None:
            Za -= chunk[2]
            Zg -= chunk[3]
            moving -= chunk[4]
            st.ledger.add(chunk[5], -1.0)
    # Z[9, 9] sums a class's sample weights (at most 1 each; round-off left otherwise)
    frozen = shift is not None and float(Za[..., 9, 9].max()) >= 0.5
    if frozen:
        assert shift is not None
        st.Za, st.Zg = stats.shift_clock(Za, Zg, *shift)
        st.moving = np.maximum(moving, 0.0)
        st.ledger.shift(*shift)
    else:
        st.Za, st.Zg, st.moving = np.zeros_like(st.Za), np.zeros_like(st.Zg), np.zeros(len(st.links))
        st.ledger.clear()
    st.chunks = deque()
    st.solutions, st.status, st.dirty, st.split_cache = {}, None, True, None
    st.windows = {}
    st.residual_norms.clear()
    if not frozen:
        st.t_last, st.t_first = float("-inf"), float("inf")
    for t, a, g, _ in raw[::-1]:
        st.pending_t.insert(0, t)
        st.pending_a.insert(0, a)
        st.pending_g.insert(0, g)


def clock_off(st: UnitState, sol: stats.Solution) -> bool:
    """The residual clock error ``tau + d (s - t_ref)`` at either end of the unit's data exceeds
    :data:`REALIGN_S` and is determined (its std below a quarter of it)."""
    i = [stats.TAU, stats.DRIFT]
    C = sol.cov[np.ix_(i, i)]
    for s in (st.t_first, st.t_last):
        e = np.array([1.0, s - st.t_ref])
        T = sol.tau + sol.drift * e[1]
        if abs(T) > REALIGN_S and np.sqrt(max(float(e @ C @ e), 0.0)) < 0.25 * abs(T):
            return True
    return False
