"""A stuck accelerometer axis (``screen_readings``) and rest runs that settle (``unit_rest_runs``).

Truths: the instant at which a synthetic axis was made to stick and the samples after it; the
run whose start was made to ring and the run that was bumped in its middle; for the end-to-end
case, the simulated pose of the unit whose axis :func:`skincal.sim.faults.stick_axis` froze.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from skincal.calib.preprocess import screen_readings
from skincal.calib.rest import unit_rest_runs
from skincal.errors import CalibrationError

from synthetic_streams import rest_runs_stream

RATE_HZ = 100.0


# ---------------------------------------------------------------------------- stuck axis
def _moving_stream(seconds: float = 120.0, seed: int = 0):
    """A unit in motion: every axis a sum of slow sines (amplitudes of m/s^2) plus white noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * RATE_HZ)) / RATE_HZ
    phases = rng.uniform(0, 2 * np.pi, 3)
    waves = [2.0 * np.sin(2 * np.pi * f * t + p) for f, p in zip((0.3, 0.45, 0.7), phases, strict=True)]
    accel = np.column_stack(waves)
    accel += np.array([0.0, 0.0, 9.81])
    accel += rng.normal(0.0, 0.02, accel.shape)
    return t, accel


def test_an_axis_stuck_from_60_s_is_excluded_and_named():
    t, accel = _moving_stream()
    first = int(np.searchsorted(t, 60.0))
    value = accel[first - 1, 0]
    accel[first:, 0] = value  # the register keeps its last value from t = 60 s on
    keep, warnings = screen_readings("su1", accel, t)
    # the stuck run starts at the last real sample (it holds the same value): it and all after are excluded
    assert np.all(keep[: first - 1]) and not np.any(keep[first - 1 :])
    assert len(warnings) == 1
    w = warnings[0]
    assert w.startswith("accelerometer x axis stuck at ")
    assert f"{value:.4g} m/s^2" in w
    assert "from 60.0 s to the end" in w
    assert f"({t.size - first + 1} samples ignored)" in w
    # the old two-argument call still works (the span is then given in samples)
    keep2, warnings2 = screen_readings("su1", accel)
    np.testing.assert_array_equal(keep2, keep)
    assert f"from sample {first - 1} to the end" in warnings2[0]


def test_an_axis_stuck_for_a_while_names_both_ends():
    t, accel = _moving_stream(seed=1)
    a, b = np.searchsorted(t, [30.0, 42.0])
    accel[a:b, 2] = accel[a - 1, 2]
    keep, warnings = screen_readings("su1", accel, t)
    assert not np.any(keep[a - 1 : b]) and np.all(keep[: a - 1]) and np.all(keep[b:])
    assert re.search(r"accelerometer z axis stuck at \S+ m/s\^2 from 30\.0 s to 42\.0 s", warnings[0])
    # a lost (NaN) sample inside the stuck span neither splits it nor hides it
    accel[a + 300] = np.nan
    keep2, warnings2 = screen_readings("su1", accel, t)
    np.testing.assert_array_equal(keep2, keep)
    assert len(warnings2) == 1 and "from 30.0 s to 42.0 s" in warnings2[0]


def test_short_repeats_and_a_still_coarsely_quantised_unit_are_not_flagged():
    # A unit at rest read through a coarse ADC (LSB 0.04 m/s^2, noise 0.002 m/s^2) whose readings
    # drift slowly by a few LSBs (warming up): every axis repeats its value for seconds, but no
    # axis moves by more than a few LSBs, so nothing is stuck.
    rng = np.random.default_rng(2)
    t = np.arange(int(60 * RATE_HZ)) / RATE_HZ
    lsb = 0.04
    g = np.array([0.37, -1.21, 9.72]) + np.outer(t / t[-1], [0.09, -0.07, 0.05])
    accel = np.round((g + rng.normal(0.0, 0.002, g.shape)) / lsb) * lsb
    longest = max(np.max(np.diff(np.flatnonzero(np.diff(accel[:, k]) != 0))) for k in range(3))
    assert longest > 2 * RATE_HZ  # repeats for more than 2 s (and more than 2 % of the samples)
    keep, warnings = screen_readings("su1", accel, t)
    assert np.all(keep) and warnings == []
    # A moving unit whose axis repeats for half a second (< 1 s and < 2 % of the samples) keeps it.
    t, accel = _moving_stream(seed=3)
    accel[1000:1050, 1] = accel[999, 1]
    keep, warnings = screen_readings("su1", accel, t)
    assert np.all(keep) and warnings == []


def test_an_axis_constant_over_the_whole_stream_is_still_an_error():
    t, accel = _moving_stream(seconds=10.0)
    accel[:, 1] = 0.37
    with pytest.raises(CalibrationError, match="y axis is stuck at 0.37"):
        screen_readings("su1", accel, t)


# ---------------------------------------------------------------------------- settling rest runs
def _ring(t: np.ndarray, a: int, b: int, amplitude: float, tau_s: float = 0.15, hz: float = 6.0) -> np.ndarray:
    """A decaying oscillation from sample ``a`` on (a servo settling after the motion), ``(b - a, 3)``."""
    s = t[a:b] - t[a]
    return amplitude * (np.exp(-s / tau_s) * np.sin(2 * np.pi * hz * s))[:, None] * np.array([1.0, -0.6, 0.3])


def test_a_run_ringing_at_its_start_is_trimmed_silently_and_a_bumped_one_dropped():
    t, rest_mask, accel, gyro, bounds = rest_runs_stream()
    ringing, bumped = 1, 4
    a, b = bounds[ringing]
    accel[a:b] += _ring(t, a, b, 3.0)
    gyro[a:b] += _ring(t, a, b, 0.5)
    clean = unit_rest_runs(rest_mask, t, *rest_runs_stream()[2:4])
    out = unit_rest_runs(rest_mask, t, accel, gyro)
    # the ringing run is kept (no warning), shorter at its start only, by at least the ringing's loud
    # part (amplitude above the 4x noise limit until ~0.4 s) and by at most half of it
    assert out.warnings == () and out.dropped.shape == (0, 2) and out.trimmed == 1
    assert len(out.bounds) == 6
    start, end = out.bounds[ringing]
    a0, b0 = clean.bounds[ringing]
    assert end == b0
    assert t[a] + 0.3 <= t[start] <= t[a] + 0.8
    assert end - start >= 0.5 * (b0 - a0)
    assert not np.any(out.rest[a:start]) and np.all(out.rest[start:end])
    np.testing.assert_array_equal(np.delete(out.bounds, ringing, axis=0), np.delete(clean.bounds, ringing, axis=0))
    # a bump in the middle of another run: that one is dropped and named, the ringing one still kept
    x, y = bounds[bumped]
    mid = (x + y) // 2
    accel[mid : mid + 8, 0] += 1.0
    out = unit_rest_runs(rest_mask, t, accel, gyro)
    assert out.trimmed == 1 and len(out.bounds) == 5
    assert len(out.warnings) == 1 and out.warnings[0].startswith("static segment moved: 1 of 6")
    np.testing.assert_allclose(out.dropped, [[t[clean.bounds[bumped][0]], t[clean.bounds[bumped][1] - 1]]])
    assert not np.any(out.rest[x:y])


def test_a_run_that_rings_for_most_of_its_length_or_moves_at_its_end_is_dropped():
    t, rest_mask, accel, gyro, bounds = rest_runs_stream(seed=1)
    a, b = bounds[2]
    accel[a:b] += _ring(t, a, b, 3.0, tau_s=0.6)  # loud for ~1.0 s of the 1.4 s run: less than half remains
    x, y = bounds[3]
    accel[x:y] += _ring(t, x, y, 3.0)
    accel[y - 25 : y, 1] += 0.8  # settles, then moves again before the run ends
    out = unit_rest_runs(rest_mask, t, accel, gyro)
    assert out.trimmed == 0 and len(out.bounds) == 4 and len(out.dropped) == 2
    assert out.warnings[0].startswith("static segment moved: 2 of 6")


# ---------------------------------------------------------------------------- end to end
def test_calibrate_ignores_the_samples_after_an_axis_sticks():
    """The robustness benchmark's base session (panda, analytic, fast protocol) with 3 units; one
    unit's x axis stuck from mid-session: with those samples the fit was off by ~28 mm."""
    from skincal.bench.robustness import Job, build_dataset
    from skincal.calib import calibrate, evaluate
    from skincal.sim.faults import session_span, stick_axis

    ds, _ = build_dataset(Job("panda", "analytic", "qd-3e-3", 0, "fast", n_units=3))
    t0, t1 = session_span(ds)
    unit, t_s = ds.units[2], t0 + 0.5 * (t1 - t0)
    faulted = stick_axis(ds, unit, 0, t_s)
    result = calibrate(faulted, "mle", workers=1)
    errors = evaluate(result, faulted).units
    assert errors[unit].position_error_mm < 1.0
    assert all(errors[u].position_error_mm < 1.0 for u in faulted.units)
    (warning,) = [w for w in result.units[unit].warnings if "stuck" in w]
    value = faulted.truth_sensor[unit]["accel_stuck_value_mps2"]
    assert warning.startswith(f"accelerometer x axis stuck at {value:.4g} m/s^2 from ")
    # named from the last sample before t_s (it holds the stuck value too), to 0.1 s
    assert float(re.search(r"from (\d+\.\d) s to the end", warning).group(1)) == pytest.approx(t_s, abs=0.07)
    assert not any("stuck" in w for u in faulted.units if u != unit for w in result.units[u].warnings)
