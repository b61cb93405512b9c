"""The streaming calibrator: samples in, each unit's pose, std and "what is missing" out at any moment.

Flow (all instants on the joint clock, s; the unit's stamps are mapped by its coarse offset)::

    add_joint_states / add_imu      any order, never blocking (buffers)
        │
    update():
      1. joint blocks: when the joint stream reaches T1 + margin + max_delay, the block [T0, T1) is conditioned
         exactly as the batch calibrator conditions a whole stream (:class:`~skincal.calib.preprocess.JointInterpolator`
         over [T0 - margin, T1 + margin]) and the link signals ``u, K, w`` (and ``du/ds``, ``dw/ds``) of EVERY
         link are evaluated on a uniform grid (``grid_hz``) once for all units; the grid is kept for ``history_s``;
      2. per unit: once its stream spans ``align_s`` of motion, its coarse time offset is found by cross-correlation
         (:func:`~skincal.calib.timing.coarse_time_offset`, as ``mle`` does), then each sample whose instant is on the
         grid adds its rows to the Gram matrices of every candidate link (:mod:`skincal.calib.online.stats`: a
         fixed-size sufficient statistic, so the cost per sample is constant and no sample is kept);
    status(): per unit, the pose solved from the Grams of each candidate link; the link whose model explains the data
      best wins once the others are worse by a clear chi-square margin; std from the normal matrix inflated by the
      residuals' autocorrelation; what is missing, and the joint whose short excitation gains the most (D-optimal).

A unit decided on its link keeps only that link's statistics (the others' are dropped). Samples that arrive after
their part of the grid left the history are counted as ``late`` and dropped. Processing runs with one BLAS thread.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from skincal.calib import consistency
from skincal.calib.online import clock, design, fit, split, stats
from skincal.calib.online.design import excitation
from skincal.calib.online.fit import JOINT_ACTIVE_RPS, decide, inflation, residuals, solve_unit, window_means
from skincal.calib.online.history import GridHistory, JointBuffer
from skincal.calib.online.options import OnlineOptions, UnitStatus, is_settled
from skincal.calib.online.screen import admit, unsaturated
from skincal.calib.online.unit import Grid, UnitState, keep_pending, rests_only, signals_at, take_pending
from skincal.calib.position import judge_position, weak_position
from skincal.calib.preprocess import JointInterpolator
from skincal.calib.rest import link_moving
from skincal.calib.signals import frame_signals
from skincal.calib.timing import resolved_speed
from skincal.data.dataset import JointStates
from skincal.data.result import CalibrationResult, UnitResult, with_events
from skincal.errors import ConfigError
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.transforms import FloatArray
from skincal.names import name_problem
from skincal.parallel import one_blas_thread
from skincal.skin.pose import SkinUnitPose

__all__ = ["OnlineCalibrator", "OnlineOptions", "UnitStatus", "excitation"]
"""``OnlineOptions``, ``UnitStatus`` (:mod:`~skincal.calib.online.options`) and ``excitation``
(:mod:`~skincal.calib.online.design`) are re-exported: their import path from here is kept."""

MIN_MOVING = 200
"""Moving samples of the best link before its link is decided."""
POSE_MISSING = "pose not determined yet: "
"""How a status's ``missing`` starts when the std exceed :data:`UNDETERMINED_M` or :data:`UNDETERMINED_DEG`."""
UNDETERMINED_M = 0.05
UNDETERMINED_DEG = 20.0
"""Std beyond these (m, deg) counts as undetermined."""


class OnlineCalibrator:
    """Streaming calibration of skin units on ``chain`` (module docstring).

    ``units``: names of the units to follow (others are refused). ``gravity``: ``(3,)`` base frame,
    m/s^2. ``on_residuals(unit, t, r)`` (set by a change monitor): called per absorbed chunk of a
    unit whose estimate has settled (:func:`~skincal.calib.online.options.is_settled`: decided, std
    within 1 mm / 0.2 deg), with the chunk's instants ``(M,)`` and accelerometer residuals ``(M, 3)``
    divided by the unit's residual std (of its class: resting or moving), at the current estimate.
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
        L, grams = len(links), ((len(links), 2, stats.NA, stats.NA), (len(links), 2, stats.NG, stats.NG))
        self._u = {u: UnitState(list(links), np.zeros(grams[0]), np.zeros(grams[1]), np.zeros(L), candidates=links)
                   for u in names}
        self._joints = JointBuffer()
        self._frontier: float | None = None  # end of the processed joint blocks
        self._grid = GridHistory()  # per block, every link
        self.spline = False  # a block's joint stream was conditioned by smoothing splines (low-rate): sandwich as mle
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
            self._joints.add(t, q, qd_a)
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
            admit(st, t[ok], a[ok], None if g is None else g[ok])

    # ---------------------------------------------------------------- processing
    @one_blas_thread
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

    @one_blas_thread
    def finish(self) -> None:
        """End of data: process the joint stream to its end and absorb what can be."""
        c0 = time.process_time()
        self._blocks(final=True)
        for u in self.units:
            admit(self._u[u], np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)) if self._u[u].has_gyro else None, True)
            if (grid := self._grid.whole()) is not None:  # the whole stream's peak (its kept samples pending again)
                clock.recheck(self._u[u], grid, None, None, None, self.options, final=True)
            self._absorb_unit(u, final=True)
            if fit.needs_rewindow(self._u[u]) and (grid := self._grid.whole()) is not None:
                self._status(u, advise=False)  # the solutions and the leading link at the data's end
                fit.rewindow(self._u[u], grid, lambda t, st=self._u[u]: clock.instants(st, t))
            self._u[u].split_cache = None  # the status after the data's end gives the std a result writes
        self.cpu_s += time.process_time() - c0

    def _blocks(self, final: bool) -> None:
        o = self.options
        newest = self._joints.newest

        def complete(T0: float) -> bool:  # a whole block from T0 is in (or the data's end with final)
            return newest >= T0 + o.block_s + o.margin_s + o.max_delay_s or (final and newest - o.margin_s > T0 + 1e-9)

        if self._frontier is not None and not complete(self._frontier):
            return  # the received states stay unmerged
        joints = self._joints.arrays()
        if joints is None or joints[0].size < 8:
            return
        t, q, qd = joints
        if self._frontier is None:
            self._frontier = float(t[0]) + o.margin_s
        while True:
            T0 = self._frontier
            if not complete(T0):
                break
            T1 = T0 + o.block_s
            if newest < T1 + o.margin_s + o.max_delay_s:
                T1 = newest - o.margin_s  # the data's end (final)
            self._condition_block(t, q, qd, T0, T1)
            self._frontier = T1
        # forget joint states no later block needs
        self._joints.forget_before(self._frontier - max(o.margin_s, o.lookback_s) - 1e-9)
        self._grid.forget_before(self._frontier - o.history_s)

    def _condition_block(self, t: FloatArray, q: FloatArray, qd: FloatArray, T0: float, T1: float) -> None:
        o = self.options
        sel = (t >= T0 - max(o.margin_s, o.lookback_s) - 1e-9) & (t <= T1 + o.margin_s + 1e-9)
        if sel.sum() < 8:
            return
        interp = JointInterpolator(JointStates(t=t[sel], q=q[sel], qd=qd[sel]), outputs_from=T0)
        self.spline = self.spline or interp.conditioning.source == "spline"
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
        self._grid.append(Grid(tg, y, dw, interp.reliable(tg), np.cumsum(np.abs(qdg), axis=1), resolved_speed(t[sel])))

    def _absorb_unit(self, name: str, final: bool = False) -> int:
        st = self._u[name]
        grid = self._grid.whole()
        if grid is None or not st.pending_t:
            return 0
        t, a, g = take_pending(st)
        st.pending_t, st.pending_a, st.pending_g = [], [], []
        if st.offset is None:
            if final or max(t[-1], grid.t[-1]) - st.align_tried >= clock.ALIGN_RETRY_S:  # the grid moves on too
                st.align_tried = float(max(t[-1], grid.t[-1]))
                clock.align(st, grid, t, a, g, self.options, final)
            if st.offset is None:
                if final:
                    st.offset, st.offset_sharpness = 0.0, 0.0  # no motion to align on: the stamps as they are
                else:
                    keep_pending(st, t, a, g)
                    return 0
        else:  # a provisional clock aligned on motion, or a longer stream's peak elsewhere: all pending again
            retry = st.clock_provisional and (final or t[-1] - st.align_tried >= clock.ALIGN_RETRY_S)
            st.align_tried = float(t[-1]) if retry else st.align_tried
            if clock.align_on_motion(st, grid, t, a, g, self.options, final) if retry else clock.recheck(
                    st, grid, t, a, g, self.options, final):  # fmt: skip
                keep_pending(st, t, a, g)
                return self._absorb_unit(name, final)
        assert st.offset is not None
        clock.track_steps(st, t)
        s = clock.instants(st, t)
        tg = grid.t
        late = s < tg[0]
        self.late += int(late.sum())
        ready = (s >= tg[0]) & (s <= tg[-1])
        if not final:
            keep_pending(st, t[~ready & ~late], a[~ready & ~late], None if g is None else g[~ready & ~late])
        if not ready.any():
            return 0
        g_ready = None if g is None else g[ready]
        n, chunk = self._absorb(name, st, grid, s[ready], a[ready], st.stuck.gyro_masked(t[ready], g_ready))
        st.raw.append((t[ready], a[ready], g_ready, chunk))
        while st.raw and clock.instants(st, st.raw[0][0][-1:])[0] < tg[0]:
            st.raw.popleft()  # its part of the grid is gone: it could not be absorbed again (its statistics stay)
        return n

    def _absorb(self, name: str, st: UnitState, grid: Grid, s: FloatArray, a: FloatArray,
                g: FloatArray | None) -> tuple[int, tuple | None]:  # fmt: skip
        """Absorb samples at instants ``s``: their count and chunk ``(s0, s1, Za, Zg, moving)`` (None: none)."""
        unsat, g = unsaturated(st, a, g)  # a gyroscope's readings at its rail: NaN rows
        if not unsat.all():
            s, a, g = s[unsat], a[unsat], None if g is None else g[unsat]
        u, K, w, dw, du, dK, ug, ok = signals_at(grid, s, st.links)
        if not ok.all():
            s, a, u, K, w, dw, du, dK = s[ok], a[ok], u[:, ok], K[:, ok], w[:, ok], dw[:, ok], du[:, ok], dK[:, ok]
            ug = ug[:, ok]
            g = None if g is None else g[ok]
        if s.size == 0:
            return 0, None
        moving = link_moving(w, dw)  # (L, M)
        huber = None
        lead = st.links[0] if st.decided and st.links[0] in st.solutions else None  # windows: a decided link's
        if lead is not None:
            j = st.links.index(lead)
            r = residuals(st.solutions[lead], a, u[j], K[j], du[j], dK[j], ug[j], s - st.t_ref)
            sig = st.sigmas[lead]
            rn = r / np.maximum(np.where(moving[j], sig[1], sig[0]), 1e-9)[:, None]
            settled = st.decided and st.status is not None and is_settled(st.status)
            keep, huber = fit.robust_weights(rn, settled, st.residual_norms)
            if self.on_residuals is not None and settled:
                self.on_residuals(name, s, rn)
            st.outliers += int((~keep).sum())
            if not keep.all():
                s, a, u, K, w, dw = s[keep], a[keep], u[:, keep], K[:, keep], w[:, keep], dw[:, keep]
                du, dK, ug = du[:, keep], dK[:, keep], ug[:, keep]
                g, moving, rn = None if g is None else g[keep], moving[:, keep], rn[keep]
            window_means(st.windows.setdefault(lead, fit.Windows()), rn)
        if s.size == 0:
            return 0, None
        L, M = u.shape[0], s.size
        cls = np.stack([~moving, moving], axis=1)[..., None, None]  # (L, 2, M, 1, 1)
        elapsed = s - st.t_ref
        rows_a = stats.accel_rows(np.broadcast_to(a, (L, M, 3)), u, K, du, dK, ug, elapsed)[:, None] * cls
        rows_g = None if g is None else stats.gyro_rows(np.broadcast_to(g, (L, M, 3)), w, dw, elapsed)[:, None] * cls
        if huber is not None:
            rows_a = rows_a * np.sqrt(huber)[:, None, None]
        speed = grid.speed[np.clip(np.searchsorted(grid.t, s), 0, grid.t.size - 1)][:, np.asarray(st.links) - 1].T
        st.ledger.setup(L)
        parts = split.pieces(s, rows_a, rows_g, moving, speed, *st.ledger.start(float(s[0])))
        st.ledger.add(parts)
        Za, Zg = (parts[0].Za, parts[0].Zg) if len(parts) == 1 else (sum(p.Za for p in parts), sum(p.Zg for p in parts))
        n_moving = moving.sum(axis=1).astype(float)
        st.Za += Za
        st.Zg += Zg
        st.moving += n_moving
        chunk = (float(s[0]), float(s[-1]), Za, Zg, n_moving, parts)
        st.chunks.append(chunk)
        horizon = s[-1] - self.options.history_s
        while st.chunks and st.chunks[0][1] < horizon:
            st.chunks.popleft()
        st.t_last = max(st.t_last, float(s[-1]))
        st.t_first = min(st.t_first, float(s[0]))
        st.dirty = True
        return int(M), chunk

    # ---------------------------------------------------------------- estimates
    def _status(self, name: str, advise: bool = True) -> UnitStatus:
        st = self._u[name]
        o = self.options
        inf3 = np.full(3, np.inf)
        solve_unit(st, self.options)
        link, margin, ambiguous = decide(st, self.joint_active_s)
        if link is None:
            why = "no samples yet" if not np.isfinite(st.t_last) and st.offset is not None else (
                "waiting for motion to align its clock" if st.offset is None else "too few samples"
            )  # fmt: skip
            # best joint 0: the first joint moves every link (nothing is known yet)
            return UnitStatus(name, None, float("nan"), None, inf3, inf3, 0, 0, why, 0, False,
                              st.t_last, st.offset is not None)  # fmt: skip
        sol = st.solutions[link]
        k = st.links.index(link)
        kappa = inflation(st.windows.get(link))
        cov = sol.pose_covariance() * kappa
        std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        pos_std, rot_std = std[:3], np.degrees(std[3:])
        determined = bool(np.all(pos_std < UNDETERMINED_M) and np.all(rot_std < UNDETERMINED_DEG))
        undecided = len(ambiguous) > 1
        rests_answer = rests_only(st, k) and bool(np.all(rot_std < UNDETERMINED_DEG))  # a result nulls the position
        if determined and not undecided and st.realigned < clock.MAX_REALIGN and clock.clock_off(st, sol):
            clock.realign(st, sol.tau, sol.drift)
            self._absorb_unit(name)  # the kept samples again, at once: the status (and a result) never shows the gap
            return self._status(name, advise)
        if not undecided and not st.decided and st.moving[k] > MIN_MOVING and determined:  # one candidate too
            self._keep_only(st, link)
            k = 0
        def within(p: FloatArray, r: FloatArray) -> bool:
            return bool(not undecided and np.all(p <= o.target_position_m) and np.all(r <= o.target_rotation_deg))

        if determined and not rests_only(st, k):  # the std a result gives: sandwich, split check
            shown, _, checked = fit.reported(st, link, fit.SPLIT_RECHECK, self.spline, o.consistency)
            std = np.sqrt(np.clip(np.diag(shown.pose_covariance() * kappa), 0.0, None))
            f_p, f_r = (checked.axes_position, checked.axes_rotation) if checked is not None else (1.0, 1.0)
            pos_std, rot_std = std[:3] * np.asarray(f_p), np.degrees(std[3:]) * np.asarray(f_r)
        reached = within(pos_std, rot_std)
        missing = ""
        if undecided:
            missing = f"link undecided between {', '.join(map(str, ambiguous))}: move joint {max(ambiguous)}"
        elif not determined and not rests_answer:
            missing = POSE_MISSING + (
                f"no motion of its link (joints 1-{link})" if rests_only(st, k) else "needs rests in more orientations"
            )  # fmt: skip
        if not determined:
            pos_std = np.where(pos_std < UNDETERMINED_M, pos_std, np.inf)
            rot_std = np.where(rot_std < UNDETERMINED_DEG, rot_std, np.inf)
        best_joint = None
        if not reached:
            if undecided:
                best_joint = max(ambiguous) - 1
            elif advise:  # the joint to move next (a design computation a result does not need)
                best_joint = design.best_joint(self.chain, self.gravity, self.q_now, st, link, sol)
        pose = SkinUnitPose(link, sol.R, sol.p)
        status = UnitStatus(name, link, margin, pose, pos_std, rot_std, st.ledger.count(), int(st.moving[k]),
                            missing, best_joint, reached, st.t_last, True)  # fmt: skip
        st.status = status
        return status

    def _keep_only(self, st: UnitState, link: int) -> None:
        k = st.links.index(link)
        st.links = [link]
        st.Za, st.Zg, st.moving = st.Za[k : k + 1].copy(), st.Zg[k : k + 1].copy(), st.moving[k : k + 1].copy()
        both = [*st.chunks, *(r[3] for r in st.raw if r[3] is not None)]  # a chunk's statistics: link k's only
        def one(c: tuple) -> tuple:  # copies: a view would keep every candidate's arrays alive
            pieces = [p.link(k) for p in c[5]]
            one_piece = len(pieces) == 1
            Za = pieces[0].Za if one_piece else c[2][k : k + 1].copy()
            Zg = pieces[0].Zg if one_piece else c[3][k : k + 1].copy()
            return (*c[:2], Za, Zg, c[4][k : k + 1].copy(), pieces)

        kept = {id(c): one(c) for c in both}
        st.ledger.keep_link(k)
        st.chunks = deque(kept[id(c)] for c in st.chunks)
        st.raw = deque((t, a, g, None if c is None else kept[id(c)]) for t, a, g, c in st.raw)
        st.solutions = {link: st.solutions[link]}
        st.windows = {link: st.windows[link]} if link in st.windows else {}
        st.decided, st.split_cache = True, None

    @one_blas_thread
    def status(self, fresh: bool = False) -> dict[str, UnitStatus]:
        """Every unit's :class:`UnitStatus` now (``fresh``: its split check made again, not the last one's)."""
        for u in self.units if fresh else ():
            self._u[u].split_cache = None
        return {u: self._status(u) for u in self.units}

    def unit_state(self, unit: str) -> UnitState:
        """The streaming state of ``unit`` (its clock mapping, Gram matrices, kept samples): live, not a
        copy, for diagnostics and tests that disturb it; :meth:`status` is the answer to read."""
        return self._u[unit]

    # ---------------------------------------------------------------- design support
    def information(self, unit: str) -> tuple[int | None, FloatArray]:
        """``(link, (6, 6))``: the current information about the pose ``[rotation (rad, unit axes),
        position (m)]`` of ``unit`` (the inverse of the marginal covariance, correlation-inflated);
        zeros when nothing is known yet."""
        st = self._u[unit]
        solve_unit(st, self.options)
        link, _, _ = decide(st, self.joint_active_s)
        if link is None:
            return None, np.zeros((6, 6))
        sol = st.solutions[link]
        idx = np.r_[0:3, 15:18]
        C = sol.cov[np.ix_(idx, idx)] * inflation(st.windows.get(link))
        return link, np.linalg.inv(C)

    def pose_information_rate(
        self, unit: str, link: int, q: FloatArray, qd: FloatArray, qdd: FloatArray, dt: float
    ) -> FloatArray:
        """``(6, 6)`` information about ``[rotation, position]`` that the motion ``q, qd, qdd``
        ``(M, n)`` (sampled every ``dt`` s, at the unit's IMU rate or finer) would add for ``unit`` on
        ``link`` at its current estimate (the full-parameter information's Schur complement, i.e.
        with the IMU errors and offset as nuisance). Zeros when the unit has no estimate yet."""
        st = self._u[unit]
        solve_unit(st, self.options)
        sol = st.solutions.get(link)
        if sol is None:
            return np.zeros((6, 6))
        H = design.design_normal(self.chain, self.gravity, sol, st.sigmas[link], link, q, qd, qdd, dt,
                                 st.has_gyro is not False)  # fmt: skip
        return design.pose_block(H)

    # ---------------------------------------------------------------- moved units
    def restart_unit(self, unit: str, t_from: float) -> None:
        """Forget ``unit``'s data before ``t_from`` (joint clock, s): its statistics become the sum of
        its chunks that start at or after ``t_from`` (within the kept history); the link stays."""
        st = self._u[unit]
        chunks = deque(c for c in st.chunks if c[0] >= t_from)
        st.chunks = chunks
        ids = {id(c) for c in chunks}  # the kept samples a re-alignment absorbs again: those still counted
        st.raw = deque(r for r in st.raw if r[3] is not None and id(r[3]) in ids)
        shape_a, shape_g = st.Za.shape, st.Zg.shape
        st.Za, st.Zg, st.moving = np.zeros(shape_a), np.zeros(shape_g), np.zeros(len(st.links))
        st.sigmas = {}
        st.ledger.clear()
        for _, _, Za, Zg, mv, parts in chunks:
            st.Za += Za
            st.Zg += Zg
            st.moving += mv
            st.ledger.add(parts)
        st.windows, st.residual_norms = {}, deque(maxlen=st.residual_norms.maxlen)
        st.solutions, st.status, st.dirty, st.split_cache = {}, None, True, None
        st.best_joint, st.best_joint_t = None, float("-inf")

    def record_event(self, event: Mapping) -> None:
        """Append a moved-unit event (written to the result's top-level ``events``)."""
        self.events.append(dict(event))

    # ---------------------------------------------------------------- result
    @one_blas_thread
    def result(self, dataset_sha256: str = "") -> CalibrationResult:
        """The current estimates as a :class:`CalibrationResult` (method ``online``): units with a
        determined pose; the others under ``failed_units`` with what is missing."""
        units: dict[str, UnitResult] = {}
        failed: dict[str, str] = {}
        for name in self.units:
            s = self._status(name, advise=False)
            st = self._u[name]
            # as mle: a decided link and rotation with a weakly determined position are written (its std and a
            # warning say how weak); an undecided link or an undetermined rotation is a failure
            rotation_only = s.missing.startswith(POSE_MISSING) and bool(np.all(np.isfinite(s.rotation_std_deg)))
            if s.pose is None or s.link is None or (s.missing and not rotation_only):
                failed[name] = s.missing or "no estimate"
                continue
            rests = rests_only(st, st.links.index(s.link) if s.link in st.links else 0)
            sol, factors, checked = (st.solutions[s.link], None, None) if rests else fit.reported(
                st, s.link, 1.0, self.spline, self.options.consistency)  # the status's  # fmt: skip
            kappa = inflation(st.windows.get(s.link))
            cov = sol.pose_covariance() * kappa
            std = np.sqrt(np.clip(np.diag(cov), 0.0, None))  # before the split check (applied below)
            imu, drift, drift_std_ppm = fit.imu_calibration(st, sol, kappa, self.gravity)
            warnings = fit.unit_warnings(st, self.spline and not rests and factors is None, sol, kappa)
            notes = fit.unit_notes(st, drift, drift_std_ppm)
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
                "gyro_saturated_samples": st.gyro_saturated,
                "stuck_samples": st.stuck.dropped,
                "gyro_stuck_samples": st.stuck.gyro_dropped,
                "realigned": st.realigned,
                "clock_rechecked": st.rechecked,
                "scale_estimated": fit.scale_std(sol) <= fit.SCALE_STD_LIMIT,
                "covariance_sandwich": None if factors is None else np.r_[factors[0:3], factors[15:18]],
            }
            notes += clock.notes(st)
            unit = UnitResult(
                pose=s.pose, observable=True, position_std_m=std[:3], rotation_std_deg=np.degrees(std[3:]),
                warnings=tuple(warnings), extras=extras, imu=imu, pose_covariance=cov, notes=tuple(notes),
            )  # fmt: skip
            unit = unit if checked is None else consistency.apply(unit, checked)  # as mle
            units[name] = weak_position(judge_position(unit, rests, static_only=st.clock_provisional))
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
