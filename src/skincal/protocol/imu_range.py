"""The protocol fitted to the IMUs' full-scale ranges, as well as to the joint limits (issue 27).

A skin unit may sit anywhere on a link's surface (the link capsules of
:func:`skincal.kinematics.geometry.link_capsules`) in any orientation, so what one of its IMUs can read
is bounded per link, in the base frame {0}:

* gyroscope, per axis: ``|w_su,k| <= |w_l|``, the link's angular rate;
* accelerometer, per axis: ``|f_su,k| <= |f(x)|`` with ``f(x) = a_l + M_l (x - o_l) - g``,
  ``M_l = [dw_l]x + [w_l]x [w_l]x``, the specific force at a point ``x`` of the link. ``f`` is affine in
  ``x``, so over a capsule (the points within ``rho`` of the segment ``x_0 x_1``) its norm is at most
  ``max_e |f(x_e)| + ||M_l||_F rho`` (a convex function peaks at an end of the segment; the Frobenius
  norm bounds the spectral one).

:func:`fit_to_imu_range` caps, before the motion is built, every excitation ``qd_j = A_j sin(2 pi f_j
t)`` of a revolute joint (one joint at a time: the links beyond it turn at ``|w| = |qd_j|``) at
``fraction G``. :func:`build_within_imu_range` then builds the
motion, evaluates both bounds on it (:func:`imu_bounds`, every 5 ms) and, where they exceed ``fraction``
of a range, scales down the amplitude of the joint excited there (by the excess of ``|f| - g``, which
grows with ``A_j`` to the first or second power) or slows the moves between poses (where several joints
move at once), and builds it again on the same poses until it fits.

``F`` (m/s^2) and ``G`` (rad/s) are the accelerometer's and gyroscope's full scale per axis
(:class:`ImuRange`; the presets' ``accel_range``/``gyro_range``, :mod:`skincal.skin.imu`).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace

import numpy as np

from skincal.errors import ConfigError, ProtocolError
from skincal.kinematics.chain import GRAVITY_BASE, SerialChain
from skincal.kinematics.geometry import DEFAULT_LINK_RADIUS, link_capsules
from skincal.kinematics.transforms import FloatArray, skew
from skincal.protocol.config import ProtocolConfig
from skincal.protocol.limits import VELOCITY_CAP_FRACTION
from skincal.protocol.trajectory import Trajectory, build_trajectory
from skincal.skin.imu import STANDARD_GRAVITY

_DPS = math.pi / 180.0

PEAK_RATE_HZ = 200.0
"""Rate the bounds are evaluated at on a built motion (exact ``Trajectory.evaluate``), Hz."""
MAX_ROUNDS = 8
"""Times :func:`build_within_imu_range` scales the motion down and builds it again before giving up."""


@dataclass(frozen=True)
class ImuRange:
    """Full scale per axis of a unit's IMU: ``accel_mps2`` (m/s^2) and ``gyro_rps`` (rad/s); ``inf``: none."""

    accel_mps2: float = math.inf
    gyro_rps: float = math.inf

    def __post_init__(self) -> None:
        for name in ("accel_mps2", "gyro_rps"):
            value = float(getattr(self, name))
            if not (value > 0) or math.isnan(value):
                raise ConfigError(f"IMU range: {name} must be positive (or inf), got {value!r}")
            object.__setattr__(self, name, value)

    @classmethod
    def parse(cls, text: str) -> ImuRange:
        """``"ACCEL,GYRO"``: the accelerometer's full scale (``19.6``, m/s^2, or ``2g``) and the
        gyroscope's (``4.28``, rad/s, or ``245dps``); or an IMU preset's name (``realistic``, ...)."""
        from skincal.skin.imu import IMU_PRESETS

        text = text.strip()
        if text in IMU_PRESETS:
            model = IMU_PRESETS[text]
            return cls(model.accel_range, model.gyro_range)
        parts = [p.strip().lower() for p in text.split(",")]
        if len(parts) != 2:
            raise ConfigError(
                f"--imu-range must be ACCEL,GYRO (e.g. 2g,245dps or 19.6,4.28 in m/s^2 and rad/s) or an IMU "
                f"preset ({', '.join(IMU_PRESETS)}), got {text!r}"
            )
        values = []
        scales = ({"g": STANDARD_GRAVITY, "": 1.0}, {"dps": _DPS, "deg/s": _DPS, "": 1.0})
        for part, units in zip(parts, scales, strict=True):
            match = re.fullmatch(r"([0-9.eE+-]+|inf)\s*([a-z/]*)", part)
            if match is None or match.group(2) not in units:
                raise ConfigError(f"--imu-range: cannot read {part!r} (a number, with g or dps if not SI)")
            try:
                values.append(float(match.group(1)) * units[match.group(2)])
            except ValueError:
                raise ConfigError(f"--imu-range: cannot read {part!r} as a number") from None
        return cls(*values)

    def describe(self) -> str:
        return f"+-{self.accel_mps2 / STANDARD_GRAVITY:.3g} g / +-{self.gyro_rps / _DPS:.4g} deg/s"


def fit_to_imu_range(
    chain: SerialChain, config: ProtocolConfig, imu_range: ImuRange, fraction: float = VELOCITY_CAP_FRACTION
) -> ProtocolConfig:
    """``config`` (already fitted to the joint limits) with the gyroscope's caps of the module docstring,
    every change in ``config.notes``."""
    n = chain.n_joints
    g = float(np.linalg.norm(GRAVITY_BASE))
    if fraction * imu_range.accel_mps2 <= g:
        raise ConfigError(
            f"IMU range: an accelerometer of +-{imu_range.accel_mps2:.3g} m/s^2 reads gravity near its rail at rest "
            "(needs more than 1 g)"
        )
    G = fraction * imu_range.gyro_rps
    A = config.amplitude_per_joint(n)
    notes = list(config.notes)
    scaled = A.copy()
    for j in config.joints_to_excite(n):
        if chain.joint_type[j] != "prismatic" and A[j] > G * (1 + 1e-12):
            scaled[j] = G
            why = f"{fraction:.0%} of the gyroscope's range"
            notes.append(f"joint {j + 1}: amplitude {A[j]:.4g} -> {G:.4g} rad/s ({why})")
    changes: dict = {}
    if not np.array_equal(scaled, A):
        changes["amplitude"] = tuple(float(a) for a in scaled)
    if notes != list(config.notes):
        changes["notes"] = tuple(notes)
    return replace(config, **changes) if changes else config


@dataclass(frozen=True)
class ImuBounds:
    """What an IMU anywhere on each link can read at most during a motion (module docstring).

    Attributes:
        t: ``(N,)`` instants, s.
        rate_rps: ``(N, n + 1)`` angular rate of each link (base included), rad/s.
        accel_mps2: ``(N, n + 1)`` specific-force bound over each link's capsule, m/s^2.
        moving: ``(N, n)`` the joints that move (or accelerate) at each instant.
    """

    t: FloatArray
    rate_rps: FloatArray
    accel_mps2: FloatArray
    moving: np.ndarray

    def exceeds(self, imu_range: ImuRange, fraction: float = 1.0) -> list[str]:
        """The links whose bound exceeds ``fraction`` of the range, one sentence each (empty: it fits)."""
        out = []
        for name, values, limit, unit in (
            ("rotation rate", self.rate_rps, imu_range.gyro_rps, "rad/s"),
            ("specific force", self.accel_mps2, imu_range.accel_mps2, "m/s^2"),
        ):
            peak, at = values.max(axis=0), values.argmax(axis=0)
            for link in np.flatnonzero(peak > fraction * limit):
                out.append(
                    f"link {link}: {name} up to {peak[link]:.3g} {unit} at {self.t[at[link]]:.1f} s "
                    f"(range {limit:.3g} {unit})"
                )
        return out


def imu_bounds(
    chain: SerialChain,
    trajectory: Trajectory,
    radius: float = DEFAULT_LINK_RADIUS,
    rate_hz: float = PEAK_RATE_HZ,
    t: FloatArray | None = None,
) -> ImuBounds:
    """The bounds of the module docstring on ``trajectory`` evaluated every ``1 / rate_hz`` s, or at the
    instants ``t`` ``(N,)`` s when given (exactly: ``Trajectory.evaluate``)."""
    if t is None:
        t = np.arange(0.0, trajectory.duration + 0.5 / rate_hz, 1.0 / rate_hz)
    t = np.asarray(t, dtype=float)
    q, qd, qdd = trajectory.evaluate(t)
    motion = chain.link_motion(q, qd, qdd)
    w, dw, a = motion.omega, motion.omega_dot, motion.a_origin  # (N, n + 1, 3)
    rate = np.linalg.norm(w, axis=2)
    g = np.asarray(GRAVITY_BASE, dtype=float)
    wx = skew(w)
    M = skew(dw) + wx @ wx  # (N, n + 1, 3, 3): a(x) = a_o + M (x - o)
    accel = np.zeros_like(rate)
    R = motion.T_base_link[..., :3, :3]
    for cap in link_capsules(chain, radius):
        ends = np.stack([cap.p0, cap.p1])  # (2, 3) in the link frame
        r = np.einsum("nij,ej->nei", R[:, cap.link], ends)  # (N, 2, 3) from the link origin, base frame
        f = a[:, cap.link, None, :] + np.einsum("nij,nej->nei", M[:, cap.link], r) - g
        bound = np.max(np.linalg.norm(f, axis=2), axis=1) + np.linalg.norm(M[:, cap.link], axis=(1, 2)) * cap.radius
        accel[:, cap.link] = np.maximum(accel[:, cap.link], bound)
    return ImuBounds(t, rate, accel, (np.abs(qd) > 1e-9) | (np.abs(qdd) > 1e-9))


def build_within_imu_range(
    chain: SerialChain,
    config: ProtocolConfig,
    imu_range: ImuRange,
    rng: np.random.Generator | None = None,
    radius: float = DEFAULT_LINK_RADIUS,
    fraction: float = VELOCITY_CAP_FRACTION,
) -> tuple[ProtocolConfig, Trajectory]:
    """The motion of ``config`` fitted to ``imu_range`` (module docstring): the fitted config (every change
    in its notes) and its trajectory. Raises :class:`ProtocolError` naming the link when it cannot be fitted."""
    g = float(np.linalg.norm(GRAVITY_BASE))
    n = chain.n_joints
    config = fit_to_imu_range(chain, config, imu_range, fraction)
    traj = build_trajectory(chain, config, rng)
    F, G = fraction * imu_range.accel_mps2, fraction * imu_range.gyro_rps
    for _ in range(MAX_ROUNDS):
        b = imu_bounds(chain, traj, radius)
        excess = np.maximum(b.rate_rps.max(axis=1) / G, (b.accel_mps2.max(axis=1) - g) / (F - g))  # (N,) > 1: over
        over = excess > 1.0
        if not over.any():
            return config, traj
        single = b.moving.sum(axis=1) == 1
        A = config.amplitude_per_joint(n)
        notes = list(config.notes)
        changes: dict = {}
        for j in range(n):
            here = over & single & b.moving[:, j]
            if here.any():
                A[j] /= float(excess[here].max()) * 1.02
                unit = "m/s" if chain.joint_type[j] == "prismatic" else "rad/s"
                notes.append(
                    f"joint {j + 1}: amplitude -> {A[j]:.4g} {unit} (an IMU on the links it moves would reach "
                    f"{fraction:.0%} of its range)"
                )
        if not np.array_equal(A, config.amplitude_per_joint(n)):
            changes["amplitude"] = tuple(float(x) for x in A)
        if (over & ~single).any():
            changes["move_speed"] = config.move_speed / (float(excess[over & ~single].max()) * 1.02)
            notes.append(
                f"moves between poses at {changes['move_speed']:.3g} rad/s per joint (was {config.move_speed:.3g}: an "
                f"IMU would reach {fraction:.0%} of its range)"
            )
        config = replace(config, notes=tuple(notes), **changes)
        traj = build_trajectory(chain, config, poses=traj.poses)
    raise ProtocolError(
        f"the motion cannot be fitted to the IMU range {imu_range.describe()}: "
        + "; ".join(imu_bounds(chain, traj, radius).exceeds(imu_range, fraction))
    )
