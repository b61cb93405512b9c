"""What the viewer draws, as plain numbers: no viser here, so every quantity is testable.

Frames: ``T_base_link`` ``(n + 1, 4, 4)`` are the link frames of :meth:`SerialChain.link_frames`
(frame 0 = base); unit poses ``T_link_su`` are in their link frame; everything shown is in the
robot base frame {0}, m. Capsules (:func:`skincal.kinematics.geometry.link_capsules`) become a
cylinder (axis = local z of its own pose ``T_link_cyl``) and two end spheres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from skincal.data.dataset import Dataset
from skincal.data.interp import interp_rows
from skincal.data.result import CalibrationResult
from skincal.errors import ConfigError
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.geometry import Capsule
from skincal.kinematics.transforms import FloatArray
from skincal.skin.pose import SkinUnitPose

UNIT_BOX_M = (0.033, 0.036, 0.005)
"""Size of a skin unit board along its x, y, z axes, m (33 x 36 x 5 mm)."""
ELLIPSOID_SIGMA = 3.0
"""Uncertainty ellipsoids are drawn at this many standard deviations."""
ELLIPSOID_FLOOR_M = 0.005
"""Smallest drawn ellipsoid semi-axis, m (a 3 sigma of micrometres would be invisible)."""
UNOBSERVABLE_SEMI_AXIS_M = 0.05
"""Semi-axis drawn along a direction the data cannot determine (std NaN), m."""
ERROR_FULL_SCALE_MM = 10.0
"""Position error shown fully red; 0 mm is green."""


def cylinder_pose(capsule: Capsule) -> tuple[FloatArray, float]:
    """Pose ``T_link_cyl`` ``(4, 4)`` of a capsule's core cylinder (centred, axis = its local z)
    and the cylinder's length, m. A zero-length capsule gives the identity rotation and length 0."""
    T = np.eye(4)
    T[:3, 3] = 0.5 * (capsule.p0 + capsule.p1)
    length = capsule.length
    if length > 0:
        z = (capsule.p1 - capsule.p0) / length
        helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        x = np.cross(helper, z)
        x /= np.linalg.norm(x)
        T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    return T, length


def ellipsoid_semi_axes(
    position_std_m: ArrayLike | None, floor_m: float = ELLIPSOID_FLOOR_M
) -> tuple[FloatArray, np.ndarray]:
    """Semi-axes ``(3,)`` (m, along the link axes) of a unit's uncertainty ellipsoid:
    ``max(ELLIPSOID_SIGMA * std, floor_m)``, and a ``(3,)`` mask of unobservable axes
    (std NaN or infinite) drawn at :data:`UNOBSERVABLE_SEMI_AXIS_M`. No std at all gives the floor."""
    if position_std_m is None:
        return np.full(3, floor_m), np.zeros(3, dtype=bool)
    std = np.asarray(position_std_m, dtype=float)
    unknown = ~np.isfinite(std)
    semi = np.maximum(ELLIPSOID_SIGMA * np.where(unknown, 0.0, std), floor_m)
    return np.where(unknown, UNOBSERVABLE_SEMI_AXIS_M, semi), unknown


def error_color(position_error_mm: float) -> tuple[int, int, int]:
    """RGB 0..255 from green (0 mm) through yellow to red (>= :data:`ERROR_FULL_SCALE_MM`)."""
    s = float(np.clip(position_error_mm / ERROR_FULL_SCALE_MM, 0.0, 1.0)) if np.isfinite(position_error_mm) else 1.0
    red = min(1.0, 2.0 * s)
    green = min(1.0, 2.0 * (1.0 - s))
    return int(round(230 * red)), int(round(200 * green)), 40


def unit_poses_base(chain: SerialChain, poses: dict[str, SkinUnitPose], q: ArrayLike) -> dict[str, FloatArray]:
    """``T_base_su = T_base_link(q) T_link_su`` ``(4, 4)`` of each unit at joint angles ``q`` ``(n,)``, rad."""
    frames = chain.link_frames(np.asarray(q, dtype=float)[None, :])[0]
    return {name: frames[pose.link] @ pose.T_link_su for name, pose in poses.items()}


@dataclass(frozen=True)
class ObstacleTrack:
    """A moving obstacle drawn as a sphere: centre ``p_base`` ``(T, 3)`` m at instants ``t`` ``(T,)`` s."""

    t: FloatArray
    p_base: FloatArray
    radius: float


@dataclass(frozen=True)
class Recording:
    """What the viewer plays back.

    Attributes:
        t: ``(N,)`` joint-stream instants, s.
        q: ``(N, n)`` joint angles, rad.
        tof_t, tof_range: per unit ``(K,)`` instants (s) and ranges along the unit's +z (m, NaN = none).
        obstacles: moving obstacles by name (avoidance scenarios); empty for calibration datasets.
    """

    t: FloatArray
    q: FloatArray
    tof_t: dict[str, FloatArray]
    tof_range: dict[str, FloatArray]
    obstacles: dict[str, ObstacleTrack]

    @classmethod
    def from_dataset(cls, dataset: Dataset) -> Recording:
        """The joint stream and ToF streams of a dataset (no obstacle tracks: datasets do not store them)."""
        return cls(
            t=np.asarray(dataset.joints.t, dtype=float),
            q=np.asarray(dataset.joints.q, dtype=float),
            tof_t={u: np.asarray(s.t, dtype=float) for u, s in dataset.tof.items()},
            tof_range={u: np.asarray(s.range, dtype=float) for u, s in dataset.tof.items()},
            obstacles={},
        )

    @property
    def t_start(self) -> float:
        return float(self.t[0])

    @property
    def t_end(self) -> float:
        return float(self.t[-1])

    def q_at(self, t: float) -> FloatArray:
        """Joint angles ``(n,)`` at instant ``t`` (s), linear between samples, held at the ends."""
        return interp_rows(float(t), self.t, self.q)

    def obstacle_positions(self, t: float) -> dict[str, FloatArray]:
        """Centre ``(3,)`` of each obstacle at instant ``t`` (s), linear between samples."""
        return {name: interp_rows(float(t), tr.t, tr.p_base) for name, tr in self.obstacles.items()}


def tof_points_base(
    chain: SerialChain,
    poses: dict[str, SkinUnitPose],
    recording: Recording,
    t_from: float,
    t_to: float,
) -> tuple[FloatArray, FloatArray, list[str]]:
    """Obstacle points seen by the ToF sensors in ``[t_from, t_to]`` (s), in the base frame.

    Each reading ``r`` of unit ``k`` becomes ``x = p_base_su + r z_base_su`` with the unit's pose
    from ``poses`` (the calibrated ones) and the robot at the reading's instant (joint angles
    interpolated linearly). Returns ``(origins (M, 3), points (M, 3), unit names (M,))``; readings
    without a target (NaN) or without a pose are skipped.
    """
    origins, points, names = [], [], []
    for unit, t in recording.tof_t.items():
        if unit not in poses:
            continue
        r = recording.tof_range[unit]
        sel = (t >= t_from) & (t <= t_to) & np.isfinite(r)
        if not np.any(sel):
            continue
        ts, rs = t[sel], r[sel]
        q = interp_rows(ts, recording.t, recording.q)
        pose = poses[unit]
        T = chain.link_frames(q, upto=pose.link)[:, pose.link] @ pose.T_link_su
        origins.append(T[:, :3, 3])
        points.append(T[:, :3, 3] + rs[:, None] * T[:, :3, 2])
        names += [unit] * len(ts)
    if not origins:
        return np.zeros((0, 3)), np.zeros((0, 3)), []
    return np.concatenate(origins), np.concatenate(points), names


def check_result_robot(result: CalibrationResult, chain: SerialChain) -> None:
    """Every unit's link must exist on ``chain``; otherwise a :class:`ConfigError` naming the unit."""
    for name, unit in result.units.items():
        if not 1 <= unit.pose.link <= chain.n_joints:
            raise ConfigError(
                f"unit '{name}': link {unit.pose.link} does not exist on robot '{chain.name}' ({chain.n_joints} links)"
            )


def project_to_image(
    points_base: ArrayLike,
    camera_position: ArrayLike,
    look_at: ArrayLike,
    fov_vertical_rad: float,
    width: int,
    height: int,
    up: ArrayLike = (0.0, 0.0, 1.0),
) -> tuple[FloatArray, FloatArray]:
    """Pixel coordinates ``(M, 2)`` (x right, y down, origin top-left) and camera depth ``(M,)`` (m)
    of base-frame points seen by a pinhole camera at ``camera_position`` looking at ``look_at``
    with ``up`` roughly up on screen and a vertical field of view ``fov_vertical_rad`` over
    ``height`` pixels: ``x = w/2 + f X/Z``, ``y = h/2 - f Y/Z``, ``f = (h/2) / tan(fov/2)``, with
    ``(X, Y, Z)`` the point in the camera frame (Z forward, Y up)."""
    p = np.atleast_2d(np.asarray(points_base, dtype=float))
    eye = np.asarray(camera_position, dtype=float)
    forward = np.asarray(look_at, dtype=float) - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, np.asarray(up, dtype=float))
    right /= np.linalg.norm(right)
    cam_up = np.cross(right, forward)
    d = p - eye
    X, Y, Z = d @ right, d @ cam_up, d @ forward
    f = 0.5 * height / np.tan(0.5 * fov_vertical_rad)
    return np.column_stack([0.5 * width + f * X / Z, 0.5 * height - f * Y / Z]), Z
