"""The streaming calibrator's stuck-axis test (:class:`~skincal.calib.online.stuck.StuckScreen`) against the
batch one (:func:`~skincal.calib.preprocess.screen_readings`) on the same streams, pushed in chunks of random
size; and end to end, a simulated session whose accelerometer axis :func:`~skincal.sim.faults.stick_axis`
froze.

Truths: the samples from the instant a synthetic axis was made to stick; the simulated pose of the frozen unit.
"""

from __future__ import annotations

import numpy as np
import pytest

from skincal.calib.online.stuck import StuckScreen
from skincal.calib.preprocess import screen_channels, screen_readings

RATE_HZ = 100.0


def _moving_stream(seconds: float = 60.0, seed: int = 0):
    """A unit in motion: every axis a sum of slow sines (m/s^2) plus white noise, 100 Hz."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * RATE_HZ)) / RATE_HZ
    phases = rng.uniform(0, 6, 3)
    freqs = (0.3, 0.45, 0.7)
    accel = np.column_stack([2.0 * np.sin(2 * np.pi * f * t + p) for f, p in zip(freqs, phases, strict=True)])
    return t, accel + np.array([0.0, 0.0, 9.81]) + rng.normal(0.0, 0.02, accel.shape)


def _streamed(t, accel, seed=0, final=True, largest=37):
    """The samples the stream screen keeps, pushed in chunks of 1-``largest`` samples: a mask over ``t``."""
    rng = np.random.default_rng(seed)
    screen, kept, i = StuckScreen(), [], 0
    g = rng.normal(0.0, 0.01, accel.shape)  # a live gyroscope (zeros would be a dead one: stuck)
    while i < t.size:
        j = min(t.size, i + int(rng.integers(1, largest + 1)))
        out_t, out_a, out_g = screen.push(t[i:j], accel[i:j], g[i:j])
        assert out_g is not None and out_a.shape == out_g.shape
        kept.append(out_t)
        i = j
    if final:
        kept.append(screen.push(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)), final=True)[0])
    return np.isin(t, np.concatenate(kept)), screen


@pytest.mark.parametrize(
    ("chunks", "largest"), [(0, 37), (1, 37), (2, 1)], ids=["chunks", "other-chunks", "one-by-one"]
)
def test_the_streamed_test_drops_what_the_batch_test_drops(chunks, largest):
    t, accel = _moving_stream()
    a, b = np.searchsorted(t, [20.0, 32.0])
    accel[a:b, 2] = accel[a - 1, 2]  # z frozen for 12 s
    first = int(np.searchsorted(t, 45.0))
    accel[first:, 0] = accel[first - 1, 0]  # x frozen from 45 s to the end
    accel[1000:1050, 1] = accel[999, 1]  # y repeats for 0.5 s: too short, kept
    keep_batch, warn_batch = screen_readings("su1", accel, t)
    keep, screen = _streamed(t, accel, seed=chunks, largest=largest)  # one by one: as a live feed may push
    # the same samples, but for a run's first one (the register's last true reading), which the stream keeps
    # when a chunk ended at it
    assert not np.any(keep_batch & ~keep)
    extra = np.flatnonzero(keep & ~keep_batch)
    assert set(extra) <= {a - 1, first - 1}
    assert len(screen.spans) == len(warn_batch) == 2 and screen.dropped == int((~keep_batch).sum()) - extra.size
    if extra.size == 0:
        assert sorted(screen.warnings()) == sorted(warn_batch)
    for sp in screen.spans:
        assert (sp.axis, sp.value) in {(2, accel[a - 1, 2]), (0, accel[first - 1, 0])}
        assert sp.t1 == (t[b - 1] if sp.axis == 2 else t[-1])


def test_the_run_length_follows_the_streams_interval_not_its_first_two_stamps():
    """A first push of two bunched stamps (0.1 ms apart) set the 1 s run length at 10,000 samples for good: a 3 s
    stuck axis went unseen and up to 2.5 s of samples were held back."""
    t, accel = _moving_stream(seconds=20.0, seed=7)
    a = int(np.searchsorted(t, 10.0))
    accel[a : a + 300, 2] = accel[a - 1, 2]
    screen = StuckScreen()
    screen.push(np.array([-0.0002, -0.0001]), np.tile(accel[0], (2, 1)) + [[0.0, 0.0, 0.01], [0.0, 0.0, 0.02]], None)
    held = 0
    for i in range(0, t.size, 50):
        screen.push(t[i : i + 50], accel[i : i + 50], None)
        held = max(held, screen.held())
    assert screen.min_run() == pytest.approx(100.0, rel=1e-9) and 0 < held <= 100
    assert [(sp.axis, sp.n) for sp in screen.spans] == [(2, 300)]


def test_a_run_cut_after_its_first_sample_keeps_that_true_reading():
    t, accel = _moving_stream(seed=5)
    a = int(np.searchsorted(t, 20.0))
    accel[a:, 1] = accel[a - 1, 1]
    screen = StuckScreen()
    first = screen.push(t[:a], accel[:a], None)[0]  # the chunk ends at the register's last update
    rest = screen.push(t[a:], accel[a:], None, final=True)[0]
    assert first.size == a and rest.size == 0
    assert screen.warnings() == [f"accelerometer y axis stuck at {accel[a - 1, 1]:.4g} m/s^2 from {t[a]:.1f} s to "
                                 f"the end ({t.size - a} samples ignored)"]


def test_held_samples_are_released_once_their_run_ends_and_at_most_one_second_is_held():
    t, accel = _moving_stream(seconds=10.0, seed=4)
    accel[300:380, 1] = accel[299, 1]  # 0.8 s of repeats: held, then released
    screen = StuckScreen()
    out = screen.push(t[:350], accel[:350], None)[0]
    assert out.size == 299 and screen.push(t[350:400], accel[350:400], None)[0].size == 101  # 299-399
    keep, _ = _streamed(t, accel, final=False)  # a noisy stream's last sample is not a repeat: nothing waits
    assert keep.all()


def test_a_still_unit_below_one_lsb_is_not_stuck_and_is_not_held_for_long():
    # at rest through a coarse ADC (LSB 0.04 m/s^2, noise 0.002): every axis repeats for seconds, nothing moves
    rng = np.random.default_rng(2)
    t = np.arange(int(30 * RATE_HZ)) / RATE_HZ
    accel = np.round((np.array([0.37, -1.21, 9.72]) + rng.normal(0.0, 0.002, (t.size, 3))) / 0.04) * 0.04
    keep, screen = _streamed(t, accel, final=False)
    assert screen.warnings() == [] and screen.dropped == 0
    assert keep.sum() >= t.size - RATE_HZ  # a run judged still is released, not held until it ends


def test_a_stuck_gyroscope_axis_is_found_as_the_batch_screening_finds_it():
    t, accel = _moving_stream(seed=6)
    gyro = 0.2 * np.roll(accel - accel.mean(axis=0), 40, axis=0)  # rad/s, moving on every axis
    a = int(np.searchsorted(t, 25.0))
    gyro[a:, 0] = 0.37  # x stuck from 25 s to the end, at a value no reading reached before
    screen = screen_channels("su1", accel, gyro, t)
    assert screen.keep.all() and np.array_equal(np.flatnonzero(screen.gyro_saturated), np.arange(a, t.size))
    (said,) = [w for w in screen.warnings if "stuck" in w]
    assert said == (f"gyroscope x axis stuck at 0.37 rad/s from {t[a]:.1f} s to the end ({t.size - a} gyroscope "
                    "readings ignored; the accelerometer's are kept)")  # fmt: skip
    streamed = StuckScreen()
    out_t, _, out_g = streamed.push(t, accel, gyro, final=True)
    assert out_t.size == t.size and streamed.warnings() == [said]  # the accelerometer's samples all kept
    masked = streamed.gyro_masked(out_t, out_g)
    assert masked is not None and np.array_equal(np.isnan(masked).any(axis=1), screen.gyro_saturated)
    # an axis held at a rail (its largest reading, beyond 1 rad/s) is the saturation test's, not stuck
    gyro[a:, 0] = 1.05 * np.abs(gyro[:a, 0]).max() + 1.0
    assert not any("stuck" in w for w in screen_channels("su1", accel, gyro, t).warnings)
    streamed = StuckScreen()
    streamed.push(t, accel, gyro, final=True)
    assert streamed.spans == []


@pytest.fixture(scope="module")
def session():
    from skincal.workflows.session import simulate_dataset

    return simulate_dataset("panda", "paper", noise="realistic", protocol="fast", seed=1)


def _rotation_error_deg(pose, truth) -> float:
    from scipy.spatial.transform import Rotation

    return float(np.degrees(Rotation.from_matrix(pose.R_link_su.T @ truth.R_link_su).magnitude()))


@pytest.mark.parametrize("dead", [False, True])
def test_a_stuck_or_dead_gyroscope_is_left_out_by_both_calibrators(session, dead):
    """Panda, ``fast`` protocol, realistic IMUs (simulated): su5's gyroscope x axis reads 0.37 rad/s from 30 % of
    the session on, or the whole gyroscope reads zeros (dead). Before the test, ``mle`` put the stuck one on
    link 5, 148 mm and 124 deg off (an std of metres), the dead one 90 mm off at 4.5 std with its clock 0.5 s
    off, and the streaming calibrator turned the stuck one 4.3 deg and put the dead one on link 3, 355 mm off;
    now both calibrators within 0.1 deg and 0.2 mm, on link 6, the stretch named."""
    from dataclasses import replace

    from skincal.calib import calibrate
    from skincal.calib.online import OnlineCalibrator, replay

    s = session.imu["su5"]
    i = int(np.searchsorted(s.t, s.t[0] + 0.3 * (s.t[-1] - s.t[0])))
    gyro = np.array(s.gyro, dtype=float)
    gyro[i:, 0] = 0.37
    if dead:
        gyro[:] = 0.0
    ds = replace(session, imu={**session.imu, "su5": replace(s, gyro=gyro)})
    cal = OnlineCalibrator(ds.robot, list(ds.imu), ds.gravity)
    replay(ds, cal, chunk_s=0.1)
    for got in (cal.result().units["su5"], calibrate(ds, "mle").units["su5"]):
        assert got.pose.link == ds.truth["su5"].link
        assert _rotation_error_deg(got.pose, ds.truth["su5"]) < 0.1
        assert np.linalg.norm(got.pose.p_link_su - ds.truth["su5"].p_link_su) < 2e-4
        said = "gyroscope x axis stuck at 0 rad/s from 0.0 s" if dead else "gyroscope x axis stuck at 0.37 rad/s from "
        assert any(w.startswith(said) for w in got.warnings)


def test_an_online_session_with_a_frozen_axis_names_it_and_keeps_its_accuracy(session):
    """Panda, ``fast`` protocol, realistic IMUs (simulated): su5's z axis frozen from mid-session. Without the
    test the streamed position was 0.54 mm off at a 1.0 mm std with no warning; with it, within 0.2 mm of the
    truth (the batch ``mle``: 0.12 mm) and the batch screening's warning, word for word."""
    from skincal.calib.online import OnlineCalibrator, replay
    from skincal.sim.faults import stick_axis

    t = session.imu["su5"].t
    ds = stick_axis(session, "su5", 2, float(t[0] + 0.5 * (t[-1] - t[0])))
    cal = OnlineCalibrator(ds.robot, list(ds.imu), ds.gravity)
    replay(ds, cal, chunk_s=0.1)
    got = cal.result().units["su5"]
    stuck = [w for w in screen_readings("su5", ds.imu["su5"].accel, t)[1] if "stuck" in w]  # mle's screening
    assert len(stuck) == 1 and stuck[0] in got.warnings
    assert got.extras["stuck_samples"] == int(stuck[0].split("(")[1].split()[0]) > 3000
    err = np.linalg.norm(got.pose.p_link_su - ds.truth["su5"].p_link_su)
    assert err < 2e-4 and err < 4 * np.linalg.norm(got.position_std_m)


def test_asymmetric_rails_of_each_axis_are_found_in_chunks_as_the_batch_screening_finds_them():
    """A real MPU6050 clips one axis at +19.56 and -19.67 m/s^2 and another at +19.24: each axis' two extremes
    are rails of their own. The streaming screen took the largest magnitude of all axes as the one range and kept
    the samples at the smaller rails (here the +19.56 and +19.24 ones)."""
    from skincal.calib.online import stats
    from skincal.calib.online.screen import unsaturated
    from skincal.calib.online.unit import UnitState
    from skincal.calib.preprocess.screening import screen_channels

    rng = np.random.default_rng(9)
    M = 3000
    a = rng.normal(0.0, 8.0, (M, 3))
    a[:, 0] = np.clip(a[:, 0], -19.67, 19.56)
    a[:, 1] = np.clip(a[:, 1], -30.0, 19.24)
    g = rng.normal(0.0, 0.3, (M, 3))
    st = UnitState([3], np.zeros((1, 2, stats.NA, stats.NA)), np.zeros((1, 2, stats.NG, stats.NG)), np.zeros(1))
    keep = np.concatenate([unsaturated(st, a[i : i + 100], g[i : i + 100])[0] for i in range(0, M, 100)])
    batch = screen_channels("su1", a, g)
    clipped = (a[:, 0] >= 19.56) | (a[:, 0] <= -19.67) | (a[:, 1] >= 19.24)
    assert np.array_equal(~batch.keep, clipped)
    # the first chunks hold a rail before it recurs often enough: the stream finds it from then on
    assert np.array_equal(~keep[1000:], clipped[1000:]) and st.saturated == int((~keep).sum()) >= 0.8 * clipped.sum()


def _state(screen: StuckScreen):
    runs = [(r.value, r.length, tuple(r.lo), tuple(r.hi), r.span) for rs in screen._runs for r in rs]
    held = None if screen._held is None else tuple(None if x is None else x.tobytes() for x in screen._held)
    return runs, held, [vars(sp) for sp in screen.spans], screen.dropped, screen.gyro_dropped, screen.t_end


@pytest.mark.parametrize("gyro", [True, False], ids=["gyro", "no-gyro"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_quick_path_leaves_what_the_per_axis_path_leaves(seed, gyro):
    """Chunks in which no run can be judged take the all-axes path (:meth:`StuckScreen._release_unjudged`):
    on a quantised stream (repeats of a few samples everywhere), with a stuck axis, a dead gyroscope axis and a
    rail, pushed in chunks of 1-150 samples, every release and the whole state after each push are those of
    the per-axis path, bit for bit."""
    rng = np.random.default_rng(seed)
    t, accel = _moving_stream(40.0, seed)
    accel = np.round(accel / 0.04) * 0.04  # 4 cm/s^2 LSB: noise of half an LSB repeats readings often
    accel[1200:1500, 1] = accel[1199, 1]  # stuck 3 s
    accel[2500:2700, 0] = 19.6  # at a rail
    gy = np.round(rng.normal(0.0, 0.01, accel.shape) / 0.01) * 0.01 if gyro else None
    if gy is not None:
        gy[3000:3300, 2] = 0.0  # dead
    quick, slow = StuckScreen(), StuckScreen()
    slow.quick = False
    i, pushes = 0, 0
    while i <= t.size:
        j = min(t.size, i + int(rng.integers(1, 151)))
        final = i == t.size
        args = (t[i:j], accel[i:j], None if gy is None else gy[i:j])
        a, b = quick.push(*args, final=final), slow.push(*args, final=final)
        pushes += 1
        for x, y in zip(a, b, strict=True):
            assert (x is None) == (y is None) and (x is None or np.array_equal(x, y))
        assert _state(quick) == _state(slow)
        i = j + final
    took_quick = quick.quick_pushes
    # both paths taken, the stuck runs found
    assert slow.quick_pushes == 0 and 10 < took_quick < pushes - 3 and len(slow.spans) == 1 + gyro
