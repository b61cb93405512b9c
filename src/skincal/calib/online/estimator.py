"""The streaming calibrator: samples in, each unit's pose, std and "what is missing" out at any moment.

Flow (all instants on the joint clock, s; the unit's stamps are mapped by its coarse offset)::

    add_joint_states / add_imu      any order, never blocking (buffers)
        │
    update():
      1. joint blocks: when the joint stream reaches T1 + margin + max_delay, the block [T0, T1) is
         conditioned exactly as the batch calibrator conditions a whole stream
         (:class:`~skincal.calib.preprocess.JointInterpolator` over [T0 - margin, T1 + margin]) and
         the link signals ``u, K, w`` (and ``du/ds``, ``dw/ds``) of EVERY link are evaluated on a
         uniform grid (``grid_hz``) once for all units; the grid is kept for ``history_s``;
      2. per unit: once its stream spans ``align_s`` of motion, its coarse time offset is found by
         cross-correlation (:func:`~skincal.calib.timing.coarse_time_offset`, as ``mle`` does), then
         each sample whose instant is on the grid adds its rows to the Gram matrices of every
         candidate link (:mod:`skincal.calib.online.stats`: a fixed-size sufficient statistic, so
         the cost per sample is constant and no sample is kept);
    status(): per unit, the pose solved from the Grams of each candidate link; the link whose model
      explains the data best wins once the others are worse by a clear chi-square margin; std from
      the normal matrix inflated by the residuals' autocorrelation; what is missing and which joint
      to move (largest D-optimal gain of a short excitation of that joint at the current posture).

A unit decided on its link keeps only that link's statistics (the others' are dropped). Samples
that arrive after their part of the grid left the history are counted as ``late`` and dropped.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from skincal.calib import rest
from skincal.calib.online import stats
from skincal.calib.preprocess import JointInterpolator
from skincal.calib.rest import link_moving
from skincal.calib.signals import frame_signals, hermite
from skincal.calib.timing import (
    ClockSteps,
    coarse_time_offset,
    compose_clock,
    find_clock_steps,
    motion_instants,
    motion_profile,
)
from skincal.data.dataset import Dataset, JointStates
from skincal.data.imu_calibration import ImuCalibration
from skincal.data.result import CalibrationResult, UnitResult, with_events
from skincal.errors import ConfigError
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.transforms import FloatArray
from skincal.names import name_problem
from skincal.skin.pose import SkinUnitPose

REST, MOVING = 0, 1
"""Rest and moving samples are two classes with their own noise level (a resting unit's residual is its sensor
noise; a moving one's adds the errors of the joint-derived accelerations), so the Grams are kept per class
(:func:`~skincal.calib.rest.link_moving`)."""
ALIGN_SHARPNESS = 0.1
"""A unit's clock is aligned once the cross-correlation peak stands out by this much (correlation units)...
"""
ALIGN_WAIT_FRACTION = 0.8
"""...or once its pending stream spans this fraction of the history (then with a warning in the result)."""
REALIGN_S = 0.004
"""A decided unit whose residual clock error (offset and drift, at either end of its data) exceeds this (s)
is re-aligned (its clock mapping composed with the residual, :func:`~skincal.calib.timing.compose_clock`)
and its statistics restarted: the first-order clock model holds for a few ms only."""
ALIGN_RETRY_S = 2.0
"""A unit not yet aligned tries again after this much more of its stream, s."""
MAX_REALIGN = 6
"""Re-alignments allowed per unit."""
DRIFT_UNDETERMINED_PPM = 100.0
"""A residual clock drift whose std exceeds this (ppm) is not determined yet: the result says so."""
DRIFT_NOTE_SIGMAS, DRIFT_NOTE_PPM = 4.0, 20.0
"""A drift beyond this many std and ppm is named in the result (``mle``'s rule)."""
SCALE_STD_LIMIT = 0.01
"""The accelerometer's scale/misalignment is estimated only when each of its 9 elements is determined to
this std (else held at the identity: a weakly determined scale absorbs what the pose should explain)."""
JOINT_ACTIVE_RPS = 0.1
JOINT_ACTIVE_MIN_S = 1.0
"""A joint counts as moved once it has turned faster than ``JOINT_ACTIVE_RPS`` (rad/s) for
``JOINT_ACTIVE_MIN_S`` (s) in all; two candidate links are told apart only after a joint between them moved."""
MIN_MOVING = 200
"""Moving samples of the best link before its link is decided."""
SATURATION_FLOOR = (1.5 * 9.80665, 2.0)
"""A recurring largest reading is taken as the sensor's range only from 1.5 g (m/s^2) and 2 rad/s up:
no accelerometer used on skin saturates below 2 g, nor a gyroscope below 250 deg/s."""
LINK_CHI2_MARGIN = 25.0
"""Two links are told apart when their costs (chi-square, correlation-inflated) differ by this much...
"""
LINK_RELATIVE_MARGIN = 0.05
"""...and by this fraction of the best one's (the joint-derived model errors are not white noise: a
few % of cost between two links is not evidence). A decision is final: the other links' statistics are
then dropped, so it waits for clear evidence."""
CORRELATION_MAX = 100.0
WINDOW_SAMPLES = 100
"""Samples per window of the correlation inflation (1 s at 100 Hz)."""
MIN_WINDOWS = 5
"""Windows before the inflation is applied."""
"""Largest variance inflation applied for autocorrelated residuals."""
GATE_SIGMAS = 6.0
"""Once a unit's link is decided, samples whose residual exceeds this many std are not absorbed."""
UNDETERMINED_M = 0.05
UNDETERMINED_DEG = 20.0
"""Std beyond these (m, deg) counts as undetermined."""


@dataclass(frozen=True)
class OnlineOptions:
    """Parameters of :class:`OnlineCalibrator` (SI units).

    Attributes:
        block_s: the joint stream is conditioned and absorbed in blocks of this length, s.
        margin_s: joint data each side of a block used to condition it (edge effects of the
            acceleration filter), s.
        lookback_s: joint data before a block used to condition it: the conditioning's decisions (stamps
            back on their grid, accelerations from positions or velocities, the noise levels) are made
            on this much of the stream, not on one short block, so that they do not change from block
            to block, s.
        max_delay_s: joint states may arrive out of order up to this late; a block is processed
            when the joint stream has reached its end plus ``margin_s + max_delay_s``.
        grid_hz: rate of the link-signal grid the units' samples are interpolated on, Hz.
        history_s: how long the grid (and each unit's per-chunk statistics, for :meth:`restart_unit`)
            is kept, s.
        align_s: span of a unit's stream (with motion) before its time offset is estimated, s.
        target_position_m, target_rotation_deg: std a unit must reach on every axis.
        links: candidate links (None: all of the chain's).
        accel_sigma, gyro_sigma: starting noise levels (m/s^2, rad/s); the fits' residual std take over.
        solve_every_s: each unit's estimate is refreshed during :meth:`update` after this much new data, s
            (its link decision, outlier gate and residual statistics follow it).
    """

    block_s: float = 1.0
    margin_s: float = 0.5
    lookback_s: float = 10.0
    max_delay_s: float = 0.5
    grid_hz: float = 125.0
    history_s: float = 60.0
    align_s: float = 10.0
    target_position_m: float = 3e-4
    target_rotation_deg: float = 0.05
    links: tuple[int, ...] | None = None
    accel_sigma: float = 0.05
    gyro_sigma: float = 0.005
    solve_every_s: float = 2.0

    def __post_init__(self) -> None:
        for name in ("block_s", "grid_hz", "history_s", "align_s", "target_position_m", "target_rotation_deg"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ConfigError(f"online calibrator: {name} must be a positive number, got {v}")
        for name in ("margin_s", "max_delay_s", "lookback_s"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ConfigError(f"online calibrator: {name} must be a non-negative number, got {v}")
        if self.history_s < 2 * self.align_s:
            raise ConfigError("online calibrator: history_s must be at least twice align_s")


@dataclass(frozen=True)
class UnitStatus:
    """What the stream says about one unit now (see :class:`OnlineCalibrator`).

    Attributes:
        unit: name; link: the best link so far (None: undecided or no data); link_margin: cost of
            the second-best link over the best's (inf: no rival left, nan: nothing fitted).
        pose: the estimate (None: none yet); position_std_m ``(3,)`` m, rotation_std_deg ``(3,)``
            deg (link axes; inf: undetermined).
        samples, moving_samples: samples absorbed (on the best link), those while its link moved.
        missing: '' when the pose is determined, else why not.
        best_joint: 0-based joint whose excitation would help most (None: nothing to gain).
        reached: std within the target on every axis; t_last: newest absorbed instant, s.
        aligned: the unit's time offset is known (its samples are being absorbed).
    """

    unit: str
    link: int | None
    link_margin: float
    pose: SkinUnitPose | None
    position_std_m: FloatArray
    rotation_std_deg: FloatArray
    samples: int
    moving_samples: int
    missing: str
    best_joint: int | None
    reached: bool
    t_last: float
    aligned: bool


@dataclass(frozen=True)
class _Grid:
    """The link signals of every link on the streaming calibrator's uniform grid.

    Attributes:
        t: ``(G,)`` grid instants on the joint clock, s.
        y: ``(G, n, 18)`` per link ``[u (3), K (9, row-major), w (3), u_g (3)]``
            (:func:`~skincal.calib.signals.frame_signals`, link frame).
        dy: ``(G, n, 18)`` their time derivatives (per block: only ``dw`` ``(G, n, 3)``, exact).
        ok: ``(G,)`` the joint accelerations are reliable there.
        speed: ``(G, n)`` ``sum_{j <= k} |qd_j|``, rad/s (the clock search without a gyroscope).
    """

    t: FloatArray
    y: FloatArray
    dy: FloatArray
    ok: np.ndarray
    speed: FloatArray


@dataclass
class _Unit:
    links: list[int]
    Za: FloatArray  # (L, 2, NA, NA): per candidate link, rest and moving samples
    Zg: FloatArray  # (L, 2, NG, NG)
    moving: FloatArray  # (L,) moving samples per candidate link
    pending_t: list[FloatArray] = field(default_factory=list)
    pending_a: list[FloatArray] = field(default_factory=list)
    pending_g: list[FloatArray | None] = field(default_factory=list)
    offset: float | None = None
    offset_sharpness: float = float("nan")
    has_gyro: bool | None = None
    chunks: deque = field(default_factory=deque)  # (t_min, t_max, Za, Zg, moving) per absorb call
    t_last: float = float("-inf")
    t_first: float = float("inf")
    dirty: bool = True
    solutions: dict[int, stats.Solution] = field(default_factory=dict)
    # link (0: the common weights of undecided candidates) -> [accel rest, accel moving, gyro rest, gyro moving]
    sigmas: dict[int, FloatArray] = field(default_factory=dict)
    decided: bool = False
    win_sum: FloatArray = field(default_factory=lambda: np.zeros(3))  # normalised residuals of the open window
    win_n: int = 0
    win_stat: float = 0.0  # sum over closed windows of n |mean|^2 (3 per window for white residuals)
    win_count: int = 0
    outliers: int = 0
    status: UnitStatus | None = None
    best_joint_t: float = float("-inf")
    best_joint: int | None = None
    peak: FloatArray = field(default_factory=lambda: np.zeros(2))  # largest |reading| seen: accel, gyro
    peak_count: FloatArray = field(default_factory=lambda: np.zeros(2))  # how often exactly that value came
    saturated: int = 0
    t_solved: float = float("-inf")
    align_tried: float = float("-inf")
    raw: deque = field(default_factory=deque)  # absorbed (stamps, accel, gyro) within the history, for _realign
    realigned: int = 0
    scale_estimated: bool = False
    # the clock mapping s = t' - offset - drift (t' - t_ref), t' the stamps less their re-sync steps
    drift: float = 0.0
    t_ref: float = 0.0
    steps: ClockSteps | None = None
    t_seen: float = float("-inf")  # newest stamp searched for re-sync steps


class OnlineCalibrator:
    """Streaming calibration of skin units on ``chain`` (module docstring).

    ``units``: names of the units to follow (others are refused). ``gravity``: ``(3,)`` base frame,
    m/s^2. ``on_residuals(unit, t, r)`` (set by a change monitor): called per absorbed chunk of a
    unit whose estimate has settled (:func:`_settled`: decided, std within 1 mm / 0.2 deg), with the
    chunk's instants ``(M,)`` and accelerometer residuals ``(M, 3)`` divided by the unit's residual
    std (of its class: resting or moving), at the current estimate.
    """

    def __init__(
        self,
        chain: SerialChain,
        units: Sequence[str],
        gravity: ArrayLike = (0.0, 0.0, -9.81),
        options: OnlineOptions | None = None,
    ) -> None:
        self.chain = chain
        self.options = options if options is not None else OnlineOptions()
        n = chain.n_joints
        links = tuple(range(1, n + 1)) if self.options.links is None else tuple(int(x) for x in self.options.links)
        if not links or any(not 1 <= link <= n for link in links):
            raise ConfigError(f"online calibrator: candidate links must lie in 1..{n}, got {links}")
        self.links = links
        names = tuple(str(u) for u in units)
        for u in names:
            problem = name_problem(u)
            if problem:
                raise ConfigError(f"online calibrator: unit name {problem}")
        if len(set(names)) != len(names):
            raise ConfigError("online calibrator: unit names repeat")
        self.units = names
        self.gravity = np.asarray(gravity, dtype=float).reshape(3)
        L = len(links)
        self._u = {
            u: _Unit(
                list(links), np.zeros((L, 2, stats.NA, stats.NA)), np.zeros((L, 2, stats.NG, stats.NG)), np.zeros(L)
            )
            for u in names
        }
        self._jt: list[FloatArray] = []
        self._jq: list[FloatArray] = []
        self._jqd: list[FloatArray | None] = []
        self._joints: tuple[FloatArray, FloatArray, FloatArray] | None = None
        self._frontier: float | None = None  # end of the processed joint blocks
        self._grid: list[_Grid] = []  # per block, every link
        self._grid_cat: _Grid | None = None
        self.q_now: FloatArray | None = None
        self.late = 0
        self.joint_active_s = np.zeros(chain.n_joints)
        """Seconds each joint has turned faster than :data:`JOINT_ACTIVE_RPS` so far."""
        self.on_residuals: Callable[[str, FloatArray, FloatArray], None] | None = None
        self.events: list[dict] = []
        self._t_start = time.perf_counter()
        self.cpu_s = 0.0

    # ---------------------------------------------------------------- input
    def add_joint_states(self, t_in: ArrayLike, q_in: ArrayLike, qd_in: ArrayLike | None = None) -> None:
        """Joint states ``t`` ``(N,)`` s, ``q`` ``(N, n)`` rad, ``qd`` ``(N, n)`` rad/s (None: from ``q``)."""
        n = self.chain.n_joints
        t = np.atleast_1d(np.asarray(t_in, dtype=float))
        q = np.asarray(q_in, dtype=float)
        if t.ndim != 1 or q.shape != (t.size, n):
            raise ConfigError(
                f"online calibrator: joint states need t (N,) and q (N, {n}) for the robot's {n} joints, "
                f"got {t.shape} and {q.shape}"
            )
        ok = np.isfinite(t) & np.all(np.isfinite(q), axis=1)
        qd_a = None if qd_in is None else np.asarray(qd_in, dtype=float)
        if qd_a is not None and qd_a.shape != q.shape:
            raise ConfigError(f"online calibrator: qd must have the shape of q {q.shape}, got {qd_a.shape}")
        if qd_a is not None:
            ok &= np.all(np.isfinite(qd_a), axis=1)
        if not ok.all():
            t, q, qd_a = t[ok], q[ok], None if qd_a is None else qd_a[ok]
        if t.size:
            self._jt.append(t)
            self._jq.append(q)
            self._jqd.append(qd_a)
            self.q_now = q[np.argmax(t)].copy()

    def add_imu(self, unit: str, t_in: ArrayLike, accel: ArrayLike, gyro: ArrayLike | None = None) -> None:
        """IMU samples of ``unit``: stamps ``(M,)`` s, ``accel`` ``(M, 3)`` m/s^2, ``gyro`` ``(M, 3)`` rad/s."""
        st = self._u.get(unit)
        if st is None:
            raise ConfigError(f"online calibrator: unknown unit {unit!r}")
        t = np.atleast_1d(np.asarray(t_in, dtype=float))
        a = np.asarray(accel, dtype=float)
        g = None if gyro is None else np.asarray(gyro, dtype=float)
        if t.ndim != 1 or a.shape != (t.size, 3) or (g is not None and g.shape != (t.size, 3)):
            raise ConfigError(
                f"online calibrator: unit {unit!r} needs t (M,), accel and gyro (M, 3), got {t.shape}, {a.shape}"
                + ("" if g is None else f", {g.shape}")
            )
        if st.has_gyro is None:
            st.has_gyro = g is not None
        if not st.has_gyro:
            g = None
        elif g is None:
            raise ConfigError(f"online calibrator: unit {unit!r} sent samples without its gyroscope")
        ok = np.isfinite(t) & np.all(np.isfinite(a), axis=1)
        if g is not None:
            ok &= np.all(np.isfinite(g), axis=1)
        if t.size and ok.any():
            st.pending_t.append(t[ok])
            st.pending_a.append(a[ok])
            st.pending_g.append(None if g is None else g[ok])

    # ---------------------------------------------------------------- processing
    def update(self) -> int:
        """Absorb every complete block; returns the number of IMU samples absorbed."""
        c0 = time.process_time()
        self._blocks(final=False)
        n = 0
        for u in self.units:
            got = self._absorb_unit(u)
            n += got
            st = self._u[u]
            if got and st.t_last - st.t_solved >= self.options.solve_every_s:
                self._status(u, advise=False)  # keeps the link decision, the gate and the residual statistics current
                st.t_solved = st.t_last
        self.cpu_s += time.process_time() - c0
        return n

    def finish(self) -> None:
        """End of data: process the joint stream to its end and absorb what can be."""
        c0 = time.process_time()
        self._blocks(final=True)
        for u in self.units:
            self._absorb_unit(u, final=True)
        self.cpu_s += time.process_time() - c0

    def _joint_arrays(self) -> tuple[FloatArray, FloatArray, FloatArray] | None:
        if self._jt:
            parts_t = ([self._joints[0]] if self._joints is not None else []) + self._jt
            parts_q = ([self._joints[1]] if self._joints is not None else []) + self._jq
            qd_new = [
                np.gradient(q, t, axis=0) if qd is None and t.size > 1 else (np.zeros_like(q) if qd is None else qd)
                for t, q, qd in zip(self._jt, self._jq, self._jqd, strict=True)
            ]
            parts_qd = ([self._joints[2]] if self._joints is not None else []) + qd_new
            t = np.concatenate(parts_t)
            order = np.argsort(t, kind="stable")
            t = t[order]
            keep = np.r_[True, np.diff(t) > 0]
            self._joints = (t[keep], np.concatenate(parts_q)[order][keep], np.concatenate(parts_qd)[order][keep])
            self._jt, self._jq, self._jqd = [], [], []
        return self._joints

    def _blocks(self, final: bool) -> None:
        o = self.options
        joints = self._joint_arrays()
        if joints is None or joints[0].size < 8:
            return
        t, q, qd = joints
        if self._frontier is None:
            self._frontier = float(t[0]) + o.margin_s
        newest = float(t[-1])
        while True:
            T0 = self._frontier
            T1 = T0 + o.block_s
            if newest < T1 + o.margin_s + o.max_delay_s:
                if not final or newest - o.margin_s <= T0 + 1e-9:
                    break
                T1 = newest - o.margin_s
            self._condition_block(t, q, qd, T0, T1)
            self._frontier = T1
        # forget joint states no later block needs
        keep = t >= self._frontier - max(o.margin_s, o.lookback_s) - 1e-9
        if not keep.all():
            self._joints = (t[keep], q[keep], qd[keep])
        horizon = self._frontier - o.history_s
        while self._grid and self._grid[0].t[-1] < horizon:
            self._grid.pop(0)
            self._grid_cat = None

    def _condition_block(self, t: FloatArray, q: FloatArray, qd: FloatArray, T0: float, T1: float) -> None:
        o = self.options
        sel = (t >= T0 - max(o.margin_s, o.lookback_s) - 1e-9) & (t <= T1 + o.margin_s + 1e-9)
        if sel.sum() < 8:
            return
        interp = JointInterpolator(JointStates(t=t[sel], q=q[sel], qd=qd[sel]))
        dt = 1.0 / o.grid_hz
        k0 = int(np.ceil((T0 - 1e-12) / dt))
        k1 = int(np.ceil((T1 - 1e-12) / dt))
        tg = dt * np.arange(k0, k1)
        tg = tg[(tg >= interp.t_start) & (tg <= interp.t_end)]
        if tg.size < 2:
            return
        qg, qdg, qddg = interp(tg)
        u, K, w, dw, ug = frame_signals(self.chain.link_motion(qg, qdg, qddg), self.gravity)  # (G, n, ...) links 1..n
        y = np.concatenate([u, K.reshape(*K.shape[:2], 9), w, ug], axis=2)
        self.joint_active_s += (np.abs(qdg) > JOINT_ACTIVE_RPS).sum(axis=0) * dt
        self._grid.append(_Grid(tg, y, dw, interp.reliable(tg), np.cumsum(np.abs(qdg), axis=1)))
        self._grid_cat = None

    def _grid_arrays(self) -> _Grid | None:
        """The kept grid blocks as one :class:`_Grid` whose ``dy`` holds the time derivatives of the
        table (central differences along the whole grid, continuous across blocks; ``w``'s exact)."""
        if not self._grid:
            return None
        if self._grid_cat is None:
            tg = np.concatenate([b.t for b in self._grid])
            y = np.concatenate([b.y for b in self._grid])
            dy = np.gradient(y, tg, axis=0) if tg.size > 1 else np.zeros_like(y)
            dy[..., 12:15] = np.concatenate([b.dy for b in self._grid])  # dw/ds from the kinematics
            self._grid_cat = _Grid(
                tg, y, dy, np.concatenate([b.ok for b in self._grid]), np.concatenate([b.speed for b in self._grid])
            )
        return self._grid_cat

    def _take_pending(self, st: _Unit) -> tuple[FloatArray, FloatArray, FloatArray | None]:
        t = np.concatenate(st.pending_t) if st.pending_t else np.zeros(0)
        a = np.concatenate(st.pending_a) if st.pending_a else np.zeros((0, 3))
        g = np.concatenate(st.pending_g) if st.has_gyro and st.pending_g else None  # type: ignore[arg-type]
        order = np.argsort(t, kind="stable")
        return t[order], a[order], None if g is None else g[order]

    def _align(self, name: str, st: _Unit, grid: _Grid, t: FloatArray, a: FloatArray,
               g: FloatArray | None) -> None:  # fmt: skip
        tg, w, speed = grid.t, grid.y[..., 12:15], grid.speed
        o = self.options
        inside = (t >= tg[0]) & (t <= tg[-1])
        if inside.sum() < 20 or t[inside][-1] - t[inside][0] < o.align_s:
            return
        lo, hi = np.searchsorted(tg, [t[inside][0], t[inside][-1]])
        ang = np.linalg.norm(w[lo:hi], axis=2)
        if ang.shape[0] < 20 or float(ang.max()) < 5 * rest.MOVING_RPS:
            return  # no motion to align on yet
        profile = motion_profile(tg[lo:hi], ang, speed[lo:hi])
        search = coarse_time_offset(profile, t[inside], a[inside], None if g is None else g[inside])
        span = t[inside][-1] - t[inside][0]
        if search.sharpness < ALIGN_SHARPNESS and span < ALIGN_WAIT_FRACTION * o.history_s:
            return  # the peak is not distinct yet: wait for more motion (the samples stay pending)
        st.offset, st.offset_sharpness = float(search.offset_s), float(search.sharpness)
        st.t_ref = float(t[inside][0])
        st.steps = find_clock_steps(t)
        st.t_seen = float(t[-1])

    def _absorb_unit(self, name: str, final: bool = False) -> int:
        st = self._u[name]
        grid = self._grid_arrays()
        if grid is None or not st.pending_t:
            return 0
        t, a, g = self._take_pending(st)
        st.pending_t, st.pending_a, st.pending_g = [], [], []
        if st.offset is None:
            if final or t[-1] - st.align_tried >= ALIGN_RETRY_S:
                st.align_tried = float(t[-1])
                self._align(name, st, grid, t, a, g)
            if st.offset is None:
                if final:
                    st.offset, st.offset_sharpness = 0.0, 0.0  # no motion to align on: the stamps as they are
                else:
                    self._keep(st, t, a, g)
                    return 0
        assert st.offset is not None
        self._track_steps(st, t)
        s = self._instants(st, t)
        tg = grid.t
        late = s < tg[0]
        self.late += int(late.sum())
        ready = (s >= tg[0]) & (s <= tg[-1])
        if not final:
            self._keep(st, t[~ready & ~late], a[~ready & ~late], None if g is None else g[~ready & ~late])
        if not ready.any():
            return 0
        st.raw.append((t[ready], a[ready], None if g is None else g[ready]))
        while st.raw and self._instants(st, st.raw[0][0][-1:])[0] < tg[0]:
            st.raw.popleft()  # its part of the grid is gone: it could not be absorbed again
        return self._absorb(name, st, grid, s[ready], a[ready], None if g is None else g[ready])

    @staticmethod
    def _track_steps(st: _Unit, t: FloatArray) -> None:
        """Search the unit's stamps ``t`` newer than any seen for further re-sync steps."""
        if st.steps is not None:
            new = t > st.t_seen
            if new.any():
                st.steps = st.steps.extend(st.t_seen, t[new])
                st.t_seen = float(t[new][-1])

    @staticmethod
    def _instants(st: _Unit, t: FloatArray) -> FloatArray:
        """Joint-clock instants of the unit's stamps ``t`` under its clock mapping (:mod:`skincal.calib.timing`:
        re-sync steps removed, then offset and drift)."""
        assert st.offset is not None
        if st.steps is not None:
            t = st.steps.correct(t)
        return motion_instants(t, st.offset, st.drift, st.t_ref)

    def _realign(self, st: _Unit, tau: float, drift: float) -> None:
        """Compose the unit's clock mapping with the residual offset ``tau`` (s) and drift and absorb its kept
        raw samples again from scratch."""
        assert st.offset is not None
        st.offset, st.drift = compose_clock(st.offset, st.drift, tau, drift)
        st.realigned += 1
        raw = list(st.raw)
        if st.steps is None and raw:  # re-sync steps seen since the alignment
            st.steps = find_clock_steps(np.concatenate([r[0] for r in raw]))
            st.t_seen = float(raw[-1][0][-1])
        st.raw = deque()
        L = len(st.links)
        st.Za, st.Zg, st.moving = np.zeros_like(st.Za), np.zeros_like(st.Zg), np.zeros(L)
        st.chunks = deque()
        st.solutions, st.status, st.dirty = {}, None, True
        st.win_sum, st.win_n, st.win_stat, st.win_count = np.zeros(3), 0, 0.0, 0
        st.t_last, st.t_first = float("-inf"), float("inf")
        for t, a, g in raw[::-1]:
            st.pending_t.insert(0, t)
            st.pending_a.insert(0, a)
            st.pending_g.insert(0, g)

    @staticmethod
    def _keep(st: _Unit, t: FloatArray, a: FloatArray, g: FloatArray | None) -> None:
        if t.size:
            st.pending_t.append(t)
            st.pending_a.append(a)
            st.pending_g.append(g)

    @staticmethod
    def _signals_at(grid: _Grid, s: FloatArray, links: Sequence[int]):
        """Link signals of ``links`` at instants ``s`` (M,) from the grid, as ``mle``'s signal table does
        (:func:`~skincal.calib.signals.hermite`: cubic Hermite for the values with their derivatives,
        linear for the derivatives). Returns u, K, w, dw_dt, du_dt, dK_dt, u_g (each ``(L, M, ...)``)
        and ok ``(M,)``."""
        y, dy, i = hermite(grid.t, grid.y, grid.dy, s, np.asarray(links) - 1)  # (M, L, 18)
        y, dy = np.moveaxis(y, 1, 0), np.moveaxis(dy, 1, 0)
        L, M = y.shape[:2]
        sig = (
            y[..., :3], y[..., 3:12].reshape(L, M, 3, 3), y[..., 12:15], dy[..., 12:15],
            dy[..., :3], dy[..., 3:12].reshape(L, M, 3, 3), y[..., 15:18],
        )  # fmt: skip
        return (*sig, grid.ok[i] & grid.ok[i + 1])

    @staticmethod
    def _unsaturated(st: _Unit, a: FloatArray, g: FloatArray | None) -> np.ndarray:
        """``(M,)`` samples below the sensors' saturation: a largest reading that recurs exactly (a
        clipped register) is taken as the range, and every sample reaching it on any axis is dropped."""
        keep = np.ones(a.shape[0], dtype=bool)
        for i, x in enumerate((a, g)):
            if x is None or x.size == 0:
                continue
            if np.abs(x).max() < SATURATION_FLOOR[i] and st.peak_count[i] < 2:
                continue  # a quantised reading at rest repeats its largest value too: not a range
            m = np.abs(x)
            top = float(m.max())
            if top > st.peak[i]:
                st.peak[i], st.peak_count[i] = top, float((m == top).sum())
            else:
                st.peak_count[i] += float((m == st.peak[i]).sum())
            if st.peak_count[i] >= 2 and st.peak[i] >= SATURATION_FLOOR[i]:
                keep &= np.all(m < st.peak[i], axis=1)
        st.saturated += int((~keep).sum())
        return keep

    def _absorb(self, name: str, st: _Unit, grid: _Grid, s: FloatArray, a: FloatArray,
                g: FloatArray | None) -> int:  # fmt: skip
        unsat = self._unsaturated(st, a, g)
        if not unsat.all():
            s, a, g = s[unsat], a[unsat], None if g is None else g[unsat]
        u, K, w, dw, du, dK, ug, ok = self._signals_at(grid, s, st.links)
        if not ok.all():
            s, a, u, K, w, dw, du, dK = s[ok], a[ok], u[:, ok], K[:, ok], w[:, ok], dw[:, ok], du[:, ok], dK[:, ok]
            ug = ug[:, ok]
            g = None if g is None else g[ok]
        if s.size == 0:
            return 0
        moving = link_moving(w, dw)  # (L, M)
        sol = st.solutions.get(st.links[0]) if st.decided else None
        if sol is not None:
            r = self._residuals(sol, a, u[0], K[0], du[0], dK[0], ug[0], s - st.t_ref)
            sig = st.sigmas[st.links[0]]
            rn = r / np.maximum(np.where(moving[0], sig[1], sig[0]), 1e-9)[:, None]
            settled = st.status is not None and _settled(st.status)
            keep = np.linalg.norm(rn, axis=1) <= GATE_SIGMAS * np.sqrt(3.0) if settled else np.ones(s.size, bool)
            if self.on_residuals is not None and settled:
                self.on_residuals(name, s, rn)
            st.outliers += int((~keep).sum())
            if not keep.all():
                s, a, u, K, w, dw = s[keep], a[keep], u[:, keep], K[:, keep], w[:, keep], dw[:, keep]
                du, dK, ug = du[:, keep], dK[:, keep], ug[:, keep]
                g, moving = None if g is None else g[keep], moving[:, keep]
                rn = rn[keep]
            self._window_means(st, rn)
        if s.size == 0:
            return 0
        L, M = u.shape[0], s.size
        cls = np.stack([~moving, moving], axis=1)[..., None, None]  # (L, 2, M, 1, 1)
        elapsed = s - st.t_ref
        rows_a = stats.accel_rows(np.broadcast_to(a, (L, M, 3)), u, K, du, dK, ug, elapsed)[:, None] * cls
        Za = stats.gram(rows_a)
        if g is not None:
            Zg = stats.gram(stats.gyro_rows(np.broadcast_to(g, (L, M, 3)), w, dw, elapsed)[:, None] * cls)
        else:
            Zg = np.zeros_like(st.Zg)
        n_moving = moving.sum(axis=1).astype(float)
        st.Za += Za
        st.Zg += Zg
        st.moving += n_moving
        st.chunks.append((float(s[0]), float(s[-1]), Za, Zg, n_moving))
        horizon = s[-1] - self.options.history_s
        while st.chunks and st.chunks[0][1] < horizon:
            st.chunks.popleft()
        st.t_last = max(st.t_last, float(s[-1]))
        st.t_first = min(st.t_first, float(s[0]))
        st.dirty = True
        return int(M)

    @staticmethod
    def _residuals(
        sol: stats.Solution,
        a: FloatArray,
        u: FloatArray,
        K: FloatArray,
        du: FloatArray,
        dK: FloatArray,
        ug: FloatArray,
        elapsed: FloatArray,
    ) -> FloatArray:
        """``(M, 3)`` residuals of equation (1) of :mod:`~skincal.calib.online.stats` at ``sol``, m/s^2
        (``elapsed`` ``(M,)`` = ``s - t_ref``, s)."""
        G = sol.R @ np.linalg.inv(sol.A)
        h = G @ sol.b
        T = (sol.tau + sol.drift * elapsed)[:, None]  # residual clock error per sample, s
        Kp = np.einsum("mij,j->mi", (1.0 + sol.gravity_scale) * K, sol.p) + T * np.einsum("mij,j->mi", dK, sol.p)
        return a @ G.T - h - Kp - du * T - sol.gravity_scale * (u - ug) - u

    # ---------------------------------------------------------------- estimates
    @staticmethod
    def _window_means(st: _Unit, rn: FloatArray) -> None:
        """Add normalised residuals ``rn`` ``(M, 3)`` to the unit's windows of :data:`WINDOW_SAMPLES`."""
        i = 0
        while i < rn.shape[0]:
            take = min(WINDOW_SAMPLES - st.win_n, rn.shape[0] - i)
            st.win_sum += rn[i : i + take].sum(axis=0)
            st.win_n += take
            i += take
            if st.win_n >= WINDOW_SAMPLES:
                st.win_stat += float(st.win_sum @ st.win_sum) / st.win_n
                st.win_count += 1
                st.win_sum, st.win_n = np.zeros(3), 0

    def _inflation(self, st: _Unit) -> float:
        """Variance inflation for correlated residuals: the variance of the residuals' means over windows
        of :data:`WINDOW_SAMPLES` consecutive samples against white noise's (``n |mean|^2`` averages 3
        for white residuals of unit variance). It covers every correlation shorter than a window, incl.
        the slow errors of joint-derived accelerations, which a lag-1 autocorrelation misses."""
        if st.win_count < MIN_WINDOWS:
            return 1.0
        return float(np.clip(st.win_stat / (3.0 * st.win_count), 1.0, CORRELATION_MAX))

    def _weighted(self, st: _Unit, k: int, sig: FloatArray) -> tuple[FloatArray, FloatArray | None]:
        """Candidate ``k``'s Grams with each class weighted by its noise level (so ``solve`` runs with 1, 1),
        corrected for the readings' own noise.

        The readings are regressors of ``G`` (``R``): their white noise adds ``n sigma^2`` to each
        diagonal element of the ``vec(G)`` block of a class's Gram (``sum a a^T = sum f f^T + n
        sigma^2 I``), which biases ``G`` toward zero along axes with little signal (errors in
        variables: a unit axis that never sees gravity at rest would read a scale several % too
        large). The rest class's residual std is the sensor noise (nothing else is left at rest), so
        ``n sigma_rest^2`` is removed from that block of both classes (bias-corrected least squares),
        once the unit's link is decided (a wrong candidate's rest residual is not the sensor's noise).
        """

        def corrected(Z: FloatArray, noise: float) -> FloatArray:
            Z = Z.copy()
            d = np.arange(9)
            Z[d, d] -= min(Z[9, 9] * noise**2, 0.5 * float(np.min(Z[d, d])))  # Z[9, 9]: the class's samples
            return Z

        if not st.decided:  # a wrong candidate's rest residual is not the sensor noise: no correction yet
            Za = st.Za[k, REST] / sig[0] ** 2 + st.Za[k, MOVING] / sig[1] ** 2
            Zg = st.Zg[k, REST] / sig[2] ** 2 + st.Zg[k, MOVING] / sig[3] ** 2 if st.has_gyro else None
            return Za, Zg
        Za = corrected(st.Za[k, REST], sig[0]) / sig[0] ** 2 + corrected(st.Za[k, MOVING], sig[0]) / sig[1] ** 2
        Zg = None
        if st.has_gyro:
            Zg = corrected(st.Zg[k, REST], sig[2]) / sig[2] ** 2 + corrected(st.Zg[k, MOVING], sig[2]) / sig[3] ** 2
        return Za, Zg

    def _class_sigmas(self, st: _Unit, k: int, sol: stats.Solution, prior: FloatArray) -> FloatArray:
        """Residual std per class ``[accel rest, accel moving, gyro rest, gyro moving]`` at ``sol``
        (a class with too few samples keeps ``prior``'s value)."""
        out = prior.copy()
        for c in (REST, MOVING):
            n = st.Za[k, c, 9, 9]
            if n >= 20:
                out[c] = max(
                    np.sqrt(
                        stats.residual_sum(st.Za[k, c], sol.x_a)
                        / max(3 * n - 16.0 * n / max(st.Za[k, :, 9, 9].sum(), 1), 1.0)
                    ),
                    1e-5,
                )
            ng = st.Zg[k, c, 9, 9]
            if st.has_gyro and ng >= 20:
                out[2 + c] = max(
                    np.sqrt(
                        stats.residual_sum(st.Zg[k, c], sol.x_g)
                        / max(3 * ng - 13.0 * ng / max(st.Zg[k, :, 9, 9].sum(), 1), 1.0)
                    ),
                    1e-6,
                )
        return out

    def _solve(self, st: _Unit) -> None:
        """Solve every candidate link. Undecided, all candidates are weighted with the same noise
        levels (those the best candidate fitted last time): a wrong link must not set its own weights,
        or it could shrink one class's noise level until it fits that class alone. Decided, the one
        link's fit sets its own levels."""
        if not st.dirty:
            return
        o = self.options
        default = np.array([o.accel_sigma, o.accel_sigma, o.gyro_sigma, o.gyro_sigma])
        common = st.sigmas.get(0, default)
        sols: dict[int, stats.Solution] = {}
        for k, link in enumerate(st.links):
            if st.Za[k, :, 9, 9].sum() < 10:
                continue
            prev = st.solutions.get(link)
            sig = st.sigmas.get(link, common) if st.decided else common
            Za, Zg = self._weighted(st, k, sig)
            sol = stats.solve(Za, Zg, 1.0, 1.0, R0=None if prev is None else prev.R)
            if sol is None:
                continue
            if st.decided:
                for _ in range(1 if prev is not None else 2):  # re-weight with the fit's own noise levels
                    sig = self._class_sigmas(st, k, sol, sig)
                    Za, Zg = self._weighted(st, k, sig)
                    sol = stats.solve(Za, Zg, 1.0, 1.0, R0=sol.R) or sol
                # like mle: the scale/misalignment is kept only where the data determine every element of it
                st.scale_estimated = bool(np.sqrt(np.clip(np.diag(sol.cov)[3:12], 0.0, None)).max() <= SCALE_STD_LIMIT)
                if not st.scale_estimated:
                    sol = stats.solve(Za, Zg, 1.0, 1.0, R0=sol.R, scale_prior=stats.SCALE_FIXED) or sol
            st.sigmas[link] = sig if st.decided else self._class_sigmas(st, k, sol, common)
            sols[link] = sol
        st.solutions = sols
        if sols and not st.decided:
            best = min(sols, key=lambda link: self._cost(st, link, common))
            st.sigmas[0] = st.sigmas[best]  # the weights of the next solve of every candidate
        st.dirty = False

    def _decide(self, st: _Unit) -> tuple[int | None, float, list[int]]:
        """Best link, its margin and the links still ambiguous with it."""
        if not st.solutions:
            return None, float("nan"), []
        if len(st.solutions) == 1:
            (link,) = st.solutions
            return link, float("inf"), [link]
        # every candidate on one chi-square scale: the noise levels they were all weighted with
        ref = st.sigmas.get(0, np.min(np.stack([st.sigmas[k] for k in st.solutions]), axis=0))
        costs = {k: self._cost(st, k, ref) for k in st.solutions}
        best_link = min(costs, key=costs.__getitem__)
        c0 = costs[best_link]
        kappa = self._inflation(st)
        others = sorted(v for k, v in costs.items() if k != best_link)
        margin = others[0] / c0 if c0 > 0 else float("inf")
        ambiguous = [k for k, v in costs.items() if v - c0 < max(LINK_CHI2_MARGIN * kappa, LINK_RELATIVE_MARGIN * c0)]
        # links joined by joints that have not moved yet are one rigid body: their costs differ only by the
        # noise of those joints' derived accelerations, which is no evidence
        active = self.joint_active_s >= JOINT_ACTIVE_MIN_S
        for k in costs:
            lo, hi = min(k, best_link), max(k, best_link)
            if k not in ambiguous and not active[lo:hi].any():  # joints lo+1..hi (0-based lo..hi-1)
                ambiguous.append(k)
        ambiguous.sort()
        return best_link, float(margin), sorted(ambiguous)

    def _cost(self, st: _Unit, link: int, sig: FloatArray) -> float:
        """Chi-square of ``link``'s fit with the noise levels ``sig`` (:meth:`_class_sigmas` order)."""
        sol = st.solutions[link]
        k = st.links.index(link)
        cost = sum(stats.residual_sum(st.Za[k, c], sol.x_a) / sig[c] ** 2 for c in (REST, MOVING))
        if st.has_gyro:
            cost += sum(stats.residual_sum(st.Zg[k, c], sol.x_g) / sig[2 + c] ** 2 for c in (REST, MOVING))
        return float(cost)

    def _status(self, name: str, advise: bool = True) -> UnitStatus:
        st = self._u[name]
        o = self.options
        inf3 = np.full(3, np.inf)
        self._solve(st)
        link, margin, ambiguous = self._decide(st)
        if link is None:
            why = "no samples yet" if not np.isfinite(st.t_last) and st.offset is not None else (
                "waiting for motion to align its clock" if st.offset is None else "too few samples"
            )  # fmt: skip
            # best joint 0: the first joint moves every link (nothing is known yet)
            return UnitStatus(name, None, float("nan"), None, inf3, inf3, 0, 0, why, 0, False,
                              st.t_last, st.offset is not None)  # fmt: skip
        sol = st.solutions[link]
        k = st.links.index(link)
        kappa = self._inflation(st)
        cov = sol.pose_covariance() * kappa
        std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        pos_std, rot_std = std[:3], np.degrees(std[3:])
        determined = bool(np.all(pos_std < UNDETERMINED_M) and np.all(rot_std < UNDETERMINED_DEG))
        undecided = len(ambiguous) > 1
        if determined and not undecided and st.realigned < MAX_REALIGN and self._clock_off(st, sol):
            self._realign(st, sol.tau, sol.drift)
            self._absorb_unit(name)  # the kept samples again, at once: the status (and a result) never shows the gap
            return self._status(name, advise)
        if not undecided and not st.decided and len(st.links) > 1 and st.moving[k] > MIN_MOVING and determined:
            self._keep_only(st, link)
            k = 0
        reached = bool(
            not undecided and np.all(pos_std <= o.target_position_m) and np.all(rot_std <= o.target_rotation_deg)
        )
        missing = ""
        if undecided:
            missing = f"link undecided between {', '.join(map(str, ambiguous))}: move joint {max(ambiguous)}"
        elif not determined:
            missing = "pose not determined yet: " + (
                f"no motion of its link (joints 1-{link})" if st.moving[k] < 10 else "needs rests in more orientations"
            )  # fmt: skip
        if not determined:
            pos_std = np.where(pos_std < UNDETERMINED_M, pos_std, np.inf)
            rot_std = np.where(rot_std < UNDETERMINED_DEG, rot_std, np.inf)
        best_joint = None
        if not reached:
            if undecided:
                best_joint = max(ambiguous) - 1
            elif advise:  # the joint to move next (a design computation a result does not need)
                best_joint = self._best_joint(name, st, link, sol)
        pose = SkinUnitPose(link, sol.R, sol.p)
        status = UnitStatus(name, link, margin, pose, pos_std, rot_std, int(st.Za[k, :, 9, 9].sum()), int(st.moving[k]),
                            missing, best_joint, reached, st.t_last, True)  # fmt: skip
        st.status = status
        return status

    @staticmethod
    def _clock_off(st: _Unit, sol: stats.Solution) -> bool:
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

    def _keep_only(self, st: _Unit, link: int) -> None:
        k = st.links.index(link)
        st.links = [link]
        st.Za, st.Zg, st.moving = st.Za[k : k + 1].copy(), st.Zg[k : k + 1].copy(), st.moving[k : k + 1].copy()
        st.chunks = deque((t0, t1, Za[k : k + 1], Zg[k : k + 1], mv[k : k + 1]) for t0, t1, Za, Zg, mv in st.chunks)
        st.solutions = {link: st.solutions[link]}
        st.decided = True

    def status(self) -> dict[str, UnitStatus]:
        """Every unit's :class:`UnitStatus` now."""
        return {u: self._status(u) for u in self.units}

    # ---------------------------------------------------------------- design support
    @staticmethod
    def _normal(sol: stats.Solution, Za: FloatArray, Zg: FloatArray | None, sig: FloatArray) -> FloatArray:
        """Normal matrix ``(NP, NP)`` of the Grams ``Za``, ``Zg`` of moving samples at ``sol`` (no prior)."""
        return stats.normal_matrix(sol.R, sol.state, Za / sig[1] ** 2, None if Zg is None else Zg / sig[3] ** 2)

    def information(self, unit: str) -> tuple[int | None, FloatArray]:
        """``(link, (6, 6))``: the current information about the pose ``[rotation (rad, unit axes),
        position (m)]`` of ``unit`` (the inverse of the marginal covariance, correlation-inflated);
        zeros when nothing is known yet."""
        st = self._u[unit]
        self._solve(st)
        link, _, _ = self._decide(st)
        if link is None:
            return None, np.zeros((6, 6))
        sol = st.solutions[link]
        idx = np.r_[0:3, 15:18]
        C = sol.cov[np.ix_(idx, idx)] * self._inflation(st)
        return link, np.linalg.inv(C)

    def pose_information_rate(
        self, unit: str, link: int, q: FloatArray, qd: FloatArray, qdd: FloatArray, dt: float
    ) -> FloatArray:
        """``(6, 6)`` information about ``[rotation, position]`` that the motion ``q, qd, qdd``
        ``(M, n)`` (sampled every ``dt`` s, at the unit's IMU rate or finer) would add for ``unit`` on
        ``link`` at its current estimate (the full-parameter information's Schur complement, i.e.
        with the IMU errors and offset as nuisance). Zeros when the unit has no estimate yet."""
        st = self._u[unit]
        self._solve(st)
        sol = st.solutions.get(link)
        if sol is None:
            return np.zeros((6, 6))
        H = self._design_normal(sol, st.sigmas[link], link, q, qd, qdd, dt, st.has_gyro is not False)
        return _pose_block(H)

    def _design_normal(
        self, sol: stats.Solution, sig: FloatArray, link: int, q, qd, qdd, dt: float, gyro: bool
    ) -> FloatArray:
        u, K, w, dw, ug = frame_signals(self.chain.link_motion(q, qd, qdd, upto=link), self.gravity, link)
        du = np.gradient(u, dt, axis=0) if u.shape[0] > 1 else np.zeros_like(u)
        dK = np.gradient(K, dt, axis=0) if u.shape[0] > 1 else np.zeros_like(K)
        f = ug + (1.0 + sol.gravity_scale) * (u - ug + np.einsum("mij,j->mi", K, sol.p))
        a = (f @ sol.R) @ sol.A.T + sol.b
        Za = stats.gram(stats.accel_rows(a, u, K, du, dK, ug))
        Zg = None
        if gyro:
            g = w @ sol.R + sol.gyro_bias
            Zg = stats.gram(stats.gyro_rows(g, w, dw))
        return self._normal(sol, Za, Zg, sig)

    def _best_joint(self, name: str, st: _Unit, link: int, sol: stats.Solution) -> int | None:
        """The joint (0-based, up to ``link``) whose 2 s excitation at the current posture adds the
        most D-optimal information (log det of the pose's marginal information); cached for 2 s."""
        if self.q_now is None:
            return None
        if st.t_last - st.best_joint_t < 2.0 and st.best_joint is not None:
            return st.best_joint
        H0 = sol.information
        base = _logdet(_pose_block(H0))
        best, gain = None, 0.0
        for j in range(link):
            q, qd, qdd, dt = excitation(self.chain, self.q_now, j)
            dH = self._design_normal(sol, st.sigmas[link], link, q, qd, qdd, dt, st.has_gyro is not False)
            g = _logdet(_pose_block(H0 + dH)) - base
            if g > gain:
                best, gain = j, g
        st.best_joint, st.best_joint_t = best, st.t_last
        return best

    # ---------------------------------------------------------------- moved units
    def restart_unit(self, unit: str, t_from: float) -> None:
        """Forget ``unit``'s data before ``t_from`` (joint clock, s): its statistics become the sum of
        its chunks that start at or after ``t_from`` (within the kept history); the link stays."""
        st = self._u[unit]
        chunks = deque(c for c in st.chunks if c[0] >= t_from)
        st.chunks = chunks
        shape_a, shape_g = st.Za.shape, st.Zg.shape
        st.Za, st.Zg, st.moving = np.zeros(shape_a), np.zeros(shape_g), np.zeros(len(st.links))
        st.sigmas = {}
        for _, _, Za, Zg, mv in chunks:
            st.Za += Za
            st.Zg += Zg
            st.moving += mv
        st.win_sum, st.win_n, st.win_stat, st.win_count = np.zeros(3), 0, 0.0, 0
        st.solutions, st.status, st.dirty = {}, None, True
        st.best_joint, st.best_joint_t = None, float("-inf")

    def record_event(self, event: Mapping) -> None:
        """Append a moved-unit event (written to the result's top-level ``events``)."""
        self.events.append(dict(event))

    # ---------------------------------------------------------------- result
    def result(self, dataset_sha256: str = "") -> CalibrationResult:
        """The current estimates as a :class:`CalibrationResult` (method ``online``): units with a
        determined pose; the others under ``failed_units`` with what is missing."""
        units: dict[str, UnitResult] = {}
        failed: dict[str, str] = {}
        for name in self.units:
            s = self._status(name, advise=False)
            st = self._u[name]
            if s.pose is None or s.link is None or s.missing:
                failed[name] = s.missing or "no estimate"
                continue
            sol = st.solutions[s.link]
            kappa = self._inflation(st)
            cov = sol.pose_covariance() * kappa
            idx_b = slice(12, 15)
            G = sol.R @ np.linalg.inv(sol.A)
            Ginv = np.linalg.inv(G)
            cov_b = Ginv @ sol.cov[idx_b, idx_b] @ Ginv.T * kappa
            # the clock: the mapping composed with the residual (stats: the samples saw s + tau + d (s - t_ref))
            offset, drift = compose_clock(st.offset or 0.0, st.drift, sol.tau, sol.drift)
            drift_std_ppm = 1e6 * float(np.sqrt(max(sol.cov[stats.DRIFT, stats.DRIFT] * kappa, 0.0)))
            imu = ImuCalibration(
                accel_bias_mps2=sol.b,
                accel_bias_std_mps2=np.sqrt(np.clip(np.diag(cov_b), 0, None)),
                accel_scale_misalignment=sol.A,
                time_offset_s=offset,
                time_offset_std_s=float(np.sqrt(max(sol.cov[stats.TAU, stats.TAU] * kappa, 0.0))),
                time_reference_s=st.t_ref,
                clock_drift_ppm=1e6 * drift + (st.steps.drift_ppm if st.steps is not None else 0.0),
                clock_drift_std_ppm=drift_std_ppm,
                clock_resync_steps=None if st.steps is None else st.steps.n_steps,
                clock_resync_period_s=None if st.steps is None else st.steps.period_s,
                clock_resync_step_s=None if st.steps is None else st.steps.mean_step_s,
                gyro_bias_rps=sol.gyro_bias if st.has_gyro else None,
                gravity_mps2=float(np.linalg.norm(self.gravity) / (1.0 + sol.gravity_scale)),
                gravity_std_mps2=float(np.linalg.norm(self.gravity) * np.sqrt(max(sol.cov[22, 22] * kappa, 0.0))),
            )
            warnings: list[str] = []
            if np.isfinite(st.offset_sharpness) and st.offset_sharpness < ALIGN_SHARPNESS:
                warnings.append("time offset uncertain (no motion to align the unit's clock on)")
            notes: list[str] = []
            if drift_std_ppm > DRIFT_UNDETERMINED_PPM:
                notes.append(
                    f"clock drift not determined yet (std {drift_std_ppm:.0f} ppm over {st.t_last - st.t_first:.0f} s"
                    " of data): the time offset holds near the data's start"
                )
            elif abs(drift) * 1e6 > max(DRIFT_NOTE_SIGMAS * drift_std_ppm, DRIFT_NOTE_PPM):
                notes.append(
                    f"clock drifts: {drift * 1e6:+.0f} ppm relative to the robot's clock (estimated and corrected)"
                )
            extras: dict[str, Any] = {
                "link_name": self.chain.link_names[s.link] if self.chain.link_names else f"link{s.link}",
                "link_margin": s.link_margin if np.isfinite(s.link_margin) else None,
                "samples": s.samples,
                "n_moving_samples": s.moving_samples,
                "residual_std_mps2": float(st.sigmas[s.link][1]),
                "rest_residual_std_mps2": float(st.sigmas[s.link][0]),
                "residual_correlation": kappa,
                "outliers": st.outliers,
                "saturated_samples": st.saturated,
                "realigned": st.realigned,
                "scale_estimated": st.scale_estimated,
            }
            units[name] = UnitResult(
                pose=s.pose, observable=True, position_std_m=s.position_std_m, rotation_std_deg=s.rotation_std_deg,
                warnings=tuple(warnings), extras=extras, imu=imu, pose_covariance=cov, notes=tuple(notes),
            )  # fmt: skip
        top: dict[str, Any] = {"late_samples": self.late, "cpu_s": self.cpu_s}
        result = CalibrationResult("online", self.chain.name, dataset_sha256, time.perf_counter() - self._t_start,
                                   units, top, failed_units=failed)  # fmt: skip
        return with_events(result, self._events_now(units)) if self.events else result

    def _events_now(self, units: Mapping[str, UnitResult]) -> list[dict]:
        """The recorded events, each unit's last one completed with the pose re-calibrated since
        (``T_link_su_after``, and ``t_recalibrated_s``: the end of the data it is estimated from) when
        that unit has a determined pose now."""
        out = [dict(e) for e in self.events]
        for i, e in enumerate(out):
            name = e["unit"]
            later = any(f["unit"] == name for f in out[i + 1 :])
            if name in units and not later:
                e["T_link_su_after"] = np.asarray(units[name].pose.T_link_su, dtype=float).tolist()
                e["t_recalibrated_s"] = float(self._u[name].t_last)
        return out


SETTLED_POSITION_M = 1e-3
SETTLED_ROTATION_DEG = 0.2
"""Std (every axis) from which a unit's estimate is stable enough to gate outliers and to be watched
for a move (looser than a calibration target: a unit that never reaches 0.3 mm is still watched)."""


def _settled(status: UnitStatus) -> bool:
    """The unit's link is decided and its pose known to :data:`SETTLED_POSITION_M` / :data:`SETTLED_ROTATION_DEG`."""
    return bool(
        status.pose is not None
        and not status.missing
        and np.all(status.position_std_m <= SETTLED_POSITION_M)
        and np.all(status.rotation_std_deg <= SETTLED_ROTATION_DEG)
    )


def _pose_block(H: FloatArray) -> FloatArray:
    """Information about ``[dtheta, p]`` with the other unknowns as nuisance (Schur complement)."""
    idx = np.r_[0:3, 15:18]
    rest = np.setdiff1d(np.arange(H.shape[0]), idx)
    A, B, D = H[np.ix_(idx, idx)], H[np.ix_(idx, rest)], H[np.ix_(rest, rest)]
    return A - B @ np.linalg.pinv(D) @ B.T


def _logdet(M: FloatArray) -> float:
    sign, ld = np.linalg.slogdet(M + 1e-12 * np.eye(M.shape[0]))
    return float(ld) if sign > 0 else -np.inf


def excitation(
    chain: SerialChain, q0: FloatArray, joint: int, duration: float = 2.0, fraction: float = 0.3, rate_hz: float = 100.0
) -> tuple[FloatArray, FloatArray, FloatArray, float]:
    """A short excitation of ``joint`` from ``q0``: ``qd_j = A sin(2 pi t / duration)`` with
    ``A = fraction`` of its velocity limit (one period: starts and ends at rest), sampled at
    ``rate_hz``. Returns ``q, qd, qdd`` ``(M, n)`` and the period ``dt``."""
    dt = 1.0 / rate_hz
    t = dt * np.arange(int(duration * rate_hz))
    w = 2 * np.pi / duration
    vmax = chain.velocity_limit[joint] if chain.velocity_limit is not None else 1.0
    A = fraction * float(vmax)
    q = np.repeat(np.asarray(q0, dtype=float)[None], t.size, axis=0)
    qd, qdd = np.zeros_like(q), np.zeros_like(q)
    q[:, joint] += A / w * (1 - np.cos(w * t))
    qd[:, joint] = A * np.sin(w * t)
    qdd[:, joint] = A * w * np.cos(w * t)
    return q, qd, qdd, dt


def replay(
    dataset: Dataset,
    calibrator: OnlineCalibrator,
    chunk_s: float = 0.1,
    speed: float | None = None,
    on_chunk: Callable[[float], bool | None] | None = None,
) -> None:
    """Feed ``dataset``'s joint states and IMU streams to ``calibrator`` in arrival order, ``chunk_s``
    of data at a time (each unit's samples by their stamps), at ``speed`` times real time (None: as
    fast as possible), calling ``update()`` per chunk and ``on_chunk(t_end)``; stops early when
    ``on_chunk`` returns True; ``finish()`` at the end (also after an early stop)."""
    if dataset.joints is None:
        raise ConfigError("online calibration needs the dataset's joint states")
    if not (np.isfinite(chunk_s) and chunk_s > 0):
        raise ConfigError(f"chunk must be a positive number of seconds, got {chunk_s}")
    j = dataset.joints
    tj = np.asarray(j.t, dtype=float)
    streams = {u: dataset.imu[u] for u in calibrator.units if u in dataset.imu}
    t0 = float(tj[0])
    t_end = max([float(tj[-1])] + [float(np.asarray(s.t)[-1]) for s in streams.values() if len(s.t)])
    wall0 = time.perf_counter()
    cursor_j = 0
    cursors = dict.fromkeys(streams, 0)
    edge = t0
    while edge < t_end:
        edge = min(edge + chunk_s, t_end)
        last = edge >= t_end
        k = int(np.searchsorted(tj, edge, side="right")) if not last else tj.size
        if k > cursor_j:
            calibrator.add_joint_states(tj[cursor_j:k], j.q[cursor_j:k], j.qd[cursor_j:k])
            cursor_j = k
        for u, s in streams.items():
            ts = np.asarray(s.t, dtype=float)
            k = int(np.searchsorted(ts, edge, side="right")) if not last else ts.size
            c = cursors[u]
            if k > c:
                calibrator.add_imu(u, ts[c:k], s.accel[c:k], None if s.gyro is None else s.gyro[c:k])
                cursors[u] = k
        calibrator.update()
        if speed is not None and speed > 0:
            ahead = (edge - t0) / speed - (time.perf_counter() - wall0)
            if ahead > 0:
                time.sleep(ahead)
        if on_chunk is not None and on_chunk(edge):
            break
    calibrator.finish()
