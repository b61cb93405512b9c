"""Skin units on a rigid body moved by hand: an IMU-only session without a robot or joint states.

A :class:`HandMotion` is a smooth random motion of one body: its rotation vector and its position
are sums of sinusoids with random frequencies in a hand's band (0.2-3 Hz by default) and random
phases, scaled so that the RMS angular rate and the RMS acceleration are the requested ones. It is
exact at any instant (:meth:`HandMotion.state`): orientation ``R_world_body``, body-frame angular
velocity ``w`` and angular acceleration ``dw``, world-frame acceleration ``a`` of the body origin.

A unit at ``T_body_su = (R_bs, r)`` then measures (:func:`unit_truth`)::

    f_su = R_bs^T (R^T (a - g) + ([dw]x + [w]x^2) r),      w_su = R_bs^T w

and :func:`simulate_rigid_bodies` draws each unit's IMU errors and clock with the same steps as the
robot simulators (:mod:`skincal.sim.common`): a :class:`~skincal.data.dataset.Dataset` with no robot
and no joints, the true poses as ``truth_body`` (``/truth/<unit>`` attrs ``body``, ``T_body_su``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from skincal.data.dataset import BodyPose, Dataset, ImuStream
from skincal.errors import ConfigError
from skincal.kinematics.chain import GRAVITY_BASE
from skincal.kinematics.transforms import FloatArray
from skincal.sim.common import sensor_truth, unit_clock_stamps
from skincal.skin.clock import ClockModel
from skincal.skin.imu import ImuModel, apply_imu_model, draw_imu_errors, sample_instants, true_sample_times

_H_ROT = 1e-6  # s, central difference of the rotation (analytic phi, so only round-off limits it)
_H_RATE = 1e-4  # s, central difference of the angular velocity


def skew(v: FloatArray) -> FloatArray:
    """``(M, 3) -> (M, 3, 3)`` cross-product matrices ``[v]x``."""
    v = np.asarray(v, dtype=float)
    S = np.zeros(v.shape[:-1] + (3, 3))
    S[..., 0, 1], S[..., 0, 2], S[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    S[..., 1, 0], S[..., 2, 0], S[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return S


def rigid_body_matrix(w: FloatArray, dw: FloatArray) -> FloatArray:
    """``K = [dw]x + [w]x^2`` ``(M, 3, 3)``: the acceleration of a point ``r`` of a rigid body relative
    to its origin is ``K r`` (body frame)."""
    W = skew(w)
    return skew(dw) + W @ W


@dataclass(frozen=True)
class HandMotion:
    """A smooth random motion of a rigid body (see the module docstring).

    Attributes:
        freq_rot, amp_rot, phase_rot: ``(K, 3)`` frequencies (Hz), amplitudes (rad) and phases of the
            rotation vector's sinusoids, per axis.
        freq_pos, amp_pos, phase_pos: ``(K, 3)`` the same for the position (m).
        R0: ``(3, 3)`` the orientation at rotation vector 0.
        axes: ``(3,)`` bool, which rotation-vector axes move (all, unless limited to test excitation).
    """

    freq_rot: FloatArray
    amp_rot: FloatArray
    phase_rot: FloatArray
    freq_pos: FloatArray
    amp_pos: FloatArray
    phase_pos: FloatArray
    R0: FloatArray

    @classmethod
    def random(
        cls,
        rng: np.random.Generator,
        *,
        band_hz: tuple[float, float] = (0.2, 3.0),
        rate_rms: float = 1.5,
        accel_rms: float = 5.0,
        n_sines: int = 6,
        rotation_axes: FloatArray | None = None,
    ) -> HandMotion:
        """A random hand-like motion: ``rate_rms`` rad/s RMS angular rate (about every axis, or about
        the single axis ``rotation_axes`` ``(3,)`` to test poor excitation), ``accel_rms`` m/s^2 RMS
        acceleration of the origin, sinusoids in ``band_hz``."""
        lo, hi = band_hz
        if not (0 < lo < hi) or n_sines < 1 or rate_rms < 0 or accel_rms < 0:
            raise ConfigError(f"hand motion: need 0 < band low < high, n_sines >= 1, got {band_hz}, {n_sines}")
        f_rot = rng.uniform(lo, hi, (n_sines, 3))
        f_pos = rng.uniform(max(lo, 0.5), hi, (n_sines, 3))
        # rate of a sinusoid = amp * 2 pi f; equal rate per sinusoid, RMS over 3 n_sines of them
        amp_rot = rate_rms / np.sqrt(1.5 * n_sines) / (2 * np.pi * f_rot)
        amp_pos = accel_rms / np.sqrt(1.5 * n_sines) / (2 * np.pi * f_pos) ** 2
        if rotation_axes is not None:
            axis = np.asarray(rotation_axes, dtype=float)
            axis = axis / np.linalg.norm(axis)
            amp_rot = np.abs(amp_rot[:, :1]) * np.sqrt(3.0) * axis[None, :]
            f_rot = np.repeat(f_rot[:, :1], 3, axis=1)
        phases = rng.uniform(0, 2 * np.pi, (2, n_sines, 3))
        R0 = Rotation.random(random_state=np.random.default_rng(rng.integers(2**32))).as_matrix()
        if rotation_axes is not None:
            phases[0] = phases[0][:, :1]
        return cls(f_rot, amp_rot, phases[0], f_pos, amp_pos, phases[1], R0)

    def _rotvec(self, t: FloatArray) -> FloatArray:
        arg = 2 * np.pi * self.freq_rot[None] * t[:, None, None] + self.phase_rot[None]
        return np.sum(self.amp_rot[None] * np.sin(arg), axis=1)

    def rotation(self, t: FloatArray) -> FloatArray:
        """``(M, 3, 3)`` orientation ``R_world_body`` at instants ``t`` ``(M,)`` s."""
        t = np.asarray(t, dtype=float)
        return self.R0 @ Rotation.from_rotvec(self._rotvec(t)).as_matrix()

    def angular_velocity(self, t: FloatArray) -> FloatArray:
        """``(M, 3)`` body-frame angular velocity, rad/s (``vee(R^T dR/dt)``, central difference)."""
        t = np.asarray(t, dtype=float)
        R = self.rotation(t)
        dR = (self.rotation(t + _H_ROT) - self.rotation(t - _H_ROT)) / (2 * _H_ROT)
        W = np.einsum("mji,mjk->mik", R, dR)
        return 0.5 * np.stack([W[:, 2, 1] - W[:, 1, 2], W[:, 0, 2] - W[:, 2, 0], W[:, 1, 0] - W[:, 0, 1]], axis=1)

    def position(self, t: FloatArray) -> FloatArray:
        """``(M, 3)`` world position of the body origin, m."""
        t = np.asarray(t, dtype=float)
        arg = 2 * np.pi * self.freq_pos[None] * t[:, None, None] + self.phase_pos[None]
        return np.sum(self.amp_pos[None] * np.sin(arg), axis=1)

    def acceleration(self, t: FloatArray) -> FloatArray:
        """``(M, 3)`` world acceleration of the body origin, m/s^2 (analytic)."""
        t = np.asarray(t, dtype=float)
        om = 2 * np.pi * self.freq_pos[None]
        return -np.sum(self.amp_pos[None] * om**2 * np.sin(om * t[:, None, None] + self.phase_pos[None]), axis=1)

    def state(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """``(R_world_body (M, 3, 3), w (M, 3), dw (M, 3), a (M, 3))`` at instants ``t``."""
        t = np.asarray(t, dtype=float)
        dw = (self.angular_velocity(t + _H_RATE) - self.angular_velocity(t - _H_RATE)) / (2 * _H_RATE)
        return self.rotation(t), self.angular_velocity(t), dw, self.acceleration(t)


def unit_truth(
    motion: HandMotion, T_body_su: FloatArray, t: FloatArray, gravity: FloatArray = GRAVITY_BASE
) -> tuple[FloatArray, FloatArray]:
    """True specific force and angular rate ``(M, 3)`` of a unit at ``T_body_su`` at instants ``t``."""
    R, w, dw, a = motion.state(t)
    R_bs, r = np.asarray(T_body_su)[:3, :3], np.asarray(T_body_su)[:3, 3]
    f_body = np.einsum("mji,mj->mi", R, a - gravity) + rigid_body_matrix(w, dw) @ r
    return f_body @ R_bs, w @ R_bs


def simulate_rigid_bodies(
    units: Mapping[str, tuple[str, FloatArray]],
    motions: Mapping[str, HandMotion],
    duration_s: float,
    imu_model: ImuModel,
    rng: np.random.Generator,
    *,
    clock_model: ClockModel | None = None,
    gravity: FloatArray = GRAVITY_BASE,
    description: str = "",
) -> Dataset:
    """An IMU-only dataset of units on hand-moved rigid bodies.

    Args:
        units: unit name -> ``(body name, T_body_su (4, 4))``.
        motions: body name -> its motion.
        duration_s: session length, s (the session runs over ``[0, duration_s]``).
        imu_model, clock_model: the IMU type and the units' clock type (as the robot simulators).
        rng: per unit a child generator (IMU errors, stamps, noise, clock), in ``units`` order.
    """
    if not units:
        raise ConfigError("rigid-body simulation: no skin units")
    if not (duration_s > 0 and np.isfinite(duration_s)):
        raise ConfigError(f"rigid-body simulation: duration must be positive, got {duration_s}")
    imu: dict[str, ImuStream] = {}
    truth_sensor: dict[str, dict] = {}
    truth_body: dict[str, BodyPose] = {}
    g = np.asarray(gravity, dtype=float)
    for (name, (body, T)), unit_rng in zip(units.items(), rng.spawn(len(units)), strict=True):
        if body not in motions:
            raise ConfigError(f"rigid-body simulation: unit {name} is on body '{body}', which has no motion")
        T = np.asarray(T, dtype=float)
        errors = draw_imu_errors(imu_model, unit_rng)
        t_stamp = sample_instants(imu_model, errors.latency_s, duration_s + min(errors.latency_s, 0.0), unit_rng)
        t_true = true_sample_times(t_stamp, errors)
        inside = (t_true >= 0.0) & (t_true <= duration_s)
        t_stamp, t_true = t_stamp[inside], t_true[inside]
        f_su, w_su = unit_truth(motions[body], T, t_true, g)
        accel, gyro = apply_imu_model(imu_model, errors, f_su, w_su, unit_rng)
        clock, t_stamp, keep = unit_clock_stamps(clock_model, unit_rng, t_stamp, t_true, 0.0)
        imu[name] = ImuStream(t=t_stamp, accel=accel[keep], gyro=gyro[keep] if gyro is not None else None)
        truth_sensor[name] = sensor_truth(errors, clock)
        truth_body[name] = BodyPose(body=body, T_body_su=T)
    return Dataset(
        robot=None,
        joints=None,
        imu=imu,
        truth_sensor=truth_sensor,
        truth_body=truth_body,
        gravity=g,
        description=description,
    )
