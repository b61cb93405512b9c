"""The faults of real recordings in the sensor models (issue 24): host reception stamps, gaps with
one-off clock steps, gyroscope scale and misalignment; each against its equation."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from skincal.errors import ConfigError
from skincal.sim.common import sensor_truth, unit_clock_stamps
from skincal.skin.clock import (
    ClockModel,
    UnitClock,
    draw_clock,
    get_clock_model,
    host_reception,
    stamp_samples,
)
from skincal.skin.imu import ImuErrors, ImuModel, apply_imu_model, draw_imu_errors, get_imu_model

HOST = get_clock_model("host")
T = 0.01  # the real-consumer IMU's sample period, s


def regular(duration_s: float, period: float = T) -> np.ndarray:
    return np.arange(0.0, duration_s, period)


def test_host_presets_have_stated_values():
    assert (HOST.offset_mean_s, HOST.offset_max_s) == (0.085, 0.01)
    assert (HOST.host_delay_max_s, HOST.host_min_spacing_s, HOST.stamp_quantum_s) == (7.5e-3, 2.5e-3, 1e-6)
    assert HOST.drift_ppm_mean == HOST.drift_ppm_std == HOST.gap_rate_hz == 0 and not HOST.is_ideal
    gaps = get_clock_model("host-gaps")
    assert replace(gaps, gap_rate_hz=0.0, gap_min_s=0.0, gap_max_s=0.0, step_std_s=0.0) == HOST
    assert (gaps.gap_rate_hz, gaps.gap_min_s, gaps.gap_max_s, gaps.step_std_s) == (1 / 30, 0.3, 0.7, 0.02)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"host_delay_max_s": -1e-3},
        {"gap_rate_hz": -1.0},
        {"gap_min_s": 0.5, "gap_max_s": 0.4},
        {"step_std_s": math.nan},
    ],
)
def test_bad_host_and_gap_values_rejected(kwargs):
    with pytest.raises(ConfigError) as info:
        ClockModel(**kwargs)
    assert "\n" not in str(info.value)


def test_host_reception_is_the_recurrence():
    rng = np.random.default_rng(3)
    a = np.cumsum(rng.uniform(0.0, 4e-3, 2000))
    m = 2.5e-3
    r, previous = [], -np.inf
    for x in a:
        previous = max(x, previous + m)
        r.append(previous)
    np.testing.assert_allclose(host_reception(a, m), r, rtol=0, atol=1e-12)
    assert np.all(np.diff(host_reception(a, m)) >= m - 1e-12)


def test_host_stamp_spacing_is_triangular_on_t_plus_minus_d():
    """At 100 Hz with D = 7.5 ms the floor never binds: spacing T + u_k - u_{k-1}, u ~ U(0, D)."""
    model = replace(HOST, stamp_quantum_s=0.0)
    rng = np.random.default_rng(7)
    clock = draw_clock(model, rng)
    t = regular(600.0)
    stamps, keep = stamp_samples(model, clock, t, t, 0.0, rng)
    assert keep.all()
    D = model.host_delay_max_s
    d = np.diff(stamps)
    assert d.min() >= T - D - 1e-12 and d.max() <= T + D + 1e-12
    assert d.min() >= model.host_min_spacing_s - 1e-12
    n = d.size
    assert abs(d.mean() - T) <= D / n + 1e-12  # telescoping: T + (u_n - u_0) / n
    assert d.var() == pytest.approx(D**2 / 6, rel=4 * math.sqrt(2 / n) * 1.2)
    c = d - d.mean()
    assert np.corrcoef(c[:-1], c[1:])[0, 1] == pytest.approx(-0.5, abs=4 / math.sqrt(n))
    # the stamp error is the offset plus U(0, D): its mean is the truth's time offset
    e = stamps - t - clock.offset_s
    assert e.min() >= 0 and e.max() <= D
    assert e.mean() == pytest.approx(clock.delay_mean_s, abs=4 * D / math.sqrt(12 * n))
    assert clock.delay_mean_s == D / 2
    assert sensor_truth(ImuErrors.ideal(), clock)["time_offset_s"] == pytest.approx(clock.offset_s + D / 2)


def test_host_offsets_are_the_stated_lag():
    offsets = np.array([draw_clock(HOST, np.random.default_rng(s)).offset_s for s in range(400)])
    assert offsets.min() >= 0.075 and offsets.max() <= 0.095
    assert offsets.mean() == pytest.approx(0.085, abs=4 * 0.01 / math.sqrt(3 * 400))


def test_gap_count_durations_and_steps_follow_the_model():
    model = get_clock_model("host-gaps")
    duration = 300.0
    clocks = [draw_clock(model, np.random.default_rng([11, s]), duration) for s in range(400)]
    counts = np.array([c.gaps.shape[0] for c in clocks])
    mean = model.gap_rate_hz * duration  # Poisson: variance = mean
    assert counts.mean() == pytest.approx(mean, abs=4 * math.sqrt(mean / counts.size))
    assert counts.var() == pytest.approx(mean, rel=0.25)
    gaps = np.concatenate([c.gaps for c in clocks])
    assert np.all((gaps[:, 0] >= 0) & (gaps[:, 0] <= duration))
    assert np.all((gaps[:, 1] >= model.gap_min_s) & (gaps[:, 1] <= model.gap_max_s))
    n = gaps.shape[0]
    assert gaps[:, 1].mean() == pytest.approx(0.5, abs=4 * 0.4 / math.sqrt(12 * n))
    assert gaps[:, 2].std() == pytest.approx(model.step_std_s, rel=4 / math.sqrt(2 * n))
    assert all(np.all(np.diff(c.gaps[:, 0]) >= 0) for c in clocks)
    # no gaps drawn without a session length, and a clock without gaps keeps its previous draws
    assert draw_clock(model, np.random.default_rng(1)).gaps.shape == (0, 3)
    a, b = draw_clock(HOST, np.random.default_rng(5), 100.0), draw_clock(HOST, np.random.default_rng(5))
    assert a.offset_s == b.offset_s and a.gaps.size == b.gaps.size == 0


def test_samples_in_a_gap_are_lost_and_the_clock_steps_after_it():
    g, d, c = 4.0, 0.6, -0.025
    clock = UnitClock(offset_s=0.09, gaps=[[g, d, c]])
    model = ClockModel(offset_mean_s=0.09)
    t0 = 1.0
    t = t0 + regular(10.0)
    stamps, keep = stamp_samples(model, clock, t, t, t0)
    lost = (t >= t0 + g) & (t < t0 + g + d)
    np.testing.assert_array_equal(keep, ~lost)
    kept = t[keep]
    tau = stamps - kept
    before, after = kept < t0 + g, kept >= t0 + g + d
    np.testing.assert_allclose(tau[before], 0.09, atol=1e-12)
    np.testing.assert_allclose(tau[after], 0.09 + c, atol=1e-12)
    # the stamp gap: the lost span (d to d + 2T on the sample grid) plus the step
    k = int(np.argmax(after))
    assert d + c < stamps[k] - stamps[k - 1] < d + c + 2 * T
    np.testing.assert_allclose(clock.error(np.array([t0 + g + d - 1e-9, t0 + g + d]), t0), [0.09, 0.09 + c])


def test_gap_truth_is_recorded_on_the_session_clock():
    model = get_clock_model("host-gaps")
    rng = np.random.default_rng(2)
    t0 = 5.0
    t = t0 + regular(200.0)
    clock, stamps, keep = unit_clock_stamps(model, rng, t, t, t0)
    assert clock.gaps.shape[0] > 0
    truth = sensor_truth(ImuErrors.ideal(), clock, t0)
    np.testing.assert_allclose(truth["clock_gap_start_s"], t0 + clock.gaps[:, 0])
    np.testing.assert_allclose(truth["clock_gap_end_s"], t0 + clock.gaps[:, 0] + clock.gaps[:, 1])
    np.testing.assert_allclose(truth["clock_step_s"], clock.gaps[:, 2])
    assert truth["clock_host_delay_mean_s"] == model.host_delay_max_s / 2
    start, end = truth["clock_gap_start_s"], truth["clock_gap_end_s"]
    assert np.all(start >= t0)
    inside = np.zeros(t.shape, dtype=bool)
    for s, e in zip(start, end, strict=True):
        inside |= (t >= s) & (t < e)
    np.testing.assert_array_equal(keep, ~inside)
    # merged gaps show as stamp spacings longer than any regular one
    inner = end < t[-1]  # a gap past the last sample leaves no spacing
    start, end = start[inner], end[inner]
    merged = 1 + int(np.sum(start[1:] > np.maximum.accumulate(end)[:-1]))
    assert int(np.sum(np.diff(stamps) > model.gap_min_s / 2)) == merged
    assert np.all(np.diff(stamps) > 0)
    # without gaps the truth has no gap keys (the truth of every other preset is unchanged)
    plain = sensor_truth(ImuErrors.ideal(), draw_clock(get_clock_model("driver"), rng, 100.0))
    assert not {"clock_gap_start_s", "clock_step_s", "clock_host_delay_mean_s"} & set(plain)


# --------------------------------------------------------------------------- gyroscope scale, misalignment
def test_gyro_scale_and_misalignment_closed_form():
    """w_m = diag(1 + s_g) (I + S_g) w + b_g: a rate about axis j reads column j of D_g M_g."""
    scale = np.array([1.04, 0.97, 1.055])
    mis = np.array([[1.0, 0.01, -0.02], [0.015, 1.0, 0.005], [-0.01, 0.02, 1.0]])
    bias = np.array([0.01, -0.02, 0.03])
    errors = ImuErrors(np.zeros(3), np.ones(3), np.eye(3), bias, 0.0, scale, mis)
    model = ImuModel()
    omega = 1.3
    w = np.zeros((3, 3))
    np.fill_diagonal(w, omega)
    _, gyro = apply_imu_model(model, errors, np.zeros((3, 3)), w)
    expected = omega * (scale[:, None] * mis).T + bias  # row j: the reading of a rate about axis j
    np.testing.assert_allclose(gyro, expected, rtol=0, atol=1e-14)
    truth = errors.gyro_truth()
    np.testing.assert_array_equal(truth["gyro_scale"], scale)
    np.testing.assert_array_equal(truth["gyro_misalignment"], mis)


def test_gyro_errors_are_drawn_with_the_stated_spread():
    model = get_imu_model("real-consumer")
    assert (model.gyro_scale_std, model.gyro_misalignment_std) == (0.045, 0.01)
    assert model.rate_hz == 100.0 and model.accel_lsb == pytest.approx(4 * 9.80665 / 2**15)
    draws = [draw_imu_errors(model, np.random.default_rng([9, k])) for k in range(2000)]
    s = np.array([e.gyro_scale for e in draws]) - 1.0
    M = np.array([e.gyro_misalignment for e in draws])
    n = s.size
    assert s.std() == pytest.approx(0.045, rel=4 / math.sqrt(2 * n))
    assert abs(s.mean()) <= 4 * 0.045 / math.sqrt(n)
    np.testing.assert_array_equal(M[:, [0, 1, 2], [0, 1, 2]], 1.0)
    off = M[:, ~np.eye(3, dtype=bool)]
    assert off.std() == pytest.approx(0.01, rel=4 / math.sqrt(2 * off.size))
    # general, not symmetric: the upper and lower entries are independent
    upper, lower = M[:, 0, 1], M[:, 1, 0]
    assert abs(np.corrcoef(upper, lower)[0, 1]) <= 4 / math.sqrt(len(draws))


def test_presets_without_gyro_errors_draw_as_before():
    for name in ("none", "datasheet", "realistic", "real"):
        model = get_imu_model(name)
        e = draw_imu_errors(model, np.random.default_rng(8))
        assert e.gyro_is_ideal and e.gyro_truth() == {}
        # the generator is left where the draws before gyroscope errors left it: bias, scale,
        # misalignment, gyro bias (and the latency spread when set), nothing more
        a, b = np.random.default_rng(8), np.random.default_rng(8)
        draw_imu_errors(model, a)
        b.normal(size=3), b.normal(size=3), b.normal(size=(3, 3)), b.normal(size=3)
        if model.latency_std_s > 0:
            b.normal()
        assert a.random() == b.random()
    e = draw_imu_errors(get_imu_model("real-consumer"), np.random.default_rng(8))
    assert not e.gyro_is_ideal and set(e.gyro_truth()) == {"gyro_scale", "gyro_misalignment"}
    with pytest.raises(ConfigError, match="unit diagonal"):
        ImuErrors(np.zeros(3), np.ones(3), np.eye(3), np.zeros(3), 0.0, np.ones(3), 2 * np.eye(3))
