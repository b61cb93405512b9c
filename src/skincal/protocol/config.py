"""The data-collection protocol's parameters (paper Sec. II-A and IV).

A protocol visits ``P`` static poses. At each pose the robot rests (the middle ``static_duration``
seconds of that rest are the static measurement window), then each excited joint ``j`` in turn
follows the velocity ``qd_j = A_j sin(2 pi f_j t)`` for ``excite_duration`` seconds while every
other joint is held, returns to the pose and rests again. See :mod:`skincal.protocol.trajectory`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from skincal.errors import ConfigError
from skincal.kinematics.transforms import FloatArray

POSE_SELECTIONS = ("uniform", "diverse")
"""How static poses are drawn (:attr:`ProtocolConfig.pose_selection`)."""


def _scalar_or_tuple(value: Any, name: str) -> float | tuple[float, ...]:
    arr = np.asarray(value, dtype=float) if not isinstance(value, str) else None
    if arr is None or arr.ndim > 1 or (arr.ndim == 1 and arr.size == 0):
        raise ConfigError(f"protocol: {name} must be a number or a list of numbers (one per joint), got {value!r}")
    if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise ConfigError(f"protocol: {name} must be finite and positive, got {arr.tolist()}")
    return float(arr) if arr.ndim == 0 else tuple(float(x) for x in arr)


@dataclass(frozen=True, eq=False)
class ProtocolConfig:
    """Parameters of the calibration motion. Equality is identity; compare :meth:`to_dict` outputs.

    Attributes:
        n_poses: number of static poses ``P`` (taken from ``poses`` when those are given).
        amplitude: velocity amplitude ``A`` of the excitation, rad/s; one number or one per joint.
        frequency: excitation frequency ``f``, Hz; one number or one per joint.
        excite_duration: length of each joint's sine window (the dynamic segment), s.
        rest_duration: rest at the pose before the first excitation and after each one, s.
        static_duration: static measurement window in the middle of the first rest at a pose, s
            (``<= rest_duration``); the accelerometer average over it is the static measurement.
        excited_joints: 0-based joints excited at every pose, in order; ``None`` = all joints.
        rate_hz: rate at which the robot stream is sampled, Hz (the paper's 100 Hz was the IMU rate).
        limit_margin: distance kept from every joint position limit, rad.
        move_speed: peak joint speed of the quintic moves between poses, rad/s (capped at each
            joint's velocity limit); sets the move duration when ``move_duration`` is ``None``.
        min_move_duration: shortest move between two poses, s.
        move_duration: fixed duration of every move between poses, s, or ``None`` (automatic).
        poses: optional user-given static poses ``(P, n)``, rad; sampled when ``None``.
        name: label of the protocol (preset name or ``"custom"``).
        velocity_fraction: when set, the amplitude of every joint is this fraction of the robot's
            velocity limit (replacing ``amplitude``; see :meth:`for_chain`), so that one preset fits
            any robot.
        collision_check: static poses are drawn collision-free and the whole motion is checked
            against self-collision and the floor (:mod:`skincal.protocol.collision`); ``False`` keeps
            the plain uniform draw (``paper-sim``: a simulation protocol, kept as the benchmarks had it).
        floor_z: height of the floor plane of the collision check in the base frame, m; ``None``: no
            floor (an arm whose base is not on the floor, e.g. a humanoid's arm hanging from its torso).
        pose_selection: ``"uniform"`` (poses drawn uniformly within the limits) or ``"diverse"``
            (drawn from a pool for gravity directions spread in every link frame; see
            :func:`skincal.protocol.limits.sample_static_poses`).
        notes: what :func:`skincal.protocol.limits.fit_to_limits` changed to fit a robot (amplitudes
            scaled, frequencies adapted), one sentence each; empty when nothing was changed.
    """

    n_poses: int = 16
    amplitude: float | tuple[float, ...] = 2.0
    frequency: float | tuple[float, ...] = 1.0
    excite_duration: float = 3.0
    rest_duration: float = 2.0
    static_duration: float = 1.0
    excited_joints: tuple[int, ...] | None = None
    rate_hz: float = 1000.0
    limit_margin: float = 0.05
    move_speed: float = 1.0
    min_move_duration: float = 1.0
    move_duration: float | None = None
    poses: FloatArray | None = None
    name: str = "custom"
    velocity_fraction: float | None = None
    collision_check: bool = False
    floor_z: float | None = 0.0
    pose_selection: str = "uniform"
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        set_ = lambda k, v: object.__setattr__(self, k, v)  # noqa: E731
        set_("amplitude", _scalar_or_tuple(self.amplitude, "amplitude (rad/s)"))
        set_("frequency", _scalar_or_tuple(self.frequency, "frequency (Hz)"))
        for key in ("excite_duration", "rate_hz", "move_speed"):
            value = getattr(self, key)
            if not (isinstance(value, (int, float, np.number)) and math.isfinite(value) and value > 0):
                raise ConfigError(f"protocol: {key} must be a positive number, got {value!r}")
            set_(key, float(value))
        for key in ("rest_duration", "static_duration", "limit_margin", "min_move_duration"):
            value = getattr(self, key)
            if not (isinstance(value, (int, float, np.number)) and math.isfinite(value) and value >= 0):
                raise ConfigError(f"protocol: {key} must be a non-negative number, got {value!r}")
            set_(key, float(value))
        if self.static_duration > self.rest_duration:
            raise ConfigError(
                f"protocol: static_duration {self.static_duration} s must not exceed rest_duration "
                f"{self.rest_duration} s (the static window lies within the rest)"
            )
        if self.move_duration is not None:
            if not (math.isfinite(self.move_duration) and self.move_duration > 0):
                raise ConfigError(f"protocol: move_duration must be positive (s) or null, got {self.move_duration!r}")
            set_("move_duration", float(self.move_duration))
        if self.excited_joints is not None:
            joints = tuple(int(j) for j in np.atleast_1d(np.asarray(self.excited_joints)))
            if any(j < 0 for j in joints) or len(set(joints)) != len(joints):
                raise ConfigError(f"protocol: excited_joints must be distinct 0-based indices, got {list(joints)}")
            set_("excited_joints", joints)
        if self.poses is not None:
            poses = np.array(self.poses, dtype=float)
            if poses.ndim != 2 or poses.shape[0] == 0 or not np.all(np.isfinite(poses)):
                raise ConfigError(f"protocol: poses must be a finite (P, n) array in rad, got shape {poses.shape}")
            poses.setflags(write=False)
            set_("poses", poses)
            set_("n_poses", int(poses.shape[0]))
        if self.velocity_fraction is not None and not (0 < self.velocity_fraction <= 1):
            raise ConfigError(f"protocol: velocity_fraction must be in (0, 1], got {self.velocity_fraction!r}")
        if not isinstance(self.collision_check, (bool, np.bool_)):
            raise ConfigError(f"protocol: collision_check must be true or false, got {self.collision_check!r}")
        set_("collision_check", bool(self.collision_check))
        if self.floor_z is not None:
            if isinstance(self.floor_z, bool) or not isinstance(self.floor_z, (int, float, np.number)) or not (
                math.isfinite(self.floor_z) and abs(self.floor_z) <= 1e3
            ):
                raise ConfigError(
                    f"protocol: floor_z must be a height in m (|z| <= 1000) or null, got {self.floor_z!r}"
                )
            set_("floor_z", float(self.floor_z))
        if self.pose_selection not in POSE_SELECTIONS:
            raise ConfigError(
                f"protocol: pose_selection must be one of {', '.join(POSE_SELECTIONS)}, got {self.pose_selection!r}"
            )
        if isinstance(self.notes, str) or not all(isinstance(x, str) for x in self.notes):
            raise ConfigError("protocol: notes must be a list of strings")
        set_("notes", tuple(self.notes))
        if not (isinstance(self.n_poses, (int, np.integer)) and self.n_poses >= 1):
            raise ConfigError(f"protocol: n_poses must be a positive integer, got {self.n_poses!r}")
        set_("n_poses", int(self.n_poses))

    def for_chain(self, chain) -> ProtocolConfig:
        """This config with robot-relative settings resolved (``velocity_fraction`` -> amplitudes)."""
        if self.velocity_fraction is None:
            return self
        if chain.velocity_limit is None:
            raise ConfigError(
                f"protocol '{self.name}' sets amplitudes as a fraction of the velocity limits, "
                f"but robot '{chain.name}' has none (a URDF chain has them when every joint's <limit velocity> is "
                "above 0): state them, or take a protocol with fixed amplitudes (paper-sim, paper-real)"
            )
        from dataclasses import replace

        amplitude = tuple(float(v) for v in self.velocity_fraction * chain.velocity_limit)
        return replace(self, amplitude=amplitude, velocity_fraction=None)

    # ------------------------------------------------------------------ per-joint views
    def _per_joint(self, value: float | tuple[float, ...], n: int, name: str) -> FloatArray:
        arr = np.broadcast_to(np.asarray(value, dtype=float), (n,)) if np.ndim(value) == 0 else np.asarray(value)
        if arr.shape != (n,):
            raise ConfigError(f"protocol '{self.name}': {name} has {arr.size} entries but the robot has {n} joints")
        return np.array(arr, dtype=float)

    def amplitude_per_joint(self, n: int) -> FloatArray:
        """Velocity amplitude ``A_j`` of every joint, ``(n,)`` rad/s."""
        return self._per_joint(self.amplitude, n, "amplitude")

    def frequency_per_joint(self, n: int) -> FloatArray:
        """Excitation frequency ``f_j`` of every joint, ``(n,)`` Hz."""
        return self._per_joint(self.frequency, n, "frequency")

    def joints_to_excite(self, n: int) -> tuple[int, ...]:
        """The 0-based excited joints for an ``n``-joint robot, in excitation order."""
        joints = tuple(range(n)) if self.excited_joints is None else self.excited_joints
        bad = [j for j in joints if j >= n]
        if bad:
            raise ConfigError(f"protocol '{self.name}': excited joint index {bad[0]} out of range for {n} joints")
        return joints

    # ------------------------------------------------------------------ (de)serialisation
    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready dictionary (tuples become lists, poses a nested list or ``None``)."""
        out: dict[str, Any] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, np.ndarray):
                value = value.tolist()
            elif isinstance(value, tuple):
                value = list(value)
            out[f.name] = value
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any], source: str = "protocol") -> ProtocolConfig:
        """Inverse of :meth:`to_dict`; unknown keys raise :class:`ConfigError` naming ``source``."""
        if not isinstance(data, dict):
            raise ConfigError(f"{source}: protocol config must be a mapping")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ConfigError(f"{source}: unknown protocol field(s) {', '.join(unknown)}")
        kwargs = dict(data)
        for key in ("amplitude", "frequency", "excited_joints", "notes"):
            if isinstance(kwargs.get(key), Sequence) and not isinstance(kwargs[key], str):
                kwargs[key] = tuple(kwargs[key])
        if kwargs.get("poses") is not None:
            kwargs["poses"] = np.asarray(kwargs["poses"], dtype=float)
        try:
            return cls(**kwargs)
        except ConfigError as exc:
            raise ConfigError(f"{source}: {exc}") from None
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"{source}: bad protocol config ({exc})") from None


def with_poses(config: ProtocolConfig, poses: ArrayLike) -> ProtocolConfig:
    """A copy of ``config`` with user-given static poses ``(P, n)`` in rad (``n_poses`` follows)."""
    from dataclasses import replace

    return replace(config, poses=np.asarray(poses, dtype=float))
