"""The time stamps of a skin unit's own clock: offset, drift, periodic re-sync, one-off steps at
gaps, host reception stamps, jitter, quantum.

A unit stamps its samples with its own clock. Drawn once per unit (:func:`draw_clock`), the stamp
error of a sample whose physical instant is ``t`` (s, the trajectory's time base) is

    tau(t) = t_stamp - t = offset_s + 1e-6 * drift_ppm * (t - t_sync(t)),
    t_sync(t) = t0 + phase + P * floor((t - t0 - phase) / P),

with ``t0`` the session start, ``P`` the re-sync period and ``phase`` in ``[0, P)`` the instant of
the first re-sync after ``t0``. Between re-syncs the clock runs free and its error grows linearly;
at each re-sync it is set back to ``offset_s``. For ``P = inf`` (never re-synced) ``t_sync = t0``:
the error grows linearly over the whole session. A slow sensor clock (``drift_ppm < 0``) makes the
stamps fall behind, then jump forward by ``|drift_ppm| 1e-6 P`` at each re-sync (the measured
driver: about 440 ppm slow, re-synced every 2.51 s, forward steps of 0.15-2.4 ms).

**Gaps and one-off steps** (``gap_rate_hz > 0``): the unit's stream stops ``G_j`` times, a Poisson
number with mean ``gap_rate_hz (t_end - t0)``; gap ``j`` starts at ``t0 + g_j``, ``g_j ~ U(0, t_end - t0)``
(sorted), lasts ``d_j ~ U(gap_min_s, gap_max_s)``, and every sample measured inside
``[t0 + g_j, t0 + g_j + d_j)`` is lost. When the stream resumes the clock has shifted by a step
``c_j ~ N(0, step_std_s^2)`` that stays (a one-off step, unlike the re-syncs' sawtooth):

    tau(t) = offset_s + 1e-6 * drift_ppm * (t - t_sync(t)) + sum_j c_j [t >= t0 + g_j + d_j].

**Host reception stamps** (``host_delay_max_s > 0``): the samples are stamped by a host when they
arrive, ``a_k = s_k + u_k``, ``u_k ~ U(0, host_delay_max_s)`` (``s_k`` the clock's stamp below, before
rounding), and no two arrivals closer than ``m = host_min_spacing_s`` (a sample's transfer time):

    r_k = max(a_k, r_{k-1} + m) = k m + max_{j <= k} (a_j - j m).

At a rate ``1 / T`` with ``m <= T - host_delay_max_s`` the floor never binds: the spacing is
``T + u_k - u_{k-1}``, triangular on ``[T - D, T + D]`` (``D = host_delay_max_s``; the recordings of
a consumer IMU read over USB by a PC: 100 Hz, spacing 2.5-17.5 ms), mean ``T``, variance ``D^2 / 6``,
lag-1 correlation ``-1/2``. The mean delay ``D / 2`` is part of the unit's constant offset
(:attr:`UnitClock.delay_mean_s`).

Stamps (:func:`stamp_samples`): ``s_k = t + latency + tau(t) + e``, ``e ~ N(0, jitter_s^2)``, then the
host reception (when on), then rounded to ``stamp_quantum_s`` (0 = off). ``latency`` is the IMU
model's constant delay (:attr:`skincal.skin.imu.ImuModel.latency_s`); it adds to the clock's offset.
A sample whose stamp does not increase over the previous kept one is dropped, so stamps stay
strictly increasing.

This is the *simulated* sensor clock; :mod:`skincal.hw.clock` estimates a real device clock from
receive times.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace

import numpy as np
from numpy.typing import ArrayLike

from skincal.errors import ConfigError
from skincal.kinematics.transforms import FloatArray


def _number(owner: str, name: str, value: object) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = math.nan
    if math.isnan(number):
        raise ConfigError(f"{owner}.{name} must be a number in SI units, got {value!r}")
    return number


@dataclass(frozen=True)
class ClockModel:
    """Clock error model of one unit type (drawn per unit by :func:`draw_clock`); SI units.

    Attributes:
        offset_max_s: constant offset, drawn ``offset_mean_s + U(-offset_max_s, +offset_max_s)`` per unit, s.
        drift_ppm_mean: mean drift rate, ppm (``< 0``: the sensor clock runs slow).
        drift_ppm_std: per-unit drift spread, ``N(drift_ppm_mean, drift_ppm_std^2)``, ppm.
        resync_period_s: period ``P`` of the re-syncs that reset the error to the offset, s
            (``inf``: never re-synced, free running).
        jitter_s: std of the Gaussian jitter of every stamp, s.
        stamp_quantum_s: stamps are rounded to multiples of this, s (0 = no rounding).
        offset_mean_s: mean of the constant offset (a host clock lagging the robot's), s; may be negative.
        host_delay_max_s: host reception delay ``U(0, host_delay_max_s)`` per sample, s (0 = off).
        host_min_spacing_s: the host stamps no two samples closer than this, s.
        gap_rate_hz: mean number of gaps per second of session (0 = none).
        gap_min_s, gap_max_s: gap durations ``U(gap_min_s, gap_max_s)``, s.
        step_std_s: std of the clock step ``N(0, step_std_s^2)`` at the end of each gap, s.
    """

    offset_max_s: float = 0.0
    drift_ppm_mean: float = 0.0
    drift_ppm_std: float = 0.0
    resync_period_s: float = math.inf
    jitter_s: float = 0.0
    stamp_quantum_s: float = 0.0
    offset_mean_s: float = 0.0
    host_delay_max_s: float = 0.0
    host_min_spacing_s: float = 0.0
    gap_rate_hz: float = 0.0
    gap_min_s: float = 0.0
    gap_max_s: float = 0.0
    step_std_s: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            number = _number("ClockModel", f.name, getattr(self, f.name))
            object.__setattr__(self, f.name, number)
            if f.name == "resync_period_s":
                if not number > 0:
                    raise ConfigError(f"ClockModel.resync_period_s must be positive (s; inf = never), got {number}")
            elif not math.isfinite(number):
                raise ConfigError(f"ClockModel.{f.name} must be finite, got {number}")
            elif f.name not in ("drift_ppm_mean", "offset_mean_s") and number < 0:
                raise ConfigError(f"ClockModel.{f.name} must be non-negative, got {number}")
        if self.gap_min_s > self.gap_max_s:
            raise ConfigError(
                f"ClockModel.gap_min_s must not exceed gap_max_s, got {self.gap_min_s} > {self.gap_max_s}"
            )
        if abs(self.drift_ppm_mean) >= 1e5:
            raise ConfigError(
                f"ClockModel.drift_ppm_mean must be a clock drift (|ppm| < 1e5), got {self.drift_ppm_mean}"
            )

    @property
    def is_ideal(self) -> bool:
        """True when stamps are exactly the physical instants plus the IMU latency."""
        return (
            self.offset_max_s == 0
            and self.drift_ppm_mean == 0
            and self.drift_ppm_std == 0
            and self.jitter_s == 0
            and self.stamp_quantum_s == 0
            and self.offset_mean_s == 0
            and self.host_delay_max_s == 0
            and self.host_min_spacing_s == 0
            and (self.gap_rate_hz == 0 or self.gap_max_s == 0 and self.step_std_s == 0)
        )


_HOST = ClockModel(
    offset_mean_s=0.085, offset_max_s=0.01, host_delay_max_s=7.5e-3, host_min_spacing_s=2.5e-3, stamp_quantum_s=1e-6
)
"""A consumer IMU read by a PC that stamps each sample when it arrives, like the robot's reports (one
host clock, so no drift): the IMU lags the robot by 80-100 ms (offset 85 +- 10 ms plus the mean
reception delay 3.75 ms); reception delays U(0, 7.5 ms) at 100 Hz give a spacing of 2.5-17.5 ms;
no two stamps closer than 2.5 ms (the transfer time of one sample); microsecond stamps. The figures
of an ABB robot's tool-IMU recordings (robot reports and IMU samples stamped by one PC)."""

CLOCK_PRESETS: dict[str, ClockModel] = {
    # Stamps are the physical instants (plus the IMU latency): the behaviour before clock models.
    "ideal": ClockModel(),
    # The driver of the public two-IMU recording: host-synchronised clock running ~440 ppm slow,
    # re-synced every 2.51 s (forward stamp steps of 0.15-2.4 ms), microsecond stamps.
    "driver": ClockModel(drift_ppm_mean=-440.0, drift_ppm_std=50.0, resync_period_s=2.51, stamp_quantum_s=1e-6),
    # A wireless unit never synchronised to the robot: up to +-0.5 s apart, free-running crystal
    # (100 ppm std), 1 ms stamp jitter.
    "wifi": ClockModel(offset_max_s=0.5, drift_ppm_std=100.0, jitter_s=1e-3, stamp_quantum_s=1e-6),
    # The same offset, with the driver's slow clock and periodic re-sync.
    "wifi-resync": ClockModel(
        offset_max_s=0.5, drift_ppm_mean=-440.0, drift_ppm_std=100.0, resync_period_s=2.51, stamp_quantum_s=1e-6
    ),
    # A consumer IMU read by a PC that stamps each sample when it arrives (module docstring).
    "host": _HOST,
    # ``host`` with the stream stopping now and then (one gap per 30 s on average, 0.3-0.7 s long),
    # after which the clock has stepped by N(0, (20 ms)^2).
    "host-gaps": replace(_HOST, gap_rate_hz=1.0 / 30.0, gap_min_s=0.3, gap_max_s=0.7, step_std_s=0.02),
}
"""Clock presets by name: ``ideal``, ``driver``, ``wifi``, ``wifi-resync``, ``host``, ``host-gaps``."""


def get_clock_model(name: str) -> ClockModel:
    """The preset ``name``; an unknown name raises :class:`ConfigError` listing the known ones."""
    try:
        return CLOCK_PRESETS[name]
    except KeyError:
        raise ConfigError(f"unknown clock model '{name}'; known: {', '.join(CLOCK_PRESETS)}") from None


@dataclass(frozen=True)
class UnitClock:
    """One unit's drawn clock (:func:`draw_clock`).

    Attributes:
        offset_s: stamp error right after a re-sync (at the session start when never re-synced), s.
        drift_ppm: rate error, ppm: the error grows by ``1e-6 drift_ppm`` s per second since the sync.
        resync_period_s: re-sync period ``P``, s (``inf``: never).
        resync_phase_s: first re-sync instant after the session start, ``t0 + phase``, ``phase``
            in ``[0, P)``, s (0 when never re-synced).
        gaps: ``(G, 3)`` per gap ``(g_j, d_j, c_j)``: its start after the session start, its
            duration and the clock step when it ends, s (sorted by start; ``(0, 3)``: none).
        delay_mean_s: the host's mean reception delay ``host_delay_max_s / 2``, s (0: no host stamps).
    """

    offset_s: float = 0.0
    drift_ppm: float = 0.0
    resync_period_s: float = math.inf
    resync_phase_s: float = 0.0
    gaps: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    delay_mean_s: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name == "gaps":
                continue
            object.__setattr__(self, f.name, _number("UnitClock", f.name, getattr(self, f.name)))
        gaps = np.array(self.gaps, dtype=float).reshape(-1, 3) if np.size(self.gaps) else np.zeros((0, 3))
        if not np.all(np.isfinite(gaps)) or np.any(gaps[:, :2] < 0) or np.any(np.diff(gaps[:, 0]) < 0):
            raise ConfigError("UnitClock.gaps must be finite (G, 3) rows (start >= 0 sorted, duration >= 0, step)")
        gaps.setflags(write=False)
        object.__setattr__(self, "gaps", gaps)
        if not (math.isfinite(self.offset_s) and math.isfinite(self.drift_ppm)):
            raise ConfigError(f"UnitClock offset_s and drift_ppm must be finite, got {self.offset_s}, {self.drift_ppm}")
        if not self.resync_period_s > 0:
            raise ConfigError(
                f"UnitClock.resync_period_s must be positive (s; inf = never), got {self.resync_period_s}"
            )
        if not (0 <= self.resync_phase_s < self.resync_period_s) or not math.isfinite(self.resync_phase_s):
            raise ConfigError(f"UnitClock.resync_phase_s must be in [0, resync_period_s), got {self.resync_phase_s}")

    def sync_instants(self, t: ArrayLike, t0: float = 0.0) -> FloatArray:
        """``t_sync(t)``: the latest re-sync at or before each physical instant ``t`` ``(M,)`` s (``t0`` when never)."""
        t = np.asarray(t, dtype=float)
        P = self.resync_period_s
        if math.isinf(P):
            return np.full_like(t, t0)
        start = t0 + self.resync_phase_s
        return start + P * np.floor((t - start) / P)

    def error(self, t: ArrayLike, t0: float = 0.0) -> FloatArray:
        """Stamp error ``tau(t) = offset_s + 1e-6 drift_ppm (t - t_sync(t)) + sum_j c_j [t >= t0 + g_j + d_j]``
        ``(M,)`` s at physical instants ``t`` (the host reception delay is not in it)."""
        t = np.asarray(t, dtype=float)
        tau = self.offset_s + 1e-6 * self.drift_ppm * (t - self.sync_instants(t, t0))
        for g, d, c in self.gaps:
            tau = tau + c * (t >= t0 + g + d)
        return tau

    def in_gap(self, t: ArrayLike, t0: float = 0.0) -> np.ndarray:
        """``(M,)`` bool: the physical instant lies inside a gap ``[t0 + g_j, t0 + g_j + d_j)`` (sample lost)."""
        t = np.asarray(t, dtype=float)
        out = np.zeros(t.shape, dtype=bool)
        for g, d, _ in self.gaps:
            out |= (t >= t0 + g) & (t < t0 + g + d)
        return out


def draw_clock(model: ClockModel, rng: np.random.Generator, duration_s: float = 0.0) -> UnitClock:
    """Draw one unit's clock: offset ``offset_mean_s + U(-max, max)``, drift ``N(mean, std^2)``, re-sync
    phase ``U(0, P)``, then (only when ``gap_rate_hz > 0``, so that the other presets' draws are
    unchanged) the gaps over a session of ``duration_s`` s: a Poisson count, starts, durations and
    steps as the module docstring says."""
    offset = model.offset_mean_s + rng.uniform(-model.offset_max_s, model.offset_max_s)
    drift = model.drift_ppm_mean + model.drift_ppm_std * rng.standard_normal()
    P = model.resync_period_s
    phase = min(rng.uniform(0.0, P), math.nextafter(P, 0.0)) if math.isfinite(P) else 0.0
    gaps = np.zeros((0, 3))
    if model.gap_rate_hz > 0 and duration_s > 0:
        n = int(rng.poisson(model.gap_rate_hz * duration_s))
        start = np.sort(rng.uniform(0.0, duration_s, n))
        length = rng.uniform(model.gap_min_s, model.gap_max_s, n)
        step = rng.normal(0.0, model.step_std_s, n) if model.step_std_s > 0 else np.zeros(n)
        gaps = np.column_stack([start, length, step])
    return UnitClock(offset, drift, P, phase, gaps, 0.5 * model.host_delay_max_s)


def host_reception(a: ArrayLike, min_spacing_s: float) -> FloatArray:
    """Host stamps of arrivals ``a`` ``(M,)`` s no two closer than ``m``:
    ``r_k = max(a_k, r_{k-1} + m) = k m + max_{j <= k} (a_j - j m)``."""
    a = np.asarray(a, dtype=np.float64)
    k = np.arange(a.size, dtype=np.float64) * float(min_spacing_s)
    out: FloatArray = k + np.maximum.accumulate(a - k) if a.size else a
    return out


def increasing_mask(t: ArrayLike) -> np.ndarray:
    """``(M,)`` bool: keep sample ``k`` iff its stamp exceeds every earlier one (a sample whose stamp
    does not increase over the last kept stamp is dropped; the kept stamps are strictly increasing)."""
    t = np.asarray(t, dtype=float)
    if t.size == 0:
        return np.ones(0, dtype=bool)
    previous = np.maximum.accumulate(np.concatenate(([-np.inf], t[:-1])))
    return t > previous


def stamp_samples(
    model: ClockModel,
    clock: UnitClock,
    t_nominal: ArrayLike,
    t_true: ArrayLike,
    t0: float,
    rng: np.random.Generator | None = None,
) -> tuple[FloatArray, np.ndarray]:
    """Stamps of samples taken at physical instants ``t_true`` by a unit on ``clock``.

    ``t_stamp = t_nominal + tau(t_true) + e``, ``e ~ N(0, jitter_s^2)``, then the host reception
    (:func:`host_reception` of ``t_stamp + U(0, host_delay_max_s)``) when on, rounded to
    ``stamp_quantum_s``; ``t_nominal = t_true + latency`` are the stamps of a perfect clock (passed in
    rather than recomputed so that the ideal clock returns them unchanged, bit for bit). Samples
    measured inside one of the clock's gaps are lost (``keep`` is False for them).

    Args:
        model: the clock type (jitter, quantum).
        clock: this unit's drawn clock.
        t_nominal: ``(M,)`` stamps on a perfect clock, s.
        t_true: ``(M,)`` physical instants of the samples, s.
        t0: session start (the clock's reference for re-syncs), s.
        rng: random generator; required when ``jitter_s > 0``.

    Returns:
        ``(t_stamp (K,) s strictly increasing, keep (M,) bool)``: ``keep`` selects the samples kept.
    """
    t_nominal = np.asarray(t_nominal, dtype=float)
    t_true = np.asarray(t_true, dtype=float)
    if t_nominal.shape != t_true.shape or t_nominal.ndim != 1:
        raise ConfigError(
            f"stamp_samples: t_nominal and t_true must be (M,) arrays, got {t_nominal.shape}, {t_true.shape}"
        )
    stamps = t_nominal + clock.error(t_true, t0)
    if rng is None and (model.jitter_s > 0 or model.host_delay_max_s > 0):
        raise ConfigError("stamp_samples needs an rng: the clock model has jitter or host reception delays")
    if model.jitter_s > 0:
        stamps = stamps + rng.normal(0.0, model.jitter_s, stamps.shape)  # type: ignore[union-attr]
    received = ~clock.in_gap(t_true, t0) if clock.gaps.size else np.ones(stamps.shape, dtype=bool)
    if model.host_delay_max_s > 0 or model.host_min_spacing_s > 0:
        delay = rng.uniform(0.0, model.host_delay_max_s, stamps.shape)  # type: ignore[union-attr]
        stamps = stamps.copy()
        stamps[received] = host_reception(stamps[received] + delay[received], model.host_min_spacing_s)
    if model.stamp_quantum_s > 0:
        stamps = np.round(stamps / model.stamp_quantum_s) * model.stamp_quantum_s
    keep = received.copy()
    keep[received] = increasing_mask(stamps[received])
    return stamps[keep], keep
