"""Robot presets and user chains from YAML/JSON files.

Presets:
* ``panda``: Franka Emika Panda, modified DH, Franka's published table, position and velocity
  limits, flange ``d = 0.107`` m along z of frame 7 (the paper's robot).
* ``sawyer``: Rethink Sawyer, standard DH (Layeghi 2017 table, as in Corke's Robotics Toolbox).
* ``ur5e``: Universal Robots UR5e, standard DH (UR's published table).
* ``ur5``, ``ur10e``: Universal Robots UR5 (CB3) and UR10e, standard DH (UR's published tables).
* ``xarm7``: UFactory xArm7, modified DH and limits of UFactory's URDF.
* ``iiwa14``: KUKA LBR iiwa 14 R820, standard DH, KUKA's axis ranges and speeds.
* ``gen3``: Kinova Gen3 7-DoF from Kinova's URDF joint origins (its link frames and names are
  Kinova's; continuous joints 1, 3, 5, 7).

``--robot`` also takes a URDF (``.urdf``, :mod:`skincal.kinematics.urdf`) or a DH chain file.

Joint names: each preset carries the names its maker's ROS driver publishes in
``sensor_msgs/JointState`` (and its ``*_description`` URDF uses), so a bag imports without a topic
map (:mod:`skincal.data.ros`; a prefixed name such as ``ur_elbow_joint`` or ``lbr_A1`` matches too):

* panda: ``panda_joint1`` .. ``panda_joint7`` (``franka_ros``/``franka_description``);
* sawyer: ``right_j0`` .. ``right_j6`` (Rethink's ``intera_sdk``);
* ur5, ur5e, ur10e: ``shoulder_pan_joint``, ``shoulder_lift_joint``, ``elbow_joint``,
  ``wrist_1_joint``, ``wrist_2_joint``, ``wrist_3_joint`` (``Universal_Robots_ROS_Driver``,
  ``ur_description``);
* xarm7: ``joint1`` .. ``joint7`` (UFactory's ``xarm_ros``/``xarm_description``);
* iiwa14: ``A1`` .. ``A7``, KUKA's axis names as the ``lbr_fri_ros2_stack`` publishes them
  (``lbr_A1`` ..); bags of ROS-Industrial's ``kuka_experimental`` (``joint_a1`` ..) or of
  ``iiwa_stack`` (``iiwa_joint_1`` ..) need ``joint_names`` in a topic map.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from skincal.errors import ConfigError
from skincal.kinematics.chain import SerialChain

_PI = np.pi
UR_JOINT_NAMES = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint",
                  "wrist_3_joint")  # fmt: skip
"""The joint names of Universal Robots' driver and URDF, base first."""


def panda() -> SerialChain:
    """Franka Emika Panda (modified DH), the robot of the paper."""
    dh = [
        [0.0, 0.333, 0.0, 0.0],
        [0.0, 0.0, 0.0, -_PI / 2],
        [0.0, 0.316, 0.0, _PI / 2],
        [0.0, 0.0, 0.0825, _PI / 2],
        [0.0, 0.384, -0.0825, -_PI / 2],
        [0.0, 0.0, 0.0, _PI / 2],
        [0.0, 0.0, 0.088, _PI / 2],
    ]
    flange = np.eye(4)
    flange[2, 3] = 0.107
    return SerialChain.from_dh(
        "panda",
        "modified",
        np.array(dh),
        joint_lower=np.array([-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973]),
        joint_upper=np.array([2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973]),
        velocity_limit=np.array([2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61]),
        T_link_flange=flange,
        joint_names=tuple(f"panda_joint{i}" for i in range(1, 8)),
    )


def sawyer() -> SerialChain:
    """Rethink Sawyer (standard DH)."""
    d = [0.317, 0.1925, 0.4, 0.1685, 0.4, 0.1363, 0.13375]
    a = [0.081, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    alpha = [-_PI / 2] * 6 + [0.0]
    dh = np.column_stack([np.zeros(7), d, a, alpha])
    return SerialChain.from_dh(
        "sawyer",
        "standard",
        dh,
        joint_lower=np.array([-3.0503, -3.8095, -3.0426, -3.0439, -2.9761, -2.9761, -4.7124]),
        joint_upper=np.array([3.0503, 2.2736, 3.0426, 3.0439, 2.9761, 2.9761, 4.7124]),
        velocity_limit=np.array([1.74, 1.328, 1.957, 1.957, 3.485, 3.485, 4.545]),
        joint_names=tuple(f"right_j{i}" for i in range(7)),
    )


def ur5e() -> SerialChain:
    """Universal Robots UR5e (standard DH), a 6-DoF standard-DH example."""
    d = [0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996]
    a = [0.0, -0.425, -0.3922, 0.0, 0.0, 0.0]
    alpha = [_PI / 2, 0.0, 0.0, _PI / 2, -_PI / 2, 0.0]
    dh = np.column_stack([np.zeros(6), d, a, alpha])
    lim = np.array([2 * _PI, 2 * _PI, _PI, 2 * _PI, 2 * _PI, 2 * _PI])
    return SerialChain.from_dh(
        "ur5e",
        "standard",
        dh,
        joint_lower=-lim,
        joint_upper=lim,
        velocity_limit=np.full(6, _PI),
        joint_names=UR_JOINT_NAMES,
    )


def _ur(name: str, d: list[float], a: list[float], velocity: list[float]) -> SerialChain:
    """A Universal Robots arm from UR's published standard-DH table (``alpha`` is the same for all)."""
    alpha = [_PI / 2, 0.0, 0.0, _PI / 2, -_PI / 2, 0.0]
    lim = np.array([2 * _PI, 2 * _PI, _PI, 2 * _PI, 2 * _PI, 2 * _PI])
    dh = np.column_stack([np.zeros(6), d, a, alpha])
    return SerialChain.from_dh(
        name, "standard", dh, joint_lower=-lim, joint_upper=lim, velocity_limit=velocity, joint_names=UR_JOINT_NAMES
    )


def ur5() -> SerialChain:
    """Universal Robots UR5 (CB3), standard DH (UR's published table)."""
    return _ur("ur5", [0.089159, 0.0, 0.0, 0.10915, 0.09465, 0.0823], [0.0, -0.425, -0.39225, 0.0, 0.0, 0.0], [_PI] * 6)


def ur10e() -> SerialChain:
    """Universal Robots UR10e, standard DH (UR's published table); base and shoulder 120 deg/s."""
    return _ur(
        "ur10e",
        [0.1807, 0.0, 0.0, 0.17415, 0.11985, 0.11655],
        [0.0, -0.6127, -0.57155, 0.0, 0.0, 0.0],
        [2 * _PI / 3, 2 * _PI / 3, _PI, _PI, _PI, _PI],
    )


def xarm7() -> SerialChain:
    """UFactory xArm7, modified DH and limits of UFactory's URDF (``xarm_description``)."""
    dh = [
        [0.0, 0.267, 0.0, 0.0],
        [0.0, 0.0, 0.0, -_PI / 2],
        [0.0, 0.293, 0.0, _PI / 2],
        [0.0, 0.0, 0.0525, _PI / 2],
        [0.0, 0.3425, 0.0775, _PI / 2],
        [0.0, 0.0, 0.0, _PI / 2],
        [0.0, 0.097, 0.076, -_PI / 2],
    ]
    return SerialChain.from_dh(
        "xarm7",
        "modified",
        np.array(dh),
        joint_lower=np.array([-2 * _PI, -2.059, -2 * _PI, -0.19198, -2 * _PI, -1.69297, -2 * _PI]),
        joint_upper=np.array([2 * _PI, 2.0944, 2 * _PI, 3.927, 2 * _PI, _PI, 2 * _PI]),
        velocity_limit=np.full(7, 3.14),
        joint_names=tuple(f"joint{i}" for i in range(1, 8)),
    )


def iiwa14() -> SerialChain:
    """KUKA LBR iiwa 14 R820, standard DH; KUKA's axis ranges (170/120/170/120/170/120/175 deg) and
    axis speeds (85/85/100/75/130/135/135 deg/s)."""
    d = [0.36, 0.0, 0.42, 0.0, 0.4, 0.0, 0.126]
    alpha = [-_PI / 2, _PI / 2, _PI / 2, -_PI / 2, -_PI / 2, _PI / 2, 0.0]
    lim = np.radians([170.0, 120.0, 170.0, 120.0, 170.0, 120.0, 175.0])
    return SerialChain.from_dh(
        "iiwa14",
        "standard",
        np.column_stack([np.zeros(7), d, np.zeros(7), alpha]),
        joint_lower=-lim,
        joint_upper=lim,
        velocity_limit=np.radians([85.0, 85.0, 100.0, 75.0, 130.0, 135.0, 135.0]),
        joint_names=tuple(f"A{i}" for i in range(1, 8)),
    )


def _gen3_urdf() -> str:
    """The kinematic part of Kinova's Gen3 7-DoF description (``ros_kortex``'s ``gen3.urdf``): joint
    origins in m with the rotations written exactly (pi/2, pi), Kinova's link and joint names,
    continuous joints 1, 3, 5, 7 and Kinova's ranges of joints 2, 4, 6 (128.9, 147.8, 120.3 deg),
    speeds 80 deg/s (actuators 1-4) and 70 deg/s (5-7)."""
    p, h = repr(_PI), repr(_PI / 2)
    rows = [  # (joint, parent, child, xyz, rpy, limit degrees or None, speed deg/s)
        ("joint_1", "base_link", "shoulder_link", "0 0 0.15643", f"{p} 0 0", None, 80.0),
        ("joint_2", "shoulder_link", "half_arm_1_link", "0 0.005375 -0.12838", f"{h} 0 0", 128.9, 80.0),
        ("joint_3", "half_arm_1_link", "half_arm_2_link", "0 -0.21038 -0.006375", f"-{h} 0 0", None, 80.0),
        ("joint_4", "half_arm_2_link", "forearm_link", "0 0.006375 -0.21038", f"{h} 0 0", 147.8, 80.0),
        ("joint_5", "forearm_link", "spherical_wrist_1_link", "0 -0.20843 -0.006375", f"-{h} 0 0", None, 70.0),
        ("joint_6", "spherical_wrist_1_link", "spherical_wrist_2_link", "0 0.00017505 -0.10593", f"{h} 0 0", 120.3,
         70.0),  # fmt: skip
        ("joint_7", "spherical_wrist_2_link", "bracelet_link", "0 -0.10593 -0.00017505", f"-{h} 0 0", None, 70.0),
    ]
    links = ["base_link"] + [r[2] for r in rows] + ["end_effector_link"]
    text = ['<robot name="gen3">'] + [f'<link name="{name}"/>' for name in links]
    for joint, parent, child, xyz, rpy, limit, speed in rows:
        v = repr(float(np.radians(speed)))
        r = repr(float(np.radians(limit))) if limit is not None else ""
        bounds = f'lower="-{r}" upper="{r}" ' if r else ""
        lim = f'<limit {bounds}velocity="{v}" effort="39"/>'

        kind = "revolute" if limit is not None else "continuous"
        text.append(
            f'<joint name="{joint}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{xyz}" rpy="{rpy}"/><axis xyz="0 0 1"/>{lim}</joint>'
        )
    text.append(
        '<joint name="end_effector" type="fixed"><parent link="bracelet_link"/><child link="end_effector_link"/>'
        f'<origin xyz="0 0 -0.061525" rpy="{p} 0 0"/></joint></robot>'
    )
    return "\n".join(text)


def gen3() -> SerialChain:
    """Kinova Gen3 (7 DoF) from Kinova's own description (:func:`_gen3_urdf`); its link frames are
    Kinova's URDF frames, checked against the classical DH table of Kinova's user guide."""
    from skincal.kinematics.urdf import chain_from_urdf

    return chain_from_urdf(text=_gen3_urdf(), name="gen3", tip_link="end_effector_link")


PRESETS = {
    "panda": panda, "iiwa14": iiwa14, "gen3": gen3, "sawyer": sawyer, "ur5": ur5, "ur5e": ur5e, "ur10e": ur10e,
    "xarm7": xarm7,
}  # fmt: skip


def get_robot(name: str, *, base_link: str | None = None, tip_link: str | None = None) -> SerialChain:
    """A preset by name, a URDF (``.urdf``; ``base_link``/``tip_link`` pick the serial chain, see
    :func:`skincal.kinematics.urdf.chain_from_urdf`) or a DH chain file (``.yaml``, ``.yml``,
    ``.json``) by path."""
    suffix = Path(name).suffix.lower()
    if (base_link is not None or tip_link is not None) and suffix != ".urdf":
        raise ConfigError("--base-link and --tip-link apply to a URDF robot only")
    if name in PRESETS:
        return PRESETS[name]()
    if suffix == ".urdf":
        from skincal.kinematics.urdf import chain_from_urdf

        return chain_from_urdf(name, base_link=base_link, tip_link=tip_link)
    if suffix in (".yaml", ".yml", ".json"):
        return load_chain(name)
    raise ConfigError(
        f"unknown robot '{name}' (presets: {', '.join(PRESETS)}; or a .urdf file, or a .yaml/.json DH chain file)"
    )


def load_chain(path: str | Path) -> SerialChain:
    """Read a chain file.

    Format (YAML or JSON)::

        name: myarm
        convention: modified          # or standard
        dh:                           # one row per joint: [theta_offset, d, a, alpha], rad and m
          - [0, 0.333, 0, 0]
        joint_lower: [...]            # optional, rad
        joint_upper: [...]            # optional, rad
        velocity_limit: [...]         # optional, rad/s
        T_link_flange: [[...], ...]   # optional 4x4
    """
    from skincal.io.jsonio import load_json, load_yaml

    path = Path(path)
    load = load_json if path.suffix.lower() == ".json" else load_yaml
    spec = load(path, "chain file", ConfigError)  # regular file, size, depth, duplicate keys
    if not isinstance(spec, dict):
        raise ConfigError(f"{path}: a chain file must be a mapping with at least 'convention' and 'dh'")
    unknown = set(spec) - {"name", "convention", "dh", "joint_lower", "joint_upper", "velocity_limit", "T_link_flange"}
    if unknown:
        raise ConfigError(f"{path}: unknown field(s) {', '.join(sorted(unknown))}")
    for key in ("convention", "dh"):
        if key not in spec:
            raise ConfigError(f"{path}: missing field '{key}'")
    try:
        kwargs = {k: np.asarray(v, dtype=float) for k, v in spec.items() if k not in ("name", "convention")}
    except (TypeError, ValueError):
        raise ConfigError(f"{path}: numeric fields must hold numbers only") from None
    try:
        return SerialChain.from_dh(str(spec.get("name", path.stem)), str(spec["convention"]), **kwargs)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
