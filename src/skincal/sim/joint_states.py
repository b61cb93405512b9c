"""Joint states as robot hardware reports them: stream rate, encoder steps, velocity noise, latency.

The simulators know the true joint motion at any instant (``motion(t) -> q, qd, qdd``: the
trajectory's closed form, or the MuJoCo dynamic run interpolated). :func:`apply_joint_state_model`
turns it into the stream a robot controller publishes:

1. sample instants: the trajectory's own samples (``rate_hz = None``) or ``t0 + k / rate_hz`` over
   ``[t0, t1]``; with ``interval_std_s > 0`` the report instants are a renewal process instead,
   ``t_k = t_{k-1} + T_k``, ``T_k = max(1 / rate_hz + interval_std_s z_k, 0.2 / rate_hz)``,
   ``z_k ~ N(0, 1)`` (a controller that reports when its cycle allows, not on a fixed grid);
2. the sample of nominal instant ``t_k`` measures the robot at ``t_k - latency_s``:
   ``q, qd, qdd = motion(t_k - latency_s)``;
3. encoder: ``q = round(q / r) r`` with ``r = encoder_resolution_rad`` (0 = exact);
4. velocity: either the true ``qd + n``, ``n ~ N(0, velocity_noise_std^2)`` white per joint and
   sample, or (``velocity_from_positions``) the backward difference of the quantised positions,
   ``qd_k = (q_k - q_{k-1}) / (t_k - t_{k-1})`` (``qd_0 = qd_1``), as many drivers compute it;
5. stamps ``t_k + e_k``, ``e_k ~ N(0, jitter_s^2)``; a sample whose stamp does not increase over
   the previous kept one is dropped; each report is lost with probability ``drop_probability``
   (the kept spacing spans ``m`` report intervals with probability ``(1 - p) p^(m - 1)``);
6. with ``velocity_scheme = "central"`` (and ``velocity_from_positions``) the velocity is computed
   by the host after all that, from the kept positions and *their stamps*: second-order central
   differences on the irregular stamps, ``numpy.gradient(q, t)`` (one-sided at the ends):
   ``qd_k = (h_-^2 q_{k+1} - h_+^2 q_{k-1} + (h_+^2 - h_-^2) q_k) / (h_- h_+ (h_- + h_+))``,
   ``h_- = t_k - t_{k-1}``, ``h_+ = t_{k+1} - t_k``, so the stamp jitter enters ``qd``;
7. ``qdd`` is reported exactly, or not at all (``report_qdd = False``: real robots rarely give it).

For ``rate_hz = 1 / T`` with independent intervals ``T_k`` and stamp jitter, the spacing of two
consecutive kept reports (``m = 1``) has mean ``T``, variance ``interval_std_s^2 + 2 jitter_s^2``
and lag-1 correlation ``-jitter_s^2 / (interval_std_s^2 + 2 jitter_s^2)``. The ``report14`` preset
sets these to the host-stamped reports of an ABB controller (13.6 Hz, spacing std 8.5 ms,
lag-1 correlation -0.11, 8 % of the spacings about two intervals).

So the sample stamped ``t`` measured the robot at ``t - latency_s`` (up to the stamp jitter).
Units: s, rad, rad/s, rad/s^2; all in the robot's joint space.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from skincal.data.dataset import JointStates
from skincal.errors import ConfigError
from skincal.kinematics.transforms import FloatArray
from skincal.skin.clock import increasing_mask

MotionFn = Callable[[FloatArray], tuple[FloatArray, FloatArray, FloatArray]]
"""True joint motion: instants ``(M,)`` s -> ``q`` rad, ``qd`` rad/s, ``qdd`` rad/s^2, each ``(M, n)``."""


@dataclass(frozen=True)
class JointStateModel:
    """How the robot reports its joint states; SI units, 0 / ``None`` / ``False`` switch an effect off.

    Attributes:
        rate_hz: stream rate, Hz (robot controllers: 125 Hz to 1 kHz); ``None``: the trajectory's
            own sample instants.
        encoder_resolution_rad: positions are rounded to multiples of this step, rad (0 = exact).
        velocity_noise_std: std of the white Gaussian noise on ``qd``, rad/s.
        velocity_from_positions: ``qd`` is the backward difference of the quantised positions
            instead of the true velocity plus noise (``velocity_noise_std`` must then be 0).
        latency_s: the sample stamped ``t`` measured the robot at ``t - latency_s``, s.
        jitter_s: std of the Gaussian jitter of each stamp, s.
        report_qdd: whether the stream carries ``qdd`` (exact); ``False``: ``JointStates.qdd`` is ``None``.
        interval_std_s: std of the report intervals (renewal instants, needs ``rate_hz``), s (0: a fixed grid).
        drop_probability: probability that a report is lost, in ``[0, 1)``.
        velocity_scheme: with ``velocity_from_positions``: ``"backward"`` (on the measured instants)
            or ``"central"`` (``numpy.gradient`` on the stamps, after jitter and drops).
    """

    rate_hz: float | None = None
    encoder_resolution_rad: float = 0.0
    velocity_noise_std: float = 0.0
    velocity_from_positions: bool = False
    latency_s: float = 0.0
    jitter_s: float = 0.0
    report_qdd: bool = True
    interval_std_s: float = 0.0
    drop_probability: float = 0.0
    velocity_scheme: str = "backward"

    def __post_init__(self) -> None:
        if self.rate_hz is not None:
            rate = _finite("rate_hz", self.rate_hz)
            if rate <= 0:
                raise ConfigError(f"JointStateModel.rate_hz must be positive (Hz) or None, got {rate}")
            object.__setattr__(self, "rate_hz", rate)
        for name in ("encoder_resolution_rad", "velocity_noise_std", "latency_s", "jitter_s", "interval_std_s"):
            value = _finite(name, getattr(self, name))
            if value < 0:
                raise ConfigError(f"JointStateModel.{name} must be non-negative, got {value}")
            object.__setattr__(self, name, value)
        for name in ("velocity_from_positions", "report_qdd"):
            if not isinstance(getattr(self, name), bool | np.bool_):
                raise ConfigError(f"JointStateModel.{name} must be True or False, got {getattr(self, name)!r}")
            object.__setattr__(self, name, bool(getattr(self, name)))
        if self.velocity_from_positions and self.velocity_noise_std > 0:
            raise ConfigError("JointStateModel: velocity_noise_std must be 0 when velocity_from_positions is set")
        p = _finite("drop_probability", self.drop_probability)
        if not 0.0 <= p < 1.0:
            raise ConfigError(f"JointStateModel.drop_probability must be in [0, 1), got {p}")
        object.__setattr__(self, "drop_probability", p)
        if self.velocity_scheme not in ("backward", "central"):
            raise ConfigError(
                f"JointStateModel.velocity_scheme must be 'backward' or 'central', got {self.velocity_scheme!r}"
            )
        if self.interval_std_s > 0 and self.rate_hz is None:
            raise ConfigError("JointStateModel.interval_std_s needs a rate_hz (the mean report interval)")

    @property
    def is_ideal(self) -> bool:
        """True when the stream is the trajectory's own samples with exact ``q, qd, qdd``."""
        return self == JointStateModel()


def _finite(name: str, value: object) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = math.nan
    if not math.isfinite(number):
        raise ConfigError(f"JointStateModel.{name} must be a finite number in SI units, got {value!r}")
    return number


JOINT_PRESETS: dict[str, JointStateModel] = {
    # The trajectory's own samples with exact q, qd, qdd (the behaviour before joint-state models).
    "ideal": JointStateModel(),
    # A robot controller's state stream: 500 Hz, 18-bit encoders (2 pi / 2**18 rad), 3e-3 rad/s
    # velocity noise, 0.2 ms stamp jitter, no latency, no qdd.
    "controller": JointStateModel(
        rate_hz=500.0,
        encoder_resolution_rad=2.0 * math.pi / 2**18,
        velocity_noise_std=3e-3,
        jitter_s=2e-4,
        report_qdd=False,
    ),
    # The host-stamped reports of an industrial controller (the ABB tool-pose recordings): 13.6 Hz
    # reports at renewal instants (interval std 7.5 ms), host stamps with 2.8 ms jitter, 8 % of the
    # reports lost (spacing std 8.5 ms, lag-1 correlation -0.11, 8 % double spacings, as measured),
    # velocity by the host's central differences on its stamps, no qdd, exact positions.
    "report14": JointStateModel(
        rate_hz=13.6,
        interval_std_s=7.5e-3,
        jitter_s=2.8e-3,
        drop_probability=0.08,
        velocity_from_positions=True,
        velocity_scheme="central",
        report_qdd=False,
    ),
}
"""Joint-state presets by name: ``ideal``, ``controller``, ``report14``."""


def get_joint_model(name: str) -> JointStateModel:
    """The preset ``name``; an unknown name raises :class:`ConfigError` listing the known ones."""
    try:
        return JOINT_PRESETS[name]
    except KeyError:
        raise ConfigError(f"unknown joint-state model '{name}'; known: {', '.join(JOINT_PRESETS)}") from None


def joint_sample_instants(
    model: JointStateModel, t_native: ArrayLike, rng: np.random.Generator | None = None
) -> FloatArray:
    """Nominal sample instants ``(N,)`` s: ``t_native`` itself, or ``t0 + k / rate_hz`` over ``[t0, t1]``
    of ``t_native`` ``(S,)`` (the trajectory's own sample instants), or with ``interval_std_s > 0``
    the renewal instants ``t0 + sum_{i <= k} T_i`` within ``[t0, t1]`` (module docstring; drawn from ``rng``)."""
    t = np.asarray(t_native, dtype=float)
    if t.ndim != 1 or t.size < 2 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise ConfigError(f"joint states: t_native must be a finite increasing (S,) array, S >= 2, got shape {t.shape}")
    if model.rate_hz is None:
        return t
    t0, t1 = float(t[0]), float(t[-1])
    if model.interval_std_s > 0:
        if rng is None:
            raise ConfigError("joint states: renewal report instants (interval_std_s > 0) need an rng")
        period = 1.0 / model.rate_hz
        n = int(math.ceil((t1 - t0) * model.rate_hz * 1.5)) + 16
        steps = np.zeros(0)
        while steps.sum() <= t1 - t0:
            more = np.maximum(period + model.interval_std_s * rng.standard_normal(n), 0.2 * period)
            steps = np.concatenate([steps, more])
        instants = t0 + np.concatenate([[0.0], np.cumsum(steps)])
        return instants[instants <= t1]
    return t0 + np.arange(int(math.floor((t1 - t0) * model.rate_hz + 1e-9)) + 1) / model.rate_hz


def apply_joint_state_model(
    model: JointStateModel,
    motion: MotionFn,
    t_native: ArrayLike,
    rng: np.random.Generator | None = None,
) -> JointStates:
    """The joint stream a robot would report for the true motion (see the module docstring).

    Args:
        model: the joint-state model (:func:`get_joint_model`).
        motion: true ``q, qd, qdd`` ``(M, n)`` at any instants ``(M,)`` s (e.g. ``trajectory.evaluate``).
        t_native: ``(S,)`` the motion's own sample instants, s; they give the session span
            ``[t0, t1]`` and are the stream's instants when ``model.rate_hz`` is ``None``.
        rng: random generator; required when the model has velocity noise or jitter. Use a
            generator of its own so that the other streams of a seed do not depend on this model.

    Returns:
        :class:`JointStates` with stamps ``t`` ``(N,)`` s strictly increasing and ``q``, ``qd``
        ``(N, n)`` (``qdd`` ``(N, n)`` or ``None``).
    """
    if rng is None and (
        model.velocity_noise_std > 0 or model.jitter_s > 0 or model.interval_std_s > 0 or model.drop_probability > 0
    ):
        raise ConfigError("apply_joint_state_model needs an rng: the joint-state model has noise, jitter or drops")
    t_nom = joint_sample_instants(model, t_native, rng)
    t_meas = t_nom - model.latency_s
    q, qd, qdd = (np.asarray(x, dtype=float) for x in motion(t_meas))
    if q.ndim != 2 or q.shape[0] != t_nom.size or qd.shape != q.shape or qdd.shape != q.shape:
        raise ConfigError(f"joint states: motion must return three ({t_nom.size}, n) arrays, got {q.shape}")
    r = model.encoder_resolution_rad
    if r > 0:
        q = np.round(q / r) * r
    if model.velocity_from_positions and model.velocity_scheme == "backward":
        qd = np.empty_like(q)
        if q.shape[0] > 1:
            qd[1:] = np.diff(q, axis=0) / np.diff(t_meas)[:, None]
            qd[0] = qd[1]
        else:
            qd[:] = 0.0
    elif model.velocity_noise_std > 0:
        qd = qd + rng.normal(0.0, model.velocity_noise_std, qd.shape)
    t = t_nom
    if model.jitter_s > 0:
        t = t + rng.normal(0.0, model.jitter_s, t.shape)
    keep = increasing_mask(t)
    if model.drop_probability > 0:
        keep &= rng.random(t.shape) >= model.drop_probability  # type: ignore[union-attr]
    if not np.all(keep):
        t, q, qd, qdd = t[keep], q[keep], qd[keep], qdd[keep]
    if model.velocity_from_positions and model.velocity_scheme == "central":
        qd = np.gradient(q, t, axis=0) if q.shape[0] > 1 else np.zeros_like(q)
    return JointStates(t=t, q=q, qd=qd, qdd=qdd if model.report_qdd else None)
