"""URDF inertias in the chain and the MuJoCo model (issue 14, item 5), checked against independent
computations: the URDF's own masses, Pinocchio's mass matrix of the same file, and brute-force sums
over point masses."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from lxml import etree

from skincal.errors import ConfigError
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.inertia import LinkInertial, combine
from skincal.kinematics.transforms import homogeneous, matrix_from_quat_wxyz
from skincal.kinematics.urdf import chain_from_urdf
from skincal.sim.mujoco_model import PANDA_INERTIALS, build_model, default_inertials, link_body_ids

from registry_robots import registry_urdf

FINGERS = ("panda_leftfinger", "panda_rightfinger")


def urdf_masses(path, skip=()) -> float:
    """Sum of the ``<mass value>`` of every link of a URDF file but ``skip`` (read with lxml)."""
    root = etree.parse(str(path)).getroot()
    total = 0.0
    for link in root.iter("link"):
        mass = link.find("inertial/mass")
        if link.get("name") not in skip and mass is not None:
            total += float(mass.get("value"))
    return total


def panda_without_fingers() -> str:
    """Franka's URDF text with the finger links and joints removed (the chain ends at the hand)."""
    root = etree.parse(str(registry_urdf("panda"))).getroot()
    for element in [*root.findall("link"), *root.findall("joint")]:
        if element.get("name") in FINGERS or element.get("name").startswith("panda_finger_joint"):
            root.remove(element)
    return etree.tostring(root, encoding="unicode")


def random_pose(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    return homogeneous(matrix_from_quat_wxyz(q / np.linalg.norm(q)), rng.uniform(-0.5, 0.5, 3))


def point_cloud_inertial(m: np.ndarray, x: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Brute force: mass, CoM and inertia tensor about the CoM of point masses ``m`` at ``x``."""
    c = m @ x / m.sum()
    d = x - c
    I = sum(mi * (di @ di * np.eye(3) - np.outer(di, di)) for mi, di in zip(m, d, strict=True))
    return float(m.sum()), c, I


def box_points(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A point-mass-like box: 8 corners of a random box, random positive masses, random offset."""
    half = rng.uniform(0.01, 0.2, 3)
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half
    return rng.uniform(0.1, 2.0, 8), corners + rng.uniform(-0.1, 0.1, 3)


# ------------------------------------------------------------------------------- (c) parallel axis
def test_combine_matches_brute_force_point_masses():
    """Two point-mass boxes, each described in its own frame and placed by a random pose: the
    combined mass, CoM and inertia about the CoM are those of the union of the points expressed in
    the common frame (no parallel-axis theorem in the reference)."""
    rng = np.random.default_rng(7)
    for _ in range(10):
        parts, poses, all_m, all_x = [], [], [], []
        for _ in range(2):
            m, x = box_points(rng)
            mass, com, tensor = point_cloud_inertial(m, x)
            parts.append(LinkInertial.from_tensor(mass, com, tensor))
            T = random_pose(rng)
            poses.append(T)
            all_m.append(m)
            all_x.append(x @ T[:3, :3].T + T[:3, 3])
        mass, com, tensor = point_cloud_inertial(np.concatenate(all_m), np.concatenate(all_x))
        got = combine(parts, poses)
        assert got is not None
        assert got.mass == pytest.approx(mass, rel=1e-12)
        np.testing.assert_allclose(got.com, com, atol=1e-12)
        np.testing.assert_allclose(got.tensor, tensor, atol=1e-12 * np.trace(tensor))
    assert combine([]) is None


def test_transformed_moves_the_com_and_rotates_the_tensor():
    rng = np.random.default_rng(8)
    m, x = box_points(rng)
    body = LinkInertial.from_tensor(*point_cloud_inertial(m, x))
    T = random_pose(rng)
    mass, com, tensor = point_cloud_inertial(m, x @ T[:3, :3].T + T[:3, 3])
    moved = body.transformed(T)
    assert moved.mass == body.mass
    np.testing.assert_allclose(moved.com, com, atol=1e-12)
    np.testing.assert_allclose(moved.tensor, tensor, atol=1e-12)


@pytest.mark.adversarial
@pytest.mark.parametrize(
    ("mass", "com", "inertia", "match"),
    [
        (0.0, [0, 0, 0], [1, 1, 1, 0, 0, 0], "mass"),
        (-1.0, [0, 0, 0], [1, 1, 1, 0, 0, 0], "mass"),
        (np.nan, [0, 0, 0], [1, 1, 1, 0, 0, 0], "mass"),
        (1.0, [0, np.inf, 0], [1, 1, 1, 0, 0, 0], "com"),
        (1.0, [0, 0], [1, 1, 1, 0, 0, 0], "com"),
        (1.0, [0, 0, 0], [1, 1, 1, 0, 0], "inertia"),
        (1.0, [0, 0, 0], [1, 1, np.nan, 0, 0, 0], "inertia"),
        (1.0, [0, 0, 0], [1, 1, -0.5, 0, 0, 0], "semi-definite"),
        (1.0, [0, 0, 0], [1, 1, 1, 2, 0, 0], "semi-definite"),
        (1.0, [0, 0, 0], [1, 1, 3, 0, 0, 0], "triangle"),
        ("heavy", [0, 0, 0], [1, 1, 1, 0, 0, 0], "numbers"),
        (1e308, [0, 0, 0], [1, 1, 1, 0, 0, 0], "up to 1e\\+06"),  # overflowed a link's sum (issue 27)
        (1.0, [0, 0, 1e300], [1, 1, 1, 0, 0, 0], "within 1000 m"),
        (1.0, [0, 0, 0], [1e300, 1e300, 1e300, 0, 0, 0], "within 1e\\+09 kg m\\^2"),
    ],
)
def test_link_inertial_refuses_unphysical_bodies(mass, com, inertia, match):
    with pytest.raises(ConfigError, match=match):
        LinkInertial(mass, com, inertia)


@pytest.mark.adversarial
def test_link_inertial_is_read_only_and_chain_checks_the_count():
    li = PANDA_INERTIALS[0]
    with pytest.raises(ValueError):
        li.com[0] = 1.0
    with pytest.raises(ConfigError, match="asymmetric|symmetric"):
        LinkInertial.from_tensor(1.0, [0, 0, 0], [[1, 0.5, 0], [0, 1, 0], [0, 0, 1]])
    chain = chain_from_urdf(registry_urdf("ur5"))
    with pytest.raises(ConfigError, match="inertials must be 7"):
        SerialChain(
            name="x",
            T_parent_joint=chain.T_parent_joint,
            axis=chain.axis,
            T_joint_link=chain.T_joint_link,
            inertials=chain.inertials[1:],
        )
    with pytest.raises(ConfigError, match="inertials must be 7"):
        SerialChain(
            name="x",
            T_parent_joint=chain.T_parent_joint,
            axis=chain.axis,
            T_joint_link=chain.T_joint_link,
            inertials=(*chain.inertials[:-1], "heavy"),
        )


# ------------------------------------------------------------------------------- (a) total mass
@pytest.mark.parametrize(("robot", "skip"), [("panda", FINGERS), ("ur5", ()), ("kinova", ()), ("xarm7", ())])
def test_model_mass_is_the_urdf_mass_of_the_links_the_chain_covers(robot, skip):
    """Every URDF link the chain covers (the chain's, the folded ones, rigid side branches such as
    Kinova's fingers; not Panda's moving fingers) is in the model, none twice, none added."""
    path = registry_urdf(robot)
    model = build_model(chain_from_urdf(path), board_geoms=False)
    assert model.body_mass.sum() == pytest.approx(urdf_masses(path, skip), rel=1e-12)


def test_panda_urdf_uses_its_own_inertials_with_the_hand_folded_into_link7():
    chain = chain_from_urdf(registry_urdf("panda"))
    inertials = default_inertials(chain)
    assert inertials is not None and len(inertials) == 7
    # links 1-6 are Franka's table (the URDF has the same numbers); link 7 carries the hand (0.73 kg)
    for got, franka in zip(inertials[:6], PANDA_INERTIALS[:6], strict=True):
        assert got.mass == pytest.approx(franka.mass, abs=1e-12)
        np.testing.assert_allclose(got.com, franka.com, atol=1e-12)
    assert inertials[6].mass == pytest.approx(0.735522 + 0.73, abs=1e-12)
    model = build_model(chain, board_geoms=False)
    assert model.body_mass[link_body_ids(model, 7)[7]] == pytest.approx(0.735522 + 0.73, abs=1e-12)
    assert model.body_mass[link_body_ids(model, 7)[0]] == pytest.approx(0.629769, abs=1e-12)


# ------------------------------------------------------------------------------- (b) mass matrix
def mujoco_mass_matrix(model, q: np.ndarray) -> np.ndarray:
    data = mujoco.MjData(model)
    data.qpos[:] = q
    mujoco.mj_forward(model, data)
    M = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, M)
    return M


def pinocchio_mass_matrix(pin, model, joint_names, q: np.ndarray) -> np.ndarray:
    """Pinocchio's CRBA mass matrix at chain coordinates ``q``, rows/columns in chain joint order."""
    data = model.createData()
    Q = pin.neutral(model)
    cols = []
    for k, name in enumerate(joint_names):
        joint = model.joints[model.getJointId(name)]
        if joint.nq == 2:  # continuous joint: Pinocchio stores (cos q, sin q)
            Q[joint.idx_q : joint.idx_q + 2] = np.cos(q[k]), np.sin(q[k])
        else:
            Q[joint.idx_q] = q[k]
        cols.append(joint.idx_v)
    assert model.nv == len(joint_names)  # the chain covers every moving joint Pinocchio models
    M = pin.crba(model, data, Q)
    M = np.triu(M) + np.triu(M, 1).T  # crba fills the upper triangle
    return M[np.ix_(cols, cols)]


@pytest.mark.parametrize("robot", ["panda", "ur5", "kinova", "xarm7"])
def test_mujoco_mass_matrix_matches_pinocchio(robot):
    """``mj_fullM`` at 10 random configurations equals Pinocchio's ``crba`` on the same URDF (its own
    parser; it merges fixed-joint links itself) to 1e-6 relative. Panda: the fingers removed from the
    file, since the chain ends at the hand."""
    pin = pytest.importorskip("pinocchio")
    if robot == "panda":
        text = panda_without_fingers()
        chain = chain_from_urdf(text=text)
        pmodel = pin.buildModelFromXML(text)
    else:
        chain = chain_from_urdf(registry_urdf(robot))
        pmodel = pin.buildModelFromUrdf(str(registry_urdf(robot)))
    model = build_model(chain, board_geoms=False)
    rng = np.random.default_rng(11)
    lo = np.where(np.isfinite(chain.joint_lower), chain.joint_lower, -np.pi)
    hi = np.where(np.isfinite(chain.joint_upper), chain.joint_upper, np.pi)
    for _ in range(10):
        q = rng.uniform(lo, hi)
        ref = pinocchio_mass_matrix(pin, pmodel, chain.joint_names, q)
        np.testing.assert_allclose(mujoco_mass_matrix(model, q), ref, rtol=1e-6, atol=1e-6 * np.abs(ref).max())


def test_mass_matrix_differs_without_the_folded_links():
    """The Pinocchio check has teeth: dropping the hand from link 7 changes the mass matrix."""
    pin = pytest.importorskip("pinocchio")
    text = panda_without_fingers()
    chain = chain_from_urdf(text=text)
    inertials = list(chain.inertials)
    inertials[7] = LinkInertial(0.735522, [0.010517, -0.004252, 0.061597], PANDA_INERTIALS[6].inertia)
    model = build_model(chain, board_geoms=False, inertials=inertials[1:])
    q = np.array([0.3, -0.5, 0.2, -2.0, 0.4, 1.5, 0.6])
    M = mujoco_mass_matrix(model, q)
    ref = pinocchio_mass_matrix(pin, pin.buildModelFromXML(text), chain.joint_names, q)
    assert np.abs(M - ref).max() > 1e-3


# ------------------------------------------------------------------------------- URDF rules
TWO_LINK = """<robot name="two">
  <link name="base"/>
  <link name="l1">{l1}</link>
  <link name="l1_box">
    <inertial><origin xyz="0.1 0 0" rpy="0 0.5 0"/><mass value="2"/>
      <inertia ixx="0.02" iyy="0.03" izz="0.04" ixy="0" ixz="0" iyz="0"/></inertial>
  </link>
  <link name="l2"/>
  <link name="side">
    <inertial><mass value="5"/><inertia ixx="1" iyy="1" izz="1" ixy="0" ixz="0" iyz="0"/></inertial>
  </link>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
  <joint name="fix" type="fixed"><parent link="l1"/><child link="l1_box"/>
    <origin xyz="0 0.2 0" rpy="0.3 0 0.7"/></joint>
  <joint name="j2" type="prismatic"><parent link="l1_box"/><child link="l2"/><axis xyz="1 0 0"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
  <joint name="off" type="revolute"><parent link="l1"/><child link="side"/><axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
</robot>"""
L1_MASS = '<inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>'


def test_urdf_rules_folded_link_in_and_moving_side_branch_out():
    """l1 collects the box folded by a rotated fixed joint (its inertial origin rotated too); the
    link below the moving side joint ('side', 5 kg) is not on the chain; the base and l2 have none."""
    chain = chain_from_urdf(text=TWO_LINK.format(l1=L1_MASS), tip_link="l2")
    assert chain.inertials is not None and chain.inertials[0] is None and chain.inertials[2] is None
    model = build_model(chain, board_geoms=False)
    bodies = link_body_ids(model, 2)
    assert model.body_mass[bodies[1]] == pytest.approx(3.0, abs=1e-12)
    assert model.body_mass[bodies[2]] > 0.1  # no inertial: its capsules' mass at the default density


def test_folded_inertial_matches_mujocos_own_urdf_import():
    """MuJoCo's URDF importer fuses the static body l1_box into l1 by its own code: same mass, CoM
    and inertia tensor (rebuilt from its principal moments and axes) as the chain's link 1."""
    text = TWO_LINK.format(l1=L1_MASS).replace('<link name="l2"/>', f'<link name="l2">{L1_MASS}</link>')
    reference = mujoco.MjModel.from_xml_string(text)  # (a moving body needs mass in MuJoCo's import)
    body = reference.body("l1").id
    R = np.zeros(9)
    mujoco.mju_quat2Mat(R, reference.body_iquat[body])
    R = R.reshape(3, 3)
    li = chain_from_urdf(text=text, tip_link="l2").inertials[1]
    assert li.mass == pytest.approx(reference.body_mass[body], abs=1e-12)
    np.testing.assert_allclose(li.com, reference.body_ipos[body], atol=1e-12)
    np.testing.assert_allclose(li.tensor, R @ np.diag(reference.body_inertia[body]) @ R.T, atol=1e-9)
    assert np.abs(li.tensor - np.diag(np.diag(li.tensor))).max() > 1e-3  # the rotations matter here


@pytest.mark.adversarial
@pytest.mark.parametrize("mass", ["-1", "nan", "1e308"])
def test_unphysical_urdf_inertial_loads_without_it(mass):
    """A URDF whose inertial is not physical still gives its kinematics; that body has no inertial."""
    bad = L1_MASS.replace('value="1"', f'value="{mass}"')
    chain = chain_from_urdf(text=TWO_LINK.format(l1=bad), tip_link="l2")
    assert chain.inertials is None  # l1 (with its box) was the only body with mass
    triangle = L1_MASS.replace('izz="0.01"', 'izz="0.05"')
    chain = chain_from_urdf(text=TWO_LINK.format(l1=triangle), tip_link="l2")
    assert chain.inertials is None
    assert chain.n_joints == 2


def test_urdf_without_inertials_keeps_capsule_masses():
    chain = chain_from_urdf(text=TWO_LINK.format(l1=""), tip_link="l2")
    assert chain.inertials is not None and chain.inertials[1].mass == pytest.approx(2.0)  # the folded box
    text = TWO_LINK.format(l1="").replace('<mass value="2"/>', '<mass value="0"/>')
    assert chain_from_urdf(text=text, tip_link="l2").inertials is None


@pytest.mark.adversarial
@pytest.mark.parametrize("moments", ['ixx="0" iyy="0" izz="0"', 'ixx="0" iyy="0.01" izz="0.01"'])
def test_point_mass_and_thin_rod_links_compile(moments):
    """A point mass or a thin rod (valid, but with zero principal moments, which MuJoCo's
    fullinertia refuses) compiles with those moments raised to 1e-12 kg m^2, the axes kept."""
    inertial = f'<inertial><origin rpy="0.3 0.2 0.1"/><mass value="1"/><inertia {moments} ixy="0" ixz="0" iyz="0"/>'
    text = TWO_LINK.format(l1="").replace('<link name="l2"/>', f'<link name="l2">{inertial}</inertial></link>')
    chain = chain_from_urdf(text=text, tip_link="l2")
    model = build_model(chain, board_geoms=False)
    body = link_body_ids(model, 2)[2]
    R = np.zeros(9)
    mujoco.mju_quat2Mat(R, model.body_iquat[body])
    R = R.reshape(3, 3)
    assert model.body_mass[body] == 1.0
    np.testing.assert_allclose(R @ np.diag(model.body_inertia[body]) @ R.T, chain.inertials[2].tensor, atol=2e-12)
