"""A unit that moved is noticed: a sequential change detector on each unit's calibrated residuals.

The streaming calibrator calls :meth:`MovedUnitMonitor.on_residuals` per absorbed block with a
unit's residuals ``r`` ``(M, 3)`` divided by the unit's noise std, at its current estimate (once that
estimate reached its target). A knock changes the *systematic* part of the residual: a turn by 2 deg
moves the gravity direction in the unit frame by ``9.81 sin 2deg = 0.34 m/s^2`` at rest and in
motion; a 5 mm move changes the centripetal and tangential terms ``K(s) dp`` only while the link
moves (a few hundredths of m/s^2, changing with the motion). Neither shows in one sample; both show
in the **mean over a short window**.

Per unit (:class:`UnitMonitor`):

1. **Windows.** Samples are cut into windows of ``window_s`` s (a gap longer than a window starts a
   new one); window ``w`` with ``n_w`` samples gives ``z_w = sqrt(n_w) mean(r)`` ``(3,)`` (unit
   variance per axis for white residuals; the residuals of joint-derived signals are correlated, so
   the true spread is learnt, not assumed).
2. **Warm-up (the null distribution, from the unit's own data).** The first ``warmup_windows``
   windows give the mean ``mu`` and covariance ``S`` of ``z`` (``S`` floored at ``min_variance`` per
   axis); each later window gives ``g_w = (z_w - mu)^T S^-1 (z_w - mu) / 3`` (mean 1 with no change,
   whatever the unit's noise level and autocorrelation).
3. **CUSUM.** ``C_w = max(0, C_{w-1} + g_w - drift)``; an alarm when ``C_w > h``. The threshold ``h``
   comes from the warm-up too: the CUSUM is run over ``bootstrap_windows`` windows resampled in
   blocks of ``block_windows`` from the warm-up's ``g`` (moving-block bootstrap: the null run
   length of a few hours of work, keeping the windows' correlation), and ``h = max(min_threshold,
   safety * max C)``.
4. **Change time.** The alarm's change time is the start of the first window after the CUSUM's last
   reset to 0 (the classical CUSUM change-point estimate).

After an alarm the unit goes back to warm-up (its estimate is restarted from the data after the
change). :class:`MovedUnitMonitor` holds one :class:`UnitMonitor` per unit and, attached to a
calibrator (:meth:`MovedUnitMonitor.attach`), restarts the moved unit
(``calibrator.restart_unit(unit, t_change)``) and records the event
(``calibrator.record_event(event)``, keys in ``docs/interfaces.md``); the other units are untouched.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from skincal.errors import ConfigError, DatasetError
from skincal.kinematics.transforms import FloatArray


@dataclass(frozen=True)
class MonitorOptions:
    """Parameters of the change detector (module docstring).

    Attributes:
        window_s: window length, s.
        min_window_samples: a window with fewer samples is dropped.
        warmup_windows: windows that give the unit's null distribution (480 of 0.25 s: 2 min of work).
        drift: CUSUM reference value ``k`` subtracted from every ``g_w`` (``g_w`` has mean 1 with no
            change, about 1.3 while the link moves; a change that more than doubles it on the windows it
            shows in is what is tuned for).
        safety: ``h`` is this multiple of the largest CUSUM value of the bootstrapped null run.
        min_threshold: the smallest ``h``. The block bootstrap of a 2-minute warm-up sees too few of the
            rare long runs of model error a work hour has: over simulated hours of teleoperation
            (``benchmarks/bench_monitor.py``, panda, 6 units, ``realistic`` and ``real`` IMUs, controller
            joint states) the largest CUSUM value without a change was 8.8 at ``drift`` 2.5, while the
            bootstrap gave 3-11; this floor keeps a margin above that.
        bootstrap_windows: length of the bootstrapped null run, windows (20000 windows of 0.25 s: 1.4 h).
        block_windows: block length of the bootstrap, windows.
        min_variance: floor of each axis' variance of ``z`` (a perfectly still, noise-free unit).
        seed: seed of the bootstrap (with the unit's name: one draw per unit, the same every run).
    """

    window_s: float = 0.25
    min_window_samples: int = 5
    warmup_windows: int = 480
    drift: float = 2.5
    safety: float = 1.5
    min_threshold: float = 12.0
    bootstrap_windows: int = 20000
    block_windows: int = 8
    min_variance: float = 1e-6
    seed: int = 0

    def __post_init__(self) -> None:
        for key in ("window_s", "drift", "safety", "min_threshold", "min_variance"):
            value = getattr(self, key)
            if not (isinstance(value, (int, float, np.number)) and np.isfinite(value) and value > 0):
                raise ConfigError(f"monitor: {key} must be a positive number, got {value!r}")
        for key, lowest in (("min_window_samples", 1), ("warmup_windows", 8), ("bootstrap_windows", 1),
                            ("block_windows", 1)):  # fmt: skip
            value = getattr(self, key)
            if not (isinstance(value, (int, np.integer)) and value >= lowest):
                raise ConfigError(f"monitor: {key} must be an integer >= {lowest}, got {value!r}")


@dataclass(frozen=True)
class Alarm:
    """A unit flagged as moved.

    Attributes:
        unit: unit name.
        t_change: estimated change time (start of the first window after the CUSUM's last reset), s.
        t_detected: end of the window that raised the alarm, s.
        statistic: the CUSUM value at the alarm.
        threshold: the unit's ``h``.
        shift: ``(3,)`` mean of ``z - mu`` over the windows since the change, in units of the
            per-sample noise (the direction the residual moved to).
    """

    unit: str
    t_change: float
    t_detected: float
    statistic: float
    threshold: float
    shift: FloatArray

    def event(self) -> dict[str, Any]:
        """The event's contract fields (``docs/interfaces.md``, moved-unit events)."""
        return {
            "unit": self.unit,
            "t_change_s": float(self.t_change),
            "t_detected_s": float(self.t_detected),
            "statistic": float(self.statistic),
            "threshold": float(self.threshold),
        }


@dataclass
class _Null:
    mu: FloatArray
    cov: FloatArray
    inv: FloatArray
    threshold: float


@dataclass
class UnitMonitor:
    """One unit's windows, null distribution and CUSUM (module docstring)."""

    unit: str
    options: MonitorOptions = field(default_factory=MonitorOptions)
    null: _Null | None = None
    cusum: float = 0.0
    alarms: list[Alarm] = field(default_factory=list)
    _warm: list[FloatArray] = field(default_factory=list)
    _t0: float | None = None
    _t_last: float | None = None
    _sum: FloatArray = field(default_factory=lambda: np.zeros(3))
    _n: int = 0
    _reset_t: float | None = None
    _since: list[FloatArray] = field(default_factory=list)
    windows: int = 0

    @property
    def state(self) -> str:
        """``"warm-up"`` while the null distribution is being learnt, else ``"watching"``."""
        return "warm-up" if self.null is None else "watching"

    @property
    def threshold(self) -> float | None:
        """The CUSUM threshold ``h``, or None during warm-up."""
        return None if self.null is None else self.null.threshold

    @property
    def window_std(self) -> FloatArray | None:
        """``(3,)`` std of the window statistic ``z`` per axis learnt in warm-up (1 for white residuals)."""
        return None if self.null is None else np.sqrt(np.diag(self.null.cov))

    def mean_alarm_level(self) -> float | None:
        """Size of a sustained window-mean shift (per-sample noise units x sqrt(window samples), along the
        least certain axis) that raises an alarm after ``h / (g - drift)`` windows when ``g = 2 drift``:
        grows with the unit's own window spread."""
        if self.null is None:
            return None
        lam = float(np.max(np.linalg.eigvalsh(self.null.cov)))
        return float(np.sqrt(3 * 2 * self.options.drift * lam))

    def restart(self) -> None:
        """Forget the null distribution and the CUSUM: warm-up again (after the unit's estimate restarted)."""
        self.null, self.cusum, self._warm, self._reset_t, self._since = None, 0.0, [], None, []
        self._t0, self._t_last, self._sum, self._n = None, None, np.zeros(3), 0

    def feed(self, t_in: ArrayLike, r_in: ArrayLike) -> Alarm | None:
        """Absorb residuals ``r`` ``(M, 3)`` (noise units) at ``t`` ``(M,)`` s, in time order; the first
        alarm raised, or None. Samples after an alarm in the same call are dropped (the unit restarts)."""
        t = np.asarray(t_in, dtype=float).reshape(-1)
        r = np.asarray(r_in, dtype=float)
        if r.shape != (t.size, 3):
            raise DatasetError(
                f"monitor: residuals of unit '{self.unit}' must be (M, 3) with M = {t.size}, got {r.shape}"
            )
        finite = np.isfinite(t) & np.all(np.isfinite(r), axis=1)
        t, r = t[finite], r[finite]
        if t.size == 0:
            return None
        if self._t_last is not None:  # out-of-order or repeated samples: only what is newer counts
            newer = t > self._t_last
            t, r = t[newer], r[newer]
        w = self.options.window_s
        start = 0
        while start < t.size:
            if self._t0 is None:
                self._t0 = float(t[start])
            elif self._t_last is not None and t[start] - self._t_last > w:  # a gap: the open window is dropped
                self._sum, self._n, self._t0 = np.zeros(3), 0, float(t[start])
            end_t = self._t0 + w
            stop = int(np.searchsorted(t, end_t, side="left"))
            if stop > start:
                self._sum += r[start:stop].sum(axis=0)
                self._n += stop - start
                self._t_last = float(t[stop - 1])
            if stop >= t.size:
                break
            alarm = self._close(self._t0, end_t)
            if alarm is not None:  # the unit restarts: the rest of this call is dropped
                return alarm
            self._t0 = None if t[stop] - end_t > w else end_t
            start = stop
        return None

    def _close(self, t_start: float, t_end: float) -> Alarm | None:
        n, s = self._n, self._sum
        self._sum, self._n = np.zeros(3), 0
        if n < self.options.min_window_samples:
            return None
        z = s / np.sqrt(n)
        self.windows += 1
        if self.null is None:
            self._warm.append(z)
            if len(self._warm) >= self.options.warmup_windows:
                self.null = learn_null(np.array(self._warm), self.options, self.unit)
                self._warm = []
            return None
        d = z - self.null.mu
        g = float(d @ self.null.inv @ d) / 3.0
        previous = self.cusum
        self.cusum = max(0.0, self.cusum + g - self.options.drift)
        if previous == 0.0:
            self._reset_t, self._since = t_start, []
        if self.cusum == 0.0:
            self._since = []
            return None
        self._since.append(d)
        if self.cusum <= self.null.threshold:
            return None
        alarm = Alarm(self.unit, float(self._reset_t), float(t_end), self.cusum, self.null.threshold,
                      np.mean(self._since, axis=0))  # fmt: skip
        self.alarms.append(alarm)
        self.restart()
        return alarm


def _seed(options: MonitorOptions, unit: str) -> np.random.Generator:
    return np.random.default_rng([options.seed, *unit.encode("utf-8")])


def learn_null(z: FloatArray, options: MonitorOptions, unit: str = "") -> _Null:
    """The null distribution of a unit's window statistic from its warm-up windows ``z`` ``(W, 3)``:
    mean, covariance (floored), and the CUSUM threshold from a moving-block bootstrap (module docstring)."""
    z = np.asarray(z, dtype=float)
    mu = z.mean(axis=0)
    cov = np.cov(z, rowvar=False) + options.min_variance * np.eye(3)
    inv = np.linalg.inv(cov)
    d = z - mu
    g = np.einsum("wi,ij,wj->w", d, inv, d) / 3.0
    rng = _seed(options, unit)
    B = min(options.block_windows, len(g))
    n_blocks = -(-options.bootstrap_windows // B)
    starts = rng.integers(0, len(g) - B + 1, size=n_blocks)
    run = g[(starts[:, None] + np.arange(B)[None]).ravel()]
    worst = cusum_max(run, options.drift)
    return _Null(mu, cov, inv, max(options.min_threshold, options.safety * worst))


def cusum_max(g: FloatArray, drift: float) -> float:
    """The largest value of ``C_w = max(0, C_{w-1} + g_w - drift)`` over ``g`` ``(W,)``, ``C_0 = 0``.

    Vectorised: ``C_w = S_w - min_{v <= w} S_v`` with ``S`` the cumulative sum of ``g - drift`` and ``S_0 = 0``
    (the CUSUM is the random walk's rise above its running minimum)."""
    s = np.concatenate([[0.0], np.cumsum(np.asarray(g, dtype=float) - drift)])
    return float(np.max(s - np.minimum.accumulate(s)))


class MovedUnitMonitor:
    """Per-unit change detection for a streaming calibrator (module docstring).

    ``monitor = MovedUnitMonitor(); monitor.attach(calibrator)`` sets ``calibrator.on_residuals``; on
    an alarm the unit's estimate is restarted from the change time and the event recorded with the
    pose the unit had before (``pose_before``: the calibrator's status at the alarm). Without a
    calibrator, alarms are only collected (:attr:`alarms`) and passed to ``on_alarm``.
    """

    def __init__(
        self,
        options: MonitorOptions = MonitorOptions(),
        on_alarm: Callable[[Alarm], None] | None = None,
    ) -> None:
        self.options = options
        self.units: dict[str, UnitMonitor] = {}
        self.alarms: list[Alarm] = []
        self.on_alarm = on_alarm
        self.calibrator: Any = None

    def attach(self, calibrator: Any) -> MovedUnitMonitor:
        """Watch ``calibrator`` (an :class:`~skincal.calib.online.estimator.OnlineCalibrator`)."""
        self.calibrator = calibrator
        calibrator.on_residuals = self.on_residuals
        return self

    def unit(self, name: str) -> UnitMonitor:
        """The monitor of unit ``name`` (created on first use)."""
        if name not in self.units:
            self.units[name] = UnitMonitor(name, self.options)
        return self.units[name]

    def on_residuals(self, unit: str, t: FloatArray, r: FloatArray) -> None:
        """Residuals of ``unit`` (noise units) at ``t``: feed its detector; act on an alarm."""
        alarm = self.unit(unit).feed(t, r)
        if alarm is None:
            return
        self.alarms.append(alarm)
        if self.calibrator is not None:
            event = alarm.event()
            status = self.calibrator.status().get(unit)
            pose = None if status is None else status.pose
            if pose is not None:
                event["link"] = int(pose.link)
                event["T_link_su_before"] = np.asarray(pose.T_link_su, dtype=float).tolist()
            self.calibrator.restart_unit(unit, alarm.t_change)
            self.calibrator.record_event(event)
        if self.on_alarm is not None:
            self.on_alarm(alarm)
