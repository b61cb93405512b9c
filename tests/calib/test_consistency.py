"""The split check (skincal.calib.consistency): independent parts of a recording calibrated and compared.

Simulated data only here (the real recordings are checked by ``skincal benchmark realdata``)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skincal.calib import calibrate
from skincal.calib.consistency import SPLITS, block_inflation, part_masks
from skincal.sim import simulate
from skincal.workflows.session import make_session


def _session(seed: int, **imu):
    ses = make_session("panda", "random", 6, "realistic", "fast", seed, joints="controller")
    if imu:
        ses = replace(ses, imu_model=replace(ses.imu_model, **imu))
    return simulate(ses, "analytic")


@pytest.fixture(scope="module")
def honest():
    ds = _session(0)
    return ds, calibrate(ds, "mle")


def test_parts_split_every_sample_once():
    t = np.linspace(0.0, 20.0, 2001)
    for split, (a, b) in part_masks(t, 0.0, 20.0).items():
        assert split in SPLITS
        assert not np.any(a & b) and np.all(a | b)
        assert 0.4 < a.mean() < 0.6


def test_block_inflation_is_one_below_the_quantile_and_the_excess_above():
    assert block_inflation(np.ones(6))[2] == 1.0  # chi2 6 on 6 dof
    c2, dof, f = block_inflation(np.full(6, 4.0))  # every component 4 std apart
    assert (c2, dof) == (96.0, 6) and f == pytest.approx(4.0)
    assert block_inflation(np.array([np.nan, 10.0]))[1] == 1  # undetermined components do not count


def test_honest_simulated_std_are_not_inflated(honest):
    """Every unit carries the block; on honest data the parts agree (chi-square per dof near 1, no
    inflation) and the std stay what the fit reported."""
    ds, result = honest
    chi2, dof = 0.0, 0
    for name, unit in result.units.items():
        c = unit.extras["consistency"]
        assert c["inflation_position"] == 1.0 and c["inflation_rotation"] == 1.0, (name, c)
        assert not c["failed"]
        assert not any("gyroscope scale" in w for w in unit.warnings), unit.warnings
        chi2 += c["chi2_position"] + c["chi2_rotation"]
        dof += c["dof_position"] + c["dof_rotation"]
    assert dof == 12 * len(result.units)
    assert 0.5 < chi2 / dof < 1.6, chi2 / dof
    off = calibrate(ds, "mle", consistency=False)
    for name, unit in result.units.items():
        assert "consistency" not in off.units[name].extras
        assert np.array_equal(unit.position_std_m, off.units[name].position_std_m)


def test_an_unmodelled_gyroscope_scale_is_caught():
    """mle carries no gyroscope scale: 4.5 % per axis (and 1 % misalignment) biases the rotations; the
    parts disagree and the rotation std is inflated, with a warning, on most units."""
    ds = _session(0, gyro_scale_std=0.045, gyro_misalignment_std=0.01)
    result = calibrate(ds, "mle")
    caught = [n for n, u in result.units.items() if u.extras["consistency"]["inflation_rotation"] > 1.5]
    assert len(caught) >= 4, caught
    for name in caught:
        assert any("independent parts of the recording disagree" in w for w in result.units[name].warnings)
    for name, unit in result.units.items():  # and the gyroscope itself is named (calib.gyro): never silent
        assert any("gyroscope scale off the robot's rotation rate" in w for w in unit.warnings), (name, unit.warnings)
