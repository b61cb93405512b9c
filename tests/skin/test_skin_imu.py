"""IMU model: specific force, noise statistics, unit errors, digitisation, timing and presets."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skincal.errors import ConfigError
from skincal.skin.imu import (
    IMU_PRESETS,
    STANDARD_GRAVITY,
    ImuErrors,
    ImuModel,
    angular_rate,
    apply_imu_model,
    draw_imu_errors,
    get_imu_model,
    sample_instants,
    specific_force,
    true_sample_times,
)

G = STANDARD_GRAVITY
DPS = math.pi / 180.0


def test_rest_reading_matches_hand_built_rotation():
    # SU rotated +90 deg about base x: its y axis points up (base +z), its z axis along base -y.
    R_base_su = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    f = specific_force(np.zeros((1, 3)), R_base_su)
    np.testing.assert_allclose(f, [[0.0, 9.81, 0.0]], atol=1e-15)
    # Upside down about x by 180 deg: reads -9.81 along its z.
    f = specific_force(np.zeros((1, 3)), np.diag([1.0, -1.0, -1.0]))
    np.testing.assert_allclose(f, [[0.0, 0.0, -9.81]], atol=1e-15)


def test_specific_force_and_rate_against_scipy(rng):
    rot = Rotation.random(500, random_state=3)
    a_base = rng.normal(size=(500, 3))
    w_base = rng.normal(size=(500, 3))
    expected_f = rot.inv().apply(a_base - np.array([0.0, 0.0, -9.81]))
    np.testing.assert_allclose(specific_force(a_base, rot.as_matrix()), expected_f, atol=1e-12)
    np.testing.assert_allclose(angular_rate(w_base, rot.as_matrix()), rot.inv().apply(w_base), atol=1e-12)
    with pytest.raises(ConfigError, match="R_base_su"):
        specific_force(a_base, np.eye(4))


def test_noise_std_is_density_times_sqrt_bandwidth():
    model = ImuModel(accel_noise_density=90e-6 * G, gyro_noise_density=7e-3 * DPS, bandwidth_hz=50.0)
    n = 200_000
    f = np.tile([0.0, 0.0, 9.81], (n, 1))
    accel, gyro = apply_imu_model(model, ImuErrors.ideal(), f, np.zeros((n, 3)), np.random.default_rng(1))
    expected_a = 90e-6 * G * math.sqrt(50.0)
    expected_g = 7e-3 * DPS * math.sqrt(50.0)
    np.testing.assert_allclose((accel - f).std(axis=0), expected_a, rtol=0.01)
    np.testing.assert_allclose(gyro.std(axis=0), expected_g, rtol=0.01)
    np.testing.assert_allclose((accel - f).mean(axis=0), 0.0, atol=4 * expected_a / math.sqrt(n))
    # independent axes
    assert abs(np.corrcoef((accel - f).T)[0, 1]) < 0.01


def test_bias_scale_misalignment_recovered_from_designed_input():
    errors = draw_imu_errors(get_imu_model("realistic"), np.random.default_rng(4))
    # Designed input: the six +-axis rest orientations plus diagonal ones, spanning R^3 with an offset.
    dirs = np.vstack([np.eye(3), -np.eye(3), Rotation.random(20, random_state=5).apply([0.0, 0.0, 1.0])])
    f = 9.81 * dirs
    model = ImuModel()  # no noise, no digitisation: the linear part only
    accel, _ = apply_imu_model(model, errors, f)
    X = np.hstack([f, np.ones((len(f), 1))])
    coef, *_ = np.linalg.lstsq(X, accel, rcond=None)
    A, b = coef[:3].T, coef[3]
    scale = np.diag(A)  # M has a unit diagonal, so diag(D M) = D
    M = A / scale[:, None]
    np.testing.assert_allclose(b, errors.accel_bias, atol=1e-12)
    np.testing.assert_allclose(scale, errors.accel_scale, atol=1e-12)
    np.testing.assert_allclose(M, errors.accel_misalignment, atol=1e-12)
    np.testing.assert_allclose(M, M.T, atol=1e-12)
    assert np.abs(M - np.eye(3)).max() > 1e-4, "misalignment was drawn"


def test_error_draws_have_stated_statistics():
    model = get_imu_model("realistic")
    rng = np.random.default_rng(6)
    draws = [draw_imu_errors(model, rng) for _ in range(4000)]
    bias = np.array([d.accel_bias for d in draws])
    scale = np.array([d.accel_scale for d in draws])
    mis = np.array([d.accel_misalignment for d in draws])
    gyro = np.array([d.gyro_bias for d in draws])
    np.testing.assert_allclose(bias.std(axis=0), 0.040 * G, rtol=0.05)
    np.testing.assert_allclose(scale.std(axis=0), 0.01, rtol=0.05)
    np.testing.assert_allclose(gyro.std(axis=0), 10.0 * DPS, rtol=0.05)
    off = mis[:, [0, 0, 1], [1, 2, 2]]
    np.testing.assert_allclose(off.std(axis=0), 0.005, rtol=0.05)
    np.testing.assert_array_equal(mis[:, [0, 1, 2], [0, 1, 2]], 1.0)
    np.testing.assert_array_equal(mis, np.swapaxes(mis, 1, 2))
    ideal = draw_imu_errors(get_imu_model("none"), rng)
    for name in ("accel_bias", "accel_scale", "accel_misalignment", "gyro_bias"):
        np.testing.assert_array_equal(getattr(ideal, name), getattr(ImuErrors.ideal(), name))


def test_saturation_clips_at_full_scale():
    model = get_imu_model("datasheet")
    f = np.array([[3 * G, -5 * G, 0.5 * G]])
    w = np.array([[10.0, -10.0, 1.0]])
    model_quiet = ImuModel(
        accel_range=model.accel_range, accel_lsb=model.accel_lsb, gyro_range=model.gyro_range, gyro_lsb=model.gyro_lsb
    )
    accel, gyro = apply_imu_model(model_quiet, ImuErrors.ideal(), f, w)
    assert accel[0, 0] == pytest.approx(2 * G, abs=model.accel_lsb)
    assert accel[0, 1] == pytest.approx(-2 * G, abs=model.accel_lsb)
    assert abs(accel[0, 0]) <= 2 * G and abs(gyro[0, 0]) <= 245 * DPS
    assert accel[0, 2] == pytest.approx(0.5 * G, abs=model.accel_lsb / 2)
    np.testing.assert_allclose(gyro[0, :2], [245 * DPS, -245 * DPS], atol=model.gyro_lsb)
    # unquantised saturation clips exactly to the range
    accel, _ = apply_imu_model(ImuModel(accel_range=2 * G), ImuErrors.ideal(), f)
    np.testing.assert_array_equal(accel[0, :2], [2 * G, -2 * G])


def test_quantisation_step_equals_lsb():
    model = get_imu_model("datasheet")
    quiet = ImuModel(accel_lsb=model.accel_lsb, gyro_lsb=model.gyro_lsb)
    ramp = np.linspace(-0.1, 0.1, 20_001)
    f = np.stack([ramp, ramp + 9.81, -ramp], axis=1)
    accel, gyro = apply_imu_model(quiet, ImuErrors.ideal(), f, f / 10.0)
    for out, lsb in ((accel, model.accel_lsb), (gyro, model.gyro_lsb)):
        counts = out / lsb
        np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
        steps = np.diff(np.unique(out[:, 0]))
        np.testing.assert_allclose(steps, lsb, rtol=1e-6)
        assert np.abs(out - (f if out is accel else f / 10.0)).max() <= lsb / 2 + 1e-12
    assert model.accel_lsb == pytest.approx(0.061e-3 * G)


def test_sample_instants_drops_and_jitter():
    model = ImuModel(rate_hz=100.0, jitter_s=0.001, drop_probability=0.01)
    t = sample_instants(model, 2.0, 1002.0, np.random.default_rng(8))
    n_nominal = 100_000
    assert np.all(np.diff(t) > 0) and t[0] >= 2.0 and t[-1] <= 1002.0
    kept = len(t) / n_nominal
    assert kept == pytest.approx(0.99, abs=4 * math.sqrt(0.01 * 0.99 / n_nominal))
    # jitter: residual from the nominal grid, phase estimated as the circular mean
    angle = 2 * np.pi * 100.0 * (t - 2.0)
    phase = np.angle(np.exp(1j * angle).mean())
    resid = np.angle(np.exp(1j * (angle - phase))) / (2 * np.pi * 100.0)
    assert resid.std() == pytest.approx(0.001, rel=0.03)


def test_sample_instants_regular_without_jitter():
    model = ImuModel(rate_hz=50.0)
    t = sample_instants(model, 0.0, 10.0, np.random.default_rng(9))
    np.testing.assert_allclose(np.diff(t), 0.02, atol=1e-12)
    assert 0.0 <= t[0] < 0.02 and len(t) in (500, 501)
    t2 = sample_instants(model, 0.0, 10.0, np.random.default_rng(10))
    assert t2[0] != t[0], "each unit gets its own phase"
    with pytest.raises(ConfigError, match="t_start"):
        sample_instants(model, 1.0, 0.0, np.random.default_rng(0))


def test_latency_helper():
    errors = draw_imu_errors(get_imu_model("realistic"), np.random.default_rng(11))
    assert errors.latency_s == pytest.approx(0.015)
    np.testing.assert_allclose(true_sample_times([1.0, 2.5], errors), [0.985, 2.485])
    assert true_sample_times(np.array([3.0]), ImuErrors.ideal())[0] == 3.0


def test_presets_have_stated_values():
    assert set(IMU_PRESETS) >= {"none", "datasheet", "realistic"}
    none = get_imu_model("none")
    assert none.accel_noise_std == 0 and none.gyro_noise_std == 0
    assert none.accel_lsb == 0 and math.isinf(none.accel_range) and math.isinf(none.gyro_range)
    assert none.latency_s == 0 and none.jitter_s == 0 and none.drop_probability == 0
    f = np.array([[0.1, -0.2, 9.81]])
    np.testing.assert_array_equal(apply_imu_model(none, draw_imu_errors(none, np.random.default_rng(0)), f)[0], f)

    ds = get_imu_model("datasheet")
    assert ds.rate_hz == 100.0 and ds.bandwidth_hz == 50.0
    assert ds.accel_noise_density == pytest.approx(90e-6 * G)
    assert ds.gyro_noise_density == pytest.approx(7e-3 * DPS)
    assert ds.accel_range == pytest.approx(2 * G) and ds.accel_lsb == pytest.approx(0.061e-3 * G)
    assert ds.gyro_range == pytest.approx(245 * DPS) and ds.gyro_lsb == pytest.approx(8.75e-3 * DPS)
    assert ds.accel_bias_std == ds.accel_scale_std == ds.misalignment_std == ds.latency_s == 0

    re = get_imu_model("realistic")
    assert re.accel_noise_density == pytest.approx(5 * ds.accel_noise_density)
    assert re.gyro_noise_density == pytest.approx(5 * ds.gyro_noise_density)
    assert re.accel_bias_std == pytest.approx(0.040 * G)
    assert re.accel_scale_std == pytest.approx(0.01) and re.misalignment_std == pytest.approx(0.005)
    assert re.latency_s == pytest.approx(0.015) and re.jitter_s == pytest.approx(0.001)
    assert re.drop_probability == pytest.approx(0.01)

    with pytest.raises(ConfigError, match="none, datasheet, realistic"):
        get_imu_model("lsm9000")


def test_bad_model_values_rejected():
    with pytest.raises(ConfigError, match="drop_probability"):
        ImuModel(drop_probability=1.0)
    with pytest.raises(ConfigError, match="rate_hz"):
        ImuModel(rate_hz=0.0)
    with pytest.raises(ConfigError, match="accel_bias_std"):
        ImuModel(accel_bias_std=-1.0)
    with pytest.raises(ConfigError, match="rng"):
        apply_imu_model(get_imu_model("datasheet"), ImuErrors.ideal(), np.zeros((2, 3)))
    with pytest.raises(ConfigError, match="symmetric"):
        ImuErrors(np.zeros(3), np.ones(3), np.eye(3) + np.triu(np.ones((3, 3)), 1) * 0.01, np.zeros(3))


def test_real_preset_has_the_measured_figures():
    real = get_imu_model("real")
    assert real.rate_hz == 62.5 and real.bandwidth_hz == 31.25
    assert real.accel_noise_density == 0.014 and real.gyro_noise_density == 2.0e-3
    assert real.accel_bias_std == 0.35 and real.accel_scale_std == 0.03 and real.misalignment_std == 0.01
    assert real.gyro_bias_std == pytest.approx(12.0 * DPS)
    assert real.accel_range == pytest.approx(8 * G) and real.gyro_range == pytest.approx(2000 * DPS)
    assert real.accel_lsb == pytest.approx(2.39e-3, rel=2e-3) and real.gyro_lsb == pytest.approx(1.07e-3, rel=5e-3)
    assert real.latency_s == 0.015 and real.drop_probability == 0.01 and real.jitter_s == 0.0
    assert get_imu_model("realistic").rate_hz == 100.0  # kept


def test_real_preset_noise_and_lsb_from_a_rest_simulation():
    from skincal.data.dataset import STATIC
    from skincal.kinematics import panda
    from skincal.protocol import ProtocolConfig, build_trajectory
    from skincal.sim.analytic import simulate
    from skincal.skin.placement import paper_placement

    chain = panda()
    config = ProtocolConfig(n_poses=2, excite_duration=0.5, rest_duration=4.0, static_duration=3.5, excited_joints=(0,))
    traj = build_trajectory(chain, config, np.random.default_rng(1))
    model = get_imu_model("real")
    ds = simulate(chain, paper_placement(chain), traj, model, np.random.default_rng(2))
    seg = ds.segments
    accel_res, gyro_res = [], []
    for name, stream in ds.imu.items():
        t_true = stream.t - ds.truth_sensor[name]["time_offset_s"]
        # Digitised: every reading is a whole number of LSBs, and the finest step seen is one LSB.
        for x, lsb in ((stream.accel, model.accel_lsb), (stream.gyro, model.gyro_lsb)):
            np.testing.assert_allclose(x / lsb, np.round(x / lsb), atol=1e-6)
            levels = np.unique(x[:, 0])
            assert np.diff(levels).min() == pytest.approx(lsb, rel=1e-6)
        for t0, t1 in zip(seg.t_start[seg.kind == STATIC], seg.t_end[seg.kind == STATIC], strict=True):
            rest = (t_true > t0) & (t_true < t1)
            assert rest.sum() > 150
            accel_res.append(stream.accel[rest] - stream.accel[rest].mean(axis=0))
            gyro_res.append(stream.gyro[rest] - stream.gyro[rest].mean(axis=0))
    accel_res, gyro_res = np.vstack(accel_res), np.vstack(gyro_res)
    assert accel_res.std() == pytest.approx(0.014 * math.sqrt(31.25), rel=0.1)  # 0.078 m/s^2
    assert gyro_res.std() == pytest.approx(2.0e-3 * math.sqrt(31.25), rel=0.1)  # 0.011 rad/s
