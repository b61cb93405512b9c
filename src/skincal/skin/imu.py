"""Accelerometer and gyroscope model of a skin unit (LSM6DS3 class IMU).

Physics (``docs/design.md``): an accelerometer fixed in the SU frame measures the specific force

    f_su = R_base_su^T (a_base - g_base),   g_base = GRAVITY_BASE = [0, 0, -9.81] m/s^2,

so at rest it reads ``R_base_su^T [0, 0, 9.81]`` (about +9.81 along the up direction). A gyroscope
measures the angular rate in its own frame, ``w_su = R_base_su^T w_base``.

Measurement model (:func:`apply_imu_model`), per sample, SI units throughout:

    a_m = D_s M f_su + b_a + n_a,   D_s = diag(1 + s),  M = I + S (S symmetric, zero diagonal)
    w_m = D_g M_g w_su + b_g + n_g, D_g = diag(1 + s_g), M_g = I + S_g (S_g zero diagonal, general)

then quantisation to the LSB and saturation at the full-scale range. ``n_a, n_g`` are white,
Gaussian, independent per axis with std = noise density * sqrt(bandwidth). Only a *symmetric*
misalignment is modelled: the unit frame is defined by the accelerometer axes (polar factor), so
an antisymmetric part would be indistinguishable from the unit's orientation (a small rotation
``R (I + [phi]x)`` and a skew misalignment ``I + [phi]x`` give the same readings). The gyroscope's
misalignment ``S_g`` is relative to those accelerometer axes, so all six off-diagonal entries are
its own (a small rotation of the gyroscope die against the accelerometer's is its antisymmetric
part); to first order a rate ``w`` reads ``w + diag(s_g) w + S_g w``.

Timing: :func:`sample_instants` gives the unit's own time stamps (nominal ``k / rate_hz`` with a
random phase, Gaussian jitter and random drops). The sample stamped ``t`` measures the physical
quantity at ``t - latency_s`` (:func:`true_sample_times`); the caller evaluates ``f_true`` there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
from numpy.typing import ArrayLike

from skincal.errors import ConfigError
from skincal.kinematics.chain import GRAVITY_BASE
from skincal.kinematics.transforms import FloatArray

STANDARD_GRAVITY = 9.80665
"""One ``g``, m/s^2: the one definition, converting datasheet units (mg, µg/√Hz) and accelerometers
that report in g (:mod:`skincal.data.ros`); the simulated gravity is ``GRAVITY_BASE``."""

_MG = 1e-3 * STANDARD_GRAVITY
_DPS = math.pi / 180.0


def _as_rotations(R_base_su: ArrayLike, m: int) -> FloatArray:
    R = np.asarray(R_base_su, dtype=float)
    if R.shape == (3, 3):
        return np.broadcast_to(R, (m, 3, 3))
    if R.shape != (m, 3, 3):
        raise ConfigError(f"R_base_su must have shape (3, 3) or ({m}, 3, 3), got {R.shape}")
    return R


def _as_vectors(x: ArrayLike, name: str) -> FloatArray:
    v = np.asarray(x, dtype=float)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ConfigError(f"{name} must have shape (M, 3), got {v.shape}")
    return v


def specific_force(a_base: ArrayLike, R_base_su: ArrayLike, gravity: ArrayLike = GRAVITY_BASE) -> FloatArray:
    """Specific force in the SU frame, ``f_su = R_base_su^T (a_base - g_base)``.

    Args:
        a_base: ``(M, 3)`` acceleration of the SU origin in the base frame, m/s^2.
        R_base_su: ``(M, 3, 3)`` or ``(3, 3)`` SU orientation in the base frame.
        gravity: ``(3,)`` gravitational acceleration in the base frame, m/s^2.

    Returns:
        ``(M, 3)`` specific force in the SU frame, m/s^2 (at rest: ``R^T [0, 0, 9.81]``).
    """
    a = _as_vectors(a_base, "a_base")
    R = _as_rotations(R_base_su, a.shape[0])
    g = np.asarray(gravity, dtype=float)
    if g.shape != (3,):
        raise ConfigError(f"gravity must have shape (3,) in m/s^2, got {g.shape}")
    return np.einsum("mji,mj->mi", R, a - g)


def angular_rate(omega_base: ArrayLike, R_base_su: ArrayLike) -> FloatArray:
    """Angular rate in the SU frame, ``w_su = R_base_su^T w_base``; ``(M, 3)`` in, ``(M, 3)`` out, rad/s."""
    w = _as_vectors(omega_base, "omega_base")
    R = _as_rotations(R_base_su, w.shape[0])
    return np.einsum("mji,mj->mi", R, w)


@dataclass(frozen=True)
class ImuModel:
    """Error and timing model of one IMU type; every field in SI units.

    A value of 0 switches an effect off; ``accel_range``/``gyro_range`` of ``inf`` mean no
    saturation and ``accel_lsb``/``gyro_lsb`` of 0 no quantisation.

    Attributes:
        rate_hz: nominal output data rate, Hz.
        accel_noise_density: accelerometer white-noise density, m/s^2/sqrt(Hz).
        gyro_noise_density: gyroscope white-noise density, rad/s/sqrt(Hz).
        bandwidth_hz: noise bandwidth, Hz; white-noise std per sample = density * sqrt(bandwidth).
        accel_bias_std: per-unit constant accelerometer bias, drawn ``N(0, std^2)`` per axis, m/s^2
            (a datasheet "typical ±" value is used as one standard deviation).
        accel_scale_std: per-axis scale factor ``1 + s``, ``s ~ N(0, std^2)``, dimensionless.
        misalignment_std: off-diagonal entries of the symmetric ``S`` in ``M = I + S``,
            ``S_ij = S_ji ~ N(0, std^2)``, rad (small-angle).
        gyro_bias_std: per-unit constant gyroscope bias, ``N(0, std^2)`` per axis, rad/s.
        gyro_scale_std: per-axis gyroscope scale ``1 + s_g``, ``s_g ~ N(0, std^2)``, dimensionless.
        gyro_misalignment_std: each of the six off-diagonal entries of ``S_g`` in ``M_g = I + S_g``,
            ``N(0, std^2)`` independently, rad (small-angle).
        accel_range: accelerometer full scale, output clipped to ``[-range, range]``, m/s^2.
        accel_lsb: accelerometer quantisation step, m/s^2.
        gyro_range: gyroscope full scale, rad/s.
        gyro_lsb: gyroscope quantisation step, rad/s.
        latency_s: constant delay, s: the sample stamped ``t`` measures the quantity at ``t - latency``.
        latency_std_s: per-unit spread of the delay, ``N(latency_s, std^2)``, s.
        jitter_s: std of the Gaussian jitter of each sample instant, s.
        drop_probability: probability that a sample is lost, in ``[0, 1)``.
    """

    rate_hz: float = 100.0
    accel_noise_density: float = 0.0
    gyro_noise_density: float = 0.0
    bandwidth_hz: float = 50.0
    accel_bias_std: float = 0.0
    accel_scale_std: float = 0.0
    misalignment_std: float = 0.0
    gyro_bias_std: float = 0.0
    accel_range: float = math.inf
    accel_lsb: float = 0.0
    gyro_range: float = math.inf
    gyro_lsb: float = 0.0
    latency_s: float = 0.0
    latency_std_s: float = 0.0
    jitter_s: float = 0.0
    drop_probability: float = 0.0
    gyro_scale_std: float = 0.0
    gyro_misalignment_std: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            try:
                number = float(value)
            except (TypeError, ValueError):
                number = math.nan
            if math.isnan(number) or number < 0:
                raise ConfigError(f"ImuModel.{f.name} must be a non-negative number in SI units, got {value!r}")
            object.__setattr__(self, f.name, number)
        if not (0.0 < self.rate_hz < math.inf):
            raise ConfigError(f"ImuModel.rate_hz must be positive and finite (Hz), got {self.rate_hz}")
        if not (0.0 < self.bandwidth_hz < math.inf):
            raise ConfigError(f"ImuModel.bandwidth_hz must be positive and finite (Hz), got {self.bandwidth_hz}")
        if self.drop_probability >= 1.0:
            raise ConfigError(f"ImuModel.drop_probability must be in [0, 1), got {self.drop_probability}")
        if self.accel_range == 0.0 or self.gyro_range == 0.0:
            raise ConfigError("ImuModel.accel_range and gyro_range must be positive (use inf for no saturation)")

    @property
    def accel_noise_std(self) -> float:
        """Per-sample accelerometer white-noise std, m/s^2."""
        return self.accel_noise_density * math.sqrt(self.bandwidth_hz)

    @property
    def gyro_noise_std(self) -> float:
        """Per-sample gyroscope white-noise std, rad/s."""
        return self.gyro_noise_density * math.sqrt(self.bandwidth_hz)


_DATASHEET = ImuModel(
    rate_hz=100.0,
    accel_noise_density=90e-6 * STANDARD_GRAVITY,
    gyro_noise_density=7e-3 * _DPS,
    bandwidth_hz=50.0,
    accel_range=2.0 * STANDARD_GRAVITY,
    accel_lsb=0.061 * _MG,
    gyro_range=245.0 * _DPS,
    gyro_lsb=8.75e-3 * _DPS,
)

IMU_PRESETS: dict[str, ImuModel] = {
    # Ideal sensor: exact specific force and rate at the nominal instants.
    "none": ImuModel(rate_hz=100.0),
    # LSM6DS3 datasheet: 90 µg/√Hz, 7 mdps/√Hz, ±2 g at 0.061 mg/LSB, ±245 dps at 8.75 mdps/LSB.
    "datasheet": _DATASHEET,
    # Uncalibrated hardware: 5x noise, typical zero-g offset ±40 mg and zero-rate level ±10 dps,
    # ±1 % sensitivity, 0.5 % cross-axis, 15 ms transport delay, 1 ms jitter, 1 % lost packets.
    "realistic": ImuModel(
        rate_hz=100.0,
        accel_noise_density=5 * _DATASHEET.accel_noise_density,
        gyro_noise_density=5 * _DATASHEET.gyro_noise_density,
        bandwidth_hz=50.0,
        accel_bias_std=40.0 * _MG,
        accel_scale_std=0.01,
        misalignment_std=0.005,
        gyro_bias_std=10.0 * _DPS,
        accel_range=_DATASHEET.accel_range,
        accel_lsb=_DATASHEET.accel_lsb,
        gyro_range=_DATASHEET.gyro_range,
        gyro_lsb=_DATASHEET.gyro_lsb,
        latency_s=0.015,
        jitter_s=0.001,
        drop_probability=0.01,
    ),
    # From figures measured on a public recording of two real 6-axis IMUs (uncalibrated boards);
    # values marked "chosen" were set by hand to match those figures, or are not in them.
    "real": ImuModel(
        # Measured: the recording's output data rate, 62.5 Hz; noise bandwidth = its Nyquist frequency.
        rate_hz=62.5,
        bandwidth_hz=31.25,
        # Measured: white-noise densities, 0.014 m/s^2/sqrt(Hz) and 2.0e-3 rad/s/sqrt(Hz).
        accel_noise_density=0.014,
        gyro_noise_density=2.0e-3,
        # Measured: |f| at rest off by +7.2 % and +8.2 % on the two units, bias and scale together;
        # chosen: 0.35 m/s^2 bias and 3 % scale std per axis, which give errors of that size.
        accel_bias_std=0.35,
        accel_scale_std=0.03,
        # Chosen: 1 % cross-axis (twice ``realistic``'s).
        misalignment_std=0.01,
        # Measured: gyro bias up to 25 deg/s; chosen: 12 deg/s std per axis.
        gyro_bias_std=12.0 * _DPS,
        # The recording's configuration: +-8 g / +-2000 deg/s at 16 bit, LSB = range / 2**15
        # (2.39e-3 m/s^2, 1.07e-3 rad/s).
        accel_range=8.0 * STANDARD_GRAVITY,
        accel_lsb=8.0 * STANDARD_GRAVITY / 2**15,
        gyro_range=2000.0 * _DPS,
        gyro_lsb=2000.0 * _DPS / 2**15,
        # Chosen: ``realistic``'s 15 ms transport delay and 1 % lost samples. The stamp errors of the
        # recording's driver clock are the clock preset ``driver`` (skincal.skin.clock), so no jitter.
        latency_s=0.015,
        drop_probability=0.01,
    ),
    # A consumer IMU board (MPU9150 / MPU6050 class) on an industrial robot's tool, read by a PC (the
    # stamps are the clock preset ``host`` / ``host-gaps``). Measured on those recordings: 100 Hz
    # steady rate, +-4 g at 16 bit (LSB 1.197e-3 m/s^2), +-2000 deg/s at 16 bit (LSB 1.064e-3
    # rad/s). Stated for those parts: scale errors of a few percent, gyroscope scale 3-6 % off.
    # Chosen: ``real``'s noise densities and biases, accelerometer scale 2 % std, gyroscope scale
    # 4.5 % std (|s_g| 3.6 % on average), 1 % cross-axis on both; no latency (the host clock
    # preset holds the lag) and no drops (its gaps hold the losses).
    "real-consumer": ImuModel(
        rate_hz=100.0,
        bandwidth_hz=50.0,
        accel_noise_density=0.014,
        gyro_noise_density=2.0e-3,
        accel_bias_std=0.35,
        accel_scale_std=0.02,
        misalignment_std=0.01,
        gyro_bias_std=12.0 * _DPS,
        gyro_scale_std=0.045,
        gyro_misalignment_std=0.01,
        accel_range=4.0 * STANDARD_GRAVITY,
        accel_lsb=4.0 * STANDARD_GRAVITY / 2**15,
        gyro_range=2000.0 * _DPS,
        gyro_lsb=2000.0 * _DPS / 2**15,
    ),
}
"""IMU presets by name: ``none``, ``datasheet``, ``realistic``, ``real``, ``real-consumer``."""


def get_imu_model(name: str) -> ImuModel:
    """The preset ``name``; an unknown name raises :class:`ConfigError` listing the known ones."""
    try:
        return IMU_PRESETS[name]
    except KeyError:
        raise ConfigError(f"unknown IMU model '{name}'; known: {', '.join(IMU_PRESETS)}") from None


@dataclass(frozen=True)
class ImuErrors:
    """The constant errors of one physical unit, drawn once per unit (:func:`draw_imu_errors`).

    Attributes:
        accel_bias: ``(3,)`` accelerometer bias ``b_a``, m/s^2, SU frame.
        accel_scale: ``(3,)`` per-axis scale ``1 + s``, dimensionless.
        accel_misalignment: ``(3, 3)`` ``M = I + S``, ``S`` symmetric with zero diagonal.
        gyro_bias: ``(3,)`` gyroscope bias ``b_g``, rad/s, SU frame.
        latency_s: delay between the physical instant and the time stamp, s.
        gyro_scale: ``(3,)`` gyroscope scale ``1 + s_g`` (``None``: ones).
        gyro_misalignment: ``(3, 3)`` ``M_g = I + S_g``, unit diagonal (``None``: identity).
    """

    accel_bias: FloatArray
    accel_scale: FloatArray
    accel_misalignment: FloatArray
    gyro_bias: FloatArray
    latency_s: float = 0.0
    gyro_scale: FloatArray | None = None
    gyro_misalignment: FloatArray | None = None

    def __post_init__(self) -> None:
        if self.gyro_scale is None:
            object.__setattr__(self, "gyro_scale", np.ones(3))
        if self.gyro_misalignment is None:
            object.__setattr__(self, "gyro_misalignment", np.eye(3))
        shapes = {
            "accel_bias": (3,), "accel_scale": (3,), "accel_misalignment": (3, 3), "gyro_bias": (3,),
            "gyro_scale": (3,), "gyro_misalignment": (3, 3),
        }  # fmt: skip
        for name, shape in shapes.items():
            arr = np.array(getattr(self, name), dtype=float)
            if arr.shape != shape or not np.all(np.isfinite(arr)):
                raise ConfigError(f"ImuErrors.{name} must be finite with shape {shape}, got {arr.shape}")
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        if not np.allclose(self.accel_misalignment, self.accel_misalignment.T, atol=1e-12):
            raise ConfigError("ImuErrors.accel_misalignment must be symmetric (M = I + S, S symmetric)")
        if not np.allclose(np.diag(self.gyro_misalignment), 1.0, atol=1e-12):
            raise ConfigError("ImuErrors.gyro_misalignment must have a unit diagonal (M_g = I + S_g)")
        object.__setattr__(self, "latency_s", float(self.latency_s))

    @classmethod
    def ideal(cls) -> ImuErrors:
        """No bias, unit scale, no misalignment, no delay."""
        return cls(np.zeros(3), np.ones(3), np.eye(3), np.zeros(3), 0.0)

    @property
    def accel_matrix(self) -> FloatArray:
        """``(3, 3)`` linear part ``D_s M`` of the accelerometer model."""
        return self.accel_scale[:, None] * self.accel_misalignment

    @property
    def gyro_matrix(self) -> FloatArray:
        """``(3, 3)`` linear part ``D_g M_g`` of the gyroscope model."""
        assert self.gyro_scale is not None and self.gyro_misalignment is not None
        return self.gyro_scale[:, None] * self.gyro_misalignment

    @property
    def gyro_is_ideal(self) -> bool:
        """True when ``D_g M_g`` is the identity (no gyroscope scale or misalignment)."""
        return bool(np.array_equal(self.gyro_matrix, np.eye(3)))

    def gyro_truth(self) -> dict[str, FloatArray]:
        """``{"gyro_scale", "gyro_misalignment"}`` for a dataset's truth, empty when ideal (so that
        the truth of IMU models without them is unchanged)."""
        if self.gyro_is_ideal:
            return {}
        assert self.gyro_scale is not None and self.gyro_misalignment is not None
        return {"gyro_scale": np.array(self.gyro_scale), "gyro_misalignment": np.array(self.gyro_misalignment)}


def draw_imu_errors(model: ImuModel, rng: np.random.Generator) -> ImuErrors:
    """Draw one unit's constant errors: Gaussian bias, scale, symmetric misalignment and delay, then
    (only when the model has them, so that the other presets' draws are unchanged) the gyroscope
    scale ``1 + N(0, gyro_scale_std^2)`` per axis and misalignment ``I + S_g``, off-diagonal
    ``N(0, gyro_misalignment_std^2)``."""
    bias = rng.normal(0.0, model.accel_bias_std, 3)
    scale = 1.0 + rng.normal(0.0, model.accel_scale_std, 3)
    upper = np.triu(rng.normal(0.0, model.misalignment_std, (3, 3)), k=1)
    gyro_bias = rng.normal(0.0, model.gyro_bias_std, 3)
    latency = model.latency_s + (rng.normal(0.0, model.latency_std_s) if model.latency_std_s > 0 else 0.0)
    gyro_scale, gyro_mis = np.ones(3), np.eye(3)
    if model.gyro_scale_std > 0 or model.gyro_misalignment_std > 0:
        gyro_scale = 1.0 + rng.normal(0.0, model.gyro_scale_std, 3)
        off = rng.normal(0.0, model.gyro_misalignment_std, (3, 3))
        np.fill_diagonal(off, 0.0)
        gyro_mis = np.eye(3) + off
    return ImuErrors(bias, scale, np.eye(3) + upper + upper.T, gyro_bias, latency, gyro_scale, gyro_mis)


def sample_instants(model: ImuModel, t_start: float, t_end: float, rng: np.random.Generator) -> FloatArray:
    """The unit's time stamps in ``[t_start, t_end]``, s, ``(M,)`` sorted and strictly increasing.

    ``t_k = t_start + phi + k / rate_hz + e_k`` with a phase ``phi ~ U(0, 1 / rate_hz)`` (units are
    not synchronised with each other), jitter ``e_k ~ N(0, jitter_s^2)``; each sample is then kept
    with probability ``1 - drop_probability``. Instants jittered outside the interval are dropped.
    """
    if not (math.isfinite(t_start) and math.isfinite(t_end)) or t_end < t_start:
        raise ConfigError(f"sample_instants needs finite t_start <= t_end (s), got {t_start}, {t_end}")
    period = 1.0 / model.rate_hz
    phase = rng.uniform(0.0, period)
    n = int(math.floor((t_end - t_start - phase) / period)) + 1
    t = t_start + phase + period * np.arange(max(n, 0))
    if model.jitter_s > 0:
        t = t + rng.normal(0.0, model.jitter_s, t.shape)
    if model.drop_probability > 0:
        t = t[rng.random(t.shape) >= model.drop_probability]
    t = t[(t >= t_start) & (t <= t_end)]
    return np.unique(t)


def true_sample_times(t_stamp: ArrayLike, errors: ImuErrors) -> FloatArray:
    """Physical instants of stamped samples: ``t_true = t_stamp - latency_s``, s."""
    return np.asarray(t_stamp, dtype=float) - errors.latency_s


def _digitise(x: FloatArray, lsb: float, full_scale: float) -> FloatArray:
    """Round to the LSB and clip to the full scale (clipping to whole LSB counts when quantised)."""
    if lsb > 0:
        counts = np.round(x / lsb)
        if math.isfinite(full_scale):
            limit = math.floor(full_scale / lsb)
            counts = np.clip(counts, -limit, limit)
        return counts * lsb
    if math.isfinite(full_scale):
        return np.clip(x, -full_scale, full_scale)
    return x


def apply_imu_model(
    model: ImuModel,
    errors: ImuErrors,
    f_true: ArrayLike,
    w_true: ArrayLike | None = None,
    rng: np.random.Generator | None = None,
) -> tuple[FloatArray, FloatArray | None]:
    """Turn true specific force and angular rate into IMU readings.

    In this order, per sample (all in the SU frame):

    1. ``a = diag(accel_scale) @ accel_misalignment @ f_true + accel_bias + n_a`` and
       ``w = diag(gyro_scale) @ gyro_misalignment @ w_true + gyro_bias + n_g``, noise std =
       density * sqrt(bandwidth);
    2. quantisation: ``round(x / lsb) * lsb`` (skipped when the LSB is 0);
    3. saturation: clip to ``[-range, range]`` (to whole LSB counts when quantised).

    ``f_true``/``w_true`` must already be evaluated at the physical instants
    ``true_sample_times(t_stamp, errors)``; this function does no resampling.

    Args:
        model: sensor type (noise, LSB, range).
        errors: this unit's constant errors.
        f_true: ``(M, 3)`` specific force, m/s^2.
        w_true: ``(M, 3)`` angular rate, rad/s, or ``None`` for an accelerometer only.
        rng: random generator; required when the model has noise.

    Returns:
        ``(accel (M, 3) m/s^2, gyro (M, 3) rad/s or None)``.
    """
    f = _as_vectors(f_true, "f_true")
    if rng is None and (model.accel_noise_std > 0 or (w_true is not None and model.gyro_noise_std > 0)):
        raise ConfigError("apply_imu_model needs an rng: the IMU model has noise")
    accel = f @ errors.accel_matrix.T + errors.accel_bias
    if model.accel_noise_std > 0 and rng is not None:
        accel = accel + rng.normal(0.0, model.accel_noise_std, accel.shape)
    accel = _digitise(accel, model.accel_lsb, model.accel_range)
    if w_true is None:
        return accel, None
    w = _as_vectors(w_true, "w_true")
    if w.shape != f.shape:
        raise ConfigError(f"w_true must have the shape of f_true {f.shape}, got {w.shape}")
    gyro = (w if errors.gyro_is_ideal else w @ errors.gyro_matrix.T) + errors.gyro_bias
    if model.gyro_noise_std > 0 and rng is not None:
        gyro = gyro + rng.normal(0.0, model.gyro_noise_std, gyro.shape)
    return accel, _digitise(gyro, model.gyro_lsb, model.gyro_range)
