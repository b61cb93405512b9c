"""ISO/TS 15066 Annex A body regions and the robot's effective mass (issue 28, items 1-2)."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from skincal.control.body_regions import (
    BODY_REGIONS,
    body_region,
    contact_force,
    pfl_speed_limit,
    reduced_mass,
    simple_robot_mass,
    transfer_energy,
)
from skincal.control.effective_mass import effective_mass, point_effective_mass
from skincal.errors import ConfigError
from skincal.kinematics import panda
from skincal.kinematics.chain import SerialChain
from skincal.kinematics.points import Q_START
from skincal.sim.scenarios import DEFAULT_REGIONS
from skincal.sim.scene import HUMAN_REGIONS


# ------------------------------------------------------------------------------- the table (item 1)
@pytest.mark.parametrize(
    ("name", "k_n_per_mm", "mass", "transient"),
    [  # ISO/TS 15066:2016 Table A.3 (k, m_H) and Table A.2 (2x quasi-static force), as field.md lists them
        ("skull", 150, 4.4, None),
        ("face", 75, 4.4, None),
        ("back", 35, 40, 420),
        ("chest", 25, 40, 280),
        ("belly", 10, 40, 220),
        ("pelvis", 25, 40, 360),
        ("upper_arm", 30, 3, 300),
        ("forearm", 40, 2, 320),
        ("hand", 75, 0.6, 280),
        ("thigh", 50, 75, 440),
        ("lower_leg", 60, 75, 260),
    ],
)
def test_annex_a_values_are_the_standards(name, k_n_per_mm, mass, transient):
    r = body_region(name)
    assert r.k == pytest.approx(k_n_per_mm * 1e3, abs=1e-9)
    assert r.mass == pytest.approx(mass, abs=1e-12)
    assert r.transient_force == (None if transient is None else pytest.approx(transient, abs=1e-9))
    if transient is not None:
        assert r.transient_force == pytest.approx(2 * r.quasi_static_force, abs=1e-9)


def test_every_default_region_is_in_the_table_and_unknown_names_are_one_line_errors():
    for name in (*DEFAULT_REGIONS.values(), *HUMAN_REGIONS, "head", "wrist"):
        assert body_region(name).name in BODY_REGIONS
    with pytest.raises(ConfigError, match="unknown body region 'elbowz'") as e:
        body_region("elbowz")
    assert "\n" not in str(e.value)


def test_hand_worked_example():
    """A hand against a robot part of effective mass 2.4 kg, worked by hand:
    mu = 1 / (1/0.6 + 1/2.4) = 1 / 2.08333 = 0.48 kg;  sqrt(mu k) = sqrt(0.48 * 75000) = sqrt(36000) = 189.737 kg/s;
    v_max = 280 / 189.737 = 1.47573 m/s;  E_max = 280^2 / (2 * 75000) = 0.522667 J = 1/2 * 0.48 * 1.47573^2.
    The standard's shortcut m_R = M/2 + m_L for 3.8 kg of moving parts and a 0.5 kg payload is 2.4 kg."""
    hand = body_region("hand")
    m_r = simple_robot_mass(3.8, 0.5)
    assert m_r == pytest.approx(2.4, abs=1e-12)
    assert reduced_mass(0.6, m_r) == pytest.approx(0.48, abs=1e-12)
    v = float(pfl_speed_limit(hand, m_r))
    assert v == pytest.approx(1.47573, abs=1e-5)
    assert hand.transient_energy == pytest.approx(0.522667, abs=1e-6)
    assert float(transfer_energy(hand, m_r, v)) == pytest.approx(hand.transient_energy, rel=1e-12)
    assert float(contact_force(hand, m_r, v)) == pytest.approx(280.0, rel=1e-12)
    # no transient contact with the skull: the allowed speed is 0 whatever the mass
    assert float(pfl_speed_limit(body_region("head"), 1.0)) == 0.0
    # a heavier robot part is allowed less speed; an infinitely heavy one: mu = m_H
    assert float(pfl_speed_limit(hand, np.inf)) == pytest.approx(280 / np.sqrt(0.6 * 75000), rel=1e-12)


# ------------------------------------------------------------------------------- effective mass (item 2)
def one_link(length: float = 0.5) -> SerialChain:
    """A single revolute joint about z with a link along x of ``length`` m."""
    return SerialChain.from_dh("one", "standard", [[0.0, 0.0, length, 0.0]])


def test_effective_mass_of_one_link_is_the_closed_form():
    """One revolute link of inertia I about its axis, a point at radius r: along the tangent M_eff = I / r^2,
    along a direction at angle a to the tangent I / (r^2 cos^2 a), along the link (radial) infinite."""
    chain = one_link(0.5)
    T = chain.link_frames(np.array([0.3]))[0]
    p = T[1, :3, 3]  # the link's end, r = 0.5
    J = chain.point_jacobians(T, [1], p[None])  # (1, 3, 1)
    tangent = np.array([-np.sin(0.3), np.cos(0.3), 0.0])
    radial = np.array([np.cos(0.3), np.sin(0.3), 0.0])
    inertia = np.array([[0.7]])
    assert point_effective_mass(J, tangent[None], inertia)[0] == pytest.approx(0.7 / 0.25, rel=1e-12)
    a = 0.4
    n = np.cos(a) * tangent + np.sin(a) * radial
    assert point_effective_mass(J, n[None], inertia)[0] == pytest.approx(0.7 / (0.25 * np.cos(a) ** 2), rel=1e-12)
    assert np.isinf(point_effective_mass(J, radial[None], inertia)[0])
    assert effective_mass(np.zeros((0, 1)), inertia).shape == (0,)


def test_effective_mass_matches_pinocchio_on_the_panda_urdf():
    """Our rows n^T J (skincal's point Jacobian) with MuJoCo's mj_fullM against Pinocchio's own frame Jacobian
    and crba on the same URDF, at random configurations and directions: equal to 1e-6 relative."""
    pin = pytest.importorskip("pinocchio")
    from lxml import etree

    from skincal.kinematics.urdf import chain_from_urdf
    from skincal.sim.mujoco_model import build_model, full_mass_matrix

    from registry_robots import registry_urdf

    root = etree.parse(str(registry_urdf("panda"))).getroot()
    for element in [*root.findall("link"), *root.findall("joint")]:
        if "finger" in element.get("name"):
            root.remove(element)
    text = etree.tostring(root, encoding="unicode")
    chain = chain_from_urdf(text=text)
    model = build_model(chain, board_geoms=False)
    data = mujoco.MjData(model)
    pmodel = pin.buildModelFromXML(text)
    pdata = pmodel.createData()
    frame, link7 = pmodel.getFrameId("panda_hand"), pmodel.getFrameId("panda_link7")
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = rng.uniform(chain.joint_lower, chain.joint_upper)
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        T = chain.link_frames(q)[0]
        pin.computeJointJacobians(pmodel, pdata, q)
        pin.updateFramePlacements(pmodel, pdata)
        np.testing.assert_allclose(pdata.oMf[link7].translation, T[7, :3, 3], atol=1e-9)  # the same link 7
        p = pdata.oMf[frame].translation  # the hand frame's origin, a point fixed to link 7
        data.qpos[:] = q
        mujoco.mj_fwdPosition(model, data)
        ours = point_effective_mass(chain.point_jacobians(T, [7], p[None]), n[None], full_mass_matrix(model, data))
        Jp = pin.getFrameJacobian(pmodel, pdata, frame, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[:3]
        M = pin.crba(pmodel, pdata, q)
        M = np.triu(M) + np.triu(M, 1).T
        ref = 1.0 / (n @ Jp @ np.linalg.solve(M, Jp.T @ n))
        assert ours[0] == pytest.approx(ref, rel=1e-6)


def test_effective_mass_is_what_mujoco_accelerates_under_a_force_at_the_point():
    """MuJoCo's own dynamics (torque robot model: published Panda inertials, armature): a force f along n
    applied at the flange (mj_applyFT) for one step h, no gravity, no limits, from rest, changes the point's
    speed along n by f h / M_eff (semi-implicit Euler is exact for a velocity change from rest)."""
    from skincal.sim.dynamics import torque_model
    from skincal.workflows.avoidance import robot_mass_matrix

    chain = panda()
    model = torque_model(chain)
    model.opt.gravity[:] = 0.0
    model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
    data = mujoco.MjData(model)
    mass = robot_mass_matrix(chain)
    rng = np.random.default_rng(5)
    body = model.body("link7").id
    for _ in range(4):
        q = Q_START + rng.uniform(-0.3, 0.3, 7)
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        T = chain.link_frames(q)[0]
        p = (T[7] @ chain.T_link_flange[:, 3])[:3]
        J = chain.point_jacobians(T, [7], p[None])
        m_eff = point_effective_mass(J, n[None], mass(q))[0]
        mujoco.mj_resetData(model, data)
        data.qpos[:7] = q
        mujoco.mj_forward(model, data)
        f = 10.0
        mujoco.mj_applyFT(model, data, f * n, np.zeros(3), p, body, data.qfrc_applied)
        mujoco.mj_step(model, data)
        dv = n @ (J[0] @ data.qvel[:7])
        assert f * model.opt.timestep / dv == pytest.approx(m_eff, rel=1e-6)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_effective_mass_is_what_a_mujoco_contact_transfers(seed):
    """A real MuJoCo contact on the torque robot's model (published Panda inertias, armature, no gravity,
    motors off): a free frictionless sphere (0.2 kg, 0.3 m/s) hits link 7's capsule head-on along a normal n
    at a random direction across the capsule. Momentum along n: m_s dv_s = -M_eff dv_R, with dv_R the robot
    point's speed change along n: M_eff from the contact impulse equals 1 / (n^T J M^-1 J^T n) within 1 %
    (the robot moves a little during the contact: 1e-3 rad)."""
    from lxml import etree

    from skincal.perception import RobotBody
    from skincal.sim.dynamics import effort_limits
    from skincal.sim.mujoco_model import build_mjcf, published_inertials
    from skincal.workflows.avoidance import robot_mass_matrix

    chain = panda()
    xml = build_mjcf(chain, board_geoms=False, inertials=published_inertials(chain), motor_limits=effort_limits(chain),
                     armature=0.1, damping=0.0, gravity=np.zeros(3))  # fmt: skip
    root = etree.fromstring(xml.encode())
    for g in root.iter("geom"):
        if g.get("name", "").startswith("link7/"):
            g.set("conaffinity", "1")  # only link 7 can touch the sphere
    body = RobotBody.of(chain)
    T = chain.link_frames(Q_START)[0]
    i = int(np.flatnonzero(body.link == 7)[0])
    a, b = (T[7] @ np.r_[body.p0_link[i], 1])[:3], (T[7] @ np.r_[body.p1_link[i], 1])[:3]
    core, axis = 0.5 * (a + b), (b - a) / np.linalg.norm(b - a)
    n = np.cross(axis, np.random.default_rng(seed).normal(size=3))
    n /= np.linalg.norm(n)
    r_s, m_s, v0 = 0.03, 0.2, 0.3
    ball = etree.SubElement(root.find("worldbody"), "body", name="ball",
                            pos=" ".join(map(str, core + n * (body.radius[i] + r_s + 0.01))))  # fmt: skip
    etree.SubElement(ball, "freejoint", name="ball")
    etree.SubElement(ball, "geom", name="ball", type="sphere", size=str(r_s), mass=str(m_s), contype="1",
                     conaffinity="0", condim="1")  # fmt: skip
    model = mujoco.MjModel.from_xml_string(etree.tostring(root).decode())
    data = mujoco.MjData(model)
    data.qpos[:7] = Q_START
    data.qvel[7:10] = -v0 * n
    touched = False
    for _ in range(400):
        mujoco.mj_step(model, data)
        touched |= data.ncon > 0
        if touched and data.ncon == 0:
            break
    assert touched and data.ncon == 0
    J = chain.point_jacobians(T, [7], (core + n * body.radius[i])[None])
    m_eff = point_effective_mass(J, n[None], robot_mass_matrix(chain)(Q_START))[0]
    dv_s = n @ data.qvel[7:10] + v0
    dv_r = n @ (J[0] @ data.qvel[:7])
    assert m_s * dv_s / -dv_r == pytest.approx(m_eff, rel=0.01)
