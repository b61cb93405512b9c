"""The in-memory dataset: plain frozen dataclasses of NumPy arrays (``docs/interfaces.md``).

Every stream carries its own time base in seconds on one shared clock; the robot and each IMU
sample at their own instants. Validation of contents lives in :mod:`skincal.data.validate`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from skincal.data.events import MoveEvent
from skincal.errors import DatasetError
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
class BodyPose:
    """A unit's true pose on a named rigid body (IMU-only simulations, no robot): ``body`` names the
    body, ``T_body_su`` ``(4, 4)`` is the unit frame in the body's frame (m)."""

    body: str
    T_body_su: FloatArray


NO_JOINTS_MESSAGE = "this dataset has no joint states"
"""Start of the one-line error of every command that needs joint states and gets an IMU-only dataset."""


@dataclass(frozen=True)
class Dataset:
    """A recording (or simulation) of one calibration session.

    An IMU-only dataset (skin without encoders: a closed controller, a hand-held patch, a bench test)
    has ``joints = None`` and may have ``robot = None``; a dataset with joints always has its robot.

    Attributes:
        robot: the kinematic chain (name, convention, DH table, limits), or ``None`` (IMU-only).
        joints: robot joint stream, or ``None`` (IMU-only: see :attr:`has_joints`).
        imu: per-unit IMU streams, keyed by unit name.
        tof: per-unit time-of-flight streams (may be empty).
        segments: protocol segments, or ``None`` (then segmented automatically).
        truth: true unit poses (simulation only; may be empty).
        gravity: ``(3,)`` gravity in the base frame, m/s^2.
        description: free text.
        truth_sensor: true simulated sensor errors per unit (simulation only; may be empty), e.g.
            ``accel_bias`` ``(3,)`` m/s^2, ``accel_scale`` ``(3,)``, ``accel_misalignment`` ``(3, 3)``,
            ``time_offset_s`` (float, s); stored as extra attrs of ``/truth/<unit>``.
        truth_body: true unit poses on named rigid bodies (IMU-only simulations; may be empty),
            stored as ``/truth/<unit>`` attrs ``body`` and ``T_body_su``.
        events: moved-unit events noticed while recording (:class:`~skincal.data.events.MoveEvent`:
            ``unit``, ``t_change_s``, ``t_detected_s``, ...), stored as ``/events/<k>`` attrs; may be empty.
    """

    robot: SerialChain | None
    joints: JointStates | None
    imu: dict[str, ImuStream]
    tof: dict[str, TofStream] = field(default_factory=dict)
    segments: Segments | None = None
    truth: dict[str, SkinUnitPose] = field(default_factory=dict)
    gravity: FloatArray = field(default_factory=lambda: GRAVITY_BASE.copy())
    description: str = ""
    truth_sensor: dict[str, dict[str, FloatArray | float]] = field(default_factory=dict)
    truth_body: dict[str, BodyPose] = field(default_factory=dict)
    events: tuple[MoveEvent, ...] = ()

    @property
    def has_joints(self) -> bool:
        """Whether the dataset has a joint stream (``False``: IMU-only)."""
        return self.joints is not None

    def require_joints(self, command: str = "this step", source: str | None = None) -> tuple[SerialChain, JointStates]:
        """The robot and the joint stream, or a one-line :class:`~skincal.errors.DatasetError` when the
        dataset is IMU-only (``command`` names what needs them; ``source``, the file, starts the message)."""
        if self.joints is None or self.robot is None:
            where = f"{source}: " if source else ""
            raise DatasetError(f"{where}{NO_JOINTS_MESSAGE}: {command} needs the robot's joint states")
        return self.robot, self.joints

    @property
    def chain(self) -> SerialChain:
        """The robot, for code that needs it (a one-line :class:`~skincal.errors.DatasetError` if none)."""
        if self.robot is None:
            raise DatasetError("this dataset has no robot: this step needs the robot's kinematic chain")
        return self.robot

    @property
    def joint_states(self) -> JointStates:
        """The joint stream, for code that needs it (a one-line :class:`~skincal.errors.DatasetError`
        for an IMU-only dataset)."""
        return self.require_joints()[1]

    @property
    def units(self) -> list[str]:
        """Unit names in a stable order (the order of ``imu``)."""
        return list(self.imu)

    @property
    def duration(self) -> float:
        """Length of the joint stream, s (IMU-only: from the first to the last IMU sample)."""
        if self.joints is not None:
            t = self.joints.t
            return float(t[-1] - t[0]) if len(t) else 0.0
        starts = [float(s.t[0]) for s in self.imu.values() if len(s.t)]
        ends = [float(s.t[-1]) for s in self.imu.values() if len(s.t)]
        return max(ends) - min(starts) if starts else 0.0
