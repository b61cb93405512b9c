"""Skin-unit placements: the paper's Table II set and random placements on link capsule surfaces."""

from __future__ import annotations

import numpy as np
import pytest

from skincal.errors import ConfigError
from skincal.kinematics import panda, sawyer, ur5e
from skincal.kinematics.geometry import link_capsules
from skincal.skin import SkinUnitPose
from skincal.skin.placement import (
    PAPER_TABLE_II,
    frame_from_normal,
    paper_placement,
    random_placement,
    ring_placement,
)


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def _eq1_by_hand(theta_v, d_v, theta_su, d_su, a_su, alpha_su):
    """Paper Eq. 1 written out independently: Rz(theta_v) Tz(d_v) Rx(alpha) Tx(a) Rz(theta) Tz(d)."""

    def Rz(a):
        c, s = np.cos(a), np.sin(a)
        return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])

    def Rx(a):
        c, s = np.cos(a), np.sin(a)
        return np.array([[1.0, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1]])

    def T(x, y, z):
        M = np.eye(4)
        M[:3, 3] = [x, y, z]
        return M

    return Rz(theta_v) @ T(0, 0, d_v) @ Rx(alpha_su) @ T(a_su, 0, 0) @ Rz(theta_su) @ T(0, 0, d_su)


def _canonical(params):
    """Map the equivalent branch (theta_v + pi, d_v, theta_su + pi, d_su, -a, -alpha) to alpha >= 0."""
    p = np.array(params, dtype=float)
    if p[5] < 0:
        p[[0, 2]] += np.pi
        p[4], p[5] = -p[4], -p[5]
    p[[0, 2, 5]] = _wrap(p[[0, 2, 5]])
    return p


def test_paper_placement_reproduces_table_ii():
    units = paper_placement(panda())
    assert list(units) == [f"su{k}" for k in range(1, 7)]
    for k, pose in enumerate(units.values()):
        assert pose.link == k + 2  # SU k on link k + 1 (the paper skips link 1)
        row = PAPER_TABLE_II[k]
        np.testing.assert_allclose(pose.T_link_su, _eq1_by_hand(*row), atol=1e-12)
        # dh6() -> from_dh6 gives the same pose, and the parameters are Table II's up to the known equivalence
        again = SkinUnitPose.from_dh6(pose.link, pose.dh6())
        np.testing.assert_allclose(again.T_link_su, pose.T_link_su, atol=1e-12)
        got, want = _canonical(pose.dh6()), _canonical(row)
        np.testing.assert_allclose(_wrap(got - want), 0.0, atol=1e-9)


def test_paper_placement_table_values():
    # spot-check the transcription of Table II (notes.md) row SU 4
    np.testing.assert_allclose(PAPER_TABLE_II[3], [3.141, -0.100, 3.141, 0.100, 0.0, 1.571])
    # SU 4: z = Rz(3.141) Rx(1.571) Rz(3.141) e_z = Rz(3.141) (0, -1, 0) ~ (0, 1, 0)
    pose = paper_placement(panda())["su4"]
    np.testing.assert_allclose(pose.R_link_su[:, 2], [0.0, 1.0, 0.0], atol=2e-3)


def test_paper_placement_short_chain_drops_missing_links():
    units = paper_placement(ur5e())
    assert list(units) == [f"su{k}" for k in range(1, 6)]
    assert [u.link for u in units.values()] == [2, 3, 4, 5, 6]


def _closest_on_segment(p0, p1, x):
    d = p1 - p0
    L2 = float(d @ d)
    s = 0.0 if L2 == 0 else float(np.clip((x - p0) @ d / L2, 0.0, 1.0))
    return p0 + s * d


@pytest.mark.parametrize("make_chain", [panda, sawyer, ur5e])
def test_random_placement_on_surface_with_outward_normal(make_chain):
    chain = make_chain()
    radius = 0.05
    units = random_placement(chain, 30, np.random.default_rng(3), radius=radius)
    capsules = link_capsules(chain, radius)
    assert len(units) == 30
    for pose in units.values():
        R, p = pose.R_link_su, pose.p_link_su
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) > 0
        # the unit sits on one capsule of its link: distance to that core segment == radius, z = outward normal
        matches = []
        for c in (c for c in capsules if c.link == pose.link):
            foot = _closest_on_segment(c.p0, c.p1, p)
            dist = np.linalg.norm(p - foot)
            if abs(dist - radius) < 1e-12:
                matches.append((p - foot) / dist)
        assert matches, f"unit on link {pose.link} is not on any of its capsule surfaces"
        assert any(np.allclose(R[:, 2], n, atol=1e-9) for n in matches)


def test_random_placement_round_robin_seeded_and_yaw_spread():
    chain = panda()
    a = random_placement(chain, 13, np.random.default_rng(7))
    b = random_placement(chain, 13, np.random.default_rng(7))
    c = random_placement(chain, 13, np.random.default_rng(8))
    assert [u.link for u in a.values()] == [2, 3, 4, 5, 6, 7] * 2 + [2]
    for name in a:
        np.testing.assert_array_equal(a[name].T_link_su, b[name].T_link_su)
    assert not np.allclose(a["su1"].p_link_su, c["su1"].p_link_su)
    # link 1 only when asked; explicit link list honoured
    d = random_placement(chain, 4, np.random.default_rng(0), links=[1, 4])
    assert [u.link for u in d.values()] == [1, 4, 1, 4]


def test_random_placement_yaw_is_uniform_about_normal():
    # many units with the same normal: the x axes' angle about z spreads over the circle
    normal = np.tile([0.0, 0.0, 1.0], (2000, 1))
    yaw = np.random.default_rng(0).uniform(0, 2 * np.pi, 2000)
    R = frame_from_normal(normal, yaw)
    np.testing.assert_allclose(R[:, :, 2], normal, atol=1e-12)
    ang = np.arctan2(R[:, 1, 0], R[:, 0, 0])
    np.testing.assert_allclose(_wrap(ang - ang[0] - (yaw - yaw[0])), 0.0, atol=1e-12)
    # an arbitrary tilted normal is kept exactly as z and R stays a rotation
    n = np.array([[0.3, -0.4, 0.866]])
    n /= np.linalg.norm(n)
    R1 = frame_from_normal(n, np.array([1.0]))[0]
    np.testing.assert_allclose(R1[:, 2], n[0], atol=1e-12)
    np.testing.assert_allclose(R1.T @ R1, np.eye(3), atol=1e-12)


def test_random_placement_per_link_radius_and_errors():
    chain = panda()
    radii = np.linspace(0.03, 0.10, chain.n_joints + 1)
    units = random_placement(chain, 6, np.random.default_rng(1), radius=radii)
    caps = link_capsules(chain, radii)
    for u in units.values():
        dist = min(
            np.linalg.norm(u.p_link_su - _closest_on_segment(c.p0, c.p1, u.p_link_su)) for c in caps if c.link == u.link
        )
        assert dist == pytest.approx(radii[u.link], abs=1e-12)
    with pytest.raises(ConfigError, match="link"):
        random_placement(chain, 2, np.random.default_rng(0), links=[8])
    with pytest.raises(ConfigError, match="n_units"):
        random_placement(chain, 0, np.random.default_rng(0))


def test_ring_placement_on_surfaces_outward_interleaved_and_tip():
    chain = panda()
    radius = 0.06
    units = ring_placement(chain, per_ring=6, spacing=0.2, radius=radius)
    capsules = [c for c in link_capsules(chain, radius) if c.link >= 2 and c.length >= 0.05]
    # rings: round(L / 0.2) (at least one) per capsule of 5 cm or more, 6 units each, plus the tip unit
    rings = sum(max(1, int(round(c.length / 0.2))) for c in capsules)
    assert len(units) == 6 * rings + 1 and list(units)[:2] == ["su1", "su2"]
    flange = [c for c in capsules if c.link == chain.n_joints][-1]
    by_ring: dict[tuple, list] = {}
    for name, pose in units.items():
        R, p = pose.R_link_su, pose.p_link_su
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
        if name == list(units)[-1]:  # the tip: on the flange capsule's end cap, looking along its axis
            axis = (flange.p1 - flange.p0) / flange.length
            np.testing.assert_allclose(p, flange.p1 + radius * axis, atol=1e-12)
            np.testing.assert_allclose(R[:, 2], axis, atol=1e-12)
            continue
        own = [c for c in capsules if c.link == pose.link]
        feet = [_closest_on_segment(c.p0, c.p1, p) for c in own]
        k = int(np.argmin([abs(np.linalg.norm(p - f) - radius) for f in feet]))
        assert np.linalg.norm(p - feet[k]) == pytest.approx(radius, abs=1e-12)
        np.testing.assert_allclose(R[:, 2], (p - feet[k]) / radius, atol=1e-12)  # z = outward normal
        by_ring.setdefault((pose.link, k, *np.round(feet[k], 6)), []).append(R[:, 2])
    assert all(len(v) == 6 for v in by_ring.values()) and len(by_ring) == rings
    # within a ring the normals are 60 deg apart; a ring and the next one are turned by half a step (30 deg)
    for normals in by_ring.values():
        n = np.array(normals)
        np.testing.assert_allclose(n[:, None, :] @ n[:, :, None], 1.0, atol=1e-12)
        cos = np.sort(n @ n[0])
        np.testing.assert_allclose(cos, np.sort(np.cos(np.deg2rad(60 * np.arange(6)))), atol=1e-9)
    upper_arm = [v for key, v in by_ring.items() if key[0] == 2]
    assert len(upper_arm) == 2
    cross = np.max(np.array(upper_arm[0]) @ np.array(upper_arm[1]).T)
    assert cross == pytest.approx(np.cos(np.deg2rad(30)), abs=1e-9)


def test_ring_placement_errors():
    with pytest.raises(ConfigError, match="per_ring"):
        ring_placement(panda(), per_ring=0)
    with pytest.raises(ConfigError, match="spacing"):
        ring_placement(panda(), spacing=0.0)
    with pytest.raises(ConfigError, match="5 cm"):
        ring_placement(panda(), links=[1])
