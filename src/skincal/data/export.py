"""Exports of a calibration result for ROS: complete URDF, xacro macro, YAML/JSON with covariance,
one static-TF node for ROS 1 or ROS 2, CSV (``docs/interfaces.md``, section "Exports").

Every unit pose of a result is ``T_link_su`` in skincal link frame ``i`` (``docs/interfaces.md``).
ROS tools name their own frames, so each link is mapped to a named parent frame with a fixed
offset ``T_frame_link`` (the pose of link frame ``i`` in that frame); the exported pose is
``T_frame_child = T_frame_link @ T_link_su [@ T_SU_RANGE]``.

Link frame names come from the robot (:func:`robot_names`), no map needed:

* a URDF robot (``--robot arm.urdf``): its own link names (link frame ``i`` *is* the URDF frame of
  the child link of the ``i``-th movable joint);
* ``panda`` and ``xarm7``: the maker's URDF names (``panda_link<i>``; ``link_base``, ``link<i>``),
  because those URDF frames are the presets' modified-DH frames (same origins and axes);
* any other DH chain (``ur5e``, ``sawyer``, a DH chain file): ``<robot>_dh_link<i>``, since its DH
  frames are *not* the maker's URDF frames and must not be taken for them;
* a result exported onto another description of its robot (a DH preset's result onto the maker's
  URDF): each pose is moved into the target's link frame, ``X_i @ T_link_su`` with ``X_i =
  T_targetlink_sourcelink`` from both chains' forward kinematics (:func:`link_offsets`, refused when
  they do not move alike; the source chain from :func:`result_chain` or the dataset);
* ``--robot-links map.yaml`` overrides: ``{links: {<i>: <frame> | {frame: <name>, xyz: [m], rpy:
  [rad]}}}``; ``rpy`` is URDF's fixed-axis roll-pitch-yaw, ``R = Rz(yaw) Ry(pitch) Rx(roll)``.

``frame="range"`` exports, instead of each unit frame, its Range frame ``<unit>_range``: the ToF
beam (the unit's +z) is its +x, as ``sensor_msgs/Range`` expects: ``T_su_range = Ry(-90 deg)``
(:data:`T_SU_RANGE`; x_range = z_su, y_range = y_su, z_range = -x_su).

Quaternion order: skincal writes ``(w, x, y, z)`` (field ``quaternion_wxyz``); ROS uses
``(x, y, z, w)``: the TF nodes hold ``(x, y, z, w)`` and the CSV names its columns ``qw, qx, qy,
qz``. Files are written atomically.

Escaping by construction (no user text is ever pasted into a template):

* names: every unit name and the robot name must pass :func:`skincal.names.name_problem`, and
  the parent and child frame names (link map, ``prefix``) the same rule for each ``/``-separated
  part; anything else is refused with a one-line error naming it, before a byte is written;
* URDF and xacro: built with :mod:`xml.etree.ElementTree` (the user's URDF parsed with ``lxml``
  and extended element by element; names only in attributes, which the libraries escape); comments
  hold fixed text, and the method and robot appear there only as JSON string literals with every
  ``-`` written ``\\u002d`` and ``$`` written ``\\u0024``; in the xacro, names pass
  :func:`_xacro_text` (a ``$`` run before ``{`` or ``(`` gets one more ``$``: xacro's escape);
* TF nodes: a fixed code skeleton; user data appear only as Python literals made by :func:`repr`
  of plain strings and numbers and checked with :func:`ast.literal_eval` (never in the docstring,
  a comment or a code position);
* CSV: through :mod:`csv`; a text cell starting with ``=``, ``+``, ``-``, ``@``, tab or CR gets a
  leading ``'`` (spreadsheet formula neutralisation); numbers are written as numbers;
* YAML and JSON: through :func:`yaml.safe_dump` and :func:`json.dumps`.
"""

from __future__ import annotations

import ast
import csv
import io
import json
import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from skincal.data.provenance import result_robot
from skincal.data.result import POSE_COVARIANCE, CalibrationResult, UnitResult, check_pose_covariance
from skincal.errors import ConfigError, DatasetError
from skincal.io.atomic import write_bytes_atomic
from skincal.io.jsonio import load_yaml
from skincal.kinematics.chain import PRISMATIC, SerialChain
from skincal.kinematics.transforms import FloatArray
from skincal.names import name_problem, printable

FORMATS = ("urdf", "xacro", "yaml", "json", "tf", "tf-ros2", "tf-ros1", "csv")
"""Export formats; ``tf`` is ``tf-ros2``."""
FRAMES = ("unit", "range")
RANGE_SUFFIX = "_range"
T_SU_RANGE = np.array([[0.0, 0.0, -1.0, 0.0], [0.0, 1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
"""Pose of a unit's Range frame in the unit frame: ``Ry(-90 deg)``, so x_range = z_su (the ToF beam)."""
T_SU_RANGE.setflags(write=False)
COVARIANCE_ORDER = ("x", "y", "z", "rx", "ry", "rz")
UNKNOWN_VARIANCE = -1.0
"""Diagonal covariance entry of an axis the data do not determine (its row and column are 0)."""


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
            raise ConfigError(f"{where}: frame name '{_shown(frame)}' {problem}")
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


SAME_MOTION_ATOL_M = 1e-4
"""Largest change (m) of a link offset ``T_target_source`` over configurations that still counts as
the same motion (a URDF rounds its numbers: xarm_description writes pi/2 as 1.5708, 1e-5 m at the
tool; far below a calibration's millimetres)."""
SAME_MOTION_ATOL_RAD = 1e-4
"""The same for the offset's rotation (rad)."""


def _offset_spread(X: FloatArray) -> tuple[float, float]:
    """Largest change over configurations of offsets ``X`` ``(N, n + 1, 4, 4)`` from ``X[0]``:
    position (m) and rotation angle (rad)."""
    dp = float(np.max(np.linalg.norm(X[:, :, :3, 3] - X[:1, :, :3, 3], axis=-1)))
    dR = np.swapaxes(X[:1, :, :3, :3], -1, -2) @ X[:, :, :3, :3]
    return dp, float(np.max(Rotation.from_matrix(dR.reshape(-1, 3, 3)).magnitude()))


def _base_offset(source: SerialChain, target: SerialChain, F_s: FloatArray, F_t: FloatArray) -> FloatArray | None:
    """``T_targetbase_sourcebase`` ``B`` with ``U_k B = B D_k`` for the motions of the last link between
    configuration 0 and the single-joint steps ``1..n`` (``U_k = F_t[k] F_t[0]^-1``, the same ``D_k`` of
    ``source``; the hand-eye equation ``AX = XB``): the rotation by Kabsch from the motions' rotation
    vectors (a prismatic joint's translation), then ``(R_U - I) t_B = R_B t_D - t_U`` by least squares.
    None when the motions do not determine ``B`` (parallel axes only)."""
    n = source.n_joints
    U = F_t[1 : n + 1, -1] @ np.linalg.inv(F_t[0, -1])
    D = F_s[1 : n + 1, -1] @ np.linalg.inv(F_s[0, -1])
    a = np.where(source.revolute[:, None], Rotation.from_matrix(U[:, :3, :3]).as_rotvec(), U[:, :3, 3])
    b = np.where(source.revolute[:, None], Rotation.from_matrix(D[:, :3, :3]).as_rotvec(), D[:, :3, 3])
    u, sv, vt = np.linalg.svd(a.T @ b)
    if sv.size < 2 or sv[1] < 1e-6 * max(sv[0], 1e-300):
        return None
    R = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    A = (U[:, :3, :3] - np.eye(3)).reshape(-1, 3)
    rhs = (D[:, :3, 3] @ R.T - U[:, :3, 3]).reshape(-1)
    t, _, rank, _ = np.linalg.lstsq(A, rhs, rcond=None)
    if rank < 3:
        return None
    B = np.eye(4)
    B[:3, :3], B[:3, 3] = R, t
    return B


def result_chain(result: CalibrationResult, target: SerialChain, source: SerialChain | None = None) -> SerialChain:
    """The chain whose link frames ``result``'s poses are in, for an export onto ``target``:
    ``source`` when known (the dataset's chain); else, from the link names the units record (extra
    ``link_name``, written by ``calibrate``): the preset the result names when they are the preset's
    (``link<i>``; ``target`` itself when it moves as that preset does), else ``target`` when it bears
    the result's robot name and those link names; a result that records no link names is of
    ``target`` when the names agree, else of the preset it names. Anything else is a result of
    another robot: a one-line :class:`ConfigError` (give its dataset)."""
    if source is not None:
        return source
    from skincal.kinematics.presets import PRESETS

    recorded = {u.pose.link: u.extras.get("link_name") for u in result.units.values()}
    named = any(isinstance(name, str) for name in recorded.values())

    def names_match(chain: SerialChain) -> bool:
        return all(not isinstance(name, str) or name == chain.link_name(link) for link, name in recorded.items())

    if result.robot == target.name and names_match(target) and not (named and result.robot in PRESETS):
        return target
    if result.robot in PRESETS:
        preset = PRESETS[result.robot]()
        if names_match(preset):
            return target if target.same_motion(preset) else preset
        if result.robot == target.name and names_match(target):
            return target
    shown = ", ".join(sorted({_shown(n) for n in recorded.values() if isinstance(n, str)})) or "unnamed links"
    raise ConfigError(
        f"the result is for robot '{_shown(str(result.robot))}' (units on {shown}), not for robot "
        f"'{_shown(target.name)}': give the dataset it was computed from (--dataset) to export it onto another "
        "description of that robot"
    )


def link_offsets(source: SerialChain, target: SerialChain) -> FloatArray:
    """``T_targetlink_sourcelink`` ``(n + 1, 4, 4)``: the pose of each link frame of ``source`` (the
    chain a result was computed on) in the same link's frame of ``target`` (the robot it is exported
    onto), so that ``T_targetlink_su = T_targetlink_sourcelink @ T_sourcelink_su``.

    The two chains describe the same robot when ``F_t_i(q) X_i = B F_s_i(q)`` for every link ``i`` and
    configuration ``q`` with constant ``X_i`` and base offset ``B`` (forward kinematics ``F``, link
    poses in each chain's base). ``B = I`` is tried first, else solved from the motions
    (:func:`_base_offset`; the UR URDFs' ``base_link`` is the controller's base turned by pi about z);
    ``X_i = F_t_i(q)^-1 B F_s_i(q)`` at ``q = 0`` and checked constant to :data:`SAME_MOTION_ATOL_M`,
    :data:`SAME_MOTION_ATOL_RAD` over single-joint steps and random configurations (seeded).
    Raises a one-line :class:`ConfigError` when they differ (another robot, or other joint zeros or
    directions)."""
    n = source.n_joints
    shown_s, shown_t = _shown(source.name), _shown(target.name)
    if target.n_joints != n or target.joint_type != source.joint_type:
        raise ConfigError(
            f"the result is for robot '{shown_s}' ({n} joints {'/'.join(source.joint_type)}), which robot "
            f"'{shown_t}' ({target.n_joints} joints) is not: the result cannot be exported onto it"
        )
    steps = np.eye(n) * 0.4
    rng = np.random.default_rng(0)
    Q = np.vstack([np.zeros((1, n)), steps, rng.uniform(-1.5, 1.5, (6, n))])
    F_s, F_t = source.link_frames(Q), target.link_frames(Q)
    inv_t = np.linalg.inv(F_t)
    X = inv_t @ F_s
    spread = _offset_spread(X)
    if spread[0] > SAME_MOTION_ATOL_M or spread[1] > SAME_MOTION_ATOL_RAD:
        B = _base_offset(source, target, F_s, F_t)
        if B is not None:
            X_b = inv_t @ B @ F_s
            spread_b = _offset_spread(X_b)
            if spread_b[0] <= SAME_MOTION_ATOL_M and spread_b[1] <= SAME_MOTION_ATOL_RAD:
                X, spread = X_b, spread_b
    if spread[0] > SAME_MOTION_ATOL_M or spread[1] > SAME_MOTION_ATOL_RAD:
        raise ConfigError(
            f"robot '{shown_t}' does not move its links as the result's robot '{shown_s}' does (their link "
            f"frames drift apart by up to {spread[0] * 1e3:.3g} mm, {math.degrees(spread[1]):.3g} deg over "
            "configurations: another robot, or other joint zeros or directions): the result cannot be "
            "exported onto it"
        )
    out = X[0].copy()
    out[:, 3, :] = (0.0, 0.0, 0.0, 1.0)
    return out


def pose_covariance(unit: UnitResult, R_frame_link: FloatArray, name: str = "unit") -> tuple[FloatArray, str]:
    """``(6, 6)`` covariance of ``(x, y, z, rx, ry, rz)`` (m^2, rad^2) of a unit in a parent frame
    whose axes are ``R_frame_link`` of the link's, and its source (``full``, ``std``, ``none``).

    From ``unit.pose_covariance`` when the result holds one (link axes; result field ``pose_covariance``), else
    ``diag(position_std_m^2, rotation_std^2)``; rotated by ``blockdiag(R, R)`` (position and small
    rotations about the link axes both turn with the frame). An undetermined axis (NaN) gets
    :data:`UNKNOWN_VARIANCE` on the diagonal and 0 elsewhere in its row and column; an offset
    frame that mixes it into other axes marks those too. No uncertainty at all: ``[0][0] = -1``."""
    cov = None
    if unit.pose_covariance is not None:
        where = f"result: units.{_shown(name)}.{POSE_COVARIANCE}"
        cov, source = check_pose_covariance(unit.pose_covariance, where), "full"
    elif unit.position_std_m is not None and unit.rotation_std_deg is not None:
        std = np.concatenate([np.asarray(unit.position_std_m, float), np.radians(unit.rotation_std_deg)])
        cov, source = np.diag(std**2), "std"
    if cov is None:
        out = np.zeros((6, 6))
        out[0, 0] = UNKNOWN_VARIANCE
        return out, "none"
    unknown = ~np.isfinite(np.diag(cov)) | np.any(~np.isfinite(cov), axis=0)
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
        raise ConfigError(f"unknown frame '{_shown(str(frame))}' (use {' or '.join(FRAMES)})")
    links = links if links is not None else link_frames_for(result_robot(result))
    if links is None:
        raise ConfigError(
            f"robot '{_shown(str(result.robot))}' is not a preset; give the robot (--robot arm.urdf or "
            "a preset) or a link map (--robot-links map.yaml with links: {1: frame, ...})"
        )
    out = []
    suffix = RANGE_SUFFIX if frame == "range" else ""
    for unit, res in result.units.items():
        parent = links.get(res.pose.link)
        if parent is None:
            raise ConfigError(
                f"unit '{_shown(str(unit))}' is on link {res.pose.link}, which the link map does not name"
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


def _num(x: float) -> str:
    return repr(float(x) + 0.0)  # + 0.0: no "-0.0"


def _nums(values) -> str:
    return " ".join(_num(v) for v in values)


# ---------------------------------------------------------------------- names and escaping
def _shown(text: str) -> str:
    """``text`` for a one-line message (:func:`printable`)."""
    return printable(text)


def _frame_problem(frame: object) -> str | None:
    """A ROS frame id may be namespaced (``robot1/base_link``): each ``/``-separated part must be a
    name (:func:`name_problem`)."""
    if not isinstance(frame, str) or "/" not in frame:
        return name_problem(frame)
    for part in frame.split("/"):
        problem = name_problem(part)
        if problem is not None:
            return f"has a part '{_shown(part)}' that {problem}"
    return None


def _check_robot_name(result: CalibrationResult) -> None:
    problem = name_problem(result.robot)
    if problem is not None:
        raise DatasetError(f"robot name '{_shown(str(result.robot))}' {problem}; the result cannot be exported")


def check_names(result: CalibrationResult, frames: list[UnitFrame]) -> None:
    """Refuse, with a one-line :class:`DatasetError` (names from the result) or :class:`ConfigError`
    (frame names from the link map or the prefix), any name an export would carry that
    :func:`skincal.names.name_problem` refuses. Every writer calls it before writing a byte."""
    _check_robot_name(result)
    children: set[str] = set()
    for f in frames:
        problem = name_problem(f.unit)
        if problem is not None:
            raise DatasetError(
                f"unit name '{_shown(str(f.unit))}' {problem}; rename the unit in the result to export it"
            )
        problem = _frame_problem(f.parent)
        if problem is not None:
            raise ConfigError(
                f"unit '{f.unit}': parent frame name '{_shown(str(f.parent))}' {problem}; fix the link map"
            )
        problem = _frame_problem(f.child)
        if problem is not None:
            raise ConfigError(f"unit '{f.unit}': frame name '{_shown(f.child)}' {problem}; choose another prefix")
        if f.child in children:  # pragma: no cover - unit names are distinct keys
            raise ConfigError(f"frame name '{_shown(f.child)}' appears twice")
        children.add(f.child)


def _comment_literal(text: str) -> str:
    """``text`` as a JSON string literal that can stand inside an XML (and xacro) comment: ASCII
    only (control characters and lone surrogates escaped), every ``-`` written ``\\u002d`` (no
    ``--`` and no trailing ``-``) and every ``$`` written ``\\u0024``; ``json.loads`` gives ``text``
    back."""
    return json.dumps(str(text), ensure_ascii=True).replace("-", "\\u002d").replace("$", "\\u0024")


def _comment(text: str) -> ET.Element[Any]:
    if "--" in text or text.endswith("-"):  # pragma: no cover - fixed text and _comment_literal only
        raise AssertionError("an XML comment cannot hold '--'")
    return ET.Comment(f" {text} ")


def _xacro_text(text: str) -> str:
    """``text`` as literal xacro attribute text: xacro reads ``${...}`` and ``$(...)`` as
    expressions and drops one ``$`` of a run of ``$`` before ``{`` or ``(``, so such a run gets one
    more ``$``."""
    return re.sub(r"\$+(?=[{(])", lambda m: "$" + m.group(0), text)


def _literal(value: object) -> str:
    """``value`` (plain strings, numbers, lists, tuples and dicts of them) as a Python literal: its
    :func:`repr`, checked to read back equal with :func:`ast.literal_eval`."""
    text = repr(value)
    if ast.literal_eval(text) != value:  # pragma: no cover - repr of plain data always reads back
        raise AssertionError(f"not a plain literal: {text}")
    return text


_FORMULA_START = ("=", "+", "-", "@", "\t", "\r")


def _cell(text: str) -> str:
    """A CSV text cell a spreadsheet will not run as a formula: a leading ``'`` when ``text``
    starts with ``=``, ``+``, ``-``, ``@``, tab or CR."""
    return "'" + text if text.startswith(_FORMULA_START) else text


# ---------------------------------------------------------------------- URDF and xacro
def _head_comment(result: CalibrationResult, frame: str) -> ET.Element:
    what = "Range frames (+x along the ToF beam: T_su_range = Ry(-90 deg))" if frame == "range" else "unit frames"
    return _comment(
        f"skin units calibrated by skincal, method {_comment_literal(result.method)}, robot "
        f"{_comment_literal(result.robot)}; {what} in the parent link frames"
    )


_UNOBSERVABLE = "next link: pose not fully observable from the data (see the result's warnings)"


def _origin(parent: ET.Element, T: FloatArray) -> None:
    ET.SubElement(parent, "origin", xyz=_nums(T[:3, 3]), rpy=_nums(rpy_from_matrix(T[:3, :3])))


def _unit_elements(frames: list[UnitFrame], make, link_text=lambda s: s, parent_text=lambda s: s) -> list:
    """Per frame: a comment when unobservable, the link and its fixed joint (``make(tag, **attrs)``
    builds an element of the target tree)."""
    out = []
    for f in frames:
        if not f.observable:
            out.append(("comment", _UNOBSERVABLE))
        link = make("link", name=link_text(f.child))
        joint = make("joint", name=link_text(f"{f.child}_joint"), type="fixed")
        for tag, attrs in (
            ("parent", {"link": parent_text(f.parent)}),
            ("child", {"link": link_text(f.child)}),
            ("origin", {"xyz": _nums(f.p_parent_child), "rpy": _nums(f.rpy)}),
        ):
            joint.append(joint.makeelement(tag, attrs))
        out += [link, joint]
    return out


def _dh_robot_urdf(robot: ET.Element, chain: SerialChain, names: RobotNames) -> set[str]:
    """Links and joints of ``chain`` (no user URDF): joint ``i`` moves ``names.links[i]`` against
    ``names.links[i - 1]``. URDF has no transform after a joint's motion, so ``T_joint_link`` is
    folded exactly: into the joint's origin when it commutes with the motion (a revolute joint whose
    ``T_joint_link`` translates along the axis, any prismatic joint; the axis is then expressed in
    the folded frame), else through an extra link ``<link>_joint`` (the moved joint frame) and a
    fixed joint ``<link>_fixed``. Returns the names used (links and joints)."""
    used = set(names.links) | set(names.joints)
    robot.append(ET.Element("link", name=names.links[0]))
    for i in range(chain.n_joints):
        A, B, u = chain.T_parent_joint[i], chain.T_joint_link[i], chain.axis[i]
        prismatic = chain.joint_type[i] == PRISMATIC
        fold = prismatic or np.linalg.norm(np.cross(B[:3, 3], u)) < 1e-12
        moved = names.links[i + 1] if fold else f"{names.links[i + 1]}_joint"
        lower = None if chain.joint_lower is None else chain.joint_lower[i]
        upper = None if chain.joint_upper is None else chain.joint_upper[i]
        limited = lower is not None and np.isfinite(lower) and np.isfinite(upper)
        kind = "prismatic" if prismatic else ("revolute" if limited else "continuous")
        joint = ET.SubElement(robot, "joint", name=names.joints[i], type=kind)
        ET.SubElement(joint, "parent", link=names.links[i])
        ET.SubElement(joint, "child", link=moved)
        _origin(joint, A @ B if fold else A)
        ET.SubElement(joint, "axis", xyz=_nums(B[:3, :3].T @ u if fold else u))
        limit = {
            "effort": _num(chain.effort_limit[i]) if chain.effort_limit is not None else "0",
            "velocity": _num(chain.velocity_limit[i]) if chain.velocity_limit is not None else "0",
        }
        if limited:
            limit = {"lower": _num(lower), "upper": _num(upper), **limit}
        ET.SubElement(joint, "limit", limit)
        robot.append(ET.Element("link", name=moved))
        if not fold:
            used |= {moved, f"{names.links[i + 1]}_fixed"}
            fixed = ET.SubElement(robot, "joint", name=f"{names.links[i + 1]}_fixed", type="fixed")
            ET.SubElement(fixed, "parent", link=moved)
            ET.SubElement(fixed, "child", link=names.links[i + 1])
            _origin(fixed, B)
            robot.append(ET.Element("link", name=names.links[i + 1]))
    if names.flange is not None:
        joint_name = "panda_joint8" if names.flange == "panda_link8" else f"{names.flange}_joint"
        used |= {names.flange, joint_name}
        joint = ET.SubElement(robot, "joint", name=joint_name, type="fixed")
        ET.SubElement(joint, "parent", link=names.links[-1])
        ET.SubElement(joint, "child", link=names.flange)
        _origin(joint, chain.T_link_flange)
        robot.append(ET.Element("link", name=names.flange))
    return used


def _check_clash(frames: list[UnitFrame], used: set[str]) -> None:
    for f in frames:
        for name in (f.child, f"{f.child}_joint"):
            if name in used:
                raise ConfigError(
                    f"unit '{_shown(f.unit)}': '{_shown(name)}' is already a link or joint of the "
                    "robot; choose a --prefix"
                )


def _user_urdf(result: CalibrationResult, frames: list[UnitFrame], chain: SerialChain, frame: str) -> str:
    """The user's URDF (``chain.source``, parsed with lxml, nothing else changed) with the unit
    links and fixed joints appended to its root."""
    from lxml import etree

    parser = etree.XMLParser(resolve_entities=False, no_network=True, recover=False)
    try:
        root = etree.fromstring(str(chain.source).encode("utf-8"), parser=parser)
    except etree.XMLSyntaxError as exc:  # pragma: no cover - chain_from_urdf parsed it already
        raise ConfigError(f"the robot's URDF: not valid XML ({exc})") from None
    used = {e.get("name") for e in root if e.tag in ("link", "joint")}
    _check_clash(frames, used)
    start = len(root)
    root.append(etree.Comment(_head_comment(result, frame).text))
    for item in _unit_elements(frames, lambda tag, **attrs: etree.Element(tag, attrs)):
        root.append(etree.Comment(f" {item[1]} ") if isinstance(item, tuple) else item)
    if start and (root[start - 1].tail or "").strip() == "":
        root[start - 1].tail = "\n  "
    for item in root[start:]:
        if isinstance(item.tag, str):  # not a comment
            etree.indent(item, space="  ", level=1)
        item.tail = "\n  "
    root[-1].tail = "\n"
    return etree.tostring(root, xml_declaration=True, encoding="UTF-8").decode("utf-8") + "\n"


def to_urdf(
    result: CalibrationResult, frames: list[UnitFrame], chain: SerialChain | None = None, frame: str = "unit"
) -> str:
    """A complete URDF: the robot (the user's URDF for a URDF chain, else the chain's links and
    joints, :func:`_dh_robot_urdf`) and one link ``<child>`` with a fixed joint ``<child>_joint`` per
    unit, parented to the unit's link frame."""
    check_names(result, frames)
    if chain is None:
        raise ConfigError(
            "a complete URDF needs the robot: give --robot (a preset or the robot's .urdf), or use "
            "-f xacro to add the units to your own robot description"
        )
    names = robot_names(chain)
    for f in frames:
        if f.parent != names.links[f.link]:
            raise ConfigError(
                "a complete URDF names its own links: --robot-links does not apply to -f urdf (use "
                "-f xacro to add the units to your own robot description)"
            )
    if chain.source is not None:
        return _user_urdf(result, frames, chain, frame)
    robot = ET.Element("robot", name=f"{result.robot}_skin")
    robot.append(_head_comment(result, frame))
    robot.append(
        _comment(
            "robot: "
            + (
                "the maker's link frames (identical to skincal's link frames)"
                if names.maker
                else "skincal's link frames (DH frames, not the maker's URDF frames)"
            )
        )
    )
    _check_clash(frames, _dh_robot_urdf(robot, chain, names))
    for item in _unit_elements(frames, ET.Element):
        robot.append(_comment(item[1]) if isinstance(item, tuple) else item)
    ET.indent(robot, "  ")
    return ET.tostring(robot, encoding="unicode", xml_declaration=True) + "\n"


XACRO_NS = "http://www.ros.org/wiki/xacro"
XACRO_MACRO = "skincal_skin_units"


def to_xacro(result: CalibrationResult, frames: list[UnitFrame], frame: str = "unit") -> str:
    """A xacro file defining the macro ``skincal_skin_units(prefix:='' parent:='')``: one link
    ``${prefix}<child>`` and fixed joint ``${prefix}<child>_joint`` per unit, parented to
    ``${parent}<link frame>`` (``parent``: the prefix of the robot's own link names, e.g. ``left_``).
    Names are literal text for xacro (:func:`_xacro_text`)."""
    check_names(result, frames)
    ET.register_namespace("xacro", XACRO_NS)
    robot = ET.Element("robot")
    robot.append(_head_comment(result, frame))
    robot.append(
        _comment(
            'usage: <xacro:include filename="skin.xacro"/> <xacro:skincal_skin_units prefix="" '
            'parent=""/> (parent: prefix of the robot\'s link names)'
        )
    )
    macro = ET.SubElement(robot, f"{{{XACRO_NS}}}macro", name=XACRO_MACRO, params="prefix:='' parent:=''")
    items = _unit_elements(
        frames,
        ET.Element,
        link_text=lambda s: "${prefix}" + _xacro_text(s),
        parent_text=lambda s: "${parent}" + _xacro_text(s),
    )
    for item in items:
        macro.append(_comment(item[1]) if isinstance(item, tuple) else item)
    ET.indent(robot, "  ")
    return ET.tostring(robot, encoding="unicode", xml_declaration=True) + "\n"


# ---------------------------------------------------------------------- YAML, JSON, CSV
def _f(value: float) -> float:
    return float(value) + 0.0  # + 0.0: no "-0.0"


def _std(values: FloatArray | None) -> list[float | None] | None:
    return None if values is None else [None if not math.isfinite(v) else float(v) for v in values]


def export_document(result: CalibrationResult, frames: list[UnitFrame], frame: str = "unit") -> dict:
    """The YAML/JSON document: per unit parent, child, link, xyz (m), quaternion_wxyz, observable,
    the result's per-axis std, and the 6x6 covariance in the parent frame with its source."""
    check_names(result, frames)
    return {
        "format": "skincal-skin-frames",
        "version": 1,
        "robot": result.robot,
        "method": result.method,
        "frame": frame,
        "covariance_order": list(COVARIANCE_ORDER),
        "units": {
            f.unit: {
                "parent": f.parent,
                "child": f.child,
                "link": f.link,
                "xyz": [_f(v) for v in f.p_parent_child],
                "quaternion_wxyz": [_f(v) for v in f.quaternion_wxyz],
                "observable": f.observable,
                "position_std_m": _std(f.position_std_m),
                "rotation_std_deg": _std(f.rotation_std_deg),
                "covariance": [[_f(v) for v in row] for row in f.covariance],
                "covariance_source": f.covariance_source,
            }
            for f in frames
        },
    }


def to_yaml(result: CalibrationResult, frames: list[UnitFrame], frame: str = "unit") -> str:
    """YAML of :func:`export_document`."""
    return yaml.safe_dump(export_document(result, frames, frame), sort_keys=False, default_flow_style=None)


def to_json(result: CalibrationResult, frames: list[UnitFrame], frame: str = "unit") -> str:
    """JSON of :func:`export_document`."""
    return json.dumps(export_document(result, frames, frame), indent=2, allow_nan=False) + "\n"


CSV_COLUMNS = ("unit", "parent", "child", "link", "x_m", "y_m", "z_m", "qw", "qx", "qy", "qz", "observable")


def to_csv(result: CalibrationResult, frames: list[UnitFrame], frame: str = "unit") -> str:
    """CSV with header :data:`CSV_COLUMNS` (quaternion columns ``qw, qx, qy, qz``); text cells are
    formula-neutralised (:func:`_cell`), numbers written as numbers."""
    check_names(result, frames)
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    for f in frames:
        writer.writerow(
            [
                _cell(f.unit),
                _cell(f.parent),
                _cell(f.child),
                int(f.link),
                *(float(v) for v in f.p_parent_child),
                *(float(v) for v in f.quaternion_wxyz),
                str(f.observable).lower(),
            ]
        )
    return buf.getvalue()


# ---------------------------------------------------------------------- TF nodes
_TRANSFORMS_FN = '''

def transforms(stamp, message_type):
    """TRANSFORMS as messages of message_type (geometry_msgs TransformStamped) stamped stamp."""
    messages = []
    for parent, child, xyz, quaternion in TRANSFORMS:
        message = message_type()
        message.header.stamp = stamp
        message.header.frame_id = parent
        message.child_frame_id = child
        translation, rotation = message.transform.translation, message.transform.rotation
        translation.x, translation.y, translation.z = xyz
        rotation.x, rotation.y, rotation.z, rotation.w = quaternion
        messages.append(message)
    return messages
'''
"""The message builder both TF nodes share (ROS 1 and ROS 2 messages have the same fields)."""

_ROS2_HEAD = '''"""Static transforms of skin units calibrated by skincal, all sent at once by one ROS 2 node
(tf2_ros StaticTransformBroadcaster, latched). Run it as a launch file (ros2 launch <this file>) or
as a node (python3 <this file>). TRANSFORMS: (parent frame, child frame, (x, y, z) in m, quaternion
(x, y, z, w) in ROS order). CALIBRATION names the robot, the calibration method and the frames.
"""

import sys

'''

_ROS2_BODY = _TRANSFORMS_FN + '''

def main(args=None):
    import rclpy
    from geometry_msgs.msg import TransformStamped
    from tf2_ros.static_transform_broadcaster import StaticTransformBroadcaster

    rclpy.init(args=args)
    node = rclpy.create_node(NODE_NAME)
    broadcaster = StaticTransformBroadcaster(node)
    broadcaster.sendTransform(transforms(node.get_clock().now().to_msg(), TransformStamped))
    try:
        rclpy.spin(node)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()


def generate_launch_description():
    from launch import LaunchDescription
    from launch.actions import ExecuteProcess

    return LaunchDescription([ExecuteProcess(cmd=[sys.executable, __file__], name=NODE_NAME, output="screen")])


if __name__ == "__main__":
    main()
'''

_ROS1_HEAD = '''#!/usr/bin/env python3
"""Static transforms of skin units calibrated by skincal, all sent at once by one ROS 1 node
(tf2_ros StaticTransformBroadcaster, latched on /tf_static). Run it with python3 <this file>, or
make it executable in a package's scripts folder and start it from a launch file:
<node pkg="your_package" type="<this file>" name="skincal_skin_tf"/>. TRANSFORMS: (parent frame,
child frame, (x, y, z) in m, quaternion (x, y, z, w) in ROS order). CALIBRATION names the robot,
the calibration method and the frames.
"""

'''

_ROS1_BODY = _TRANSFORMS_FN + '''

def main():
    import rospy
    import tf2_ros
    from geometry_msgs.msg import TransformStamped

    rospy.init_node(NODE_NAME)
    broadcaster = tf2_ros.StaticTransformBroadcaster()
    broadcaster.sendTransform(transforms(rospy.Time.now(), TransformStamped))
    rospy.spin()


if __name__ == "__main__":
    main()
'''


def tf_transforms(frames: list[UnitFrame]) -> list[tuple]:
    """``(parent, child, (x, y, z), (qx, qy, qz, qw))`` per frame, ROS quaternion order."""
    out = []
    for f in frames:
        w, x, y, z = (_f(v) for v in f.quaternion_wxyz)
        out.append((str(f.parent), str(f.child), tuple(_f(v) for v in f.p_parent_child), (x, y, z, w)))
    return out


def _tf_node(result: CalibrationResult, frames: list[UnitFrame], frame: str, head: str, body: str) -> str:
    check_names(result, frames)
    rows = "".join(f"    {_literal(t)},\n" for t in tf_transforms(frames))
    calibration = _literal({"robot": str(result.robot), "method": str(result.method), "frame": frame})
    node = "skincal_skin_range_tf" if frame == "range" else "skincal_skin_tf"
    return head + f"CALIBRATION = {calibration}\nNODE_NAME = {_literal(node)}\nTRANSFORMS = [\n{rows}]\n" + body


def to_tf_ros2(result: CalibrationResult, frames: list[UnitFrame], frame: str = "unit") -> str:
    """One Python file that is a ROS 2 node (``rclpy``, one ``StaticTransformBroadcaster`` sending
    every unit's transform at once) and a launch file starting it; a fixed skeleton with user data
    only as literals (:func:`_literal`)."""
    return _tf_node(result, frames, frame, _ROS2_HEAD, _ROS2_BODY)


def to_tf_ros1(result: CalibrationResult, frames: list[UnitFrame], frame: str = "unit") -> str:
    """One ROS 1 node script (``rospy``, one ``tf2_ros.StaticTransformBroadcaster`` sending every
    unit's transform at once); a fixed skeleton with user data only as literals."""
    return _tf_node(result, frames, frame, _ROS1_HEAD, _ROS1_BODY)


_WRITERS = {
    "xacro": to_xacro,
    "yaml": to_yaml,
    "json": to_json,
    "tf": to_tf_ros2,
    "tf-ros2": to_tf_ros2,
    "tf-ros1": to_tf_ros1,
    "csv": to_csv,
}


def export_text(
    result: CalibrationResult,
    fmt: str,
    *,
    link_map: str | Path | None = None,
    prefix: str = "",
    robot: str | None = None,
    base_link: str | None = None,
    tip_link: str | None = None,
    frame: str = "unit",
    source: SerialChain | None = None,
) -> tuple[str, list[UnitFrame]]:
    """The text of ``result`` as ``fmt`` and the exported frames (see :func:`export_result`)."""
    if fmt not in FORMATS:
        raise ConfigError(f"unknown export format '{_shown(str(fmt))}' (use {', '.join(FORMATS)})")
    if frame not in FRAMES:
        raise ConfigError(f"unknown frame '{_shown(str(frame))}' (use {' or '.join(FRAMES)})")
    if fmt == "urdf" and link_map is not None:
        raise ConfigError(
            "a complete URDF names its own links: --robot-links does not apply to -f urdf (use -f xacro "
            "to add the units to your own robot description)"
        )
    _check_robot_name(result)  # before the robot is looked at: a crafted name is refused as such
    if robot is None and source is not None:
        if base_link is not None or tip_link is not None:
            raise ConfigError("--base-link and --tip-link apply to a URDF robot given with --robot")
        from skincal.data.result import check_links

        check_links(result, source, "result")
        chain: SerialChain | None = source
    else:
        chain = result_robot(result, robot, base_link=base_link, tip_link=tip_link)
    links = link_frames_for(chain, link_map)
    if links is not None and link_map is None and chain is not None:
        computed_on = result_chain(result, chain, source)
        if computed_on is not chain:
            X = link_offsets(computed_on, chain)
            links = {i: LinkFrame(f.name, X[i] @ f.T_frame_link) for i, f in links.items()}
    frames = unit_frames(result, links, frame=frame, prefix=prefix) if links is not None else None
    if frames is None:
        raise ConfigError(
            f"robot '{_shown(str(result.robot))}' is not a preset; give the robot (--robot arm.urdf or "
            "a preset, or --dataset: the dataset the result was computed from) or a link map (--robot-links "
            "map.yaml with links: {1: frame, ...})"
        )
    if fmt == "urdf":
        return to_urdf(result, frames, chain, frame), frames
    return _WRITERS[fmt](result, frames, frame), frames


def export_result(
    result: CalibrationResult,
    fmt: str,
    out: str | Path,
    *,
    link_map: str | Path | None = None,
    prefix: str = "",
    robot: str | None = None,
    base_link: str | None = None,
    tip_link: str | None = None,
    frame: str = "unit",
    source: SerialChain | None = None,
) -> list[UnitFrame]:
    """Write ``result`` as ``fmt`` (:data:`FORMATS`) to ``out`` atomically; returns the exported
    frames. The robot is ``robot`` (preset, ``.urdf`` with ``base_link``/``tip_link``, DH chain
    file), else ``source``, else the result's preset; ``source`` is the chain the result was computed
    on (its dataset's, checked by the caller), else found by :func:`result_chain`; each pose is moved
    from the source's link frame into the robot's (:func:`link_offsets`). ``link_map`` overrides the
    link frame names and offsets (not for ``urdf``); ``frame`` is ``unit`` or ``range``
    (:data:`T_SU_RANGE`)."""
    text, frames = export_text(
        result,
        fmt,
        link_map=link_map,
        prefix=prefix,
        robot=robot,
        base_link=base_link,
        tip_link=tip_link,
        frame=frame,
        source=source,
    )
    write_bytes_atomic(out, text.encode("utf-8"))
    return frames
