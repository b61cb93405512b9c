"""The moved-unit change detector (issue 16, item 5) on residual streams with known statistics: no alarm
without a change, the alarm and the change time of a shift, thresholds from the unit's own data."""

from __future__ import annotations

import numpy as np
import pytest

from skincal.calib.online.monitor import (
    MonitorOptions,
    MovedUnitMonitor,
    UnitMonitor,
    cusum_max,
)
from skincal.errors import ConfigError, DatasetError

RATE = 100.0
OPTS = MonitorOptions(warmup_windows=240)  # 60 s of warm-up at 0.25 s windows


def white(seconds: float, seed: int, t0: float = 0.0, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    n = int(seconds * RATE)
    t = t0 + np.arange(n) / RATE + rng.uniform(0, 1e-3, n)  # jittered stamps
    return np.sort(t), scale * rng.normal(size=(n, 3))


def ar1(seconds: float, seed: int, phi: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit-variance AR(1) residuals (correlated, like residuals of joint-derived signals)."""
    t, e = white(seconds, seed)
    x = np.empty_like(e)
    x[0] = e[0]
    for i in range(1, len(e)):
        x[i] = phi * x[i - 1] + np.sqrt(1 - phi**2) * e[i]
    return t, x


def feed(mon: UnitMonitor | MovedUnitMonitor, t, r, chunk_s: float = 1.0, unit: str = "su1"):
    """Feed in chunks like a calibrator's blocks; returns the alarms raised."""
    edges = np.searchsorted(t, np.arange(t[0], t[-1] + chunk_s, chunk_s))
    alarms = []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        if isinstance(mon, UnitMonitor):
            alarm = mon.feed(t[a:b], r[a:b])
            if alarm is not None:
                alarms.append(alarm)
        else:
            mon.on_residuals(unit, t[a:b], r[a:b])
    return alarms if isinstance(mon, UnitMonitor) else list(mon.alarms)


def test_no_alarm_over_an_hour_of_white_residuals():
    mon = UnitMonitor("su1", OPTS)
    t, r = white(3600.0, seed=1)
    assert feed(mon, t, r) == []
    assert mon.state == "watching"
    assert mon.threshold >= OPTS.min_threshold
    assert mon.windows > 14000  # every window of the hour was tested


def test_no_alarm_over_an_hour_of_correlated_residuals():
    """Autocorrelated residuals (window means spread 3x wider than white ones) raise no alarm: the
    spread is learnt in warm-up, not assumed."""
    mon = UnitMonitor("su1", OPTS)
    t, r = ar1(3600.0, seed=2, phi=0.8)
    assert feed(mon, t, r) == []
    assert np.all(mon.window_std > 2.0)


@pytest.mark.parametrize("shift", [0.6, 1.0])
def test_a_mean_shift_is_flagged_with_its_change_time(shift):
    """A shift of the residual mean by ``shift`` noise std on one axis at t = 300 s: alarm after it,
    change time within 1 s of it (tolerance: 4 windows)."""
    t, r = white(400.0, seed=3)
    r[t >= 300.0, 1] += shift
    mon = UnitMonitor("su1", OPTS)
    alarms = feed(mon, t, r)
    assert len(alarms) == 1
    a = alarms[0]
    assert 300.0 < a.t_detected < 300.0 + (2.0 if shift >= 1 else 10.0)
    assert abs(a.t_change - 300.0) <= 1.0
    assert np.argmax(np.abs(a.shift)) == 1 and a.shift[1] > 0  # the axis and sign of the move
    # restarted after the alarm: the new null distribution is learnt at the new level (z = sqrt(25) shift)
    assert mon.state == "watching" and mon.null.mu[1] == pytest.approx(5 * shift, abs=0.5)


def test_larger_shift_is_flagged_sooner():
    delays = []
    for shift in (0.5, 0.8, 2.0):
        t, r = white(400.0, seed=4)
        r[t >= 300.0, 0] -= shift
        (alarm,) = feed(UnitMonitor("su1", OPTS), t, r)
        delays.append(alarm.t_detected - 300.0)
    assert delays[0] > delays[1] > delays[2]


def test_thresholds_come_from_the_units_own_data():
    """A noisier unit (its residuals twice as wide as the calibrator's noise figure says) gets a higher
    alarm level; a unit with bursts (heavy-tailed window statistic) gets a higher CUSUM threshold; and a
    shift that flags the quiet unit does not flag the noisy one."""
    quiet, noisy, bursty = UnitMonitor("a", OPTS), UnitMonitor("b", OPTS), UnitMonitor("c", OPTS)
    t, r = white(120.0, seed=5)
    feed(quiet, t, r)
    t2, r2 = white(120.0, seed=6, scale=2.0)
    feed(noisy, t2, r2)
    t3, r3 = white(120.0, seed=7)
    rng = np.random.default_rng(8)
    for start in rng.uniform(0, 118, size=25):  # short bursts of model error
        r3[(t3 >= start) & (t3 < start + 0.5)] *= 4.0
    feed(bursty, t3, r3)
    assert noisy.mean_alarm_level() > 1.7 * quiet.mean_alarm_level()
    assert np.all(noisy.window_std > 1.7 * quiet.window_std)
    assert bursty.threshold > quiet.threshold
    # the same absolute shift (0.4 units of the nominal noise) after warm-up
    t, r = white(200.0, seed=9, t0=120.0)
    t2, r2 = white(200.0, seed=10, t0=120.0, scale=2.0)
    r[:, 2] += 0.4
    r2[:, 2] += 0.4
    assert feed(quiet, t, r) and not feed(noisy, t2, r2)


def test_cusum_max_is_the_recursion():
    g = np.random.default_rng(0).chisquare(3, size=5000) / 3
    c, best = 0.0, 0.0
    for x in g:
        c = max(0.0, c + x - 1.2)
        best = max(best, c)
    assert cusum_max(g, 1.2) == pytest.approx(best, rel=1e-12)


def test_units_are_watched_independently():
    seen = []
    mon = MovedUnitMonitor(OPTS, on_alarm=seen.append)
    t, r = white(400.0, seed=11)
    shifted = r.copy()
    shifted[t >= 250.0, 0] += 1.0
    feed(mon, t, r, unit="su1")
    feed(mon, t, shifted, unit="su2")
    assert [a.unit for a in mon.alarms] == ["su2"] and seen == mon.alarms
    assert abs(mon.unit("su1").null.mu[0]) < 0.5 and mon.unit("su2").null.mu[0] > 4.0


def test_gaps_and_stale_samples():
    """A gap longer than a window drops the open window; samples not newer than the last one and
    non-finite ones are ignored (a calibrator may re-send a block)."""
    mon = UnitMonitor("su1", OPTS)
    t, r = white(10.0, seed=12)
    mon.feed(t, r)
    w = mon.windows
    mon.feed(t, r)  # the same block again: nothing new
    assert mon.windows == w
    r2 = r.copy()
    r2[::3] = np.nan
    mon.feed(t + 100.0, r2)  # after a gap
    assert w < mon.windows <= w + 40


@pytest.mark.adversarial
def test_bad_residual_shape_is_one_error():
    with pytest.raises(DatasetError, match="must be \\(M, 3\\)"):
        UnitMonitor("su1").feed(np.arange(4.0), np.zeros((4, 2)))


@pytest.mark.adversarial
@pytest.mark.parametrize(
    "bad",
    [dict(window_s=0.0), dict(drift=float("nan")), dict(warmup_windows=3), dict(block_windows=0),
     dict(min_threshold=-1.0), dict(warmup_windows=2.5)],
)  # fmt: skip
def test_bad_options_are_config_errors(bad):
    with pytest.raises(ConfigError):
        MonitorOptions(**bad)
