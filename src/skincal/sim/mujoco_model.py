"""MuJoCo model (MJCF) of any chain (DH or URDF), with skin-unit sites and IMU / range sensors.

Frames
------
Body ``link{i}`` IS link frame ``i`` of the chain (DH frame {i}, or the URDF frame of the child link
of the i-th movable joint; ``docs/interfaces.md``), so a unit pose ``T_link_su`` becomes a site at
that pose on body ``link{i}`` with no conversion. ``link0`` is a static body at the base frame {0}
(= MuJoCo world frame).

A joint moves its link by ``T_{i-1,i}(q) = A M(q) B`` (``A = T_parent_joint``, ``B = T_joint_link``,
``M`` a rotation about / translation along ``u = axis``; :mod:`skincal.kinematics.chain`)
``= (A B) (B^-1 M(q) B)``: body ``i`` sits at ``A B`` in body ``i-1`` and its hinge (slide) joint
is the axis ``R_B^T u`` through the point ``-R_B^T p_B``, both constant in body ``i``'s frame: no
intermediate body. (Modified DH: ``B = Tz(d)``, the hinge is the body's z axis; standard DH:
``A = Rz(theta)``, the axis passes through the origin of frame {i-1}.) A continuous joint has no
range.

Sensors per unit ``u`` (site ``su/u``, site frame = SU frame): ``su/u/accel`` (MuJoCo's
accelerometer: ``f = R_base_su^T (a - g)``, +9.81 m/s^2 along "up" at rest), ``su/u/gyro``
(rad/s, SU frame) and ``su/u/range`` (distance along the site's +z to the nearest geom not on the
unit's own body, m; -1 when nothing is hit). All geoms have ``contype = conaffinity = 0``: no
contacts are simulated (the obstacles of :mod:`skincal.sim.scene` are seen by the range sensors only).

Masses: a chain's own link inertials when it has them (``SerialChain.inertials``: a URDF's
``<inertial>`` elements, the links folded by fixed joints combined into their link frame), else for
the Panda the link inertials of Franka's ``franka_description`` (see :data:`PANDA_INERTIALS`);
a body with none gets MuJoCo's inertia of its link capsules at :data:`DEFAULT_LINK_DENSITY`.
``mujoco`` is optional: it is imported only when a model is compiled.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from skincal.errors import ConfigError
from skincal.kinematics.chain import GRAVITY_BASE, SerialChain
from skincal.kinematics.geometry import DEFAULT_LINK_RADIUS, link_capsules
from skincal.kinematics.inertia import LinkInertial
from skincal.kinematics.presets import iiwa14, panda, ur5e
from skincal.kinematics.transforms import FloatArray, quat_wxyz_from_matrix
from skincal.sim.mjcf import mjcf_floats
from skincal.skin.pose import SkinUnitPose

if TYPE_CHECKING:  # pragma: no cover
    import mujoco

    from skincal.sim.scene import Scene

DEFAULT_LINK_DENSITY = 1350.0
"""Density of the solid link capsules of non-Panda chains, kg/m^3: aluminium (2700) at half fill,
giving 2-8 kg per 0.3-0.4 m link of 6 cm radius, about what UR5e/Sawyer links weigh."""

BOARD_SIZE = (0.033, 0.036, 0.005)
"""Skin-unit board (x, y, z) extent, m; the board lies under the site (its top face at z = 0)."""

TIMESTEP = 0.001
"""Physics time step, s (1 kHz, the Panda's control rate)."""

_MISSING_MUJOCO = "MuJoCo is not installed: pip install 'skincal[mujoco]'"


def _li(mass: float, com: Sequence[float], inertia: Sequence[float]) -> LinkInertial:
    return LinkInertial(float(mass), np.array(com, dtype=float), np.array(inertia, dtype=float))


# Franka Emika Panda links 1-7 as published in franka_ros, franka_description/robots/common/inertial.yaml
# (values from C. Gaz, M. Cognetti, A. Oliva, P. Robuffo Giordano, A. De Luca, "Dynamic identification of
# the Franka Emika Panda robot with retrieval of feasible parameters using penalty-based optimization",
# IEEE RA-L 4(4), 2019). franka_description's link frames are the modified DH frames of the Panda table.
# Columns: mass [kg], CoM [m], [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] [kg m^2] about the CoM.
PANDA_INERTIALS: tuple[LinkInertial, ...] = (
    _li(4.970684, [0.003875, 0.002081, -0.04762], [0.70337, 0.70661, 0.009117, -0.000139, 0.006772, 0.019169]),
    _li(0.646926, [-0.003141, -0.02872, 0.003495], [0.007962, 0.02811, 0.025995, -0.003925, 0.010254, 0.000704]),
    _li(3.228604, [0.027518, 0.039252, -0.066502], [0.037242, 0.036155, 0.01083, -0.004761, -0.011396, -0.012805]),
    _li(3.587895, [-0.05317, 0.104419, 0.027454], [0.025853, 0.019552, 0.028323, 0.007796, -0.001332, 0.008641]),
    _li(1.225946, [-0.011953, 0.041065, -0.038437], [0.035549, 0.029474, 0.008627, -0.002117, -0.004037, 0.000229]),
    _li(1.666555, [0.060149, -0.014117, -0.010517], [0.001964, 0.004354, 0.005433, 0.000109, -0.001158, 0.000341]),
    _li(0.735522, [0.010517, -0.004252, 0.061597], [0.012516, 0.010027, 0.004815, -0.000428, -0.001196, -0.000741]),
)

# Universal Robots UR5e links 1-6 in the standard DH frames of the ``ur5e`` preset: masses and centres of
# mass from UR's "DH parameters for calculations of kinematics and dynamics" (given there in these DH
# frames), inertia tensors about the CoM from UR's ur_description (config/ur5e/physical_parameters.yaml,
# whose inertia frames are rotated onto the same DH axes). Columns as PANDA_INERTIALS.
UR5E_INERTIALS: tuple[LinkInertial, ...] = (
    _li(3.761, [0.0, -0.02561, 0.00193], [0.0070021, 0.00648091, 0.00657286, 0.00000073, -0.00001053, 0.00049994]),
    _li(8.058, [0.2125, 0.0, 0.11336], [0.01505885, 0.33388086, 0.33247207, -0.000054, 0.00000563, -0.00000181]),
    _li(2.846, [0.15, 0.0, 0.0265], [0.00399632, 0.07879254, 0.0784851, -0.00001365, 0.00137272, -0.0000066]),
    _li(1.37, [0.0, -0.0018, 0.01634], [0.00165491, 0.00135962, 0.00126279, -0.00000282, -0.00000438, 0.00010157]),
    _li(1.3, [0.0, 0.0018, 0.01634], [0.00135617, 0.00127827, 0.00096614, -0.00000274, 0.00000444, -0.00005048]),
    _li(0.365, [0.0, 0.0, -0.001159], [0.00018694, 0.00018908, 0.00025756, 0.00000006, -0.00000017, -0.00000092]),
)

# KUKA LBR iiwa 14 R820 links 1-7 in the standard DH frames of the ``iiwa14`` preset: the link inertials of
# Drake's iiwa14 description (manipulation/models/iiwa_description, as in MuJoCo Menagerie's kuka_iiwa_14;
# KUKA publishes none), each moved from its URDF link frame into the DH frame by the constant transform
# between the two (exact axis permutations: the two chains agree for every q, joint signs equal).
IIWA14_INERTIALS: tuple[LinkInertial, ...] = (
    _li(5.76, [0.0, 0.0825, -0.03], [0.0333, 0.0123, 0.033, 0.0, 0.0, 0.0]),
    _li(6.35, [-0.0003, 0.042, 0.059], [0.0305, 0.011, 0.0304, 0.0, 0.0, 0.0]),
    _li(3.5, [0.0, -0.0855, -0.03], [0.025, 0.0076, 0.0238, 0.0, 0.0, 0.0]),
    _li(3.5, [0.0, -0.034, 0.067], [0.017, 0.006, 0.0164, 0.0, 0.0, 0.0]),
    _li(3.5, [-0.0001, 0.1395, -0.021], [0.01, 0.00449, 0.0087, 0.0, 0.0, 0.0]),
    _li(1.8, [0.0, 0.0004, 0.0006], [0.0049, 0.0036, 0.0047, 0.0, 0.0, 0.0]),
    _li(1.2, [0.0, 0.0, -0.025], [0.001, 0.001, 0.001, 0.0, 0.0, 0.0]),
)


def require_mujoco() -> Any:
    """Import and return the ``mujoco`` module, or raise :class:`ConfigError` saying how to install it."""
    try:
        import mujoco
    except ImportError:  # pragma: no cover - exercised only without the extra
        raise ConfigError(_MISSING_MUJOCO) from None
    return mujoco


def default_inertials(chain: SerialChain) -> list[LinkInertial | None] | None:
    """Inertials of links ``1..n``: the chain's own (``SerialChain.inertials``, e.g. a URDF's; an
    entry is ``None`` for a link without one), else Franka's published ones for the Panda, else
    ``None`` (MuJoCo derives every link's from its capsules)."""
    if chain.inertials is not None:
        return list(chain.inertials[1:])
    return list(PANDA_INERTIALS) if chain.same_motion(panda()) else None


def published_inertials(chain: SerialChain) -> list[LinkInertial | None] | None:
    """Inertials of links ``1..n`` for dynamics (:mod:`skincal.sim.dynamics`): the chain's own, else the
    maker's published ones of the Panda, UR5e or iiwa14 (:data:`PANDA_INERTIALS`, :data:`UR5E_INERTIALS`,
    :data:`IIWA14_INERTIALS`, matched by motion), else ``None`` (the capsules'). :func:`default_inertials`
    (what :func:`build_mjcf` uses unless told) keeps capsule inertias for UR5e and iiwa14, so the
    kinematic simulators' models are unchanged."""
    if chain.inertials is not None:
        return list(chain.inertials[1:])
    for table, preset in ((PANDA_INERTIALS, panda), (UR5E_INERTIALS, ur5e), (IIWA14_INERTIALS, iiwa14)):
        if chain.same_motion(preset()):
            return list(table)
    return None


# ---------------------------------------------------------------------------------------------- names
def body_name(link: int) -> str:
    """Name of the body of link frame ``link`` (0 = base)."""
    return f"link{link}"


def joint_name(joint: int) -> str:
    """Name of joint ``joint`` (1-based)."""
    return f"joint{joint}"


def site_name(unit: str) -> str:
    """Name of the site of skin unit ``unit``."""
    return f"su/{unit}"


def motor_name(joint: int) -> str:
    """Name of the torque (``motor``) actuator of joint ``joint`` (1-based)."""
    return f"{joint_name(joint)}/motor"


def sensor_name(unit: str, kind: str) -> str:
    """Name of a unit's sensor; ``kind`` is ``accel``, ``gyro`` or ``range``."""
    return f"su/{unit}/{kind}"


# ---------------------------------------------------------------------------------------------- MJCF
def _body_offset(chain: SerialChain, i: int) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Body ``i`` (1-based) in body ``i-1`` at ``q_i = 0``, and its joint: ``(pos, quat_wxyz, axis,
    anchor)``. With ``T_{i-1,i}(q) = A M(q) B = (A B) (B^-1 M(q) B)`` (module docstring) the body sits
    at ``A B`` and moves about (or along) the axis ``R_B^T u`` through the point ``-R_B^T p_B``, both
    constant in its own frame."""
    A, B, u = chain.T_parent_joint[i - 1], chain.T_joint_link[i - 1], chain.axis[i - 1]
    AB = A @ B
    R_B, p_B = B[:3, :3], B[:3, 3]
    return AB[:3, 3], quat_wxyz_from_matrix(AB[:3, :3]), R_B.T @ u, -R_B.T @ p_B


MIN_PRINCIPAL_INERTIA = 1e-12
"""Smallest principal moment written to MuJoCo, kg m^2: MuJoCo needs positive ones, and a valid
:class:`LinkInertial` may have zero ones (a point mass, a thin rod); those are raised to this."""


def _add_inertial(body: ET.Element, inertial: LinkInertial | None) -> None:
    if inertial is None:
        return
    attrs = {"pos": mjcf_floats(inertial.com), "mass": mjcf_floats(inertial.mass)}
    moments, axes = np.linalg.eigh(inertial.tensor)
    if moments[0] >= MIN_PRINCIPAL_INERTIA:
        attrs["fullinertia"] = mjcf_floats(inertial.inertia)
    else:  # principal axes and raised moments (raising all alike keeps A + B >= C)
        axes[:, 2] *= np.sign(np.linalg.det(axes))  # a proper rotation
        attrs["quat"] = mjcf_floats(quat_wxyz_from_matrix(axes))
        attrs["diaginertia"] = mjcf_floats(np.maximum(moments, MIN_PRINCIPAL_INERTIA))
    ET.SubElement(body, "inertial", attrs)


def _add_capsules(body: ET.Element, chain: SerialChain, link: int, radius: float | FloatArray, density: float) -> None:
    for k, cap in enumerate(c for c in link_capsules(chain, radius) if c.link == link):
        attrs = {
            "name": f"{body_name(link)}/capsule{k}",
            "contype": "0",
            "conaffinity": "0",
            "density": repr(float(density)),
            "rgba": "0.85 0.85 0.88 1",
        }
        if cap.length > 0:
            attrs |= {
                "type": "capsule",
                "fromto": mjcf_floats(np.concatenate([cap.p0, cap.p1])),
                "size": mjcf_floats(cap.radius),
            }
        else:
            attrs |= {"type": "sphere", "pos": mjcf_floats(cap.p0), "size": mjcf_floats(cap.radius)}
        ET.SubElement(body, "geom", attrs)


def _check_placements(chain: SerialChain, placements: Mapping[str, SkinUnitPose]) -> None:
    for unit, pose in placements.items():
        if not isinstance(unit, str) or not unit:
            raise ConfigError(f"skin unit names must be non-empty strings, got {unit!r}")
        if not isinstance(pose, SkinUnitPose):
            raise ConfigError(f"skin unit '{unit}': placement must be a SkinUnitPose, got {type(pose).__name__}")
        if pose.link > chain.n_joints:
            raise ConfigError(
                f"skin unit '{unit}': link {pose.link} does not exist on '{chain.name}' (1..{chain.n_joints})"
            )


def build_mjcf(
    chain: SerialChain,
    placements: Mapping[str, SkinUnitPose] | None = None,
    *,
    scene: Scene | None = None,
    board_geoms: bool = True,
    inertials: Sequence[LinkInertial | None] | None = None,
    link_radius: float | FloatArray = DEFAULT_LINK_RADIUS,
    density: float = DEFAULT_LINK_DENSITY,
    velocity_gain: float | Sequence[float] | None = None,
    gravity_compensation: bool = False,
    range_directions: FloatArray | None = None,
    gravity: FloatArray = GRAVITY_BASE,
    motor_limits: float | Sequence[float] | None = None,
    armature: float | Sequence[float] | None = None,
    damping: float | Sequence[float] | None = None,
) -> str:
    """MJCF text of ``chain`` with one site and accelerometer/gyro/rangefinder per skin unit.

    Args:
        chain: any DH chain (modified or standard); already validated by :class:`SerialChain`.
        placements: unit name -> :class:`SkinUnitPose` (pose in link frame ``pose.link``).
        scene: obstacles (:class:`skincal.sim.scene.Scene`), added as mocap bodies.
        board_geoms: add a 33 x 36 x 5 mm massless, non-colliding box per unit (visual only).
        inertials: ``n`` inertials of links ``1..n`` in the link frames, ``None`` entries for links
            whose capsules give theirs; default :func:`default_inertials` (the chain's own, e.g. a
            URDF's; Panda: Franka's values; others: MuJoCo's inertia of the solid capsules at
            ``density``). The static base body ``link0`` takes the chain's base inertial
            (``chain.inertials[0]``) when it has one, else its capsules'.
        link_radius: capsule radius (m), one or ``(n + 1,)``.
        density: capsule density for links without explicit inertials, kg/m^3.
        velocity_gain: when given, one MuJoCo ``velocity`` actuator per joint with this gain
            ``kv`` (N m s/rad, one or ``(n,)``): ``tau = kv (ctrl - qd)``, ``ctrl`` in rad/s.
        gravity_compensation: cancel gravity on every link (MuJoCo ``gravcomp``), as the robot's own
            controller does; sensors still feel gravity.
        range_directions: ``(K, 3)`` unit ray directions in the SU frame (e.g. a ToF cone from
            :func:`skincal.skin.tof.cone_directions`): rangefinders ``su/u/range{k}`` on extra sites
            ``su/u/ray{k}`` at the unit's origin. Default: one rangefinder ``su/u/range`` along +z.
        gravity: ``(3,)`` gravity in the base frame, m/s^2.
        motor_limits: when given, one MuJoCo ``motor`` actuator ``joint{i}/motor`` per joint (after any
            velocity actuators): ``ctrl`` is the joint torque (N m; force N for a prismatic joint),
            ``ctrlrange`` +-these limits (one or ``(n,)``, e.g. the chain's ``effort_limit``).
        armature: rotor inertia reflected at each joint, kg m^2 (one or ``(n,)``; MuJoCo ``armature``).
        damping: viscous joint damping, N m s/rad (one or ``(n,)``; MuJoCo ``damping``).
        Without ``motor_limits``, ``armature`` and ``damping`` the text is what it was before they existed.
    """
    placements = dict(placements or {})
    _check_placements(chain, placements)
    n = chain.n_joints
    if inertials is None:
        inertials = default_inertials(chain)
    if inertials is not None and len(inertials) != n:
        raise ConfigError(f"robot '{chain.name}': inertials must list {n} links, got {len(inertials)}")
    motor = _joint_values(motor_limits, n, "motor_limits", positive=True)
    joint_armature = _joint_values(armature, n, "armature")
    joint_damping = _joint_values(damping, n, "damping")
    g = np.asarray(gravity, dtype=float)
    if g.shape != (3,) or not np.all(np.isfinite(g)):
        raise ConfigError(f"gravity must be 3 finite numbers in m/s^2, got {np.asarray(gravity).tolist()}")

    root = ET.Element("mujoco", {"model": f"skincal_{chain.name}"})
    ET.SubElement(root, "compiler", {"angle": "radian", "autolimits": "true", "inertiafromgeom": "auto"})
    ET.SubElement(root, "option", {"timestep": repr(TIMESTEP), "gravity": mjcf_floats(g), "integrator": "implicitfast"})
    world = ET.SubElement(root, "worldbody")
    parent = ET.SubElement(world, "body", {"name": body_name(0)})
    _add_inertial(parent, None if chain.inertials is None else chain.inertials[0])
    _add_capsules(parent, chain, 0, link_radius, density)
    bodies = [parent]
    for i in range(1, n + 1):
        pos, quat, axis, anchor = _body_offset(chain, i)
        battrs = {"name": body_name(i), "pos": mjcf_floats(pos), "quat": mjcf_floats(quat)}
        if gravity_compensation:
            battrs["gravcomp"] = "1"
        body = ET.SubElement(parent, "body", battrs)
        kind = "hinge" if chain.joint_type[i - 1] == "revolute" else "slide"
        jattrs = {"name": joint_name(i), "type": kind, "axis": mjcf_floats(axis), "pos": mjcf_floats(anchor)}
        if (
            chain.joint_lower is not None
            and chain.joint_upper is not None
            and np.isfinite(chain.joint_lower[i - 1])
            and np.isfinite(chain.joint_upper[i - 1])
        ):
            jattrs["range"] = mjcf_floats([chain.joint_lower[i - 1], chain.joint_upper[i - 1]])
        if joint_armature is not None:
            jattrs["armature"] = mjcf_floats(joint_armature[i - 1])
        if joint_damping is not None:
            jattrs["damping"] = mjcf_floats(joint_damping[i - 1])
        ET.SubElement(body, "joint", jattrs)
        if inertials is not None:
            _add_inertial(body, inertials[i - 1])
        _add_capsules(body, chain, i, link_radius, density)
        bodies.append(body)
        parent = body

    sensors = ET.SubElement(root, "sensor")
    for unit, pose in placements.items():
        body = bodies[pose.link]
        site_quat = mjcf_floats(quat_wxyz_from_matrix(pose.R_link_su))
        ET.SubElement(
            body,
            "site",
            {
                "name": site_name(unit),
                "pos": mjcf_floats(pose.p_link_su),
                "quat": site_quat,
                "size": "0.005",
                "rgba": "0.1 0.6 0.2 1",
            },
        )
        if board_geoms:
            half = np.asarray(BOARD_SIZE) / 2
            centre = pose.p_link_su - half[2] * pose.R_link_su[:, 2]
            ET.SubElement(
                body,
                "geom",
                {
                    "name": f"{site_name(unit)}/board",
                    "type": "box",
                    "size": mjcf_floats(half),
                    "pos": mjcf_floats(centre),
                    "quat": site_quat,
                    "mass": "0",
                    "contype": "0",
                    "conaffinity": "0",
                    "group": "3",
                    "rgba": "0.1 0.5 0.2 1",
                },
            )
        for kind, tag in (("accel", "accelerometer"), ("gyro", "gyro")):
            ET.SubElement(sensors, tag, {"name": sensor_name(unit, kind), "site": site_name(unit)})
        if range_directions is None:
            ET.SubElement(sensors, "rangefinder", {"name": sensor_name(unit, "range"), "site": site_name(unit)})
            continue
        for k, R_su_ray in enumerate(_frames_along(np.asarray(range_directions, dtype=float))):
            ray_site = f"{site_name(unit)}/ray{k}"
            ET.SubElement(
                body,
                "site",
                {
                    "name": ray_site,
                    "pos": mjcf_floats(pose.p_link_su),
                    "quat": mjcf_floats(quat_wxyz_from_matrix(pose.R_link_su @ R_su_ray)),
                },
            )
            ET.SubElement(sensors, "rangefinder", {"name": sensor_name(unit, f"range{k}"), "site": ray_site})

    actuators = None
    if velocity_gain is not None:
        kv = np.broadcast_to(np.asarray(velocity_gain, dtype=float), (n,))
        if not np.all(np.isfinite(kv) & (kv > 0)):
            raise ConfigError(f"velocity_gain must be positive N m s/rad, got {kv.tolist()}")
        actuators = ET.SubElement(root, "actuator")
        for i in range(1, n + 1):
            ET.SubElement(
                actuators,
                "velocity",
                {"name": f"{joint_name(i)}/velocity", "joint": joint_name(i), "kv": repr(float(kv[i - 1]))},
            )
    if motor is not None:
        actuators = actuators if actuators is not None else ET.SubElement(root, "actuator")
        for i in range(1, n + 1):
            limit = float(motor[i - 1])
            ET.SubElement(
                actuators,
                "motor",
                {"name": motor_name(i), "joint": joint_name(i), "ctrlrange": mjcf_floats([-limit, limit])},
            )
    if scene is not None:
        scene.add_to_mjcf(world)
    ET.indent(root)
    return ET.tostring(root, encoding="unicode")


def _joint_values(
    values: float | Sequence[float] | None, n: int, what: str, positive: bool = False
) -> FloatArray | None:
    """``(n,)`` finite per-joint values (one broadcast to all), non-negative (positive when told), or
    ``None``; a one-line :class:`ConfigError` otherwise."""
    if values is None:
        return None
    try:
        arr = np.broadcast_to(np.asarray(values, dtype=float), (n,))
    except ValueError:
        raise ConfigError(f"{what} must be one number or {n} numbers, got {np.shape(values)}") from None
    bad = ~np.isfinite(arr) | (arr <= 0 if positive else arr < 0)
    if np.any(bad):
        need = "positive" if positive else "non-negative"
        raise ConfigError(f"{what} must be finite {need} numbers, got {arr.tolist()}")
    return arr


def _frames_along(directions: FloatArray) -> FloatArray:
    """Rotations ``(K, 3, 3)`` whose z columns are the given unit directions ``(K, 3)``."""
    if directions.ndim != 2 or directions.shape[1] != 3 or not np.all(np.isfinite(directions)):
        raise ConfigError(f"range_directions must be a finite (K, 3) array, got shape {directions.shape}")
    z = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    helper = np.where(np.abs(z[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    return np.stack([x, np.cross(z, x), z], axis=-1)


def build_model(
    chain: SerialChain, placements: Mapping[str, SkinUnitPose] | None = None, **kwargs: Any
) -> mujoco.MjModel:
    """Compiled :class:`mujoco.MjModel` of :func:`build_mjcf` (same arguments)."""
    mujoco = require_mujoco()
    xml = build_mjcf(chain, placements, **kwargs)
    try:
        return mujoco.MjModel.from_xml_string(xml)
    except ValueError as exc:
        raise ConfigError(f"robot '{chain.name}': MuJoCo rejected the generated model: {exc}") from None


@dataclass(frozen=True)
class SensorIndex:
    """Where each unit's readings live in ``MjData.sensordata`` and which site it is.

    Attributes:
        units: unit names in placement order.
        site: ``(U,)`` site ids.
        accel, gyro: ``(U, 3)`` sensordata indices.
        range: ``(U, K)`` sensordata indices of the ``K`` rangefinders of each unit.
    """

    units: tuple[str, ...]
    site: np.ndarray
    accel: np.ndarray
    gyro: np.ndarray
    range: np.ndarray

    @classmethod
    def of(cls, model: mujoco.MjModel, units: Sequence[str], n_rays: int | None = None) -> SensorIndex:
        """Look the units' sites and sensors up in a model built by :func:`build_model`.

        ``n_rays``: the number of ``range_directions`` the model was built with (``None``: one
        rangefinder along +z)."""
        range_kinds = ["range"] if n_rays is None else [f"range{k}" for k in range(n_rays)]

        def adr(unit: str, kind: str, dim: int) -> np.ndarray:
            start = int(model.sensor(sensor_name(unit, kind)).adr[0])
            return np.arange(start, start + dim)

        try:
            return cls(
                units=tuple(units),
                site=np.array([model.site(site_name(u)).id for u in units], dtype=int),
                accel=np.array([adr(u, "accel", 3) for u in units], dtype=int).reshape(-1, 3),
                gyro=np.array([adr(u, "gyro", 3) for u in units], dtype=int).reshape(-1, 3),
                range=np.array([[adr(u, kind, 1)[0] for kind in range_kinds] for u in units], dtype=int).reshape(
                    len(units), len(range_kinds)
                ),
            )
        except KeyError as exc:
            raise ConfigError(f"MuJoCo model has no skin unit sensors for {exc}") from None


def full_mass_matrix(model: mujoco.MjModel, data: mujoco.MjData) -> FloatArray:
    """Dense joint-space inertia ``(nv, nv)`` of ``data``'s last position pass (``mj_fwdPosition``)."""
    mujoco = require_mujoco()
    M = np.zeros((model.nv, model.nv))
    try:
        mujoco.mj_fullM(model, data, M)  # MuJoCo >= 3.3
    except TypeError:  # pragma: no cover - older signature (m, dst, qM)
        mujoco.mj_fullM(model, M, data.qM)
    return M


def link_body_ids(model: mujoco.MjModel, n_joints: int) -> np.ndarray:
    """Body ids ``(n + 1,)`` of link frames 0..n."""
    return np.array([model.body(body_name(i)).id for i in range(n_joints + 1)], dtype=int)
