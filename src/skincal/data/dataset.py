"""The in-memory dataset: plain frozen dataclasses of NumPy arrays (``docs/interfaces.md``).

Every stream carries its own time base in seconds on one shared clock; the robot and each IMU
sample at their own instants. Validation of contents lives in :mod:`skincal.data.validate`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from skincal.kinematics.chain import GRAVITY_BASE, SerialChain
from skincal.kinematics.transforms import FloatArray
from skincal.skin.pose import SkinUnitPose

STATIC = 0
"""``Segments.kind`` of a static segment (robot at rest)."""
DYNAMIC = 1
"""``Segments.kind`` of a dynamic segment (one joint excited)."""


@dataclass(frozen=True)
class JointStates:
    """Robot joint stream. ``t``: ``(N,)`` s, strictly increasing; ``q``, ``qd``, ``qdd``: ``(N, n)``
    in rad, rad/s, rad/s^2 (``qdd`` optional: real robots rarely report it)."""

    t: FloatArray
    q: FloatArray
    qd: FloatArray
    qdd: FloatArray | None = None


@dataclass(frozen=True)
class ImuStream:
    """One unit's IMU stream in the unit frame. ``t``: ``(M,)`` s; ``accel``: ``(M, 3)`` specific
    force ``f = R_base_su^T (a - g)`` m/s^2; ``gyro``: ``(M, 3)`` rad/s (optional)."""

    t: FloatArray
    accel: FloatArray
    gyro: FloatArray | None = None


@dataclass(frozen=True)
class TofStream:
    """One unit's time-of-flight stream: ``t`` ``(K,)`` s, ``range`` ``(K,)`` m along the unit's +z,
    NaN where no target was seen."""

    t: FloatArray
    range: FloatArray


@dataclass(frozen=True)
class Segments:
    """Protocol segments, each ``(S,)``: start/end time (s), ``kind`` (:data:`STATIC` or
    :data:`DYNAMIC`), 0-based ``pose`` index and 0-based excited ``joint`` (-1 when static)."""

    t_start: FloatArray
    t_end: FloatArray
    kind: np.ndarray
    pose: np.ndarray
    joint: np.ndarray

    def __len__(self) -> int:
        return int(np.asarray(self.t_start).shape[0])


@dataclass(frozen=True)
class Dataset:
    """A recording (or simulation) of one calibration session.

    Attributes:
        robot: the kinematic chain (name, convention, DH table, limits).
        joints: robot joint stream.
        imu: per-unit IMU streams, keyed by unit name.
        tof: per-unit time-of-flight streams (may be empty).
        segments: protocol segments, or ``None`` (then segmented automatically).
        truth: true unit poses (simulation only; may be empty).
        gravity: ``(3,)`` gravity in the base frame, m/s^2.
        description: free text.
        truth_sensor: true simulated sensor errors per unit (simulation only; may be empty), e.g.
            ``accel_bias`` ``(3,)`` m/s^2, ``accel_scale`` ``(3,)``, ``accel_misalignment`` ``(3, 3)``,
            ``time_offset_s`` (float, s); stored as extra attrs of ``/truth/<unit>``.
    """

    robot: SerialChain
    joints: JointStates
    imu: dict[str, ImuStream]
    tof: dict[str, TofStream] = field(default_factory=dict)
    segments: Segments | None = None
    truth: dict[str, SkinUnitPose] = field(default_factory=dict)
    gravity: FloatArray = field(default_factory=lambda: GRAVITY_BASE.copy())
    description: str = ""
    truth_sensor: dict[str, dict[str, FloatArray | float]] = field(default_factory=dict)

    @property
    def units(self) -> list[str]:
        """Unit names in a stable order (the order of ``imu``)."""
        return list(self.imu)

    @property
    def duration(self) -> float:
        """Length of the joint stream, s."""
        t = self.joints.t
        return float(t[-1] - t[0]) if len(t) else 0.0
