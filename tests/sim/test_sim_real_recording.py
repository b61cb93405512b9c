"""The simulator's real-recording faults (issue 24): the report14 joint stream, unit mistakes, the
real-recording-like session from the command line, and the new robustness cells."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from skincal.cli import main
from skincal.data.hdf5 import read_dataset
from skincal.errors import ConfigError
from skincal.sim import faults as F
from skincal.sim.joint_states import JointStateModel, apply_joint_state_model, get_joint_model
from skincal.skin.imu import STANDARD_GRAVITY
from skincal.workflows.session import resolve_timing, simulate_dataset

REPORT14 = get_joint_model("report14")


def motion(t):
    t = np.asarray(t, dtype=float)[:, None]
    w = np.array([0.7, 1.3])
    return np.sin(w * t), w * np.cos(w * t), -(w**2) * np.sin(w * t)


@pytest.fixture(scope="module")
def stream():
    return apply_joint_state_model(REPORT14, motion, np.linspace(0.0, 900.0, 9001), np.random.default_rng(14))


def test_report14_preset_has_stated_values():
    m = REPORT14
    assert (m.rate_hz, m.interval_std_s, m.jitter_s, m.drop_probability) == (13.6, 7.5e-3, 2.8e-3, 0.08)
    assert m.velocity_from_positions and m.velocity_scheme == "central" and not m.report_qdd
    assert m.velocity_noise_std == m.latency_s == m.encoder_resolution_rad == 0


@pytest.mark.parametrize(
    "kwargs",
    [
        {"rate_hz": None, "interval_std_s": 1e-3},
        {"rate_hz": 10.0, "drop_probability": 1.0},
        {"rate_hz": 10.0, "velocity_scheme": "forward"},
        {"rate_hz": 10.0, "interval_std_s": -1e-3},
    ],
)
def test_bad_report_values_rejected(kwargs):
    with pytest.raises(ConfigError) as info:
        JointStateModel(**kwargs)
    assert "\n" not in str(info.value)


def test_report14_spacing_follows_its_equation(stream):
    """Kept spacing spans m report intervals, P(m) = (1 - p) p^(m - 1); for m = 1: mean T, variance
    sigma^2 + 2 j^2, lag-1 correlation -j^2 / (sigma^2 + 2 j^2)."""
    T, sigma, j, p = 1 / 13.6, 7.5e-3, 2.8e-3, 0.08
    d = np.diff(stream.t)
    n = d.size
    assert np.all(d > 0) and stream.qdd is None
    assert d.mean() == pytest.approx(
        T / (1 - p), abs=4 * T * math.sqrt(p) / (1 - p) / math.sqrt(n) + 4 * sigma / math.sqrt(n)
    )
    long = d > 1.5 * T
    assert long.mean() == pytest.approx(p, abs=4 * math.sqrt(p * (1 - p) / n))
    core = d[~long]
    var = sigma**2 + 2 * j**2
    assert core.mean() == pytest.approx(T, abs=4 * math.sqrt(var / core.size))
    assert core.std() == pytest.approx(math.sqrt(var), rel=4 / math.sqrt(2 * core.size))
    pair = ~long[:-1] & ~long[1:]
    c = d - T
    rho = np.corrcoef(c[:-1][pair], c[1:][pair])[0, 1]
    assert rho == pytest.approx(-(j**2) / var, abs=4 / math.sqrt(pair.sum()))
    assert 1 / np.median(d) == pytest.approx(13.6, rel=0.03)


def test_report14_velocity_is_the_hosts_central_difference(stream):
    np.testing.assert_array_equal(stream.qd, np.gradient(stream.q, stream.t, axis=0))
    # positions are exact at the report instants: the stamp minus its jitter
    t = stream.t
    h = np.diff(t)
    k = np.arange(1, t.size - 1)
    hm, hp = h[:-1, None], h[1:, None]
    q = stream.q
    central = (hm**2 * q[k + 1] - hp**2 * q[k - 1] + (hp**2 - hm**2) * q[k]) / (hm * hp * (hm + hp))
    np.testing.assert_allclose(stream.qd[1:-1], central, rtol=0, atol=1e-10)


def test_report14_without_jitter_or_drops_is_a_renewal_stream_of_exact_positions():
    model = JointStateModel(rate_hz=13.6, interval_std_s=7.5e-3)
    js = apply_joint_state_model(model, motion, np.linspace(0.0, 100.0, 1001), np.random.default_rng(1))
    np.testing.assert_allclose(js.q, motion(js.t)[0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(js.qd, motion(js.t)[1], rtol=0, atol=1e-15)
    assert np.diff(js.t).min() >= 0.2 / 13.6 - 1e-12 and js.t[0] == 0.0 and js.t[-1] <= 100.0


def test_older_presets_are_unchanged_by_the_new_fields():
    old = get_joint_model("controller")
    a = apply_joint_state_model(old, motion, np.linspace(0.0, 5.0, 51), np.random.default_rng(3))
    rng = np.random.default_rng(3)
    t = np.arange(int(5.0 * 500.0) + 1) / 500.0
    q, qd, _ = motion(t)
    q = np.round(q / old.encoder_resolution_rad) * old.encoder_resolution_rad
    qd = qd + rng.normal(0.0, old.velocity_noise_std, qd.shape)
    stamps = t + rng.normal(0.0, old.jitter_s, t.shape)
    keep = np.concatenate([[True], stamps[1:] > np.maximum.accumulate(stamps)[:-1]])
    np.testing.assert_array_equal(a.t, stamps[keep])
    np.testing.assert_array_equal(a.qd, qd[keep])


# --------------------------------------------------------------------------- unit mistakes
@pytest.fixture(scope="module")
def small():
    return simulate_dataset("panda", noise="realistic", protocol="fast", seed=3)


def test_gyro_in_degrees_is_57_times(small):
    ds = F.misstate_units(small, "gyro-deg")
    for u in small.units:
        np.testing.assert_allclose(ds.imu[u].gyro, small.imu[u].gyro * 180.0 / math.pi, rtol=1e-15)
        np.testing.assert_array_equal(ds.imu[u].accel, small.imu[u].accel)
        np.testing.assert_array_equal(ds.imu[u].t, small.imu[u].t)
        assert ds.truth_sensor[u]["gyro_unit_factor"] == 180.0 / math.pi
        assert ds.truth_sensor[u]["accel_unit_factor"] == 1.0
    assert small.truth_sensor[small.units[0]].get("gyro_unit_factor") is None  # input untouched


def test_accel_in_g_and_raw_counts(small, tmp_path):
    g = F.misstate_units(small, "accel-g", units=[small.units[0]])
    u, other = small.units[0], small.units[1]
    np.testing.assert_allclose(g.imu[u].accel * STANDARD_GRAVITY, small.imu[u].accel, rtol=1e-15)
    assert g.truth_sensor[u]["accel_unit_factor"] == 1.0 / STANDARD_GRAVITY
    np.testing.assert_array_equal(g.imu[other].accel, small.imu[other].accel)
    assert "accel_unit_factor" not in g.truth_sensor.get(other, {})

    raw = F.misstate_units(small, "raw-counts")
    a, w = raw.imu[u].accel, raw.imu[u].gyro
    assert np.all(a == np.round(a)) and np.all(np.abs(a) <= 32767) and np.all(np.abs(w) <= 32767)
    lsb_a, lsb_g = 4 * STANDARD_GRAVITY / 2**15, math.radians(2000.0) / 2**15
    assert raw.truth_sensor[u]["accel_unit_factor"] == pytest.approx(1 / lsb_a, rel=1e-15)
    assert raw.truth_sensor[u]["gyro_unit_factor"] == pytest.approx(1 / lsb_g, rel=1e-15)
    np.testing.assert_allclose(a * lsb_a, small.imu[u].accel, rtol=0, atol=lsb_a / 2 + 1e-12)
    np.testing.assert_allclose(w * lsb_g, small.imu[u].gyro, rtol=0, atol=lsb_g / 2 + 1e-12)
    # two mistakes compose: the factors multiply; the truth survives the file
    both = F.misstate_units(F.misstate_units(small, "gyro-deg"), "accel-g")
    assert both.truth_sensor[u]["gyro_unit_factor"] == 180.0 / math.pi
    from skincal.data.hdf5 import write_dataset

    write_dataset(both, tmp_path / "b.h5")
    back = read_dataset(tmp_path / "b.h5").truth_sensor[u]
    assert back["accel_unit_factor"] == pytest.approx(1 / STANDARD_GRAVITY, rel=1e-15)
    with pytest.raises(ConfigError, match="unknown unit mistake 'furlongs'") as info:
        F.misstate_units(small, "furlongs")
    assert "\n" not in str(info.value)


# --------------------------------------------------------------------------- the real-recording-like session
def test_real_consumer_resolves_to_the_real_recording_timing():
    assert resolve_timing("real-consumer") == ("report14", "host-gaps")
    assert resolve_timing("real-consumer", "controller", "host") == ("controller", "host")


def test_simulate_real_recording_like_dataset_that_calibrate_accepts(tmp_path, capsys):
    out = tmp_path / "rr.h5"
    assert main(["simulate", "--noise", "real-consumer", "--protocol", "fast", "--seed", "2", "-o", str(out)]) == 0
    ds = read_dataset(out)
    assert "joints=report14" in ds.description and "clock=host-gaps" in ds.description
    assert ds.joints.qdd is None and 1 / np.median(np.diff(ds.joints.t)) == pytest.approx(13.6, rel=0.05)
    for u in ds.units:
        d = np.diff(ds.imu[u].t)
        assert np.percentile(d, 1) >= 2.5e-3 - 1e-6 and np.percentile(d, 99) <= 17.5e-3 + 1e-6
        truth = ds.truth_sensor[u]
        assert {"gyro_scale", "gyro_misalignment", "clock_host_delay_mean_s"} <= set(truth)
        assert 0.075 <= truth["time_offset_s"] <= 0.1
    result = tmp_path / "rr.json"
    capsys.readouterr()
    assert main(["calibrate", str(out), "-o", str(result)]) == 0  # accuracy is not asserted (issue 24)
    doc = json.loads(result.read_text())
    assert doc["format"] and doc["units"] and set(doc["units"]) <= set(ds.units)


@pytest.mark.parametrize(
    ("fault", "key"),
    [
        ("joints-report14", None),
        ("clock-gaps", "clock_host_delay_mean_s"),
        ("gyro-scale", "gyro_scale"),
        ("units-gyro-deg", "gyro_unit_factor"),
        ("units-raw", "accel_unit_factor"),
        ("real-recording", "gyro_misalignment"),
    ],
)
def test_robustness_cells_build_their_fault(fault, key):
    from skincal.bench import robustness as rb

    assert fault in rb.FAULTS and fault in rb.RobustnessConfig().faults
    ds, _ = rb.build_dataset(rb.Job("panda", "analytic", fault, 0, "fast"))
    if key is not None:
        assert all(key in ds.truth_sensor[u] for u in ds.units)
    if rb.FAULTS[fault].clock == "host-gaps":  # about 2.6 gaps per unit over the fast protocol
        assert any("clock_step_s" in ds.truth_sensor[u] for u in ds.units)
    if rb.FAULTS[fault].joints == "report14":
        assert ds.joints.qdd is None and np.median(np.diff(ds.joints.t)) > 0.05
