"""ToF model: exact ray distances (hand-computed, sphere tracing, MuJoCo), cone, limits, noise."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skincal.errors import ConfigError
from skincal.kinematics import panda, rot_x, rot_z
from skincal.kinematics.geometry import link_capsules
from skincal.skin.tof import (
    TOF_PRESETS,
    Box,
    Capsule,
    Plane,
    Sphere,
    TofModel,
    capsules_in_base,
    cone_directions,
    get_tof_model,
    ray_distance,
    tof_range,
)

SPHERE = Sphere([0.1, -0.2, 1.5], 0.4)
CAPSULE = Capsule([-0.5, 0.2, 1.2], [0.6, -0.1, 1.8], 0.25)
PLANE = Plane([0.0, 0.0, -0.5], [0.2, -0.1, 1.0])
BOX = Box([0.2, 0.1, 1.4], [0.5, 0.3, 0.2], Rotation.from_euler("xyz", [0.3, -0.2, 0.7]).as_matrix())
PRIMITIVES = {"sphere": SPHERE, "capsule": CAPSULE, "plane": PLANE, "box": BOX}


def test_hand_computed_distances():
    o = np.zeros((1, 3))
    z = np.array([[0.0, 0.0, 1.0]])
    sphere = Sphere([0.0, 0.0, 2.0], 0.5)
    assert ray_distance(o, z, sphere)[0] == pytest.approx(1.5)
    assert ray_distance([[0.3, 0.0, 0.0]], z, sphere)[0] == pytest.approx(2.0 - 0.4)  # sqrt(0.25 - 0.09)
    assert ray_distance(o, -z, sphere)[0] == np.inf  # behind
    assert ray_distance(o, [[1.0, 0.0, 0.0]], sphere)[0] == np.inf  # missed
    assert ray_distance([[0.0, 0.0, 2.1]], z, sphere)[0] == 0.0  # inside
    assert ray_distance(o, 3 * z, sphere)[0] == pytest.approx(1.5)  # direction normalised

    capsule = Capsule([-1.0, 0.0, 2.0], [1.0, 0.0, 2.0], 0.2)
    assert ray_distance(o, z, capsule)[0] == pytest.approx(1.8)  # side
    assert ray_distance([[1.5, 0.0, 2.0]], [[-1.0, 0.0, 0.0]], capsule)[0] == pytest.approx(0.3)  # end cap
    assert ray_distance([[1.1, 0.0, 0.0]], z, capsule)[0] == pytest.approx(2.0 - math.sqrt(0.04 - 0.01))
    assert ray_distance([[0.0, 0.5, 2.0]], [[1.0, 0.0, 0.0]], capsule)[0] == np.inf  # parallel, outside
    assert ray_distance([[0.5, 0.1, 2.0]], z, capsule)[0] == 0.0
    point_capsule = Capsule([0.0, 0.0, 2.0], [0.0, 0.0, 2.0], 0.5)  # degenerate: a sphere
    assert ray_distance(o, z, point_capsule)[0] == pytest.approx(1.5)

    floor = Plane([0.0, 0.0, 0.0], [0.0, 0.0, 2.0])
    up = np.array([[0.0, 0.0, 1.0]])
    assert ray_distance(up, -z, floor)[0] == pytest.approx(1.0)
    tilted = [[math.sin(math.pi / 3), 0.0, -math.cos(math.pi / 3)]]  # 60 deg from straight down
    assert ray_distance(up, tilted, floor)[0] == pytest.approx(2.0)
    assert ray_distance(up, z, floor)[0] == np.inf
    assert ray_distance(-up, z, floor)[0] == 0.0  # inside the half-space

    box = Box([0.0, 0.0, 3.0], [0.5, 1.0, 0.25], rot_z(math.pi / 2))  # base extents: x +-1, y +-0.5
    assert ray_distance(o, z, box)[0] == pytest.approx(2.75)
    assert ray_distance([[5.0, 0.0, 3.0]], [[-1.0, 0.0, 0.0]], box)[0] == pytest.approx(4.0)
    assert ray_distance([[0.0, 5.0, 3.0]], [[0.0, -1.0, 0.0]], box)[0] == pytest.approx(4.5)
    assert ray_distance([[0.0, 5.0, 3.0]], [[0.0, 1.0, 0.0]], box)[0] == np.inf
    assert ray_distance([[0.9, 0.4, 3.2]], z, box)[0] == 0.0
    assert ray_distance([[2.0, 0.0, 0.0]], z, box)[0] == np.inf  # parallel to a slab, outside it


def _sdf(primitive, x):
    """Independent signed distance functions (negative inside)."""
    if isinstance(primitive, Sphere):
        return np.linalg.norm(x - primitive.center, axis=-1) - primitive.radius
    if isinstance(primitive, Capsule):
        ab = primitive.p1 - primitive.p0
        s = np.clip((x - primitive.p0) @ ab / (ab @ ab), 0.0, 1.0)
        return np.linalg.norm(x - primitive.p0 - s[:, None] * ab, axis=-1) - primitive.radius
    if isinstance(primitive, Plane):
        return (x - primitive.point) @ primitive.normal
    q = np.abs((x - primitive.center) @ primitive.R) - primitive.half_extents
    return np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(axis=-1), 0.0)


def _sphere_trace(primitive, o, d, t_max=20.0, iters=4000, eps=1e-11):
    t = np.zeros(len(o))
    for _ in range(iters):
        step = _sdf(primitive, o + t[:, None] * d)
        active = (step > eps) & (t < t_max)
        if not active.any():
            break
        t = np.where(active, t + step, t)
    hit = _sdf(primitive, o + t[:, None] * d) <= 1e-9
    return np.where(hit & (t < t_max), t, np.inf)


@pytest.mark.parametrize("name", list(PRIMITIVES))
def test_distance_matches_sphere_tracing(name):
    primitive = PRIMITIVES[name]
    rng = np.random.default_rng(21)
    n = 300
    o = rng.uniform([-2, -2, -0.4], [2, 2, 3.5], size=(n, 3))
    o = o[_sdf(primitive, o) > 1e-3]  # origins outside the solid
    targets = np.array([0.15, -0.05, 1.5]) + rng.normal(scale=0.5, size=o.shape)
    d = targets - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = ray_distance(o, d, primitive)
    t_ref = _sphere_trace(primitive, o, d, t_max=20.0)
    t = np.where(t < 20.0, t, np.inf)  # the infinite plane is also hit far away, beyond the tracer's reach
    assert np.isfinite(t).sum() > len(o) // 4 and (~np.isfinite(t)).sum() > 5, "both hits and misses tested"
    np.testing.assert_array_equal(np.isfinite(t), np.isfinite(t_ref))
    np.testing.assert_allclose(t[np.isfinite(t)], t_ref[np.isfinite(t)], atol=1e-8)
    inside = primitive.center if name in ("sphere", "box") else (primitive.p0 if name == "capsule" else [0, 0, -2.0])
    assert ray_distance(np.atleast_2d(inside), d[:1], primitive)[0] == 0.0


@pytest.mark.parametrize("name", ["sphere", "capsule", "box", "plane"])
def test_distance_matches_mujoco(name):
    mujoco = pytest.importorskip("mujoco")
    primitive = PRIMITIVES[name]
    if name == "sphere":
        pos, mat, size, kind = primitive.center, np.eye(3), [primitive.radius, 0, 0], mujoco.mjtGeom.mjGEOM_SPHERE
    elif name == "capsule":
        axis = primitive.p1 - primitive.p0
        mat = Rotation.align_vectors([axis], [[0.0, 0.0, 1.0]])[0].as_matrix()
        pos, kind = (primitive.p0 + primitive.p1) / 2, mujoco.mjtGeom.mjGEOM_CAPSULE
        size = [primitive.radius, np.linalg.norm(axis) / 2, 0]
    elif name == "box":
        pos, mat, size, kind = primitive.center, primitive.R, primitive.half_extents, mujoco.mjtGeom.mjGEOM_BOX
    else:
        mat = Rotation.align_vectors([primitive.normal], [[0.0, 0.0, 1.0]])[0].as_matrix()
        pos, size, kind = primitive.point, [1e6, 1e6, 0], mujoco.mjtGeom.mjGEOM_PLANE
    rng = np.random.default_rng(22)
    o = rng.uniform([-2, -2, 0.0], [2, 2, 3.5], size=(150, 3))
    o = o[_sdf(primitive, o) > 1e-3]
    d = Rotation.random(len(o), random_state=23).apply([0.0, 0.0, 1.0])
    d[::2] = np.array([0.1, 0.0, 1.5]) + rng.normal(scale=0.4, size=d[::2].shape) - o[::2]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    ref = np.array(
        [
            mujoco.mju_rayGeom(np.array(pos, float), np.ravel(mat), np.array(size, float), oi, di, kind, None)
            for oi, di in zip(o, d, strict=True)
        ]
    )
    ref = np.where(ref < 0, np.inf, ref)
    t = ray_distance(o, d, primitive)
    np.testing.assert_array_equal(np.isfinite(t), np.isfinite(ref))
    np.testing.assert_allclose(t[np.isfinite(t)], ref[np.isfinite(ref)], atol=1e-9)


def test_cone_directions_layout():
    assert cone_directions(27.0, 1).tolist() == [[0.0, 0.0, 1.0]]
    for n_rays, rings in ((7, 1), (19, 2), (37, 3), (61, 4), (4, 1), (25, 2)):
        d = cone_directions(27.0, n_rays)
        assert d.shape == (n_rays, 3)
        np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
        polar = np.degrees(np.arccos(np.clip(d[:, 2], -1, 1)))
        assert polar.max() == pytest.approx(13.5) and polar[0] == 0.0
        assert len(np.unique(np.round(polar, 9))) == rings + 1
        np.testing.assert_allclose(d.mean(axis=0)[:2], 0.0, atol=1e-12)  # symmetric about +z


def _rotation_looking_along(direction):
    """An SU orientation whose +z axis is ``direction``."""
    return Rotation.align_vectors([direction], [[0.0, 0.0, 1.0]])[0].as_matrix()


def test_target_inside_cone_seen_outside_not():
    model = get_tof_model("ideal")
    R = np.repeat(np.eye(3)[None], 1, axis=0)
    o = np.zeros((1, 3))
    radius = 0.3
    edge = math.degrees(math.asin(radius / 1.0))  # angular radius of the ball seen at 1 m
    for edge_angle, seen in ((12.0, True), (15.0, False), (-5.0, True)):
        centre_angle = math.radians(edge_angle + edge)
        ball = Sphere([math.sin(centre_angle), 0.0, math.cos(centre_angle)], radius)
        r = tof_range(o, R, [ball], model)
        assert np.isfinite(r[0]) == seen, edge_angle
        if seen:
            assert 1.0 - radius <= r[0] < 1.0
    # a thin target straight ahead is seen by the central ray alone
    r1 = tof_range(o, R, [Sphere([0.0, 0.0, 1.0], 0.01)], dataclasses.replace(model, n_rays=1))
    assert r1[0] == pytest.approx(0.99)


def test_tilted_wall_nearest_ray_is_on_the_cone_edge():
    # SU at height h above a floor, tilted by beta > fov/2 from straight down about y: the nearest
    # ray of the cone is the edge ray closest to the floor normal, distance h / cos(beta - 13.5 deg).
    h, beta = 0.8, math.radians(30.0)
    R = (rot_x(math.pi) @ Rotation.from_euler("y", -beta).as_matrix())[None]
    axis = R[0] @ [0.0, 0.0, 1.0]
    assert math.degrees(math.acos(-axis[2])) == pytest.approx(30.0)
    floor = Plane([0.0, 0.0, 0.0], [0.0, 0.0, 1.0])
    model = get_tof_model("ideal")
    r = tof_range([[0.0, 0.0, h]], R, [floor], model)
    assert r[0] == pytest.approx(h / math.cos(beta - math.radians(13.5)), rel=1e-12)
    r_axes = tof_range([[0.0, 0.0, h]], axis[None], [floor], dataclasses.replace(model, n_rays=1))
    assert r_axes[0] == pytest.approx(h / math.cos(beta))


def test_range_limits_give_nan():
    R = np.repeat(np.eye(3)[None], 4, axis=0)
    o = np.zeros((4, 3))
    ceiling = [Plane([[0.0, 0.0, z] for z in (0.005, 0.5, 1.5, 4.5)], [0.0, 0.0, -1.0])]  # moving plane
    r = tof_range(o, R, ceiling, get_tof_model("ideal"))
    np.testing.assert_allclose(r[:3], [0.005, 0.5, 1.5])
    assert np.isnan(r[3])  # beyond 4 m
    r = tof_range(o, R, ceiling, get_tof_model("roboskin-firmware"), np.random.default_rng(0))
    assert np.isnan(r[0]) and np.isfinite(r[1]) and np.isnan(r[2]) and np.isnan(r[3])
    assert np.all(np.isnan(tof_range(o, R, [], get_tof_model("ideal"))))


def test_noise_std_as_configured():
    model = get_tof_model("vl53l1x")
    n = 20_000
    o = np.zeros((n, 3))
    for z in (0.5, 2.0):
        wall = [Plane([0.0, 0.0, z], [0.0, 0.0, -1.0])]
        r = tof_range(o, np.repeat(np.eye(3)[None], n, axis=0), wall, model, np.random.default_rng(30))
        expected = 0.005 + 0.005 * z
        assert r.std() == pytest.approx(math.sqrt(expected**2 + 0.001**2 / 12), rel=0.03)
        assert r.mean() == pytest.approx(z, abs=4 * expected / math.sqrt(n))
        np.testing.assert_allclose(r / 0.001, np.round(r / 0.001), atol=1e-6)
    with pytest.raises(ConfigError, match="rng"):
        tof_range(o[:1], np.eye(3)[None], [], model)


def test_presets():
    assert set(TOF_PRESETS) >= {"vl53l1x", "roboskin-firmware", "ideal", "ideal-ray"}
    v = get_tof_model("vl53l1x")
    assert (v.max_range, v.min_range, v.fov_deg, v.rate_hz) == (4.0, 0.0, 27.0, 50.0)
    fw = get_tof_model("roboskin-firmware")
    assert (fw.min_range, fw.max_range) == (0.01, 1.0)
    assert get_tof_model("ideal-ray").n_rays == 1
    with pytest.raises(ConfigError, match="vl53l1x, roboskin-firmware"):
        get_tof_model("sharp")
    with pytest.raises(ConfigError, match="max_range"):
        TofModel(min_range=1.0, max_range=0.5)


def test_robot_links_as_moving_capsules():
    chain = panda()
    q = np.array([[0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.7], [0.5, 0.2, 0.0, -1.5, 0.0, 1.5, 0.0]])
    T = chain.link_frames(q)
    caps = link_capsules(chain, 0.06)
    moved = capsules_in_base(caps, T, exclude_links=[0])
    assert len(moved) == sum(c.link != 0 for c in caps)
    c0 = next(c for c in caps if c.link == 4)
    m0 = moved[[c.link for c in caps if c.link != 0].index(4)]
    np.testing.assert_allclose(m0.p1, (T[:, 4] @ np.append(c0.p1, 1.0))[:, :3])
    # looking straight down at the robot from 3 m above its base: hits some link below 3 m
    o = np.tile([0.0, 0.0, 3.0], (2, 1))
    r = tof_range(o, np.repeat(rot_x(math.pi)[None], 2, axis=0), moved, get_tof_model("ideal"))
    assert np.all((r > 1.5) & (r < 3.0))
    per_sample = np.array(
        [ray_distance(o[i : i + 1], [[0.0, 0.0, -1.0]], Capsule(m0.p0[i], m0.p1[i], 0.06))[0] for i in range(2)]
    )
    np.testing.assert_allclose(ray_distance(o, [[0.0, 0.0, -1.0]], m0), per_sample)


def test_measure_is_window_noise_rounding_with_one_normal_per_sample():
    """The stream contract: a noisy model draws rng.normal(size=shape), invalid samples included."""
    model = dataclasses.replace(get_tof_model("roboskin-firmware"), resolution_m=0.0)
    d = np.array([[0.005, 0.5], [np.inf, 0.9], [1.5, np.nan]])
    z = np.random.default_rng(3).normal(size=d.shape)
    got = model.measure(d, np.random.default_rng(3))
    valid = np.isfinite(d) & (d >= 0.01) & (d <= 1.0)
    np.testing.assert_array_equal(np.isnan(got), ~valid)
    np.testing.assert_array_equal(got[valid], d[valid] + z[valid] * (0.005 + 0.005 * d[valid]))
    rng = np.random.default_rng(3)
    model.measure(d, rng)
    assert rng.normal() == np.random.default_rng(3).normal(size=d.size + 1)[-1]  # exactly d.size draws
    rounded = get_tof_model("roboskin-firmware").measure(d, np.random.default_rng(3))
    np.testing.assert_allclose(rounded[valid], np.round(got[valid] / 0.001) * 0.001, rtol=0, atol=1e-15)


def test_noise_free_measure_draws_nothing_and_needs_no_rng():
    rng = np.random.default_rng(5)
    r = get_tof_model("ideal").measure([0.3, 5.0, np.inf], rng)
    np.testing.assert_array_equal(r, [0.3, np.nan, np.nan])
    assert rng.normal() == np.random.default_rng(5).normal()
    assert get_tof_model("ideal").measure(0.3) == 0.3
    with pytest.raises(ConfigError, match="rng"):
        get_tof_model("vl53l1x").measure([0.3])


def test_tof_range_is_measure_of_the_nearest_in_cone():
    from skincal.skin.tof import nearest_in_cone

    rng = np.random.default_rng(11)
    o = rng.uniform(-0.3, 0.3, (50, 3))
    axes = rng.normal(size=(50, 3)) + [0.0, 0.0, 3.0]
    scene = list(PRIMITIVES.values())[:2] + [BOX]
    model = get_tof_model("vl53l1x")
    true = nearest_in_cone(o, axes, scene, model)
    assert np.isfinite(true).sum() > 10
    np.testing.assert_array_equal(
        tof_range(o, axes, scene, model, np.random.default_rng(2)), model.measure(true, np.random.default_rng(2))
    )


@pytest.mark.adversarial
@pytest.mark.parametrize("bad", [[1.0, 2.0], [1.0, np.nan, 0.0], 3.0, "abc", [[1, 2, 3], [4, 5]], np.ones((2, 4))])
def test_solid_vectors_are_checked_by_the_one_validator(bad):
    from skincal.skin.tof import finite_array

    with pytest.raises(ConfigError, match=r"Sphere.center \(m\) must be finite with shape \(\.\.\., 3\)"):
        Sphere(bad, 0.1)
    with pytest.raises(ConfigError, match="must be finite with shape"):
        finite_array(bad, "x", (3,))
    ok = finite_array([[1, 2, 3]], "x")
    assert ok.shape == (1, 3) and not ok.flags.writeable
