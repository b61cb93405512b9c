"""The URDF and xacro exports: a complete URDF (a DH chain's robot, or the user's URDF extended) with a
fixed link per unit, and a xacro macro adding the units to an existing description."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np

from skincal.data.export.escape import comment_literal, num, nums, shown, xacro_text, xml_comment
from skincal.data.export.frames import RobotNames, UnitFrame, check_names, robot_names, rpy_from_matrix
from skincal.data.result import CalibrationResult
from skincal.errors import ConfigError
from skincal.kinematics.chain import PRISMATIC, SerialChain
from skincal.kinematics.transforms import FloatArray


# ---------------------------------------------------------------------- URDF and xacro
def _head_comment(result: CalibrationResult, frame: str) -> ET.Element:
    what = "Range frames (+x along the ToF beam: T_su_range = Ry(-90 deg))" if frame == "range" else "unit frames"
    return xml_comment(
        f"skin units calibrated by skincal, method {comment_literal(result.method)}, robot "
        f"{comment_literal(result.robot)}; {what} in the parent link frames"
    )


_UNOBSERVABLE = "next link: pose not fully observable from the data (see the result's warnings)"


def _origin(parent: ET.Element, T: FloatArray) -> None:
    ET.SubElement(parent, "origin", xyz=nums(T[:3, 3]), rpy=nums(rpy_from_matrix(T[:3, :3])))


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
            ("origin", {"xyz": nums(f.p_parent_child), "rpy": nums(f.rpy)}),
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
        ET.SubElement(joint, "axis", xyz=nums(B[:3, :3].T @ u if fold else u))
        limit = {
            "effort": num(chain.effort_limit[i]) if chain.effort_limit is not None else "0",
            "velocity": num(chain.velocity_limit[i]) if chain.velocity_limit is not None else "0",
        }
        if limited:
            limit = {"lower": num(lower), "upper": num(upper), **limit}
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
                    f"unit '{shown(f.unit)}': '{shown(name)}' is already a link or joint of the "
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
        xml_comment(
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
        robot.append(xml_comment(item[1]) if isinstance(item, tuple) else item)
    ET.indent(robot, "  ")
    return ET.tostring(robot, encoding="unicode", xml_declaration=True) + "\n"


XACRO_NS = "http://www.ros.org/wiki/xacro"
XACRO_MACRO = "skincal_skin_units"


def to_xacro(result: CalibrationResult, frames: list[UnitFrame], frame: str = "unit") -> str:
    """A xacro file defining the macro ``skincal_skin_units(prefix:='' parent:='')``: one link
    ``${prefix}<child>`` and fixed joint ``${prefix}<child>_joint`` per unit, parented to
    ``${parent}<link frame>`` (``parent``: the prefix of the robot's own link names, e.g. ``left_``).
    Names are literal text for xacro (:func:`xacro_text`)."""
    check_names(result, frames)
    ET.register_namespace("xacro", XACRO_NS)
    robot = ET.Element("robot")
    robot.append(_head_comment(result, frame))
    robot.append(
        xml_comment(
            'usage: <xacro:include filename="skin.xacro"/> <xacro:skincal_skin_units prefix="" '
            'parent=""/> (parent: prefix of the robot\'s link names)'
        )
    )
    macro = ET.SubElement(robot, f"{{{XACRO_NS}}}macro", name=XACRO_MACRO, params="prefix:='' parent:=''")
    items = _unit_elements(
        frames,
        ET.Element,
        link_text=lambda s: "${prefix}" + xacro_text(s),
        parent_text=lambda s: "${parent}" + xacro_text(s),
    )
    for item in items:
        macro.append(xml_comment(item[1]) if isinstance(item, tuple) else item)
    ET.indent(robot, "  ")
    return ET.tostring(robot, encoding="unicode", xml_declaration=True) + "\n"
