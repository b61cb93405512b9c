"""The frames a result is exported in: each link's ROS frame name (:func:`robot_names`, a link map
:func:`load_link_map`), each unit's parent frame, pose and covariance in it (:func:`unit_frames`,
:func:`pose_covariance`), and the check of every name an export would carry (:func:`check_names`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from skincal.data.export.escape import shown
from skincal.data.provenance import result_robot
from skincal.data.result import POSE_COVARIANCE, CalibrationResult, UnitResult, check_pose_covariance
from skincal.errors import ConfigError, DatasetError
from skincal.io.jsonio import load_yaml
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.transforms import FloatArray
from skincal.names import name_problem

FRAMES = ("unit", "range")
RANGE_SUFFIX = "_range"
T_SU_RANGE = np.array([[0.0, 0.0, -1.0, 0.0], [0.0, 1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
"""Pose of a unit's Range frame in the unit frame: ``Ry(-90 deg)``, so x_range = z_su (the ToF beam)."""
T_SU_RANGE.setflags(write=False)
COVARIANCE_ORDER = ("x", "y", "z", "rx", "ry", "rz")
UNKNOWN_VARIANCE = -1.0
"""Diagonal covariance entry of an axis the data do not determine (its row and column are 0)."""
MAX_EXPORT_VARIANCE = 1e12
"""A covariance entry beyond this (m^2 or rad^2: a std of 1000 km or rad) says the axis is not determined:
exported as :data:`UNKNOWN_VARIANCE` (a result's 1e308 overflowed the frame rotation to inf, then NaN)."""


@dataclass(frozen=True)
class RobotNames:
    """Frame names of a chain for ROS: ``links`` ``(n + 1)``, base first; ``joints`` ``(n)``;
    ``flange`` (a fixed frame at ``T_link_flange``) or None; ``maker`` True when they are the
    maker's URDF names of the same frames."""

    links: tuple[str, ...]
    joints: tuple[str, ...]
    flange: str | None
    maker: bool


_MAKER_NAMES = {
    # franka_description: panda_link<i> are the modified-DH frames {i}; panda_link8 the flange
    "panda": ("panda_link{i}", "panda_joint{i}", "panda_link0", "panda_link8"),
    # xarm_description: link<i> are the modified-DH frames {i} (joint origins rpy +-pi/2, xyz from the table)
    "xarm7": ("link{i}", "joint{i}", "link_base", None),
}


def _is_preset(chain: SerialChain) -> bool:
    from skincal.kinematics.presets import PRESETS

    return chain.name in PRESETS and chain.same_motion(PRESETS[chain.name]())


def robot_names(chain: SerialChain) -> RobotNames:
    """Link, joint and flange frame names of ``chain`` (see the module docstring)."""
    n = chain.n_joints
    has_flange = not np.array_equal(chain.T_link_flange, np.eye(4))
    if chain.source is not None or (chain.link_names is not None and chain.joint_names is not None):
        links = tuple(chain.link_name(i) for i in range(n + 1))
        joints = tuple(chain.joint_name(i) for i in range(1, n + 1))
        return RobotNames(links, joints, f"{links[-1]}_flange" if has_flange else None, chain.source is not None)
    if _is_preset(chain) and chain.name in _MAKER_NAMES:
        link, joint, base, flange = _MAKER_NAMES[chain.name]
        links = (base, *(link.format(i=i) for i in range(1, n + 1)))
        return RobotNames(
            links, tuple(joint.format(i=i) for i in range(1, n + 1)), flange if has_flange else None, True
        )
    links = tuple(f"{chain.name}_dh_link{i}" for i in range(n + 1))
    joints = tuple(f"{chain.name}_dh_joint{i}" for i in range(1, n + 1))
    return RobotNames(links, joints, f"{chain.name}_dh_flange" if has_flange else None, False)


@dataclass(frozen=True)
class LinkFrame:
    """A named parent frame for skincal link ``i``: ``T_frame_link`` ``(4, 4)``, m, is the pose of
    link frame ``i`` in the frame called ``name``."""

    name: str
    T_frame_link: FloatArray


@dataclass(frozen=True)
class UnitFrame:
    """One exported frame: the ``child`` frame (``<prefix><unit>`` or ``<prefix><unit>_range``) of
    ``unit`` in its ``parent`` frame (``link`` 1-based): ``p_parent_child`` ``(3,)`` m,
    ``R_parent_child`` ``(3, 3)``, ``observable``; ``covariance`` ``(6, 6)`` of ``(x, y, z, rx, ry,
    rz)`` in the parent frame's axes (m^2, rad^2; :data:`UNKNOWN_VARIANCE` on the diagonal of an
    undetermined axis, whose row and column are otherwise 0) and its ``covariance_source``: ``full``
    (the result's full covariance), ``std`` (diagonal from the per-axis std, correlations unknown) or
    ``none`` (no uncertainty in the result: ``[0][0] = -1``, the rest 0, ROS's "unknown")."""

    unit: str
    child: str
    parent: str
    link: int
    p_parent_child: FloatArray
    R_parent_child: FloatArray
    observable: bool
    covariance: FloatArray
    covariance_source: str
    position_std_m: FloatArray | None = None
    rotation_std_deg: FloatArray | None = None

    @property
    def T(self) -> FloatArray:
        """``T_parent_child`` ``(4, 4)``."""
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.R_parent_child, self.p_parent_child
        return T

    @property
    def quaternion_wxyz(self) -> FloatArray:
        """Unit quaternion ``(w, x, y, z)`` of ``R_parent_child`` with ``w >= 0``."""
        q = Rotation.from_matrix(self.R_parent_child).as_quat(scalar_first=True)
        return -q if q[0] < 0 else q

    @property
    def rpy(self) -> FloatArray:
        """URDF roll, pitch, yaw (rad): ``R = Rz(yaw) Ry(pitch) Rx(roll)``."""
        return rpy_from_matrix(self.R_parent_child)


def rpy_from_matrix(R: FloatArray) -> FloatArray:
    """URDF roll, pitch, yaw (rad) of a rotation ``R = Rz(yaw) Ry(pitch) Rx(roll)``; yaw and pitch
    from the first column, roll from the remainder ``(Rz Ry)^T R`` (accurate near pitch = +-90 deg;
    yaw 0 exactly there)."""
    R = np.asarray(R, dtype=float)
    cp = math.hypot(R[0, 0], R[1, 0])
    yaw = math.atan2(R[1, 0], R[0, 0])  # atan2(0, 0) = 0 at exact gimbal lock
    pitch = math.atan2(-R[2, 0], cp)
    rest = Rotation.from_euler("ZY", [yaw, pitch]).as_matrix().T @ R  # intrinsic: (Rz(yaw) Ry(pitch))^T R
    roll = math.atan2(rest[2, 1], rest[1, 1])
    return np.array([roll, pitch, yaw])


def _transform(xyz: object, rpy: object, where: str) -> FloatArray:
    try:
        p = np.array(xyz, dtype=float).reshape(3)
        angles = np.array(rpy, dtype=float).reshape(3)
    except (TypeError, ValueError):
        raise ConfigError(f"{where}: xyz (m) and rpy (rad) must be lists of 3 numbers") from None
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(angles))):
        raise ConfigError(f"{where}: xyz and rpy must be finite")
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", angles).as_matrix()
    T[:3, 3] = p
    return T


def load_link_map(path: str | Path) -> dict[int, LinkFrame]:
    """Read a link map YAML (see the module docstring) into ``{link: LinkFrame}``."""
    doc = load_yaml(path, "link map", ConfigError)
    links = doc.get("links") if isinstance(doc, dict) else None
    if not isinstance(links, dict) or not links:
        raise ConfigError(f"{path}: expected a mapping 'links: {{<link number>: <frame name> or {{frame, xyz, rpy}}}}'")
    out = {}
    for key, value in links.items():
        if isinstance(key, bool) or not isinstance(key, int) or key < 1:
            raise ConfigError(f"{path}: links key {key!r} must be a 1-based link number")
        where = f"{path}: links.{key}"
        frame = value.get("frame") if isinstance(value, dict) else value
        problem = _frame_problem(frame) if isinstance(frame, str) else None
        if problem is not None:
            raise ConfigError(f"{where}: frame name '{shown(frame)}' {problem}")
        if isinstance(value, str):
            out[key] = LinkFrame(value, np.eye(4))
        elif isinstance(value, dict) and isinstance(value.get("frame"), str) and value["frame"]:
            unknown = set(value) - {"frame", "xyz", "rpy"}
            if unknown:
                raise ConfigError(f"{where}: unknown key(s) {', '.join(sorted(unknown))} (frame, xyz, rpy)")
            out[key] = LinkFrame(
                value["frame"], _transform(value.get("xyz", [0, 0, 0]), value.get("rpy", [0, 0, 0]), where)
            )
        else:
            raise ConfigError(f"{where}: must be a frame name or {{frame: name, xyz: [m], rpy: [rad]}}")
    return out


def link_frames_for(chain: SerialChain | None, link_map: str | Path | None = None) -> dict[int, LinkFrame] | None:
    """The link frames: from ``link_map`` when given, else named after ``chain``
    (:func:`robot_names`, identity offsets); ``None`` when neither is given."""
    if link_map is not None:
        return load_link_map(link_map)
    if chain is None:
        return None
    names = robot_names(chain).links
    return {i: LinkFrame(names[i], np.eye(4)) for i in range(1, chain.n_joints + 1)}


def pose_covariance(unit: UnitResult, R_frame_link: FloatArray, name: str = "unit") -> tuple[FloatArray, str]:
    """``(6, 6)`` covariance of ``(x, y, z, rx, ry, rz)`` (m^2, rad^2) of a unit in a parent frame
    whose axes are ``R_frame_link`` of the link's, and its source (``full``, ``std``, ``none``).

    From ``unit.pose_covariance`` when the result holds one (link axes; result field ``pose_covariance``), else
    ``diag(position_std_m^2, rotation_std^2)``; rotated by ``blockdiag(R, R)`` (position and small
    rotations about the link axes both turn with the frame). An undetermined axis (NaN, or an entry in
    its row beyond :data:`MAX_EXPORT_VARIANCE`) gets
    :data:`UNKNOWN_VARIANCE` on the diagonal and 0 elsewhere in its row and column; an offset
    frame that mixes it into other axes marks those too. No uncertainty at all: ``[0][0] = -1``."""
    cov = None
    if unit.pose_covariance is not None:
        where = f"result: units.{shown(name)}.{POSE_COVARIANCE}"
        cov, source = check_pose_covariance(unit.pose_covariance, where), "full"
    elif unit.position_std_m is not None and unit.rotation_std_deg is not None:
        std = np.concatenate([np.asarray(unit.position_std_m, float), np.radians(unit.rotation_std_deg)])
        with np.errstate(over="ignore"):
            cov, source = np.diag(std**2), "std"
    if cov is None:
        out = np.zeros((6, 6))
        out[0, 0] = UNKNOWN_VARIANCE
        return out, "none"
    with np.errstate(over="ignore", invalid="ignore"):  # std^2 of a huge std: inf, i.e. undetermined
        huge = ~np.isfinite(cov) | (np.abs(np.nan_to_num(cov)) > MAX_EXPORT_VARIANCE)
    unknown = ~np.isfinite(np.diag(cov)) | np.any(huge, axis=0)
    cov = np.where(unknown[:, None] | unknown[None, :], 0.0, cov)
    cov = 0.5 * (cov + cov.T)
    B = np.zeros((6, 6))
    B[:3, :3] = B[3:, 3:] = R_frame_link
    out = B @ cov @ B.T
    out = 0.5 * (out + out.T)  # exactly symmetric after rounding
    mixed = (np.abs(B) > 1e-12) @ unknown.astype(float) > 0  # parent axes any unknown link axis reaches
    out[mixed, :] = 0.0
    out[:, mixed] = 0.0
    out[mixed, mixed] = UNKNOWN_VARIANCE
    return out, source


def unit_frames(
    result: CalibrationResult, links: dict[int, LinkFrame] | None = None, *, frame: str = "unit", prefix: str = ""
) -> list[UnitFrame]:
    """Each unit's exported frame in its named parent frame, ``T_frame_link @ T_link_su`` (``frame
    = "unit"``) or ``... @ T_SU_RANGE`` (``"range"``).

    ``links`` defaults to the frames of ``result.robot`` when it is a preset; raises
    :class:`ConfigError` when a unit's link has no frame (naming the unit and the options to use).
    """
    if frame not in FRAMES:
        raise ConfigError(f"unknown frame '{shown(str(frame))}' (use {' or '.join(FRAMES)})")
    links = links if links is not None else link_frames_for(result_robot(result))
    if links is None:
        raise ConfigError(
            f"robot '{shown(str(result.robot))}' is not a preset; give the robot (--robot arm.urdf or "
            "a preset) or a link map (--robot-links map.yaml with links: {1: frame, ...})"
        )
    out = []
    suffix = RANGE_SUFFIX if frame == "range" else ""
    for unit, res in result.units.items():
        parent = links.get(res.pose.link)
        if parent is None:
            raise ConfigError(
                f"unit '{shown(str(unit))}' is on link {res.pose.link}, which the link map does not name"
            )
        T = parent.T_frame_link @ res.pose.T_link_su
        if frame == "range":
            T = T @ T_SU_RANGE
        cov, source = pose_covariance(res, parent.T_frame_link[:3, :3], unit)
        out.append(
            UnitFrame(
                unit,
                f"{prefix}{unit}{suffix}",
                parent.name,
                res.pose.link,
                T[:3, 3].copy(),
                T[:3, :3].copy(),
                res.observable,
                cov,
                source,
                res.position_std_m,
                res.rotation_std_deg,
            )
        )
    return out


def _frame_problem(frame: object) -> str | None:
    """A ROS frame id may be namespaced (``robot1/base_link``): each ``/``-separated part must be a
    name (:func:`name_problem`)."""
    if not isinstance(frame, str) or "/" not in frame:
        return name_problem(frame)
    for part in frame.split("/"):
        problem = name_problem(part)
        if problem is not None:
            return f"has a part '{shown(part)}' that {problem}"
    return None


def check_robot_name(result: CalibrationResult) -> None:
    problem = name_problem(result.robot)
    if problem is not None:
        raise DatasetError(f"robot name '{shown(str(result.robot))}' {problem}; the result cannot be exported")


def check_names(result: CalibrationResult, frames: list[UnitFrame]) -> None:
    """Refuse, with a one-line :class:`DatasetError` (names from the result) or :class:`ConfigError`
    (frame names from the link map or the prefix), any name an export would carry that
    :func:`skincal.names.name_problem` refuses. Every writer calls it before writing a byte."""
    check_robot_name(result)
    children: set[str] = set()
    for f in frames:
        problem = name_problem(f.unit)
        if problem is not None:
            raise DatasetError(
                f"unit name '{shown(str(f.unit))}' {problem}; rename the unit in the result to export it"
            )
        problem = _frame_problem(f.parent)
        if problem is not None:
            raise ConfigError(
                f"unit '{f.unit}': parent frame name '{shown(str(f.parent))}' {problem}; fix the link map"
            )
        problem = _frame_problem(f.child)
        if problem is not None:
            raise ConfigError(f"unit '{f.unit}': frame name '{shown(f.child)}' {problem}; choose another prefix")
        if f.child in children:  # pragma: no cover - unit names are distinct keys
            raise ConfigError(f"frame name '{shown(f.child)}' appears twice")
        children.add(f.child)
