"""skincal.sim.faults: each fault against its closed form on a tiny simulated dataset."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skincal.data.dataset import STATIC
from skincal.errors import ConfigError
from skincal.kinematics import get_robot
from skincal.kinematics.transforms import rotation_angle
from skincal.protocol import build_trajectory, get_protocol
from skincal.sim import faults
from skincal.sim.analytic import simulate
from skincal.skin.imu import get_imu_model
from skincal.skin.placement import random_placement

TINY = dict(n_poses=2, rate_hz=200.0, excite_duration=1.0, rest_duration=1.0, static_duration=0.5)


@pytest.fixture(scope="module")
def setup():
    chain = get_robot("panda")
    rng = np.random.default_rng(7)
    placements = random_placement(chain, 2, rng, links=[4, 7])
    trajectory = build_trajectory(chain, replace(get_protocol("paper-sim"), **TINY), rng)
    return chain, placements, trajectory


def run(setup, placements=None, gravity=None, noise="realistic"):
    chain, default, trajectory = setup
    kw = {} if gravity is None else {"gravity": gravity}
    return simulate(chain, placements or default, trajectory, get_imu_model(noise), np.random.default_rng(11), **kw)


@pytest.fixture(scope="module")
def ds(setup):
    return run(setup)


def test_shift_imu_stamps(ds):
    out = faults.shift_imu_stamps(ds, 0.4)
    for u in ds.units:
        np.testing.assert_array_equal(out.imu[u].t, ds.imu[u].t + 0.4)
        np.testing.assert_array_equal(out.imu[u].accel, ds.imu[u].accel)
        assert out.truth_sensor[u]["time_offset_s"] == pytest.approx(ds.truth_sensor[u]["time_offset_s"] + 0.4)
    assert ds.truth_sensor["su1"]["time_offset_s"] == pytest.approx(0.015)  # the input is untouched
    one = faults.shift_imu_stamps(ds, -0.1, units=["su2"])
    assert one.imu["su1"] is ds.imu["su1"] and np.allclose(one.imu["su2"].t, ds.imu["su2"].t - 0.1)


def test_saturate_accel(ds):
    r = 12.0
    out = faults.saturate_accel(ds, r)
    for u in ds.units:
        np.testing.assert_array_equal(out.imu[u].accel, np.clip(ds.imu[u].accel, -r, r))
        assert out.truth_sensor[u]["accel_range_mps2"] == r
    assert np.abs(ds.imu["su2"].accel).max() > r  # the tiny session does reach the range
    with pytest.raises(ConfigError):
        faults.saturate_accel(ds, 0.0)


def test_stick_axis_is_constant_from_t(ds):
    t = ds.imu["su1"].t
    t_s = float(t[len(t) // 2]) + 1e-4  # between two samples
    out = faults.stick_axis(ds, "su1", 2, t_s)
    a, b = ds.imu["su1"].accel, out.imu["su1"].accel
    late = t >= t_s
    k_last = np.flatnonzero(~late)[-1]
    assert np.all(b[late, 2] == a[k_last, 2])  # constant from t_s: the last value before it
    np.testing.assert_array_equal(b[~late], a[~late])
    np.testing.assert_array_equal(b[:, :2], a[:, :2])
    np.testing.assert_array_equal(out.imu["su2"].accel, ds.imu["su2"].accel)
    assert out.truth_sensor["su1"]["accel_stuck_axis"] == 2.0
    assert out.truth_sensor["su1"]["accel_stuck_from_s"] == t_s
    assert out.truth_sensor["su1"]["accel_stuck_value_mps2"] == a[k_last, 2]


def test_drift_bias_is_a_ramp_of_the_given_size(ds):
    t0, t1 = faults.session_span(ds)
    u = np.array([1.0, 2.0, 2.0]) / 3.0
    out = faults.drift_bias(ds, 0.05, directions={"su1": u, "su2": -u})
    for name, sign in (("su1", 1.0), ("su2", -1.0)):
        t = ds.imu[name].t
        delta = out.imu[name].accel - ds.imu[name].accel
        ramp = np.clip((t - t0) / (t1 - t0), 0.0, 1.0)
        np.testing.assert_allclose(delta, sign * 0.05 * ramp[:, None] * u, atol=1e-12)
        np.testing.assert_allclose(out.truth_sensor[name]["accel_bias_drift_mps2"], sign * 0.05 * u)
    drawn = faults.drift_bias(ds, 0.05, rng=np.random.default_rng(0))
    for name in ds.units:
        assert np.linalg.norm(drawn.truth_sensor[name]["accel_bias_drift_mps2"]) == pytest.approx(0.05)
    # the ramp grows by exactly 0.05 m/s^2 over the session
    t = ds.imu["su1"].t
    slope = np.diff(out.imu["su1"].accel - ds.imu["su1"].accel, axis=0) / np.diff(t)[:, None]
    np.testing.assert_allclose(np.linalg.norm(slope, axis=1), 0.05 / (t1 - t0), rtol=1e-6)


def test_knock_splices_the_two_simulations(setup, ds):
    _, placements, _ = setup
    moved = faults.knocked_pose(placements["su2"], 0.03, 10.0, np.random.default_rng(3))
    assert np.linalg.norm(moved.p_link_su - placements["su2"].p_link_su) == pytest.approx(0.03)
    assert np.degrees(rotation_angle(moved.R_link_su, placements["su2"].R_link_su)) == pytest.approx(10.0)
    after = run(setup, {**placements, "su2": moved})
    t0, t1 = faults.session_span(ds)
    t_s = t0 + 0.7 * (t1 - t0)
    out = faults.simulate_knock(lambda pl: run(setup, pl), placements, "su2", t_s, moved)
    t = ds.imu["su2"].t
    early = t < t_s
    assert 0 < early.sum() < t.size
    for field in ("accel", "gyro"):
        got = getattr(out.imu["su2"], field)
        np.testing.assert_array_equal(got[early], getattr(ds.imu["su2"], field)[early])
        np.testing.assert_array_equal(got[~early], getattr(after.imu["su2"], field)[~early])
        np.testing.assert_array_equal(getattr(out.imu["su1"], field), getattr(ds.imu["su1"], field))
    # the truth is the pose held for the larger part of the session (here: before the knock)
    assert out.truth["su2"] is placements["su2"]
    np.testing.assert_array_equal(out.truth_sensor["su2"]["knock_T_link_su_after"], moved.T_link_su)
    np.testing.assert_array_equal(out.truth_sensor["su2"]["knock_T_link_su_before"], placements["su2"].T_link_su)
    early_knock = faults.splice_knock(ds, after, "su2", t0 + 0.2 * (t1 - t0))
    assert early_knock.truth["su2"] is moved
    other_seed = simulate(setup[0], placements, setup[2], get_imu_model("realistic"), np.random.default_rng(12))
    with pytest.raises(ConfigError, match="same seed"):
        faults.splice_knock(ds, other_seed, "su2", t_s)


def test_gravity_mismatch_static_reading(setup):
    out = faults.simulate_gravity_mismatch(lambda g: run(setup, gravity=g, noise="none"), 9.796, 9.81)
    np.testing.assert_allclose(out.gravity, [0.0, 0.0, -9.81])
    seg = out.segments
    k = int(np.flatnonzero(seg.kind == STATIC)[0])
    for name in out.units:
        s = out.imu[name]
        inside = (s.t > seg.t_start[k]) & (s.t < seg.t_end[k])
        assert inside.any()
        np.testing.assert_allclose(np.linalg.norm(s.accel[inside], axis=1), 9.796, atol=1e-9)
        np.testing.assert_allclose(out.truth_sensor[name]["gravity_true_mps2"], [0.0, 0.0, -9.796])


def test_faulted_dataset_round_trips_hdf5(ds, tmp_path):
    from skincal.data.hdf5 import read_dataset, write_dataset

    out = faults.stick_axis(faults.drift_bias(ds, 0.05, rng=np.random.default_rng(1)), "su1", 0, 1.0)
    out = faults.declare_gravity(out, [0.0, 0.0, -9.81])
    write_dataset(out, tmp_path / "f.h5")
    back = read_dataset(tmp_path / "f.h5")
    assert back.truth_sensor["su1"]["accel_stuck_axis"] == 0.0
    np.testing.assert_allclose(back.truth_sensor["su2"]["accel_bias_drift_mps2"],
                               out.truth_sensor["su2"]["accel_bias_drift_mps2"])
