"""Parsing URDFs that trust nothing (:func:`skincal.kinematics.urdf.parse_urdf`): entity declarations and
external DTDs are refused before yourdfpy's own parser could expand them, and a URDF whose joints do not form a tree
(a link with two parent joints, a loop of links no root reaches) is one ConfigError line instead of
an endless walk."""

from __future__ import annotations

import pytest

from skincal.errors import ConfigError
from skincal.kinematics.urdf import chain_from_urdf

JOINT = (
    '<joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>'
    '<origin xyz="0 0 0.3"/><axis xyz="0 0 1"/><limit lower="-2" upper="2" velocity="2" effort="10"/></joint>'
)


def urdf(links: list[str], joints: list[tuple[str, str, str]], doctype: str = "") -> str:
    body = "".join(f'<link name="{link}"/>' for link in links)
    body += "".join(JOINT.format(name=n, parent=p, child=c) for n, p, c in joints)
    return f'<?xml version="1.0"?>\n{doctype}<robot name="r">{body}</robot>'


CHAIN = (["base", "l1", "l2"], [("j1", "base", "l1"), ("j2", "l1", "l2")])


def test_plain_chain_reads():
    """The reference the hostile variants below differ from: two joints, base to l2."""
    chain = chain_from_urdf(text=urdf(*CHAIN))
    assert chain.joint_names == ("j1", "j2")
    assert chain.link_names == ("base", "l1", "l2")


@pytest.mark.adversarial
@pytest.mark.parametrize(
    "doctype",
    [
        '<!DOCTYPE robot [<!ENTITY n "l1">]>',  # an internal entity yourdfpy's parser would expand
        '<!DOCTYPE robot [<!ENTITY x SYSTEM "file:///etc/passwd">]>',
        '<!DOCTYPE robot SYSTEM "file:///etc/passwd">',
    ],
)
def test_entity_declarations_and_external_dtds_are_refused(doctype):
    """README: "strict XML, no entities". The internal entity used to be expanded by yourdfpy (and
    written back as a bare ``&n;`` by ``export -f urdf --robot``, an invalid URDF)."""
    text = urdf(*CHAIN)
    if "ENTITY n" in doctype:
        text = text.replace('"l1"', '"&n;"')
    text = text.replace("<robot ", doctype + "<robot ")
    with pytest.raises(ConfigError, match="DOCTYPE declaring entities or an external DTD"):
        chain_from_urdf(text=text)


@pytest.mark.adversarial
def test_a_link_with_two_parent_joints_is_refused():
    """l1 hangs below base and below l2 (a loop through the root's chain): the tip search used to walk
    base -> l1 -> l2 -> l1 ... forever."""
    links, joints = CHAIN
    with pytest.raises(ConfigError, match="'l1' is the child of several joints"):
        chain_from_urdf(text=urdf(links, [*joints, ("j3", "l2", "l1")]))


@pytest.mark.adversarial
@pytest.mark.parametrize("base_link", [None, "a"])
def test_a_loop_no_root_reaches_is_refused(base_link):
    """a -> b -> a with one parent each: no root; given --base-link a, the tip search used to walk the
    loop forever."""
    text = urdf(["a", "b"], [("j1", "a", "b"), ("j2", "b", "a")])
    with pytest.raises(ConfigError, match="the joints form a loop through link"):
        chain_from_urdf(text=text, base_link=base_link)


@pytest.mark.adversarial
def test_a_loop_beside_a_good_chain_is_refused():
    """A detached loop next to a valid chain: the chain alone would read, the file is still no tree."""
    links, joints = CHAIN
    text = urdf([*links, "x", "y"], [*joints, ("jx", "x", "y"), ("jy", "y", "x")])
    with pytest.raises(ConfigError, match="the joints form a loop through link"):
        chain_from_urdf(text=text)


@pytest.mark.adversarial
@pytest.mark.parametrize("limit", ["1e16", "1e308"])
def test_huge_position_limits_mean_no_limit_to_the_protocol(limit):
    """URDFs write +-1e16 for "no limit": the protocol draws such a joint's poses in [-pi, pi] as for
    a continuous joint (was: a 133 GiB allocation at 1e9, an OverflowError, exit 3, at 1e308)."""
    import numpy as np

    from skincal.protocol import build_trajectory, get_protocol

    text = urdf(*CHAIN).replace('lower="-2" upper="2"', f'lower="-{limit}" upper="{limit}"', 1)
    chain = chain_from_urdf(text=text)
    assert chain.joint_upper[0] == float(limit)
    traj = build_trajectory(chain, get_protocol("fast"), np.random.default_rng(0))
    assert np.all(np.abs(traj.poses[:, 0]) <= np.pi)
    assert np.all(np.abs(traj.q) < 10) and traj.duration < 120


@pytest.mark.adversarial
def test_a_urdf_text_over_the_file_limit_is_refused_unparsed():
    """The text of a bag's /robot_description (or a dataset's) had no size limit, unlike a file."""
    from skincal.kinematics.urdf import MAX_URDF_BYTES

    links = [f"l{i}" for i in range(MAX_URDF_BYTES // 16)]
    text = urdf(links, [])
    assert len(text) > MAX_URDF_BYTES
    with pytest.raises(ConfigError, match="is too large for a URDF"):
        chain_from_urdf(text=text)


@pytest.mark.adversarial
def test_a_long_run_of_fixed_joints_is_no_recursion_error():
    """3000 fixed joints below the one moving joint: the tip search recursed once per link (RecursionError,
    exit 3); given as the tip, the last link is the flange, 2999 mm up."""
    n = 3000
    fixed = '<joint name="f{i}" type="fixed"><parent link="l{i}"/><child link="l{j}"/><origin xyz="0 0 0.001"/></joint>'
    text = urdf([f"l{i}" for i in range(n + 1)], [("j0", "l0", "l1")])
    text = text.replace("</robot>", "".join(fixed.format(i=i, j=i + 1) for i in range(1, n)) + "</robot>")
    assert chain_from_urdf(text=text).link_names == ("l0", "l1")
    chain = chain_from_urdf(text=text, tip_link=f"l{n}")
    assert chain.n_joints == 1 and chain.link_names == ("l0", "l1")
    assert chain.T_link_flange[2, 3] == pytest.approx((n - 1) * 0.001)


def test_the_default_chain_leaves_a_trailing_gripper_joint_out():
    """Issue 27: a moving joint at the tip named like a gripper's (Unitree Z1's ``jointGripper``) is the
    end effector's, not the arm's: the default chain ends before it and says so; ``tip_link`` takes it in.
    A wrist whose child link is named ``gripper_link`` (SO-101's wrist roll) stays; so does a lone joint."""
    from skincal.kinematics.urdf import urdf_chain

    from registry_robots import registry_urdf

    z1 = urdf_chain(registry_urdf("z1"))
    assert z1.chain.n_joints == 6 and z1.excluded == ("jointGripper",) and z1.tip_link == "gripperStator"
    assert z1.chain.joint_names == tuple(f"joint{k}" for k in range(1, 7))
    assert urdf_chain(registry_urdf("z1"), tip_link="gripperMover").chain.n_joints == 7
    so101 = urdf_chain(registry_urdf("so101"))
    assert so101.excluded == ("gripper",) and so101.chain.joint_names[-1] == "wrist_roll"
    text = urdf(["base", "l1", "l2", "l3"], [("j1", "base", "l1"), ("j2", "l1", "l2"), ("finger_joint", "l2", "l3")])
    picked = urdf_chain(text=text)
    assert picked.chain.joint_names == ("j1", "j2") and picked.excluded == ("finger_joint",) and picked.tip_link == "l2"
    alone = urdf_chain(text=urdf(["base", "jaw"], [("jaw_joint", "base", "jaw")]))
    assert alone.chain.n_joints == 1 and alone.excluded == ()


def test_z1_fast_protocol_finds_its_poses():
    """Issue 27: with the gripper joint as joint 7 the protocol found no collision-free pose for the Z1."""
    from dataclasses import replace

    import numpy as np

    from skincal.protocol import build_trajectory, get_protocol
    from skincal.protocol.limits import fit_to_limits

    from registry_robots import registry_urdf

    chain = chain_from_urdf(registry_urdf("z1"))
    config = replace(fit_to_limits(chain, get_protocol("fast")), collision_check=True, pose_selection="diverse")
    traj = build_trajectory(chain, config, np.random.default_rng(0))
    assert traj.poses.shape == (config.n_poses, 6)


@pytest.mark.adversarial
def test_a_urdf_of_ten_thousand_joints_is_refused_before_it_is_built():
    """A 10,000-joint URDF (2.4 MB) took `protocol` to 2.5 GB and beyond: refused at the XML count, at once."""
    import time

    from skincal.kinematics.urdf import MAX_URDF_JOINTS

    n = 10_000
    text = urdf([f"l{i}" for i in range(n + 1)], [(f"j{i}", f"l{i}", f"l{i + 1}") for i in range(n)])
    start = time.process_time()
    with pytest.raises(ConfigError, match=rf": 10000 joints is too many for a URDF \(at most {MAX_URDF_JOINTS}\)$"):
        chain_from_urdf(text=text)
    assert time.process_time() - start < 5.0


@pytest.mark.adversarial
def test_a_chain_of_more_movable_joints_than_any_arm_is_one_line_error():
    """100 revolute joints from base to tip: a chain, but of no robot skincal can calibrate or plan for."""
    from skincal.kinematics.chain import MAX_JOINTS

    n = 100
    text = urdf([f"l{i}" for i in range(n + 1)], [(f"j{i}", f"l{i}", f"l{i + 1}") for i in range(n)])
    with pytest.raises(ConfigError, match=rf"100 joints in one chain \(at most {MAX_JOINTS}\)"):
        chain_from_urdf(text=text)
    ok = urdf([f"l{i}" for i in range(MAX_JOINTS + 1)], [(f"j{i}", f"l{i}", f"l{i + 1}") for i in range(MAX_JOINTS)])
    assert chain_from_urdf(text=ok).n_joints == MAX_JOINTS
