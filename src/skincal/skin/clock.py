"""The time stamps of a skin unit's own clock: offset, drift, periodic re-sync, jitter, quantum.

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

Stamps (:func:`stamp_samples`): ``t_stamp = t + latency + tau(t) + e``, ``e ~ N(0, jitter_s^2)``,
then rounded to ``stamp_quantum_s`` (0 = off). ``latency`` is the IMU model's constant delay
(:attr:`skincal.skin.imu.ImuModel.latency_s`); it adds to the clock's offset. A sample whose stamp
does not increase over the previous kept one is dropped, so stamps stay strictly increasing.

This is the *simulated* sensor clock; :mod:`skincal.hw.clock` estimates a real device clock from
receive times.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

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
        offset_max_s: constant offset, drawn ``U(-offset_max_s, +offset_max_s)`` per unit, s.
        drift_ppm_mean: mean drift rate, ppm (``< 0``: the sensor clock runs slow).
        drift_ppm_std: per-unit drift spread, ``N(drift_ppm_mean, drift_ppm_std^2)``, ppm.
        resync_period_s: period ``P`` of the re-syncs that reset the error to the offset, s
            (``inf``: never re-synced, free running).
        jitter_s: std of the Gaussian jitter of every stamp, s.
        stamp_quantum_s: stamps are rounded to multiples of this, s (0 = no rounding).
    """

    offset_max_s: float = 0.0
    drift_ppm_mean: float = 0.0
    drift_ppm_std: float = 0.0
    resync_period_s: float = math.inf
    jitter_s: float = 0.0
    stamp_quantum_s: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            number = _number("ClockModel", f.name, getattr(self, f.name))
            object.__setattr__(self, f.name, number)
            if f.name == "resync_period_s":
                if not number > 0:
                    raise ConfigError(f"ClockModel.resync_period_s must be positive (s; inf = never), got {number}")
            elif not math.isfinite(number):
                raise ConfigError(f"ClockModel.{f.name} must be finite, got {number}")
            elif f.name != "drift_ppm_mean" and number < 0:
                raise ConfigError(f"ClockModel.{f.name} must be non-negative, got {number}")
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
        )


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
}
"""Clock presets by name: ``ideal``, ``driver``, ``wifi``, ``wifi-resync``."""


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
    """

    offset_s: float = 0.0
    drift_ppm: float = 0.0
    resync_period_s: float = math.inf
    resync_phase_s: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            object.__setattr__(self, f.name, _number("UnitClock", f.name, getattr(self, f.name)))
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
        """Stamp error ``tau(t) = offset_s + 1e-6 drift_ppm (t - t_sync(t))`` ``(M,)`` s at physical instants ``t``."""
        t = np.asarray(t, dtype=float)
        return self.offset_s + 1e-6 * self.drift_ppm * (t - self.sync_instants(t, t0))


def draw_clock(model: ClockModel, rng: np.random.Generator) -> UnitClock:
    """Draw one unit's clock: offset ``U(-max, max)``, drift ``N(mean, std^2)``, re-sync phase ``U(0, P)``."""
    offset = rng.uniform(-model.offset_max_s, model.offset_max_s)
    drift = model.drift_ppm_mean + model.drift_ppm_std * rng.standard_normal()
    P = model.resync_period_s
    phase = min(rng.uniform(0.0, P), math.nextafter(P, 0.0)) if math.isfinite(P) else 0.0
    return UnitClock(offset, drift, P, phase)


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

    ``t_stamp = t_nominal + tau(t_true) + e``, ``e ~ N(0, jitter_s^2)``, rounded to
    ``stamp_quantum_s``; ``t_nominal = t_true + latency`` are the stamps of a perfect clock (passed in
    rather than recomputed so that the ideal clock returns them unchanged, bit for bit).

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
    if model.jitter_s > 0:
        if rng is None:
            raise ConfigError("stamp_samples needs an rng: the clock model has jitter")
        stamps = stamps + rng.normal(0.0, model.jitter_s, stamps.shape)
    if model.stamp_quantum_s > 0:
        stamps = np.round(stamps / model.stamp_quantum_s) * model.stamp_quantum_s
    keep = increasing_mask(stamps)
    return stamps[keep], keep
