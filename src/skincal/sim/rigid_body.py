"""Skin units on a rigid body moved by hand: an IMU-only session without a robot or joint states.

A :class:`HandMotion` is a smooth random motion of one body: its rotation vector and its position
are sums of sinusoids with random frequencies in a hand's band (0.2-3 Hz by default) and random
phases, scaled so that the RMS angular rate and the RMS acceleration are the requested ones. It is
exact at any instant (:meth:`HandMotion.state`): orientation ``R_world_body``, body-frame angular
velocity ``w`` and angular acceleration ``dw``, world-frame acceleration ``a`` of the body origin.

A unit at ``T_body_su = (R_bs, r)`` then measures (:func:`unit_truth`)::

    f_su = R_bs^T (R^T (a - g) + ([dw]x + [w]x^2) r),      w_su = R_bs^T w

**Holds** (:meth:`HandMotion.turn_over`): the motion a user makes to calibrate the accelerometers'
scale by hand. Hold the body still for 1-2 s, turn it over to another orientation, hold it again,
and so on, 9 or more times (12 by default), so that the direction of gravity seen by the units
covers the whole sphere (face up, face down, on each edge, and in between); shake and twist it
freely between the holds. Inside a hold the body is exactly still; the random motion fades in and
out over ``ramp_s`` around each hold (a quintic smoothstep envelope, C2), while the base orientation
turns from one hold's orientation to the next along a smoothstep geodesic.

Then :func:`simulate_rigid_bodies` draws each unit's IMU errors and clock with the same steps as the
robot simulators (:mod:`skincal.sim.common`): a :class:`~skincal.data.dataset.Dataset` with no robot
and no joints, the true poses as ``truth_body`` (``/truth/<unit>`` attrs ``body``, ``T_body_su``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial.transform import Rotation

from skincal.data.dataset import BodyPose, Dataset, ImuStream
from skincal.errors import ConfigError
from skincal.kinematics.chain import GRAVITY_BASE
from skincal.kinematics.transforms import FloatArray, skew
from skincal.sim.common import sensor_truth, unit_clock_stamps
from skincal.skin.clock import ClockModel
from skincal.skin.imu import ImuModel, apply_imu_model, draw_imu_errors, sample_instants, true_sample_times

_H_ROT = 1e-6  # s, central difference of the rotation (analytic phi, so only round-off limits it)
_H_RATE = 1e-4  # s, central difference of the angular velocity
MIN_MOVE_S = 1.0
"""Shortest motion before, between and after the holds of :meth:`HandMotion.turn_over`, s."""


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
        hold_times: ``(H, 2)`` start and end (s) of the holds, in time order (none: no holds).
        hold_R: ``(H, 3, 3)`` orientation ``R_world_body`` during each hold.
        ramp_s: the random motion fades out before and in after a hold over this time, s.
    """

    freq_rot: FloatArray
    amp_rot: FloatArray
    phase_rot: FloatArray
    freq_pos: FloatArray
    amp_pos: FloatArray
    phase_pos: FloatArray
    R0: FloatArray
    hold_times: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    hold_R: FloatArray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    ramp_s: float = 0.4

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

    @classmethod
    def turn_over(
        cls,
        rng: np.random.Generator,
        duration_s: float,
        *,
        holds: int = 12,
        hold_s: float = 1.5,
        **random: object,
    ) -> HandMotion:
        """A hand-held "turn it over" calibration motion of ``duration_s``: ``holds`` still periods of
        ``hold_s`` s whose gravity directions (body frame) are spread over the sphere (Fibonacci points,
        randomly rotated, visited nearest-first, random heading), evenly spaced in time with the random
        motion of :meth:`random` (``random``: its options) in the moves before, between and after them."""
        if holds < 1 or not (hold_s > 0 and np.isfinite(hold_s)):
            raise ConfigError(f"hand motion: need holds >= 1 and a positive hold time, got {holds}, {hold_s}")
        move_s = (duration_s - holds * hold_s) / (holds + 1)
        if not move_s >= MIN_MOVE_S:
            raise ConfigError(
                f"hand motion: {holds} holds of {hold_s:g} s do not fit in {duration_s:g} s "
                f"(at least {MIN_MOVE_S:g} s of motion before, between and after them)"
            )
        motion = cls.random(rng, **random)  # type: ignore[arg-type]
        k = np.arange(holds) + 0.5
        z = 1.0 - 2.0 * k / holds
        azimuth = np.pi * (1.0 + np.sqrt(5.0)) * k
        up = np.stack([np.sqrt(1 - z**2) * np.cos(azimuth), np.sqrt(1 - z**2) * np.sin(azimuth), z], axis=1)
        up = up @ Rotation.random(random_state=np.random.default_rng(rng.integers(2**32))).as_matrix().T
        order = [0]
        while len(order) < holds:
            left = [i for i in range(holds) if i not in order]
            order.append(left[int(np.argmax(up[left] @ up[order[-1]]))])
        hold_R = []
        for i in order:
            # R_world_body with R^T e_z = up (gravity's direction in the body frame), then a random heading
            align = Rotation.align_vectors([[0.0, 0.0, 1.0]], [up[i]])[0]
            heading = Rotation.from_rotvec([0.0, 0.0, rng.uniform(-np.pi / 3, np.pi / 3)])
            hold_R.append((heading * align).as_matrix())
        starts = move_s + np.arange(holds) * (hold_s + move_s)
        times = np.stack([starts, starts + hold_s], axis=1)
        return replace(motion, hold_times=times, hold_R=np.array(hold_R), ramp_s=min(0.4, move_s / 2))

    def _envelope(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Weight of the random motion and its first two time derivatives ``(M,)``: 0 inside a hold,
        a quintic smoothstep of the distance to the nearest hold over ``ramp_s``, 1 beyond."""
        one = np.ones_like(t)
        if not len(self.hold_times):
            return one, 0 * one, 0 * one
        a, b = self.hold_times[:, 0][None], self.hold_times[:, 1][None]
        before, after = a - t[:, None], t[:, None] - b
        dist = np.maximum(np.maximum(before, after), 0.0)
        k = np.argmin(dist, axis=1)
        rows = np.arange(len(t))
        d = dist[rows, k]
        sign = np.where(after[rows, k] > 0, 1.0, np.where(before[rows, k] > 0, -1.0, 0.0))
        x = d / self.ramp_s
        ramp = x < 1.0
        xc = np.minimum(x, 1.0)
        e = 10 * xc**3 - 15 * xc**4 + 6 * xc**5
        de = np.where(ramp, 30 * x**2 * (1 - x) ** 2, 0.0) * sign / self.ramp_s
        dde = np.where(ramp, 60 * x * (1 - x) * (1 - 2 * x), 0.0) * sign**2 / self.ramp_s**2
        return e, de, dde

    def _base_rotation(self, t: FloatArray) -> FloatArray:
        """``(M, 3, 3)``: ``R0`` without holds; else the hold orientation, turning to the next one along
        a smoothstep geodesic between holds (the first before, the last after them)."""
        if not len(self.hold_times):
            return np.broadcast_to(self.R0, (len(t), 3, 3))
        out = np.empty((len(t), 3, 3))
        i = np.searchsorted(self.hold_times[:, 0], t, side="right") - 1  # last hold started
        out[:] = self.hold_R[np.clip(i, 0, None)]
        for k in range(len(self.hold_times) - 1):
            t1, t2 = self.hold_times[k, 1], self.hold_times[k + 1, 0]
            m = (t > t1) & (t < t2)
            if not m.any():
                continue
            x = (t[m] - t1) / (t2 - t1)
            s = 10 * x**3 - 15 * x**4 + 6 * x**5
            step = Rotation.from_matrix(self.hold_R[k].T @ self.hold_R[k + 1]).as_rotvec()
            out[m] = self.hold_R[k] @ Rotation.from_rotvec(s[:, None] * step[None]).as_matrix()
        return out

    def _rotvec(self, t: FloatArray) -> FloatArray:
        arg = 2 * np.pi * self.freq_rot[None] * t[:, None, None] + self.phase_rot[None]
        return np.sum(self.amp_rot[None] * np.sin(arg), axis=1) * self._envelope(t)[0][:, None]

    def rotation(self, t: FloatArray) -> FloatArray:
        """``(M, 3, 3)`` orientation ``R_world_body`` at instants ``t`` ``(M,)`` s."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        return self._base_rotation(t) @ Rotation.from_rotvec(self._rotvec(t)).as_matrix()

    def still(self, t: FloatArray) -> np.ndarray:
        """``(M,)`` True inside a hold."""
        t = np.asarray(t, dtype=float)
        return np.any((t[:, None] >= self.hold_times[:, 0]) & (t[:, None] <= self.hold_times[:, 1]), axis=1)

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
        return np.sum(self.amp_pos[None] * np.sin(arg), axis=1) * self._envelope(t)[0][:, None]

    def acceleration(self, t: FloatArray) -> FloatArray:
        """``(M, 3)`` world acceleration of the body origin, m/s^2 (analytic)."""
        t = np.asarray(t, dtype=float)
        om = 2 * np.pi * self.freq_pos[None]
        arg = om * t[:, None, None] + self.phase_pos[None]
        p = np.sum(self.amp_pos[None] * np.sin(arg), axis=1)
        dp = np.sum(self.amp_pos[None] * om * np.cos(arg), axis=1)
        ddp = -np.sum(self.amp_pos[None] * om**2 * np.sin(arg), axis=1)
        e, de, dde = self._envelope(t)
        return e[:, None] * ddp + 2 * de[:, None] * dp + dde[:, None] * p

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
