"""A :class:`~skincal.kinematics.chain.SerialChain` from a URDF (parsed by ``yourdfpy``).

The serial chain runs from ``base_link`` (default: the tree's root) to ``tip_link`` (default: the
last link before the tree branches into several moving sub-chains, e.g. a gripper's fingers, or the
single leaf of a serial arm; then before a trailing gripper joint, a moving joint at the end whose
name contains ``gripper``, ``finger`` or ``jaw``, e.g. Unitree Z1's ``jointGripper`` or SO-101's
``gripper`` (its jaw): the end effector's own motion, not the arm's; the joint's child link does not
count, SO-101's wrist roll carries a ``gripper_link``; :func:`urdf_chain` names what was left out).
Along it:

* every ``revolute``, ``continuous`` (revolute without position limits) and ``prismatic`` joint is
  a joint of the chain; link frame ``i`` is the URDF frame of the child link of the ``i``-th of
  them, and the base frame {0} is ``base_link``'s frame;
* ``fixed`` joints are folded into the next joint's origin (``T_parent_joint``), or, after the last
  moving joint, into ``T_link_flange`` (the flange is then ``tip_link``'s frame);
* URDF joint ``origin`` (xyz, rpy: fixed-axis roll-pitch-yaw, ``R = Rz(yaw) Ry(pitch) Rx(roll)``) is
  ``T_parent_joint``; ``T_joint_link`` is the identity; ``axis`` is the joint's ``<axis>`` (default
  ``1 0 0``) in the joint frame;
* ``<limit>`` gives position (rad or m), velocity and effort limits; a chain whose joints do not all
  state a velocity (or effort) has none of that kind. ``mimic``, ``floating`` and ``planar`` joints
  in the chain are refused: they are not independent serial joints.
* ``<inertial>``: link frame ``i`` (and the base, frame {0}) is one rigid body made of its own URDF
  link and every link hanging below it by ``fixed`` joints only (the folded links up to the next
  moving joint or the tip, and fixed side branches such as sensor frames or rigid fingers; links
  below a joint that is not in the chain are not covered). Their ``<inertial>`` elements (mass,
  CoM ``origin``, inertia about the CoM in the origin's axes) are combined in the link frame
  (:func:`skincal.kinematics.inertia.combine`: parallel-axis theorem, tensors rotated into the link
  frame) into ``SerialChain.inertials``. A body with no mass (no ``<inertial>``, or mass 0) has
  ``None``; so has one with an inertial that is not physical (negative, non-finite or over 1e6 kg
  mass, an inertia that is not positive semi-definite or breaks the triangle inequality, bounds of
  :mod:`skincal.kinematics.inertia`): such URDFs exist
  and their kinematics are still good, the simulator gives those bodies capsule masses instead.

Every failure is one :class:`~skincal.errors.ConfigError` line naming the file.
"""

from __future__ import annotations

import io
import re
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skincal.errors import ConfigError
from skincal.kinematics.chain import PRISMATIC, REVOLUTE, SerialChain
from skincal.kinematics.inertia import LinkInertial, combine
from skincal.names import name_problem, printable

_MOVING = {"revolute": REVOLUTE, "continuous": REVOLUTE, "prismatic": PRISMATIC}
MAX_URDF_BYTES = 32 * 1024 * 1024
"""Largest URDF text read, bytes (robot descriptions are kilobytes; meshes live in other files)."""
MAX_URDF_JOINTS = 5000
"""Most ``<joint>`` elements a URDF may have (fixed ones included): a humanoid with hands has about a hundred,
a long run of fixed frames a few thousand."""


def parse_urdf(text: str, source: str):  # -> yourdfpy.URDF
    """A URDF's text parsed by yourdfpy (no scene graph, no meshes), trusting nothing: at most
    :data:`MAX_URDF_BYTES`, strictly well-formed XML without entities, external DTDs or network access.

    Raises:
        ConfigError: one line ``<source>: ...`` for any of those or any parser error.
    """
    try:
        import yourdfpy
    except ImportError:  # pragma: no cover - a core dependency
        raise ConfigError("reading a URDF needs yourdfpy (pip install yourdfpy)") from None
    from lxml import etree  # yourdfpy's own XML library

    if len(text) > MAX_URDF_BYTES:  # a bag's /robot_description, a dataset's URDF: the file limit too
        raise ConfigError(f"{source}: {len(text)} characters is too large for a URDF")
    data = text.encode("utf-8")
    try:  # strictly well-formed, no entities, no network (yourdfpy alone would "recover" broken XML)
        root = etree.fromstring(data, parser=etree.XMLParser(resolve_entities=False, no_network=True, recover=False))
    except etree.XMLSyntaxError as exc:
        raise ConfigError(f"{source}: not a valid URDF (XML: {exc})") from None
    joints = sum(1 for _ in root.iterchildren("joint"))
    if joints > MAX_URDF_JOINTS:  # before yourdfpy builds them all (the chain takes at most MAX_JOINTS)
        raise ConfigError(f"{source}: {joints} joints is too many for a URDF (at most {MAX_URDF_JOINTS})")
    for kind in ("link", "joint"):  # yourdfpy keeps the last of two same-named elements: the tree is ambiguous
        twice = sorted(n for n, c in Counter(str(e.get("name")) for e in root.iterchildren(kind)).items() if c > 1)
        if twice:
            raise ConfigError(f"{source}: not a valid URDF (two {kind}s named {printable(twice[0])!r})")
    docinfo = root.getroottree().docinfo
    dtd = docinfo.internalDTD
    if docinfo.public_id or docinfo.system_url or (dtd is not None and any(True for _ in dtd.iterentities())):
        # yourdfpy's own parser would expand them (and a URDF written back would keep bare references)
        raise ConfigError(f"{source}: not a valid URDF (XML: a DOCTYPE declaring entities or an external DTD)")
    try:
        return yourdfpy.URDF.load(
            io.BytesIO(data), build_scene_graph=False, load_meshes=False, load_collision_meshes=False
        )
    except Exception as exc:  # noqa: BLE001 - XML, attribute and reference errors of the parser alike
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise ConfigError(f"{source}: not a valid URDF ({first})") from None


def read_urdf_text(path: str | Path) -> str:
    """The text of a URDF file, with the file named in any error."""
    path = Path(path)
    try:
        if not path.is_file():
            raise ConfigError(f"{path}: no such URDF file" if not path.exists() else f"{path}: not a regular file")
        if path.stat().st_size > MAX_URDF_BYTES:
            raise ConfigError(f"{path}: {path.stat().st_size} bytes is too large for a URDF")
        return path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the URDF ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not UTF-8 text") from None


def _link_inertial(link) -> LinkInertial | None:  # link: yourdfpy.Link
    """A URDF link's ``<inertial>`` in the link's frame; ``None`` without one or with mass 0.
    Raises :class:`ConfigError` for an inertial that is not physical."""
    inertial = link.inertial
    if inertial is None or inertial.mass is None or float(inertial.mass) == 0.0:
        return None
    origin = np.eye(4) if inertial.origin is None else np.asarray(inertial.origin, dtype=float)
    tensor = np.zeros((3, 3)) if inertial.inertia is None else np.asarray(inertial.inertia, dtype=float)
    R = origin[:3, :3]
    return LinkInertial.from_tensor(float(inertial.mass), origin[:3, 3], R @ tensor @ R.T)


def _rigid_body(urdf_links: dict, joints: dict, children: dict[str, list[str]], root: str) -> LinkInertial | None:
    """The inertial, in ``root``'s frame, of ``root`` and every link below it by fixed joints only."""
    parts: list[LinkInertial] = []
    poses: list[np.ndarray] = []
    stack, seen = [(root, np.eye(4))], {root}
    while stack:
        name, T = stack.pop()
        own = _link_inertial(urdf_links[name])
        if own is not None:
            parts.append(own)
            poses.append(T)
        for child in children[name]:
            j = joints[child]
            if j.type == "fixed" and child not in seen:  # (a malformed URDF may loop)
                seen.add(child)
                stack.append((child, T @ (np.eye(4) if j.origin is None else np.asarray(j.origin, dtype=float))))
    return combine(parts, poses)


def _inertials(urdf_links: dict, joints: dict, children: dict[str, list[str]], frames: list[str]):
    """``SerialChain.inertials`` of the link frames ``frames`` (URDF link names, the base first)."""
    bodies: list[LinkInertial | None] = []
    for frame in frames:
        try:
            bodies.append(_rigid_body(urdf_links, joints, children, frame))
        except ConfigError:  # not physical: the body gets capsule masses (module docstring)
            bodies.append(None)
    return None if all(b is None for b in bodies) else tuple(bodies)


GRIPPER_WORDS = re.compile(r"gripper|finger|jaw", re.IGNORECASE)
"""A moving joint at the end of the default chain whose name matches is the end effector's (module
docstring)."""


@dataclass(frozen=True)
class UrdfChain:
    """The chain :func:`chain_from_urdf` picks and why: ``base_link`` and ``tip_link`` (the flange's
    link), ``excluded`` the trailing gripper joints the default tip leaves out (names)."""

    chain: SerialChain
    base_link: str
    tip_link: str
    excluded: tuple[str, ...]


def chain_from_urdf(
    path: str | Path | None = None,
    *,
    text: str | None = None,
    base_link: str | None = None,
    tip_link: str | None = None,
    name: str | None = None,
) -> SerialChain:
    """The serial chain of a URDF file (``path``) or text (``text``) from ``base_link`` to
    ``tip_link`` (see the module docstring for the defaults and the frames)."""
    return urdf_chain(path, text=text, base_link=base_link, tip_link=tip_link, name=name).chain


def urdf_chain(
    path: str | Path | None = None,
    *,
    text: str | None = None,
    base_link: str | None = None,
    tip_link: str | None = None,
    name: str | None = None,
) -> UrdfChain:
    """:func:`chain_from_urdf` with the links it runs between and the gripper joints it left out."""
    if (path is None) == (text is None):
        raise ConfigError("give a URDF file or its text, not both")
    source = str(path) if path is not None else "URDF"
    if text is None:
        text = read_urdf_text(path)  # type: ignore[arg-type]
    urdf = parse_urdf(text, source)
    robot = urdf.robot
    joints = {j.child: j for j in robot.joints}
    links = [link.name for link in robot.links]
    known = set(links)
    children: dict[str, list[str]] = {link: [] for link in links}
    for j in robot.joints:
        if j.parent not in known or j.child not in known:
            raise ConfigError(f"{source}: joint '{j.name}' connects unknown link(s) '{j.parent}' -> '{j.child}'")
        if joints[j.child] is not j:  # a URDF is a tree: one parent joint per link (else the walks below never end)
            raise ConfigError(f"{source}: link '{j.child}' is the child of several joints; a URDF is a tree")
        children[j.parent].append(j.child)
    rooted = {link for link in links if link not in joints}
    for link in links:  # with one parent each, a loop is a cycle of links that no root reaches
        walked: set[str] = set()
        while link not in rooted:
            if link in walked:
                raise ConfigError(f"{source}: the joints form a loop through link '{link}'; a URDF is a tree")
            walked.add(link)
            link = joints[link].parent
        rooted.update(walked)
    roots = [link for link in links if link not in joints]
    for link, what in ((base_link, "--base-link"), (tip_link, "--tip-link")):
        if link is not None and link not in known:
            raise ConfigError(f"{source}: {what} '{link}' is not a link of the URDF (links: {', '.join(links)})")
    if base_link is None:
        if len(roots) != 1:
            raise ConfigError(f"{source}: the URDF has {len(roots)} root links ({', '.join(roots)}); give --base-link")
        base_link = roots[0]

    order = [link for link in links if link not in joints]  # every link, parents first (the joints form a tree)
    for link in order:
        order.extend(children[link])
    below: dict[str, bool] = {}  # whether a moving joint is below the link (bottom-up: no recursion, no rescans)
    for link in reversed(order):
        below[link] = any(joints[c].type != "fixed" or below[c] for c in children[link])

    def moving_below(link: str) -> bool:
        return below[link]

    def path_to(tip: str) -> list:
        path_joints = []
        link = tip
        while link != base_link:
            if link not in joints:
                raise ConfigError(f"{source}: '{tip}' is not below '{base_link}' in the URDF tree")
            path_joints.append(joints[link])
            link = joints[link].parent
        return path_joints[::-1]

    branches: list[str] = []
    excluded: list[str] = []
    if tip_link is None:
        tip_link = base_link
        while True:
            branches = [c for c in children[tip_link] if joints[c].type != "fixed" or moving_below(c)]
            if len(branches) != 1:
                break
            tip_link = branches[0]
        while True:  # a trailing gripper joint is the end effector's, not the arm's (module docstring)
            moving = [j for j in path_to(tip_link) if j.type != "fixed"]
            if len(moving) < 2 or not GRIPPER_WORDS.search(moving[-1].name):
                break
            excluded.insert(0, moving[-1].name)
            tip_link = moving[-1].parent
    path_joints = path_to(tip_link)
    origins, axes, types, lower, upper, velocity, effort, joint_names, link_names = [], [], [], [], [], [], [], [], []
    pending = np.eye(4)
    for j in path_joints:
        origin = np.eye(4) if j.origin is None else np.asarray(j.origin, dtype=float)
        if j.type == "fixed":
            pending = pending @ origin
            continue
        if j.type not in _MOVING:
            raise ConfigError(
                f"{source}: joint '{j.name}' is {j.type}; a serial chain takes revolute, continuous, "
                "prismatic and fixed joints"
            )
        if j.mimic is not None:
            raise ConfigError(
                f"{source}: joint '{j.name}' mimics '{j.mimic.joint}'; mimic joints are not independent "
                "serial joints (end the chain before it with --tip-link)"
            )
        origins.append(pending @ origin)
        pending = np.eye(4)
        axes.append(np.array([1.0, 0.0, 0.0]) if j.axis is None else np.asarray(j.axis, dtype=float))
        types.append(_MOVING[j.type])
        limit = j.limit
        if j.type == "continuous" or limit is None or limit.lower is None or limit.upper is None:
            if j.type != "continuous" and (limit is None or limit.lower is None or limit.upper is None):
                raise ConfigError(f"{source}: {j.type} joint '{j.name}' has no position limits (<limit lower upper>)")
            lower.append(-np.inf)
            upper.append(np.inf)
        else:
            lower.append(float(limit.lower))
            upper.append(float(limit.upper))
        velocity.append(None if limit is None or not limit.velocity else float(limit.velocity))
        effort.append(None if limit is None or not limit.effort else float(limit.effort))
        joint_names.append(j.name)
        link_names.append(j.child)
    # the names the chain carries into datasets, results and exports follow the one rule for names
    checked = [("robot", name or robot.name or Path(source).stem), ("link", base_link)]
    checked += [("joint", n) for n in joint_names] + [("link", n) for n in link_names]
    for what, label in checked:
        problem = name_problem(label)
        if problem is not None:
            raise ConfigError(f"{source}: {what} name '{printable(str(label))}' {problem}")
    if not origins and len(branches) > 1:
        raise ConfigError(
            f"{source}: not a serial chain: it branches at '{tip_link}' into "
            f"{', '.join(repr(b) for b in branches)}; give --tip-link (and --base-link)"
        )
    if not origins:
        raise ConfigError(f"{source}: no moving joint between '{base_link}' and '{tip_link}'")
    try:
        chain = SerialChain(
            name=name or robot.name or Path(source).stem,
            T_parent_joint=np.array(origins),
            axis=np.array(axes),
            T_joint_link=np.tile(np.eye(4), (len(origins), 1, 1)),
            joint_type=tuple(types),
            joint_lower=np.array(lower),
            joint_upper=np.array(upper),
            velocity_limit=None if None in velocity else np.array(velocity),
            effort_limit=None if None in effort else np.array(effort),
            T_link_flange=pending,
            joint_names=tuple(joint_names),
            link_names=(base_link, *link_names),
            convention="urdf",
            source=text,
            inertials=_inertials({link.name: link for link in robot.links}, joints, children, [base_link, *link_names]),
        )
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}") from None
    return UrdfChain(chain, base_link, tip_link, tuple(excluded))
