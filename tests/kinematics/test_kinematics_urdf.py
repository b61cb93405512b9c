"""The general chain and its URDF constructor, checked against independent computations: the DH
presets, Pinocchio (its own URDF parser and kinematics), and finite differences of the frames."""

from __future__ import annotations

import numpy as np
import pytest

from skincal.errors import ConfigError
from skincal.kinematics import panda
from skincal.kinematics.urdf import chain_from_urdf

from registry_robots import REGISTRY_URDFS, random_chain, robots_dir


def test_panda_urdf_frames_are_the_dh_presets_frames():
    """Franka's URDF link frames are the modified-DH frames of the preset: FK agrees to 1e-9 m."""
    chain = chain_from_urdf(robots_dir() / REGISTRY_URDFS["panda"])
    q = np.random.default_rng(0).uniform(chain.joint_lower, chain.joint_upper, (20, 7))
    np.testing.assert_allclose(chain.link_frames(q), panda().link_frames(q), atol=1e-9)
    np.testing.assert_allclose(chain.joint_lower, panda().joint_lower)
    np.testing.assert_allclose(chain.velocity_limit, panda().velocity_limit)
    assert chain.link_names == tuple(f"panda_link{i}" for i in range(8))
    assert chain.joint_names == tuple(f"panda_joint{i}" for i in range(1, 8))
    # the tree branches into the two fingers at panda_hand: the chain ends there
    np.testing.assert_allclose(chain.T_link_flange[:3, 3], [0.0, 0.0, 0.107], atol=1e-12)


@pytest.mark.parametrize("robot", sorted(REGISTRY_URDFS))
def test_urdf_kinematics_match_pinocchio(robot):
    """Frames, link velocities and accelerations of every link against Pinocchio's own parser and
    algorithms (classical acceleration of the frame origins, world-aligned), 20 random states."""
    pin = pytest.importorskip("pinocchio")
    path = robots_dir() / REGISTRY_URDFS[robot]
    chain = chain_from_urdf(path)
    model = pin.buildModelFromUrdf(str(path))
    data = model.createData()
    rng = np.random.default_rng(1)
    lo = np.where(np.isfinite(chain.joint_lower), chain.joint_lower, -np.pi)
    hi = np.where(np.isfinite(chain.joint_upper), chain.joint_upper, np.pi)
    idx = [model.getJointId(name) for name in chain.joint_names]
    for _ in range(20):
        q, qd, qdd = rng.uniform(lo, hi), rng.normal(size=chain.n_joints), rng.normal(size=chain.n_joints)
        Q, V, A = (pin.neutral(model), np.zeros(model.nv), np.zeros(model.nv))
        for k, j in enumerate(idx):
            joint = model.joints[j]
            if joint.nq == 2:  # continuous joint: Pinocchio stores (cos q, sin q)
                Q[joint.idx_q : joint.idx_q + 2] = np.cos(q[k]), np.sin(q[k])
            else:
                Q[joint.idx_q] = q[k]
            V[joint.idx_v], A[joint.idx_v] = qd[k], qdd[k]
        pin.forwardKinematics(model, data, Q, V, A)
        pin.updateFramePlacements(model, data)
        motion = chain.link_motion(q, qd, qdd)
        for k, link in enumerate(chain.link_names):
            fid = model.getFrameId(link)
            M = data.oMf[fid]
            np.testing.assert_allclose(motion.T_base_link[0, k, :3, :3], M.rotation, atol=1e-9)
            np.testing.assert_allclose(motion.T_base_link[0, k, :3, 3], M.translation, atol=1e-9)
            v = pin.getFrameVelocity(model, data, fid, pin.LOCAL_WORLD_ALIGNED)
            a = pin.getFrameClassicalAcceleration(model, data, fid, pin.LOCAL_WORLD_ALIGNED)
            np.testing.assert_allclose(motion.omega[0, k], v.angular, atol=1e-9)
            np.testing.assert_allclose(motion.v_origin[0, k], v.linear, atol=1e-9)
            np.testing.assert_allclose(motion.omega_dot[0, k], a.angular, atol=1e-9)
            np.testing.assert_allclose(motion.a_origin[0, k], a.linear, atol=1e-9)


def test_general_chain_motion_matches_finite_differences():
    """Random origins, axes and prismatic joints: velocities and accelerations of every link frame
    are the time derivatives of its pose along a smooth joint trajectory (central differences)."""
    rng = np.random.default_rng(2)
    chain = random_chain(rng, 6)
    w = rng.uniform(0.5, 2.0, 6)
    ph = rng.uniform(0, 2 * np.pi, 6)
    q = lambda t: np.sin(w * t + ph)  # noqa: E731
    qd = lambda t: w * np.cos(w * t + ph)  # noqa: E731
    qdd = lambda t: -w * w * np.sin(w * t + ph)  # noqa: E731
    t, h = 0.37, 1e-5
    m = chain.link_motion(q(t), qd(t), qdd(t))
    T = [chain.link_frames(q(t + k * h))[0] for k in (-1, 0, 1)]
    p = [x[:, :3, 3] for x in T]
    np.testing.assert_allclose(m.v_origin[0], (p[2] - p[0]) / (2 * h), atol=1e-7)
    np.testing.assert_allclose(m.a_origin[0], (p[2] - 2 * p[1] + p[0]) / h**2, atol=2e-4)
    dR = (T[2][:, :3, :3] - T[0][:, :3, :3]) / (2 * h)
    W = dR @ np.swapaxes(T[1][:, :3, :3], 1, 2)  # skew(omega)
    np.testing.assert_allclose(m.omega[0], np.stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]], 1), atol=1e-7)
    # the point Jacobian maps qd to the point's velocity
    p_link = np.array([0.05, -0.02, 0.1])
    J = chain.point_jacobian(q(t), 6, p_link)[0]
    x = lambda s: chain.link_frames(q(s))[0, 6] @ np.append(p_link, 1.0)  # noqa: E731
    np.testing.assert_allclose(J[:3] @ qd(t), (x(t + h) - x(t - h))[:3] / (2 * h), atol=1e-7)
    np.testing.assert_allclose(J[3:] @ qd(t), m.omega[0, 6], atol=1e-12)


def test_point_jacobians_on_a_chain_with_prismatic_joints_match_finite_differences():
    """``point_jacobians`` (points in the base frame on any links, one configuration or one per point) against
    each point carried by its link with each joint moved by +-h; on a prismatic joint the column is the axis."""
    rng = np.random.default_rng(3)
    chain = random_chain(rng, 6)
    assert not chain.revolute.all()
    K = 12
    links = rng.integers(0, 7, K)
    p_link = rng.normal(size=(K, 3)) * 0.1
    h = 1e-6
    for q in (rng.uniform(-1, 1, 6), rng.uniform(-1, 1, (K, 6))):
        T = chain.link_frames(q)
        T = T[0] if q.ndim == 1 else T
        T_pt = T[links] if q.ndim == 1 else T[np.arange(K), links]
        p_base = np.einsum("kij,kj->ki", T_pt[:, :3, :3], p_link) + T_pt[:, :3, 3]
        J = chain.point_jacobians(T, links, p_base)
        for j in range(6):
            dq = np.zeros(6)
            dq[j] = h
            moved = []
            for sign in (1.0, -1.0):
                Tm = chain.link_frames(q + sign * dq)
                Tm = Tm[0][links] if q.ndim == 1 else Tm[np.arange(K), links]
                moved.append(np.einsum("kij,kj->ki", Tm[:, :3, :3], p_link) + Tm[:, :3, 3])
            np.testing.assert_allclose(J[:, :, j], (moved[0] - moved[1]) / (2 * h), atol=1e-8)
        assert np.all(J[links == 0] == 0)


URDF_HEAD = '<?xml version="1.0"?>\n<robot name="r">'


def _link(name: str) -> str:
    return f'<link name="{name}"/>'


def _joint(name: str, parent: str, child: str, kind: str = "revolute", extra: str = "") -> str:
    limit = '<limit lower="-1" upper="1" velocity="1" effort="1"/>' if kind in ("revolute", "prismatic") else ""
    return (
        f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
        f'<origin xyz="0 0 0.1"/><axis xyz="0 0 1"/>{limit}{extra}</joint>'
    )


def test_a_continuous_joint_is_a_revolute_joint_without_position_limits(tmp_path):
    text = (
        URDF_HEAD
        + "".join(map(_link, "abc"))
        + _joint("j1", "a", "b", "continuous")
        + _joint("j2", "b", "c")
        + "</robot>"
    )
    chain = chain_from_urdf(text=text)
    assert chain.joint_type == ("revolute", "revolute")
    assert chain.joint_lower[0] == -np.inf and chain.joint_upper[0] == np.inf and chain.joint_upper[1] == 1.0


@pytest.mark.parametrize(
    ("body", "kwargs", "message"),
    [
        (
            "".join(map(_link, "abcd")) + _joint("j1", "a", "b") + _joint("j2", "a", "c") + _joint("j3", "a", "d"),
            {},
            "not a serial chain: it branches at 'a'",
        ),
        (
            "".join(map(_link, "abc")) + _joint("j1", "a", "b") + _joint("j2", "b", "c", extra='<mimic joint="j1"/>'),
            {},
            "joint 'j2' mimics 'j1'",
        ),
        ("".join(map(_link, "ab")) + _joint("j1", "a", "b"), {"tip_link": "zz"}, "--tip-link 'zz' is not a link"),
        (
            "".join(map(_link, "ab")) + _joint("j1", "a", "b"),
            {"base_link": "b", "tip_link": "a"},
            "'a' is not below 'b'",
        ),
        ("".join(map(_link, "ab")) + _joint("j1", "a", "b", "floating"), {}, "joint 'j1' is floating"),
        ("".join(map(_link, "ab")) + _joint("j1", "a", "b", "fixed"), {}, "no moving joint between 'a'"),
        (
            "".join(map(_link, "abc"))
            + _joint("j1", "a", "b")
            + _joint("j2", "b", "c").replace("0 0 0.1", "0 0 1e300"),
            {},
            r"T_parent_joint of joint 2 is 1e\+300 m from its parent",
        ),
        (
            "".join(map(_link, "abc"))
            + _joint("j1", "a", "b")
            + _joint("j2", "b", "c", "fixed").replace("0 0 0.1", "-2e3 0 0"),
            {"tip_link": "c"},
            r"T_link_flange is 2e\+03 m from its parent",
        ),
        ("<link name='a'", {}, "not a valid URDF"),
        ('<!DOCTYPE r [<!ENTITY x "y">]><link name="&x;"/>', {}, "not a valid URDF"),
        ("".join(map(_link, "abcb")) + _joint("j1", "a", "b") + _joint("j2", "b", "c"), {},
         r"not a valid URDF \(two links named 'b'\)"),
        ("".join(map(_link, "abc")) + _joint("j1", "a", "b") + _joint("j1", "b", "c"), {},
         r"not a valid URDF \(two joints named 'j1'\)"),
    ],
)
def test_urdf_errors_are_one_line(body, kwargs, message):
    with pytest.raises(ConfigError, match=message) as info:
        chain_from_urdf(text=URDF_HEAD + body + "</robot>", **kwargs)
    assert "\n" not in str(info.value)


def test_a_missing_urdf_file_is_named(tmp_path):
    with pytest.raises(ConfigError, match="no such URDF file"):
        chain_from_urdf(tmp_path / "nope.urdf")
    with pytest.raises(ConfigError, match="not a regular file"):
        chain_from_urdf(tmp_path)


@pytest.mark.parametrize(
    ("preset", "urdf", "tip", "tol"),
    [
        ("panda", "panda", "panda_hand", 1e-12),
        ("ur5", "ur5", "tool0", 1e-9),
        # xarm_description writes pi/2 as 1.5708 (3.7e-6 rad off), hence micrometres
        ("xarm7", "xarm7", "link_eef", 3e-5),
    ],
)
def test_dh_presets_match_the_registry_urdfs(preset, urdf, tip, tol):
    """The same robot from its DH preset and from the URDF its maker publishes: every joint axis is
    the same line in space with the same direction (frames may differ by convention) and the flange is
    the same point, over
    20 random configurations. The UR URDF's base_link is the DH base turned by pi about z."""
    from skincal.kinematics import get_robot

    pin = pytest.importorskip("pinocchio")
    path = robots_dir() / REGISTRY_URDFS[urdf]
    u, d = chain_from_urdf(path, tip_link=tip), get_robot(preset)
    model = pin.buildModelFromUrdf(str(path))
    data = model.createData()
    pin.framesForwardKinematics(model, data, pin.neutral(model))
    frame = "base" if model.existFrame("base") else u.link_names[0]
    T_base_root = np.linalg.inv(data.oMf[model.getFrameId(frame)].homogeneous)
    q = np.random.default_rng(3).uniform(-2.0, 2.0, (20, d.n_joints))
    Fu, Fd = T_base_root @ u.link_frames(q), d.link_frames(q)
    (cu, zu), (cd, zd) = u.joint_axes(Fu), d.joint_axes(Fd)
    np.testing.assert_allclose(zu, zd, atol=tol)
    np.testing.assert_allclose(np.linalg.norm(np.cross(cu - cd, zd), axis=-1), 0.0, atol=tol)
    flange_u, flange_d = (Fu[:, -1] @ u.T_link_flange)[:, :3, 3], (Fd[:, -1] @ d.T_link_flange)[:, :3, 3]
    np.testing.assert_allclose(flange_u, flange_d, atol=tol)  # the point; its axes are a convention


def test_get_robot_takes_a_urdf_and_its_chain_options(tmp_path):
    from skincal.kinematics import get_robot

    path = robots_dir() / REGISTRY_URDFS["ur5"]
    assert get_robot(str(path)).n_joints == 6
    assert get_robot(str(path), tip_link="wrist_1_link").n_joints == 4
    with pytest.raises(ConfigError, match="apply to a URDF robot only"):
        get_robot("panda", tip_link="panda_link3")
    with pytest.raises(ConfigError, match="no such URDF file"):
        get_robot(str(tmp_path / "arm.urdf"))


@pytest.mark.parametrize("robot", ["ur5", "xarm7", "kinova"])
def test_urdf_link_capsules_form_one_connected_body(robot):
    """Each link's capsule core starts where the previous link's ends (at the joint between them),
    in the base frame at random configurations: the body has no gaps and no detached pieces."""
    from skincal.kinematics.chain import transform_points
    from skincal.kinematics.geometry import link_capsules

    chain = chain_from_urdf(robots_dir() / REGISTRY_URDFS[robot])
    capsules = link_capsules(chain)
    q = np.random.default_rng(4).uniform(-2.0, 2.0, (5, chain.n_joints))
    T = chain.link_frames(q)
    first = {c.link: c for c in reversed(capsules)}  # each link's first piece
    last = {c.link: c for c in capsules}  # each link's last piece
    assert sorted(first) == list(range(chain.n_joints + 1))
    for k in range(chain.n_joints):
        end = transform_points(T[:, k], last[k].p1)
        start = transform_points(T[:, k + 1], first[k + 1].p0)
        np.testing.assert_allclose(end, start, atol=1e-12)


def test_iiwa14_axes_at_zero_are_the_published_joint_twists():
    """KUKA LBR iiwa 14 at q = 0: each joint axis passes through the published point with the
    published direction (explicit-robotics' iiwa14 joint twist table, frame {S} = base)."""
    from skincal.kinematics import get_robot

    points = [(0, 0, 0.1525), (0, -0.013, 0.36), (0, 0, 0.5925), (0, 0.011, 0.78), (0, 0, 0.9925),
              (0, -0.062, 1.18), (0, 0, 1.2596)]  # fmt: skip
    directions = [(0, 0, 1), (0, 1, 0), (0, 0, 1), (0, -1, 0), (0, 0, 1), (0, 1, 0), (0, 0, 1)]
    chain = get_robot("iiwa14")
    c, z = chain.joint_axes(chain.link_frames(np.zeros(7)))
    np.testing.assert_allclose(z[0], directions, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(np.cross(c[0] - np.array(points), z[0]), axis=-1), 0.0, atol=1e-12)
    np.testing.assert_allclose(chain.flange_pose(np.zeros(7))[0, :3, 3], [0.0, 0.0, 1.306], atol=1e-12)


def test_same_motion_and_description_do_not_depend_on_the_chains_origin():
    from skincal.kinematics import get_robot

    urdf = chain_from_urdf(robots_dir() / REGISTRY_URDFS["panda"])
    assert urdf.same_motion(panda()) and panda().same_motion(urdf)
    assert not urdf.same_motion(get_robot("xarm7"))  # 7 revolute joints too, other kinematics
    assert (urdf.described_by, panda().described_by, get_robot("ur5").described_by) == (
        "URDF", "modified DH", "standard DH",
    )  # fmt: skip


@pytest.mark.adversarial
@pytest.mark.parametrize("bad", ["a/b", "bidi\u202ename", " padded", "x" * 129])
def test_urdf_names_that_no_dataset_can_carry_are_refused_on_read(bad):
    """Joint and link names of the chain (and the robot's) go into datasets, results and exports:
    the one name rule is applied when the URDF is read, naming the URDF, not later naming an output."""
    from xml.sax.saxutils import quoteattr

    for body in (
        f"<link name='a'/><link name={quoteattr(bad)}/>" + _joint("j1", "a", bad),
        "<link name='a'/><link name='b'/>" + _joint(bad, "a", "b"),
    ):
        with pytest.raises(ConfigError, match=r"URDF: (joint|link) name .* ") as info:
            chain_from_urdf(text=URDF_HEAD + body + "</robot>")
        assert "\n" not in str(info.value)


def test_gen3_preset_agrees_with_kinovas_classical_dh_table():
    """Kinova Gen3: the preset (Kinova's URDF joint origins) against the classical DH table of Kinova's
    user guide (base frame Rx(pi), alpha = pi/2 (x6), pi; theta offsets 0, pi, ...; d sums of the
    actuator lengths): the same joint axis lines with the same directions at random configurations, to
    the table's rounding (it gives lengths to 0.1 mm)."""
    from skincal.kinematics import SerialChain, get_robot
    from skincal.kinematics.transforms import rot_x

    pi = np.pi
    d = [-(0.1564 + 0.1284), -(0.0054 + 0.0064), -(0.2104 + 0.2104), -(0.0064 + 0.0064), -(0.2084 + 0.1059), 0.0,
         -(0.1059 + 0.0615)]  # fmt: skip
    table = np.column_stack([[0.0] + [pi] * 6, d, np.zeros(7), [pi / 2] * 6 + [pi]])
    guide = SerialChain.from_dh("gen3-guide", "standard", table)
    preset = get_robot("gen3")
    q = np.random.default_rng(5).uniform(-2.0, 2.0, (20, 7))
    T_base_0 = np.eye(4)
    T_base_0[:3, :3] = rot_x(pi)
    (cu, zu), (cd, zd) = preset.joint_axes(preset.link_frames(q)), guide.joint_axes(T_base_0 @ guide.link_frames(q))
    np.testing.assert_allclose(zu, zd, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(np.cross(cu - cd, zd), axis=-1), 0.0, atol=1e-3)
    flange = (preset.link_frames(q)[:, -1] @ preset.T_link_flange)[:, :3, 3]
    np.testing.assert_allclose(flange, (T_base_0 @ guide.link_frames(q))[:, -1, :3, 3], atol=1e-3)
    assert preset.joint_names == tuple(f"joint_{i}" for i in range(1, 8)) and np.isinf(preset.joint_upper[0])
