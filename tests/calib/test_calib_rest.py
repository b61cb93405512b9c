"""Rest detection of the ``mle`` calibrator (``skincal.calib.rest``) against known truths.

Every check compares with something computed independently: the std of the noise that was added,
the instants at which a synthetic joint was made to move, the segment table, the run that was
bumped.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from skincal.calib.rest import (
    joint_rest_from_data,
    joint_rest_from_segments,
    runs,
    second_difference_noise,
    unit_rest_runs,
)
from skincal.data.dataset import DYNAMIC, STATIC, JointStates, Segments

from synthetic_streams import rest_runs_stream

RATE_HZ = 500.0
ENCODER_STEP = 2.0 * np.pi / 2**18
"""An 18-bit encoder, rad."""
VELOCITY_NOISE = 3e-3
"""A robot controller's velocity noise, rad/s."""


# ---------------------------------------------------------------------------- second differences
@pytest.mark.parametrize("shape", ["quadratic", "sinusoid"])
def test_second_difference_noise_recovers_white_noise_std(shape):
    rng = np.random.default_rng(7)
    dt = 1e-3
    t = np.arange(40000) * dt
    if shape == "quadratic":
        smooth = np.column_stack([0.3 + 0.2 * t + 0.05 * t**2, -1.0 + 0.7 * t**2, 2.0 - 0.1 * t])
    else:
        smooth = np.column_stack([np.sin(2 * np.pi * 1.0 * t), 0.5 * np.cos(2 * np.pi * 0.3 * t), 3 * np.sin(t)])
    sigma = np.array([1e-3, 5e-3, 2e-2])
    x = smooth + rng.normal(0.0, 1.0, smooth.shape) * sigma
    est = second_difference_noise(x)
    assert est.shape == (3,)
    np.testing.assert_allclose(est, sigma, rtol=0.05)
    # The smooth signal alone gives (almost) nothing: the estimate is the noise's, not the motion's.
    # (the sinusoid's own second difference, (2 pi dt)^2 sin, is 4e-5: its MAD part stays below 2 % of sigma)
    assert np.all(second_difference_noise(smooth) < 0.02 * sigma)


def test_second_difference_noise_ignores_motion_starts():
    """A few samples where the signal bends sharply (a start, a stop) do not move the MAD estimate."""
    rng = np.random.default_rng(8)
    n = 20000
    x = np.zeros(n)
    x[n // 2 :] = 0.01 * np.arange(n - n // 2)  # a ramp starts: one second difference of 0.01
    x[3 * n // 4 :] = x[3 * n // 4]  # and stops
    sigma = 2e-4
    est = second_difference_noise((x + rng.normal(0, sigma, n))[:, None])
    assert est[0] == pytest.approx(sigma, rel=0.05)


# ---------------------------------------------------------------------------- rest from joint data
def _synthetic_joint_stream(seed: int = 0):
    """Three joints at 500 Hz: rests of 2 s and a sinusoidal excitation of each joint in turn
    (``qd = A sin(2 pi f (t - t0))`` over whole periods), 3e-3 rad/s velocity noise, 18-bit encoder.

    Returns the stream, the true moving mask ``(N, 3)`` and the transition instants.
    """
    rng = np.random.default_rng(seed)
    amp, freq, periods = 1.0, 1.0, 2
    rest_s = 2.0
    t = np.arange(int(round((rest_s + 4 * (periods / freq + rest_s)) * RATE_HZ))) / RATE_HZ
    q_true = np.tile([0.1, -0.4, 0.8], (t.size, 1)).astype(float)
    qd_true = np.zeros_like(q_true)
    moving = np.zeros(q_true.shape, dtype=bool)
    edges = []
    # joint 0, joint 1, joint 2, then joint 0 again
    for k, j in enumerate([0, 1, 2, 0]):
        t0 = rest_s + k * (periods / freq + rest_s)
        t1 = t0 + periods / freq
        inside = (t > t0) & (t < t1)
        tau = t[inside] - t0
        w = 2 * np.pi * freq
        qd_true[inside, j] = amp * np.sin(w * tau)
        q_true[inside, j] += amp / w * (1 - np.cos(w * tau))
        moving[inside, j] = True
        edges += [t0, t1]
    q = np.round(q_true / ENCODER_STEP) * ENCODER_STEP
    qd = qd_true + rng.normal(0.0, VELOCITY_NOISE, qd_true.shape)
    return JointStates(t=t, q=q, qd=qd), moving, np.array(edges)


def test_joint_rest_from_data_marks_rests_and_motion():
    joints, moving, edges = _synthetic_joint_stream()
    rest = joint_rest_from_data(joints)
    assert rest.source == "joint positions"
    # The noise figures are the ones put in (velocity: white 3e-3; positions: the encoder step / sqrt 12).
    np.testing.assert_allclose(rest.velocity_noise, VELOCITY_NOISE, rtol=0.05)
    np.testing.assert_allclose(rest.position_noise, ENCODER_STEP / np.sqrt(12.0), rtol=0.05)
    t = joints.t
    away = np.min(np.abs(t[:, None] - edges[None, :]), axis=1) > 0.25  # a window (0.2 s) plus margin
    agree = rest.rest[away] == ~moving[away]
    per_joint = agree.mean(axis=0)
    assert np.all(per_joint >= 0.99), per_joint
    # Every sample of a joint that truly rests (away from edges) is called rest: no false motion.
    assert np.all(rest.rest[away & ~moving[:, 0], 0])
    # The per-sample rule a controller's noise breaks: |qd| < 5e-3 rad/s.
    naive = np.abs(joints.qd) < 5e-3
    naive_agree = (naive[away] == ~moving[away]).mean(axis=0)
    assert np.all(naive_agree < 0.97), naive_agree  # ~10 % of resting samples exceed 1.67 sigma
    # ...because it calls resting samples moving at the Gaussian tail rate 2 (1 - Phi(5/3)) = 9.6 %.
    false_motion = 1 - naive[away[:, None] & ~moving].mean()
    assert false_motion == pytest.approx(0.0956, abs=0.01)


def test_joint_rest_unit_rest_combines_the_joints_up_to_the_link():
    joints, moving, edges = _synthetic_joint_stream(seed=1)
    rest = joint_rest_from_data(joints)
    t = joints.t
    away = np.min(np.abs(t[:, None] - edges[None, :]), axis=1) > 0.25
    probe = t[away][::7] + 0.3e-3  # instants between joint samples
    truth = moving[away][::7]
    for link in (1, 2, 3):
        expected = ~np.any(truth[:, :link], axis=1)
        got = rest.unit_rest(probe, link)
        assert (got == expected).mean() > 0.99, link


def test_joint_rest_from_segments_gives_rest_to_the_other_joints():
    joints, _, _ = _synthetic_joint_stream(seed=2)
    segments = Segments(
        t_start=np.array([0.5, 2.0, 6.0]),
        t_end=np.array([1.5, 4.0, 8.0]),
        kind=np.array([STATIC, DYNAMIC, DYNAMIC]),
        pose=np.array([0, 0, 0]),
        joint=np.array([-1, 0, 1]),
    )
    rest = joint_rest_from_segments(joints, segments)
    assert rest.source == "segments"
    t = joints.t
    static = (t >= 0.5) & (t <= 1.5)
    dyn0 = (t >= 2.0) & (t <= 4.0)
    dyn1 = (t >= 6.0) & (t <= 8.0)
    outside = ~(static | dyn0 | dyn1)
    assert np.all(rest.rest[static])
    np.testing.assert_array_equal(rest.rest[dyn0], np.tile([False, True, True], (dyn0.sum(), 1)))
    np.testing.assert_array_equal(rest.rest[dyn1], np.tile([True, False, True], (dyn1.sum(), 1)))
    assert not np.any(rest.rest[outside])
    # A unit on link 1 rests while joint 1 (0-based) is excited, one on link 2 does not.
    mid = np.array([7.0])
    assert rest.unit_rest(mid, 1)[0] and not rest.unit_rest(mid, 2)[0]
    # noise figures still come from the data
    np.testing.assert_allclose(rest.velocity_noise, VELOCITY_NOISE, rtol=0.05)


def test_runs_are_half_open_true_ranges():
    mask = np.array([1, 1, 0, 0, 1, 0, 1, 1, 1], dtype=bool)
    assert runs(mask) == [(0, 2), (4, 5), (6, 9)]
    assert runs(np.zeros(4, dtype=bool)) == []


# ---------------------------------------------------------------------------- IMU cross-check
def _guard(out, bounds) -> int:
    """The guard the function applied, checked to be the 60 ms of GUARD_S (6 or 7 samples at 100 Hz)."""
    a0 = bounds[0][0]
    guard = int(out.bounds[0, 0] - a0) if out.bounds[0, 0] - a0 < 10 else int(out.bounds[0, 0] - bounds[1][0])
    assert guard in (6, 7), guard
    return guard


def test_unit_rest_runs_keeps_still_runs_with_the_guard():
    t, rest_mask, accel, gyro, bounds = rest_runs_stream()
    out = unit_rest_runs(rest_mask, t, accel, gyro)
    # The 60 ms guard at 100 Hz: 6 samples (7 when the median period rounds just below 10 ms).
    guard = _guard(out, bounds)
    np.testing.assert_array_equal(out.bounds, [(a + guard, b - guard) for a, b in bounds])
    assert out.warnings == () and out.dropped.shape == (0, 2)
    assert out.rest.sum() == sum(b - a - 2 * guard for a, b in bounds)
    np.testing.assert_array_equal(out.moving, ~rest_mask)
    # the typical rest spread is the noise put in (max over axes of the per-run std: a bit above 0.03)
    assert 0.03 <= out.accel_noise < 0.036
    assert 5e-3 <= out.gyro_noise < 6e-3


@pytest.mark.parametrize("with_gyro", [True, False])
def test_unit_rest_runs_drops_the_run_in_which_the_imu_moved(with_gyro):
    t, rest_mask, accel, gyro, bounds = rest_runs_stream(seed=1)
    bumped = 3
    a, b = bounds[bumped]
    mid = (a + b) // 2
    accel = accel.copy()
    accel[mid : mid + 8, 0] += 1.0  # a knock: 1 m/s^2 for 80 ms inside the run
    out = unit_rest_runs(rest_mask, t, accel, gyro if with_gyro else None)
    guard = _guard(out, bounds)
    kept = [(x + guard, y - guard) for k, (x, y) in enumerate(bounds) if k != bumped]
    np.testing.assert_array_equal(out.bounds, kept)
    assert not np.any(out.rest[a:b])
    assert np.all(out.rest[kept[0][0] : kept[0][1]])
    np.testing.assert_allclose(out.dropped, [[t[a + guard], t[b - guard - 1]]])
    assert len(out.warnings) == 1
    warning = out.warnings[0]
    assert warning.startswith("static segment moved: 1 of 6")
    # The warning names the run's interval (after the guard), in seconds with one decimal.
    found = re.findall(r"(\d+\.\d)-(\d+\.\d) s", warning)
    assert found == [(f"{t[a + guard]:.1f}", f"{t[b - guard - 1]:.1f}")]
    assert float(found[0][0]) == pytest.approx(t[a], abs=0.1)
    assert float(found[0][1]) == pytest.approx(t[b - 1], abs=0.1)


def test_unit_rest_runs_drops_a_run_that_only_the_gyroscope_sees():
    """A slow turn of the unit barely changes the accelerometer's spread but shows on the gyroscope."""
    t, rest_mask, accel, gyro, bounds = rest_runs_stream(seed=2)
    a, b = bounds[1]
    gyro = gyro.copy()
    gyro[a + 20 : a + 60, 2] += 0.05  # 0.05 rad/s for 0.4 s: a 1.1 deg turn
    out = unit_rest_runs(rest_mask, t, accel, gyro)
    assert len(out.bounds) == 5 and len(out.dropped) == 1
    assert out.dropped[0, 0] == pytest.approx(t[a + _guard(out, bounds)])
    # Without the gyroscope that run is kept.
    assert len(unit_rest_runs(rest_mask, t, accel, None).bounds) == 6


def test_unit_rest_runs_too_short_runs_are_not_candidates():
    t = np.arange(300) / 100.0
    mask = np.zeros(300, dtype=bool)
    mask[10:26] = True  # 16 samples: 4 after a 6-sample guard on each side < MIN_RUN_SAMPLES
    mask[100:200] = True
    accel = np.random.default_rng(0).normal(0, 0.01, (300, 3)) + [0, 0, 9.81]
    out = unit_rest_runs(mask, t, accel, None)
    np.testing.assert_array_equal(out.bounds, [(106, 194)])


def test_a_gyroscope_reading_left_out_at_its_rail_drops_no_rest_run():
    """A NaN gyroscope row (a reading at its rail, left out) inside one rest run made that run's spread NaN, the
    median spread NaN and the limit NaN: every run failed the check (10 of 10 dropped as "moved")."""
    from skincal.calib.rest import unit_rest_runs

    rng = np.random.default_rng(7)
    t = np.arange(10_000) * 0.01
    rest = (t % 10.0) < 5.0  # 10 rests of 5 s, 5 s of motion between
    accel = np.where(rest[:, None], 0.0, 2.0 * np.sin(t)[:, None]) + rng.normal(0.0, 0.02, (t.size, 3))
    gyro = np.where(rest[:, None], 0.0, np.cos(t)[:, None]) + rng.normal(0.0, 0.005, (t.size, 3))
    gyro[3 * 1000 + 250] = np.nan  # inside the fourth rest
    runs = unit_rest_runs(rest, t, accel, gyro)
    assert len(runs.bounds) == 10 and len(runs.dropped) == 0
