"""Unit clocks: the stamp error sawtooth, free-running drift, offsets, quantum, and the simulators' stamps."""

from __future__ import annotations

import math

import h5py
import numpy as np
import pytest

from skincal.data.hdf5 import read_dataset, write_dataset
from skincal.errors import ConfigError
from skincal.kinematics import panda
from skincal.protocol import ProtocolConfig, build_trajectory
from skincal.sim.analytic import simulate, unit_kinematics
from skincal.sim.joint_states import get_joint_model
from skincal.skin.clock import (
    CLOCK_PRESETS,
    ClockModel,
    UnitClock,
    draw_clock,
    get_clock_model,
    increasing_mask,
    stamp_samples,
)
from skincal.skin.imu import (
    ImuModel,
    apply_imu_model,
    draw_imu_errors,
    get_imu_model,
    sample_instants,
    true_sample_times,
)
from skincal.skin.placement import paper_placement

CONFIG = ProtocolConfig(n_poses=3, amplitude=1.5, excite_duration=1.0, rest_duration=0.6, static_duration=0.3)


@pytest.fixture(scope="module")
def session():
    chain = panda()
    traj = build_trajectory(chain, CONFIG, np.random.default_rng(21))
    placements = {k: v for k, v in paper_placement(chain).items() if k in ("su2", "su5", "su6")}
    return chain, traj, placements


def test_presets_have_stated_values():
    assert set(CLOCK_PRESETS) == {"ideal", "driver", "wifi", "wifi-resync", "host", "host-gaps"}
    ideal = get_clock_model("ideal")
    assert ideal.is_ideal and ideal == ClockModel() and math.isinf(ideal.resync_period_s)
    driver = get_clock_model("driver")
    assert (driver.offset_max_s, driver.drift_ppm_mean, driver.drift_ppm_std) == (0.0, -440.0, 50.0)
    assert (driver.resync_period_s, driver.jitter_s, driver.stamp_quantum_s) == (2.51, 0.0, 1e-6)
    wifi = get_clock_model("wifi")
    assert (wifi.offset_max_s, wifi.drift_ppm_mean, wifi.drift_ppm_std) == (0.5, 0.0, 100.0)
    assert math.isinf(wifi.resync_period_s) and (wifi.jitter_s, wifi.stamp_quantum_s) == (1e-3, 1e-6)
    resync = get_clock_model("wifi-resync")
    assert (resync.offset_max_s, resync.drift_ppm_mean, resync.drift_ppm_std) == (0.5, -440.0, 100.0)
    assert (resync.resync_period_s, resync.jitter_s, resync.stamp_quantum_s) == (2.51, 0.0, 1e-6)
    assert not any(get_clock_model(n).is_ideal for n in ("driver", "wifi", "wifi-resync"))
    with pytest.raises(ConfigError, match="ideal, driver, wifi, wifi-resync, host, host-gaps") as info:
        get_clock_model("sundial")
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"offset_max_s": -0.1},
        {"drift_ppm_std": -1.0},
        {"resync_period_s": 0.0},
        {"jitter_s": float("nan")},
        {"stamp_quantum_s": float("inf")},
        {"drift_ppm_mean": "fast"},
    ],
)
def test_bad_clock_models_rejected(kwargs):
    with pytest.raises(ConfigError, match="ClockModel"):
        ClockModel(**kwargs)


def test_bad_unit_clocks_rejected():
    with pytest.raises(ConfigError, match="resync_phase_s"):
        UnitClock(resync_period_s=2.0, resync_phase_s=2.0)
    with pytest.raises(ConfigError, match="finite"):
        UnitClock(offset_s=float("inf"))


def test_tau_is_a_sawtooth_with_forward_steps_at_resyncs():
    clock = UnitClock(offset_s=2e-3, drift_ppm=-440.0, resync_period_s=2.51, resync_phase_s=0.7)
    t0 = 0.3
    syncs = t0 + 0.7 + 2.51 * np.arange(-1, 8)
    after = clock.error(syncs, t0)
    np.testing.assert_allclose(after, 2e-3, atol=1e-12)  # back to the offset at each re-sync
    before = clock.error(syncs - 1e-7, t0)
    steps = after - before
    np.testing.assert_allclose(steps, 440e-6 * 2.51, atol=1e-9)  # |drift| P forward
    # Linear in between with slope drift, falling behind (slow clock).
    t = np.linspace(syncs[2] + 0.01, syncs[3] - 0.01, 50)
    np.testing.assert_allclose(np.diff(clock.error(t, t0)) / np.diff(t), -440e-6, rtol=1e-6)
    np.testing.assert_allclose(clock.sync_instants(t, t0), syncs[2], atol=1e-12)

    # The same steps appear in the stamps of a dense sample stream (no jitter, microsecond quantum).
    model = ClockModel(drift_ppm_mean=-440.0, resync_period_s=2.51, stamp_quantum_s=1e-6)
    t_true = t0 + np.arange(0, 12.0, 0.01)
    stamps, keep = stamp_samples(model, clock, t_true + 0.015, t_true, t0)
    assert keep.all()
    err = stamps - t_true - 0.015
    jumps = np.flatnonzero(np.diff(err) > 5e-4)
    expected = np.searchsorted(t_true, syncs[(syncs > t_true[0]) & (syncs <= t_true[-1])]) - 1
    np.testing.assert_array_equal(jumps, expected)
    np.testing.assert_allclose(np.diff(err)[jumps], 440e-6 * 2.51 - 440e-6 * 0.01, atol=2e-6)


def test_free_running_clock_drifts_linearly():
    model = get_clock_model("wifi")
    rng = np.random.default_rng(3)
    clock = draw_clock(model, rng)
    assert math.isinf(clock.resync_period_s) and clock.resync_phase_s == 0.0
    t0 = 1.0
    t_true = t0 + np.arange(0, 200.0, 1 / 62.5)
    stamps, keep = stamp_samples(model, clock, t_true, t_true, t0, rng)
    assert keep.all()  # 1 ms jitter never reorders 16 ms samples
    slope, intercept = np.polyfit(t_true - t0, stamps - t_true, 1)
    assert slope * 1e6 == pytest.approx(clock.drift_ppm, abs=3.0)
    assert intercept == pytest.approx(clock.offset_s, abs=1e-4)
    resid = stamps - t_true - (intercept + slope * (t_true - t0))
    assert np.std(resid) == pytest.approx(1e-3, rel=0.1)  # the stamp jitter


def test_offsets_and_drifts_follow_the_model():
    model = get_clock_model("wifi-resync")
    rng = np.random.default_rng(7)
    clocks = [draw_clock(model, rng) for _ in range(3000)]
    offsets = np.array([c.offset_s for c in clocks])
    drifts = np.array([c.drift_ppm for c in clocks])
    phases = np.array([c.resync_phase_s for c in clocks])
    assert np.all(np.abs(offsets) <= 0.5) and offsets.max() > 0.48 and offsets.min() < -0.48
    assert drifts.mean() == pytest.approx(-440.0, abs=6.0) and drifts.std() == pytest.approx(100.0, rel=0.1)
    assert np.all((phases >= 0) & (phases < 2.51)) and phases.max() > 2.4
    assert {c.resync_period_s for c in clocks} == {2.51}


def test_quantised_stamps_stay_strictly_increasing():
    model = ClockModel(stamp_quantum_s=1e-3)
    t_true = np.arange(0, 1.0, 1 / 2000.0)  # two samples per quantum: every other one collides
    stamps, keep = stamp_samples(model, UnitClock(), t_true, t_true, 0.0)
    counts = stamps / 1e-3
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
    assert np.all(np.diff(stamps) > 0)
    assert 0.4 < keep.mean() < 0.6
    np.testing.assert_array_equal(increasing_mask([0.0, 1.0, 1.0, 0.5, 2.0, 1.5, 3.0]), [1, 1, 0, 0, 1, 0, 1])


def _old_path(chain, placements, traj, model, seed):
    """The analytic simulator's IMU streams as written before clock models (kept here verbatim)."""
    rng = np.random.default_rng(seed)
    t0, t1 = float(traj.t[0]), float(traj.t[-1])
    out = {}
    for (name, pose), unit_rng in zip(placements.items(), rng.spawn(len(placements)), strict=True):
        errors = draw_imu_errors(model, unit_rng)
        t_stamp = sample_instants(model, t0 + errors.latency_s, t1 + min(errors.latency_s, 0.0), unit_rng)
        t_true = true_sample_times(t_stamp, errors)
        inside = (t_true >= t0) & (t_true <= t1)
        f_su, w_su, _, _ = unit_kinematics(chain, pose, traj, t_true[inside])
        accel, gyro = apply_imu_model(model, errors, f_su, w_su, unit_rng)
        out[name] = (t_stamp[inside], accel, gyro, errors.latency_s)
    return out


@pytest.mark.parametrize("noise", ["realistic", "real"])
def test_ideal_clock_reproduces_the_previous_simulator(session, noise):
    chain, traj, placements = session
    model = get_imu_model(noise)
    old = _old_path(chain, placements, traj, model, 4)
    default = simulate(chain, placements, traj, model, np.random.default_rng(4))
    ideal = simulate(chain, placements, traj, model, np.random.default_rng(4), clock_model=get_clock_model("ideal"))
    for ds in (default, ideal):
        for name, (t, accel, gyro, latency) in old.items():
            np.testing.assert_array_equal(ds.imu[name].t, t)
            np.testing.assert_array_equal(ds.imu[name].accel, accel)
            np.testing.assert_array_equal(ds.imu[name].gyro, gyro)
            assert ds.truth_sensor[name]["time_offset_s"] == latency
            assert ds.truth_sensor[name]["clock_drift_ppm"] == 0.0
            assert "clock_resync_period_s" not in ds.truth_sensor[name]
        np.testing.assert_array_equal(ds.joints.q, traj.q)


@pytest.mark.parametrize("clock", ["driver", "wifi", "wifi-resync"])
def test_clock_changes_only_the_stamps(session, clock):
    chain, traj, placements = session
    model = get_imu_model("real")
    ideal = simulate(chain, placements, traj, model, np.random.default_rng(4))
    other = simulate(chain, placements, traj, model, np.random.default_rng(4), clock_model=get_clock_model(clock))
    for name in placements:
        a, b = ideal.imu[name], other.imu[name]
        np.testing.assert_array_equal(b.accel, a.accel)  # same readings, same noise draws (none dropped)
        np.testing.assert_array_equal(b.gyro, a.gyro)
        assert np.all(np.diff(b.t) > 0)
        assert np.abs(b.t - a.t).max() > 1e-4  # the stamps moved
        np.testing.assert_allclose(b.t / 1e-6, np.round(b.t / 1e-6), atol=1e-5)  # microsecond stamps
        truth = other.truth_sensor[name]
        assert abs(truth["time_offset_s"] - 0.015) <= 0.5
        assert truth["clock_drift_ppm"] != 0.0
        assert ("clock_resync_period_s" in truth) == (clock != "wifi")
    np.testing.assert_array_equal(other.joints.q, ideal.joints.q)


def test_free_running_stamps_measure_drift_and_offset(session):
    chain, traj, placements = session
    imu = ImuModel(rate_hz=62.5, latency_s=0.015)  # no jitter, no drops: sample k is at phase + k / rate
    clock = ClockModel(offset_max_s=0.5, drift_ppm_mean=300.0, drift_ppm_std=100.0)
    ds = simulate(chain, placements, traj, imu, np.random.default_rng(8), clock_model=clock)
    t0 = float(traj.t[0])
    for name, pose in placements.items():
        stream, truth = ds.imu[name], ds.truth_sensor[name]
        k = np.arange(stream.t.size)
        slope, _ = np.polyfit(k, stream.t, 1)
        assert (slope * 62.5 - 1.0) * 1e6 == pytest.approx(truth["clock_drift_ppm"], abs=0.01)
        d = 1e-6 * truth["clock_drift_ppm"]
        # Invert t_stamp = t + time_offset + d (t - t0): the readings are of the physical instants.
        t_true = (stream.t - truth["time_offset_s"] + d * t0) / (1.0 + d)
        assert t_true[0] >= t0 and t_true[0] < t0 + 1 / 62.5 + 1e-9
        f_su, _, _, _ = unit_kinematics(chain, pose, traj, t_true)
        np.testing.assert_allclose(stream.accel, f_su, atol=1e-7)
        late, _, _, _ = unit_kinematics(chain, pose, traj, stream.t - 0.015)
        assert np.abs(stream.accel - late).max() > 1e-2  # the clock error is visible


def test_truth_round_trips_through_hdf5(session, tmp_path):
    chain, traj, placements = session
    for clock in ("driver", "wifi"):
        ds = simulate(
            chain,
            placements,
            traj,
            get_imu_model("real"),
            np.random.default_rng(2),
            clock_model=get_clock_model(clock),
            joint_model=get_joint_model("controller"),
        )
        path = tmp_path / f"{clock}.h5"
        write_dataset(ds, path)
        back = read_dataset(path)
        for name in placements:
            assert set(back.truth_sensor[name]) == set(ds.truth_sensor[name])
            for key, value in ds.truth_sensor[name].items():
                np.testing.assert_array_equal(back.truth_sensor[name][key], value)
            np.testing.assert_array_equal(back.imu[name].t, ds.imu[name].t)
        with h5py.File(path, "r") as f:
            attrs = f["/truth/su2"].attrs
            assert ("clock_resync_period_s" in attrs) == (clock == "driver")
            assert float(attrs["clock_drift_ppm"]) == ds.truth_sensor["su2"]["clock_drift_ppm"]


def test_mujoco_stamps_match_the_analytic_simulator(session):
    pytest.importorskip("mujoco")
    from skincal.sim.mujoco_backend import simulate_mujoco

    chain, traj, placements = session
    model, clock = get_imu_model("real"), get_clock_model("wifi")
    a = simulate(chain, placements, traj, model, np.random.default_rng(6), clock_model=clock)
    m = simulate_mujoco(chain, placements, traj, model, np.random.default_rng(6), clock_model=clock)
    for name in placements:
        np.testing.assert_array_equal(m.imu[name].t, a.imu[name].t)
        assert set(m.truth_sensor[name]) == set(a.truth_sensor[name])
        for key, value in a.truth_sensor[name].items():
            np.testing.assert_array_equal(m.truth_sensor[name][key], value)
        np.testing.assert_allclose(m.imu[name].accel, a.imu[name].accel, atol=0.02)  # noise 0.08, LSB 2.4e-3
