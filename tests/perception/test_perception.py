"""Perception: known obstacles placed where they are, time alignment, validity, filter, expiry, distances."""

from __future__ import annotations

import numpy as np
import pytest

from skincal.kinematics import panda
from skincal.kinematics.transforms import invert
from skincal.perception import (
    PerceptionConfig,
    ProximityTracker,
    RobotBody,
    body_proximity,
    interpolate_joints,
    points_from_streams,
    ray_velocity,
    segment_distance,
    unit_points,
    unit_rays,
)
from skincal.skin import SkinUnitPose
from skincal.skin.placement import frame_from_normal, paper_placement
from skincal.skin.tof import Plane, Sphere, TofModel, cone_directions, tof_range

Q0 = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, np.pi / 4])


def test_sphere_in_front_of_unit_is_placed_within_noise(rng):
    chain, poses = panda(), paper_placement(panda())
    model = TofModel(noise_std=0.005, noise_std_per_m=0.005)  # full 27 deg cone, VL53L1X-like noise
    q = np.repeat(Q0[None], 200, axis=0)
    for name in ("su4", "su6"):
        origin, axis = unit_rays(chain, poses[name], Q0[None])
        centre = origin[0] + 0.5 * axis[0]  # sphere of 0.1 m radius, its near surface 0.4 m ahead
        r = tof_range(np.repeat(origin, 200, axis=0), np.repeat(axis, 200, axis=0), [Sphere(centre, 0.1)], model, rng)
        p, ok = unit_points(chain, poses[name], q, r)
        assert ok.all()
        expected = origin[0] + 0.4 * axis[0]
        err = np.linalg.norm(p - expected, axis=1)
        sigma = model.noise_std_at(0.4)
        assert np.max(err) < 4 * sigma
        assert abs(np.mean(p @ axis[0] - expected @ axis[0])) < 4 * sigma / np.sqrt(200)


def test_moving_robot_time_alignment_puts_points_on_a_wall(rng):
    """Joints at 1 kHz, ToF at 50 Hz on another clock: points land on the true plane within the noise."""
    chain, poses = panda(), paper_placement(panda())
    pose = poses["su4"]  # looks along +y at Q0
    t_j = np.arange(0.0, 2.0, 0.001)
    q_j = Q0 + np.outer(np.sin(2 * np.pi * 0.5 * t_j), [0.4, 0.1, 0.2, 0.1, 0.3, 0.1, 0.0])
    t_tof = 0.0137 + np.arange(0.0, 1.95, 0.02)
    # the true joint angles at the ToF instants (the exact motion, not the 1 kHz samples)
    q_true = Q0 + np.outer(np.sin(2 * np.pi * 0.5 * t_tof), [0.4, 0.1, 0.2, 0.1, 0.3, 0.1, 0.0])
    wall = Plane([0.0, 0.6, 0.0], [0.0, -1.0, 0.0])
    origin, axis = unit_rays(chain, pose, q_true)
    model = TofModel(noise_std=0.003, n_rays=1)
    r = tof_range(origin, axis, [wall], model, rng)
    pts = points_from_streams(chain, {"su4": pose}, t_j, q_j, {"su4": (t_tof, r)}, PerceptionConfig(max_range=2.0))
    assert len(pts) == t_tof.size
    assert np.max(np.abs(pts.positions[:, 1] - 0.6)) < 4 * 0.003
    # without time alignment (latest joint sample 20 ms late) the points miss the wall by more
    q_late = interpolate_joints(t_j, q_j, t_tof + 0.02)
    p_late, _ = unit_points(chain, pose, q_late, r, PerceptionConfig(max_range=2.0))
    assert np.max(np.abs(p_late[:, 1] - 0.6)) > 0.01


def test_interpolation_is_linear_and_holds_ends():
    t = np.array([0.0, 1.0, 2.0])
    q = np.array([[0.0, 1.0], [1.0, 3.0], [3.0, 3.0]])
    out = interpolate_joints(t, q, [-1.0, 0.5, 1.5, 5.0])
    np.testing.assert_allclose(out, [[0, 1], [0.5, 2], [2, 3], [3, 3]])


def test_validity_drops_nan_out_of_range_and_self():
    chain, poses = panda(), paper_placement(panda())
    cfg = PerceptionConfig(min_range=0.01, max_range=1.0, self_margin=0.02)
    q = np.repeat(Q0[None], 4, axis=0)
    _, ok = unit_points(chain, poses["su4"], q, [np.nan, 0.005, 1.5, 0.5], cfg)
    np.testing.assert_array_equal(ok, [False, False, False, True])
    # su5 looks back along the arm: a reading that ends inside the robot's own capsules is the robot
    origin, axis = unit_rays(chain, poses["su5"], Q0[None])
    body = RobotBody.of(chain)
    r = np.linspace(0.02, 0.6, 60)
    p, ok = unit_points(chain, poses["su5"], np.repeat(Q0[None], 60, axis=0), r, cfg, body)
    d = body_proximity(body, chain.link_frames(Q0), origin + r[:, None] * axis).distance
    np.testing.assert_array_equal(ok, d > cfg.self_margin)
    assert (~ok).any() and ok.any()


def test_tracker_median_velocity_and_extrapolation():
    chain, poses = panda(), paper_placement(panda())
    origin, axis = unit_rays(chain, poses["su4"], Q0[None])
    cfg = PerceptionConfig(window=3, rate_window_s=0.1, predict_s=0.5, coast_m=0.2)
    tracker = ProximityTracker(chain, {"su4": poses["su4"]}, cfg)
    t = 0.02 * np.arange(8)
    r = 0.8 - 0.5 * t  # a target coming straight down the ray at 0.5 m/s
    for tk, rk in zip(t, r, strict=True):
        tracker.update(tk, Q0, {"su4": rk})
    pts = tracker.points(t[-1])
    # the median of the last three readings, moved on by the estimated velocity to t_now
    np.testing.assert_allclose(pts.ranges, [r[-2]])
    np.testing.assert_allclose(pts.velocities[0], -0.5 * axis[0], atol=1e-9)
    np.testing.assert_allclose(pts.positions[0], origin[0] + r[-1] * axis[0], atol=1e-9)
    np.testing.assert_allclose(pts.spread, r[-2] * np.sin(np.deg2rad(13.5)))
    # unseen, it coasts for at most coast_m, then stands still (no velocity)
    later = tracker.points(t[-1] + 0.2)
    np.testing.assert_allclose(later.positions[0], origin[0] + (r[-1] - 0.1) * axis[0], atol=1e-9)
    still = tracker.points(t[-1] + 0.9)
    np.testing.assert_allclose(still.positions[0], origin[0] + (r[-2] - 0.2) * axis[0], atol=1e-9)
    np.testing.assert_allclose(still.velocities, 0.0)


def test_tracker_memory_survives_a_jump_and_expires():
    chain, poses = panda(), paper_placement(panda())
    cfg = PerceptionConfig(window=1, memory_s=1.0, jump=0.1)
    tracker = ProximityTracker(chain, {"su4": poses["su4"]}, cfg)
    for k in range(3):
        tracker.update(0.02 * k, Q0, {"su4": 0.4})
    tracker.update(0.06, Q0, {"su4": np.nan})  # nothing: the point stays (no evidence it has gone)
    assert len(tracker.points(0.5)) == 1
    tracker.update(0.6, Q0, {"su4": 0.9})  # another, farther target: the near one is remembered
    pts = tracker.points(0.6)
    np.testing.assert_allclose(np.sort(pts.ranges), [0.4, 0.9])
    assert len(tracker.points(0.04 + 1.0 + 1e-3)) == 1  # the memory expires memory_s after its last reading
    tracker.update(0.7, Q0, {"su4": 0.41})  # lands on the 0.4 memory (cleared); the 0.9 track is remembered
    np.testing.assert_allclose(np.sort(tracker.points(0.7).ranges), [0.41, 0.9])
    assert len(tracker.points(0.7 + 1.0 + 1e-3)) == 0  # and every point expires unseen


def test_ray_velocity_is_the_slope_along_the_ray(rng):
    t = np.linspace(0.0, 0.1, 6)
    a = np.array([0.0, 0.6, 0.8])
    p = np.outer(t, [0.3, -0.5, 0.2]) + rng.normal(size=(6, 3)) * 1e-12
    np.testing.assert_allclose(ray_velocity(t, p, a), (0.6 * -0.5 + 0.8 * 0.2) * a, atol=1e-9)
    np.testing.assert_allclose(ray_velocity(t[:2], p[:2], a), 0.0)


def test_segment_distance_against_brute_force(rng):
    s = np.linspace(0.0, 1.0, 801)
    for _ in range(30):
        a1, b1, a2, b2 = rng.normal(size=(4, 3))
        if rng.random() < 0.2:
            b2 = a2.copy()  # a point (sphere core)
        if rng.random() < 0.2:
            b2 = a2 + 0.5 * (b1 - a1)  # parallel
        brute = np.linalg.norm((a1 + s[:, None] * (b1 - a1))[:, None] - (a2 + s[:, None] * (b2 - a2))[None], axis=-1)
        assert segment_distance(a1, b1, a2, b2) == pytest.approx(brute.min(), abs=2e-3)
        assert segment_distance(a1, b1, a2, b2) <= brute.min() + 1e-12


def test_body_proximity_against_sampled_surface(rng):
    chain = panda()
    body = RobotBody.of(chain)
    T = chain.link_frames(Q0)
    a, b = body.segments(T)
    pts = rng.uniform([-0.3, -0.5, 0.0], [0.8, 0.5, 1.0], size=(50, 3))
    prox = body_proximity(body, T, pts)
    s = np.linspace(0, 1, 400)
    core = a[0][:, None] + s[None, :, None] * (b[0] - a[0])[:, None]  # (C, 400, 3)
    brute = (np.linalg.norm(pts[:, None, None] - core[None], axis=-1).min(axis=2) - body.radius).min(axis=1)
    np.testing.assert_allclose(prox.distance, brute, atol=2e-3)
    assert np.all(prox.distance <= brute + 1e-12)
    np.testing.assert_allclose(np.linalg.norm(prox.normal, axis=1), 1.0)


def _looking_at(chain, link: int, origin, target) -> SkinUnitPose:
    """A unit on ``link`` at ``origin`` (base frame at ``Q0``) whose +z axis points at ``target``."""

    origin, target = np.asarray(origin, dtype=float), np.asarray(target, dtype=float)
    z = (target - origin) / np.linalg.norm(target - origin)
    T_base_su = np.eye(4)
    T_base_su[:3, :3], T_base_su[:3, 3] = frame_from_normal(z[None], np.zeros(1))[0], origin
    T_link_su = invert(chain.link_frames(Q0)[0, link]) @ T_base_su
    return SkinUnitPose(link, T_link_su[:3, :3], T_link_su[:3, 3])


def test_free_space_of_other_cones_clears_stale_points_only_inside_them():
    """A point one unit saw is dropped when another unit's cone passes through it and finds nothing
    (or something farther); a cone that misses it, or whose reading stops short of it, leaves it."""
    chain = panda()
    target = np.array([0.6, 0.5, 0.7])
    poses = {
        "a": _looking_at(chain, 4, [0.3, 0.1, 0.7], target),
        "b": _looking_at(chain, 6, [0.5, -0.1, 0.6], target),  # its cone passes through the target
        "c": _looking_at(chain, 6, [0.5, -0.1, 0.6], [1.5, -0.5, 0.6]),  # looks elsewhere
    }
    r_a = float(np.linalg.norm(target - [0.3, 0.1, 0.7]))
    r_b = float(np.linalg.norm(target - [0.5, -0.1, 0.6]))
    cfg = PerceptionConfig(window=1, max_age_s=0.1, memory_s=2.0, jump=0.1)

    def seen_by_a() -> ProximityTracker:
        tracker = ProximityTracker(chain, poses, cfg)
        for k in range(3):
            tracker.update(0.02 * k, Q0, {"a": r_a})
        tracker.update(0.06, Q0, {"a": np.nan})  # a loses it: its own silence keeps the point
        np.testing.assert_allclose(tracker.points(0.3).positions, [target], atol=1e-9)
        return tracker

    tracker = seen_by_a()
    tracker.update(0.3, Q0, {"c": np.nan, "b": r_b + 0.05})  # c misses it; b sees something just behind it
    assert {*tracker.points(0.3).units} == {"a", "b"}  # b's reading is within jump of the point: not free there
    tracker = seen_by_a()
    tracker.update(0.3, Q0, {"b": r_b - 0.3})  # something in front of the point hides it from b
    assert {*tracker.points(0.3).units} == {"a", "b"}
    tracker = seen_by_a()
    tracker.update(0.3, Q0, {"b": np.nan})  # b's cone is empty through the point: it has gone
    assert len(tracker.points(0.3)) == 0
    tracker = seen_by_a()
    tracker.update(0.3, Q0, {"b": r_b + 0.5})  # b sees only a farther target: same
    assert tracker.points(0.3).units == ("b",)
    # a fresh track (its unit read it within max_age_s) is not carved: its own unit vouches for it
    fresh = ProximityTracker(chain, poses, cfg)
    fresh.update(0.0, Q0, {"a": r_a})
    fresh.update(0.05, Q0, {"b": np.nan})
    assert fresh.points(0.05).units == ("a",)


def test_body_proximity_of_groups_is_the_nearest_of_each_group(rng):
    chain = panda()
    body = RobotBody.of(chain).inflated(0.02)
    T = chain.link_frames(Q0)
    x = rng.normal(size=(40 * 7, 3)) * 0.5
    every = body_proximity(body, T, x)
    nearest = body_proximity(body, T, x, group=7)
    pick = np.argmin(every.distance.reshape(40, 7), axis=1) + 7 * np.arange(40)
    for f in ("distance", "capsule", "link", "p_base_robot", "normal"):
        np.testing.assert_array_equal(getattr(nearest, f), getattr(every, f)[pick])
    assert not np.array_equal(pick, 7 * np.arange(40))  # not simply the first of each group


def test_cone_spread_bounds_where_the_target_of_a_reading_can_be(rng):
    """A reading's ``spread`` (``points_from_streams``) is how far across the ray the target that gave it
    can lie: a small target on every ray of the simulated 27 deg cone (``skin.tof``), one per reading,
    lies within the spread of the point placed on the axis, and those on the cone's edge at it (a halved
    spread would leave them outside)."""
    chain, pose = panda(), paper_placement(panda())["su4"]
    model = TofModel()  # 37 rays: the axis and rings at 4.5, 9 and 13.5 deg
    dirs_su = cone_directions(model.fov_deg, model.n_rays)
    k = len(dirs_su)
    origin, _ = unit_rays(chain, pose, Q0[None])
    R_base_su = (chain.link_frames(Q0[None])[0, pose.link] @ pose.T_link_su)[:3, :3]
    d = rng.uniform(0.2, 1.5, k)  # target distance along its ray, m
    radius = 0.002  # small beside the 4.5 deg between rays at 0.2 m (16 mm): only its own ray hits it
    centres = origin + (d + radius)[:, None] * (dirs_su @ R_base_su.T)
    r = tof_range(np.repeat(origin, k, axis=0), np.repeat(R_base_su[None], k, axis=0), [Sphere(centres, radius)], model)
    np.testing.assert_allclose(r, d, atol=1e-9)
    t = np.arange(k) * 0.02
    t_j, q_j = np.array([-1.0, 1.0]), np.repeat(Q0[None], 2, axis=0)
    pts = points_from_streams(chain, {"su4": pose}, t_j, q_j, {"su4": (t, r)}, PerceptionConfig(max_range=2.0))
    assert len(pts) == k
    target = origin + d[:, None] * (dirs_su @ R_base_su.T)  # the hit points, in reading order (stamps sorted)
    rel = target - origin
    across = np.linalg.norm(rel - np.sum(rel * pts.axes, axis=1, keepdims=True) * pts.axes, axis=1)
    assert np.all(across <= pts.spread * (1 + 1e-9)), np.max(across / pts.spread)
    edge = np.isclose(np.arccos(np.clip(dirs_su[:, 2], -1, 1)), np.deg2rad(model.fov_deg / 2))
    assert edge.sum() == 18
    np.testing.assert_allclose(across[edge], pts.spread[edge], rtol=1e-9)
