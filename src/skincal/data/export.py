"""Exports of a calibration result: URDF snippet, YAML, ROS 2 static-transform launch file, CSV.

Every unit pose of a result is ``T_link_su`` in skincal link frame ``i`` = DH frame {i} of the
robot's convention (``docs/interfaces.md``). ROS tools name their own frames, so each link is
mapped to a named parent frame with a fixed offset ``T_frame_link`` (the pose of DH frame {i} in
that frame); the exported pose is ``T_frame_su = T_frame_link @ T_link_su``.

* ``panda``: Franka's ``panda_link<i>`` frames (franka_description) coincide with the modified-DH
  frames {i} (same origins and axes; joint ``i`` turns about their z), so the offset is identity.
* other robots: a YAML map ``{links: {<i>: <frame> | {frame: <name>, xyz: [m], rpy: [rad]}}}``;
  ``rpy`` is URDF's fixed-axis roll-pitch-yaw, ``R = Rz(yaw) Ry(pitch) Rx(roll)``.

Quaternion order: skincal writes ``(w, x, y, z)`` (field ``quaternion_wxyz``); ROS uses
``(x, y, z, w)``: the launch file passes ``--qx --qy --qz --qw`` by name, and the CSV names its
columns ``qw, qx, qy, qz``. Files are written atomically.

Escaping by construction (no user text is ever pasted into a template):

* names: every unit name and the robot name must pass :func:`skincal.data.names.name_problem`, and
  the parent and child frame names (link map, ``prefix``) the same rule for each ``/``-separated
  part; anything else is refused with a one-line error naming it, before a byte is written;
* URDF: built with :mod:`xml.etree.ElementTree` (names only in attributes, which the library
  escapes); comments hold fixed text, and the method and robot appear there only as JSON string
  literals with every ``-`` written ``\\u002d``, so ``--`` cannot occur in a comment;
* launch file: a fixed code skeleton; user data appear only as Python literals made by
  :func:`repr` of plain strings and checked with :func:`ast.literal_eval` (never in the docstring,
  a comment or a code position); ROS node names are reduced to ``[A-Za-z0-9_]``;
* CSV: through :mod:`csv`; a text cell starting with ``=``, ``+``, ``-``, ``@``, tab or CR gets a
  leading ``'`` (spreadsheet formula neutralisation); numbers are written as numbers;
* YAML: through :func:`yaml.safe_dump`.
"""

from __future__ import annotations

import ast
import csv
import io
import json
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from skincal.data.atomic import write_bytes_atomic
from skincal.data.jsonio import load_yaml
from skincal.data.names import name_problem, printable
from skincal.data.result import CalibrationResult
from skincal.errors import ConfigError, DatasetError
from skincal.kinematics.transforms import FloatArray

FORMATS = ("urdf", "yaml", "tf", "csv")
PRESET_LINK_FRAMES: dict[str, str] = {"panda": "panda_link{i}"}
"""Robots whose URDF link frames equal skincal's link frames (identity offset), by name pattern."""


@dataclass(frozen=True)
class LinkFrame:
    """A named parent frame for skincal link ``i``: ``T_frame_link`` ``(4, 4)``, m, is the pose of
    DH frame {i} in the frame called ``name``."""

    name: str
    T_frame_link: FloatArray


@dataclass(frozen=True)
class UnitFrame:
    """One exported unit: ``parent`` frame name, ``link`` (1-based), ``p_parent_su`` ``(3,)`` m,
    ``R_parent_su`` ``(3, 3)``, ``observable``."""

    unit: str
    parent: str
    link: int
    p_parent_su: FloatArray
    R_parent_su: FloatArray
    observable: bool

    @property
    def quaternion_wxyz(self) -> FloatArray:
        """Unit quaternion ``(w, x, y, z)`` of ``R_parent_su`` with ``w >= 0``."""
        q = Rotation.from_matrix(self.R_parent_su).as_quat(scalar_first=True)
        return -q if q[0] < 0 else q

    @property
    def rpy(self) -> FloatArray:
        """URDF roll, pitch, yaw (rad): ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (extrinsic x-y-z)."""
        return Rotation.from_matrix(self.R_parent_su).as_euler("xyz")


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
            out[key] = LinkFrame(value["frame"], _transform(value.get("xyz", [0, 0, 0]), value.get("rpy", [0, 0, 0]),
                                                            where))
        else:
            raise ConfigError(f"{where}: must be a frame name or {{frame: name, xyz: [m], rpy: [rad]}}")
    return out


def link_frames_for(robot: str, link_map: str | Path | None = None) -> dict[int, LinkFrame] | None:
    """The link map: from ``link_map`` when given, else the preset of ``robot`` (links 1..n of the
    preset chain, identity offsets); ``None`` when neither exists."""
    if link_map is not None:
        return load_link_map(link_map)
    pattern = PRESET_LINK_FRAMES.get(robot)
    if pattern is None:
        return None
    from skincal.kinematics import get_robot

    return {i: LinkFrame(pattern.format(i=i), np.eye(4)) for i in range(1, get_robot(robot).n_joints + 1)}


def unit_frames(result: CalibrationResult, links: dict[int, LinkFrame] | None = None) -> list[UnitFrame]:
    """Each unit's pose in its named parent frame, ``T_frame_su = T_frame_link @ T_link_su``.

    ``links`` defaults to the preset of ``result.robot``; raises :class:`ConfigError` when a unit's
    link has no frame (naming the robot, the unit and the option to use).
    """
    links = links if links is not None else link_frames_for(result.robot)
    if links is None:
        raise ConfigError(f"robot '{_shown(str(result.robot))}' has no preset link frame names; give a link map "
                          "(--robot-links map.yaml with links: {1: frame, ...})")
    out = []
    for unit, res in result.units.items():
        frame = links.get(res.pose.link)
        if frame is None:
            raise ConfigError(f"unit '{_shown(str(unit))}' is on link {res.pose.link}, which the link map does not "
                              "name")
        T = frame.T_frame_link @ res.pose.T_link_su
        out.append(UnitFrame(unit, frame.name, res.pose.link, T[:3, 3].copy(), T[:3, :3].copy(), res.observable))
    return out


def _num(x: float) -> str:
    return repr(float(x))


# ---------------------------------------------------------------------- names and escaping
def _shown(text: str) -> str:
    """``text`` for a one-line message (:func:`printable`)."""
    return printable(text)


def _frame_problem(frame: object) -> str | None:
    """A ROS frame id may be namespaced (``robot1/base_link``): each ``/``-separated part must be a
    name (:func:`_name_problem`)."""
    if not isinstance(frame, str) or "/" not in frame:
        return name_problem(frame)
    for part in frame.split("/"):
        problem = name_problem(part)
        if problem is not None:
            return f"has a part '{_shown(part)}' that {problem}"
    return None


def check_names(result: CalibrationResult, frames: list[UnitFrame], prefix: str = "") -> None:
    """Refuse, with a one-line :class:`DatasetError` (names from the result) or :class:`ConfigError`
    (frame names from the link map or the prefix), any name an export would carry that
    :func:`skincal.data.names.name_problem` refuses. Every writer calls it before writing a byte."""
    problem = name_problem(result.robot)
    if problem is not None:
        raise DatasetError(f"robot name '{_shown(str(result.robot))}' {problem}; the result cannot be exported")
    for f in frames:
        problem = name_problem(f.unit)
        if problem is not None:
            raise DatasetError(f"unit name '{_shown(str(f.unit))}' {problem}; rename the unit in the result to "
                               "export it")
        problem = _frame_problem(f.parent)
        if problem is not None:
            raise ConfigError(f"unit '{f.unit}': parent frame name '{_shown(str(f.parent))}' {problem}; fix the "
                              "link map")
        problem = _frame_problem(prefix + f.unit)
        if problem is not None:
            raise ConfigError(f"unit '{f.unit}': frame name '{_shown(prefix + f.unit)}' (prefix "
                              f"'{_shown(prefix)}') {problem}; choose another prefix")


def _comment_literal(text: str) -> str:
    """``text`` as a JSON string literal that can stand inside an XML comment: ASCII only (control
    characters and lone surrogates escaped) and every ``-`` written ``\\u002d``, so neither ``--``
    nor a trailing ``-`` can occur; ``json.loads`` gives ``text`` back."""
    return json.dumps(str(text), ensure_ascii=True).replace("-", "\\u002d")


def _comment(text: str) -> ET.Element:
    if "--" in text or text.endswith("-"):  # pragma: no cover - fixed text and _comment_literal only
        raise AssertionError("an XML comment cannot hold '--'")
    return ET.Comment(f" {text} ")


def _literal(value: object) -> str:
    """``value`` (plain strings, numbers, lists and dicts of them) as a Python literal: its
    :func:`repr`, checked to read back equal with :func:`ast.literal_eval`."""
    text = repr(value)
    if ast.literal_eval(text) != value:  # pragma: no cover - repr of plain data always reads back
        raise AssertionError(f"not a plain literal: {text}")
    return text


def _node_name(text: str, used: set[str]) -> str:
    """A ROS 2 node name (``[A-Za-z_][A-Za-z0-9_]*``, unique in ``used``) made from ``text``."""
    name = re.sub(r"[^A-Za-z0-9_]", "_", text)
    if not name or name[0].isdigit():
        name = "_" + name
    base, k = name, 2
    while name in used:
        name, k = f"{base}_{k}", k + 1
    used.add(name)
    return name


_FORMULA_START = ("=", "+", "-", "@", "\t", "\r")


def _cell(text: str) -> str:
    """A CSV text cell a spreadsheet will not run as a formula: a leading ``'`` when ``text``
    starts with ``=``, ``+``, ``-``, ``@``, tab or CR."""
    return "'" + text if text.startswith(_FORMULA_START) else text


# ---------------------------------------------------------------------- writers
def to_urdf(result: CalibrationResult, frames: list[UnitFrame], prefix: str = "") -> str:
    """URDF: one link ``<prefix><unit>`` and one fixed joint ``<prefix><unit>_joint`` per unit,
    built with :mod:`xml.etree.ElementTree`."""
    check_names(result, frames, prefix)
    robot = ET.Element("robot", name=f"{result.robot}_skin")
    robot.append(_comment(f"skin units calibrated by skincal, method {_comment_literal(result.method)}, robot "
                          f"{_comment_literal(result.robot)}; poses in the parent link frames"))
    for f in frames:
        child = f"{prefix}{f.unit}"
        if not f.observable:
            robot.append(_comment("next link: pose not fully observable from the data (see the result's warnings)"))
        ET.SubElement(robot, "link", name=child)
        joint = ET.SubElement(robot, "joint", name=f"{child}_joint", type="fixed")
        ET.SubElement(joint, "parent", link=f.parent)
        ET.SubElement(joint, "child", link=child)
        ET.SubElement(joint, "origin", xyz=" ".join(_num(v) for v in f.p_parent_su),
                      rpy=" ".join(_num(v) for v in f.rpy))
    ET.indent(robot, "  ")
    return ET.tostring(robot, encoding="unicode", xml_declaration=True) + "\n"


def to_yaml(result: CalibrationResult, frames: list[UnitFrame], prefix: str = "") -> str:
    """YAML: unit -> parent frame, child frame, link, xyz (m), quaternion_wxyz, observable."""
    check_names(result, frames, prefix)
    doc = {"format": "skincal-skin-frames", "version": 1, "robot": result.robot, "method": result.method,
           "units": {f.unit: {"parent": f.parent, "child": f"{prefix}{f.unit}", "link": f.link,
                              "xyz": [float(v) for v in f.p_parent_su],
                              "quaternion_wxyz": [float(v) for v in f.quaternion_wxyz],
                              "observable": f.observable} for f in frames}}
    return yaml.safe_dump(doc, sort_keys=False)


_LAUNCH_HEAD = '''"""Static transforms of skin units calibrated by skincal: one tf2_ros static_transform_publisher
per unit. Quaternions in ROS order (x, y, z, w), passed by name (--qx --qy --qz --qw). The robot and
the calibration method are in CALIBRATION below.
"""

from launch import LaunchDescription
from launch_ros.actions import Node

'''


def to_tf_launch(result: CalibrationResult, frames: list[UnitFrame], prefix: str = "") -> str:
    """ROS 2 Python launch file: one ``tf2_ros static_transform_publisher`` per unit, new-style
    named arguments; the quaternion is passed as ``--qx --qy --qz --qw`` (ROS order x, y, z, w).

    The code is a fixed skeleton: names, frames, robot and method enter only as string literals
    (:func:`_literal`); node names are reduced to ROS's ``[A-Za-z0-9_]``."""
    check_names(result, frames, prefix)
    nodes: list[str] = []
    used: set[str] = set()
    for f in frames:
        w, x, y, z = f.quaternion_wxyz
        child = f"{prefix}{f.unit}"
        numbers = ["--x", f.p_parent_su[0], "--y", f.p_parent_su[1], "--z", f.p_parent_su[2],
                   "--qx", x, "--qy", y, "--qz", z, "--qw", w]
        args = [a if isinstance(a, str) else _num(a) for a in numbers]
        args += ["--frame-id", str(f.parent), "--child-frame-id", str(child)]
        nodes.append("        Node(package='tf2_ros', executable='static_transform_publisher',\n"
                     f"             name={_literal(_node_name(child + '_tf', used))},\n"
                     f"             arguments={_literal(args)}),")
    calibration = _literal({"robot": str(result.robot), "method": str(result.method)})
    return (_LAUNCH_HEAD + f"CALIBRATION = {calibration}\n\n\n"
            "def generate_launch_description():\n    return LaunchDescription([\n" + "\n".join(nodes) + "\n    ])\n")


CSV_COLUMNS = ("unit", "parent", "child", "link", "x_m", "y_m", "z_m", "qw", "qx", "qy", "qz", "observable")


def to_csv(result: CalibrationResult, frames: list[UnitFrame], prefix: str = "") -> str:
    """CSV with header :data:`CSV_COLUMNS` (quaternion columns ``qw, qx, qy, qz``); text cells are
    formula-neutralised (:func:`_cell`), numbers written as numbers."""
    check_names(result, frames, prefix)
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    for f in frames:
        writer.writerow([_cell(f.unit), _cell(f.parent), _cell(f"{prefix}{f.unit}"), int(f.link),
                         *(float(v) for v in f.p_parent_su), *(float(v) for v in f.quaternion_wxyz),
                         str(f.observable).lower()])
    return buf.getvalue()


_WRITERS = {"urdf": to_urdf, "yaml": to_yaml, "tf": to_tf_launch, "csv": to_csv}


def export_result(result: CalibrationResult, fmt: str, out: str | Path, *, link_map: str | Path | None = None,
                  prefix: str = "") -> list[UnitFrame]:
    """Write ``result`` as ``fmt`` (``urdf``, ``yaml``, ``tf``, ``csv``) to ``out`` atomically;
    returns the exported unit frames."""
    if fmt not in _WRITERS:
        raise ConfigError(f"unknown export format '{fmt}' (use {', '.join(FORMATS)})")
    frames = unit_frames(result, link_frames_for(result.robot, link_map))
    write_bytes_atomic(out, _WRITERS[fmt](result, frames, prefix).encode("utf-8"))
    return frames
