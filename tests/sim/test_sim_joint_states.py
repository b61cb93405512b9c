"""Joint states as hardware reports them: rate, encoder steps, velocity noise, latency, jitter, qdd;
both simulators and the command line."""

from __future__ import annotations

import math
from dataclasses import replace

import h5py
import numpy as np
import pytest

from skincal.cli import main
from skincal.data.dataset import STATIC
from skincal.data.hdf5 import read_dataset, write_dataset
from skincal.errors import ConfigError
from skincal.kinematics import panda
from skincal.protocol import ProtocolConfig, build_trajectory
from skincal.sim.analytic import simulate
from skincal.sim.joint_states import (
    JOINT_PRESETS,
    JointStateModel,
    apply_joint_state_model,
    get_joint_model,
    joint_sample_instants,
)
from skincal.skin.imu import get_imu_model
from skincal.skin.placement import paper_placement
from skincal.workflows.session import resolve_timing, simulate_dataset

CONFIG = ProtocolConfig(n_poses=3, amplitude=1.5, excite_duration=1.0, rest_duration=0.6, static_duration=0.3)
CONTROLLER = get_joint_model("controller")
EXACT = JointStateModel(rate_hz=500.0, report_qdd=False)  # resampled only


@pytest.fixture(scope="module")
def session():
    chain = panda()
    traj = build_trajectory(chain, CONFIG, np.random.default_rng(21))
    placements = {k: v for k, v in paper_placement(chain).items() if k in ("su2", "su5")}
    return chain, traj, placements


def test_presets_have_stated_values():
    assert set(JOINT_PRESETS) == {"ideal", "controller", "report14"}
    assert get_joint_model("ideal") == JointStateModel() and JointStateModel().is_ideal
    c = CONTROLLER
    assert c.rate_hz == 500.0 and c.encoder_resolution_rad == 2 * math.pi / 2**18
    assert c.velocity_noise_std == 3e-3 and c.jitter_s == 2e-4 and c.latency_s == 0.0
    assert not c.report_qdd and not c.velocity_from_positions and not c.is_ideal
    with pytest.raises(ConfigError, match="known: ideal, controller, report14") as info:
        get_joint_model("robotic")
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"rate_hz": 0.0},
        {"rate_hz": float("inf")},
        {"encoder_resolution_rad": -1e-4},
        {"velocity_noise_std": float("nan")},
        {"latency_s": -0.001},
        {"report_qdd": "no"},
        {"velocity_from_positions": True, "velocity_noise_std": 1e-3},
    ],
)
def test_bad_models_rejected(kwargs):
    with pytest.raises(ConfigError, match="JointStateModel"):
        JointStateModel(**kwargs)


def test_ideal_is_the_trajectory_bit_for_bit(session):
    _, traj, _ = session
    js = apply_joint_state_model(JointStateModel(), traj.evaluate, traj.t)
    for key in ("t", "q", "qd", "qdd"):
        np.testing.assert_array_equal(getattr(js, key), getattr(traj, key))


def test_stream_rate_and_jitter(session):
    _, traj, _ = session
    exact = apply_joint_state_model(EXACT, traj.evaluate, traj.t)
    assert exact.t.size == math.floor(traj.duration * 500 + 1e-9) + 1
    np.testing.assert_allclose(np.diff(exact.t), 1 / 500.0, atol=1e-12)
    assert exact.t[0] == traj.t[0] and exact.t[-1] <= traj.t[-1]
    js = apply_joint_state_model(CONTROLLER, traj.evaluate, traj.t, np.random.default_rng(1))
    assert np.all(np.diff(js.t) > 0)
    assert np.median(np.diff(js.t)) == pytest.approx(1 / 500.0, abs=2e-5)
    grid = joint_sample_instants(CONTROLLER, traj.t)
    assert js.t.size == grid.size  # 0.2 ms jitter never reorders 2 ms samples
    assert np.std(js.t - grid) == pytest.approx(2e-4, rel=0.1)


@pytest.mark.parametrize("resolution", [1e-4, 2 * math.pi / 2**18])
def test_encoder_step_is_recovered_from_the_stream(session, resolution):
    _, traj, _ = session
    model = replace(EXACT, encoder_resolution_rad=resolution)
    js = apply_joint_state_model(model, traj.evaluate, traj.t)
    counts = js.q / resolution
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)  # multiples of the step
    steps = np.abs(np.diff(js.q, axis=0))
    step = steps[steps > resolution / 2].min()  # smallest change seen = one encoder count
    assert step == pytest.approx(resolution, rel=1e-6)
    true_q, _, _ = traj.evaluate(js.t)
    assert np.abs(js.q - true_q).max() <= resolution / 2 + 1e-12
    assert np.abs(js.q - true_q).max() > resolution / 4


def test_velocity_noise_on_rest_segments(session):
    _, traj, _ = session
    js = apply_joint_state_model(CONTROLLER, traj.evaluate, traj.t, np.random.default_rng(2))
    seg = traj.segments
    static = np.zeros(js.t.size, dtype=bool)
    for t_start, t_end in zip(seg.t_start[seg.kind == STATIC], seg.t_end[seg.kind == STATIC], strict=True):
        static |= (js.t > t_start + 1e-3) & (js.t < t_end - 1e-3)
    assert static.sum() > 300
    _, true_qd, _ = traj.evaluate(js.t[static])
    assert np.abs(true_qd).max() == 0.0  # at rest
    assert np.std(js.qd[static]) == pytest.approx(3e-3, rel=0.1)
    assert abs(np.mean(js.qd[static])) < 3e-4


def test_velocity_from_positions_is_the_difference_of_quantised_positions(session):
    _, traj, _ = session
    model = replace(EXACT, encoder_resolution_rad=1e-4, velocity_from_positions=True)
    js = apply_joint_state_model(model, traj.evaluate, traj.t)
    np.testing.assert_allclose(js.qd[1:], np.diff(js.q, axis=0) / np.diff(js.t)[:, None], rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(js.qd[0], js.qd[1])
    _, mid_qd, _ = traj.evaluate(js.t[1:] - 1e-3)  # a backward difference is the velocity half a sample earlier
    err = js.qd[1:] - mid_qd
    assert np.abs(err).max() < 2 * 1e-4 * 500 + 0.01  # encoder steps over one sample, and curvature
    assert np.abs(err).max() > 1e-3  # not the true velocity


def test_latency_the_sample_stamped_t_measured_t_minus_latency(session):
    _, traj, _ = session
    model = JointStateModel(rate_hz=250.0, latency_s=0.02)
    js = apply_joint_state_model(model, traj.evaluate, traj.t)
    q, qd, qdd = traj.evaluate(js.t - 0.02)
    np.testing.assert_array_equal(js.q, q)
    np.testing.assert_array_equal(js.qd, qd)
    np.testing.assert_array_equal(js.qdd, qdd)
    assert np.abs(js.q - traj.evaluate(js.t)[0]).max() > 1e-3  # the delay is visible


def test_no_qdd_and_the_file_has_none(session, tmp_path):
    chain, traj, placements = session
    ds = simulate(chain, placements, traj, get_imu_model("none"), np.random.default_rng(3), joint_model=CONTROLLER)
    assert ds.joints.qdd is None and ds.joints.q.shape == (ds.joints.t.size, 7)
    path = tmp_path / "joints.h5"
    write_dataset(ds, path)
    with h5py.File(path, "r") as f:
        assert "qdd" not in f["joints"] and "q" in f["joints"]
    back = read_dataset(path)
    assert back.joints.qdd is None
    np.testing.assert_array_equal(back.joints.q, ds.joints.q)
    np.testing.assert_array_equal(back.joints.t, ds.joints.t)


def test_joint_model_does_not_change_the_imu_streams(session):
    chain, traj, placements = session
    model = get_imu_model("realistic")
    ideal = simulate(chain, placements, traj, model, np.random.default_rng(5))
    ctrl = simulate(chain, placements, traj, model, np.random.default_rng(5), joint_model=CONTROLLER)
    for name in placements:
        np.testing.assert_array_equal(ctrl.imu[name].t, ideal.imu[name].t)
        np.testing.assert_array_equal(ctrl.imu[name].accel, ideal.imu[name].accel)
    assert ctrl.joints.t.size != ideal.joints.t.size


def test_mujoco_kinematic_gives_the_same_joint_stream(session):
    pytest.importorskip("mujoco")
    from skincal.sim.mujoco_backend import simulate_mujoco

    chain, traj, placements = session
    model = replace(CONTROLLER, latency_s=0.004)
    a = simulate(chain, placements, traj, get_imu_model("none"), np.random.default_rng(9), joint_model=model)
    m = simulate_mujoco(chain, placements, traj, get_imu_model("none"), np.random.default_rng(9), joint_model=model)
    for key in ("t", "q", "qd"):
        np.testing.assert_array_equal(getattr(m.joints, key), getattr(a.joints, key))
    assert m.joints.qdd is None


def test_mujoco_dynamic_streams_the_reached_state(session):
    pytest.importorskip("mujoco")
    from skincal.sim.mujoco_backend import simulate_mujoco

    chain, traj, placements = session
    pl = {"su5": placements["su5"]}
    none = get_imu_model("none")
    ideal = simulate_mujoco(chain, pl, traj, none, np.random.default_rng(9), mode="dynamic")
    model = replace(EXACT, encoder_resolution_rad=1e-5, latency_s=0.002, report_qdd=True)
    late = simulate_mujoco(chain, pl, traj, none, np.random.default_rng(9), mode="dynamic", joint_model=model)
    # 500 Hz stamps on the 1 kHz grid: the sample stamped t is the 1 kHz state at t - 2 ms, encoded.
    i = np.round((late.joints.t - 0.002 - ideal.joints.t[0]) * 1000.0).astype(int)
    ok = i >= 0
    assert ok.sum() == late.joints.t.size - 1 and np.all(i < ideal.joints.t.size)
    assert np.abs(late.joints.q[ok] - ideal.joints.q[i[ok]]).max() <= 0.5e-5 + 1e-9
    np.testing.assert_allclose(late.joints.q / 1e-5, np.round(late.joints.q / 1e-5), atol=1e-6)
    np.testing.assert_allclose(late.joints.qd[ok], ideal.joints.qd[i[ok]], atol=1e-9)
    np.testing.assert_allclose(late.joints.qdd[ok], ideal.joints.qdd[i[ok]], atol=1e-6)
    np.testing.assert_array_equal(late.imu["su5"].accel, ideal.imu["su5"].accel)


def test_auto_timing_rule():
    assert resolve_timing("none") == ("ideal", "ideal")
    assert resolve_timing("datasheet") == ("ideal", "ideal")
    assert resolve_timing("realistic") == ("controller", "ideal")
    assert resolve_timing("real") == ("controller", "driver")
    assert resolve_timing("real", "ideal", "wifi") == ("ideal", "wifi")
    with pytest.raises(ConfigError, match="unknown clock model 'atomic'"):
        resolve_timing("none", "auto", "atomic")


def test_simulate_dataset_defaults():
    none = simulate_dataset(noise="none", protocol="fast", seed=1)
    assert none.joints.qdd is not None and np.diff(none.joints.t).max() < 1.1e-3
    real = simulate_dataset(noise="real", protocol="fast", seed=1)
    assert real.joints.qdd is None and np.median(np.diff(real.joints.t)) == pytest.approx(2e-3, abs=2e-5)
    assert all(v["clock_resync_period_s"] == 2.51 for v in real.truth_sensor.values())
    assert "joints=controller clock=driver" in real.description
    same = simulate_dataset(noise="real", protocol="fast", seed=1, joints="controller", clock="driver")
    np.testing.assert_array_equal(same.imu["su1"].t, real.imu["su1"].t)


def test_cli_simulate_with_real_timing(tmp_path, capsys):
    out = tmp_path / "real.h5"
    args = ["simulate", "--out", str(out), "--protocol", "fast", "--noise", "real", "--seed", "2"]
    assert main([*args, "--joints", "controller", "--clock", "wifi"]) == 0
    ds = read_dataset(out)
    assert ds.joints.qdd is None and np.median(np.diff(ds.joints.t)) == pytest.approx(2e-3, abs=2e-5)
    assert all("clock_resync_period_s" not in v and v["clock_drift_ppm"] != 0 for v in ds.truth_sensor.values())
    assert np.median(np.diff(ds.imu["su1"].t)) == pytest.approx(1 / 62.5, rel=0.01)
    capsys.readouterr()
    for option, bad, message in (
        ("--joints", "robotic", "unknown joint-state model 'robotic'"),
        ("--clock", "sundial", "unknown clock model 'sundial'"),
    ):
        assert main([*args, "--force", option, bad]) == 2  # the file exists: --force, to reach the preset
        err = capsys.readouterr().err.strip()
        assert message in err and len(err.splitlines()) == 1 and "Traceback" not in err
