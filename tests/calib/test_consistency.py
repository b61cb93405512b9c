"""The split check (skincal.calib.consistency): independent parts of a recording calibrated and compared.

Simulated data only here (the real recordings are checked by ``skincal benchmark realdata``)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skincal.calib import calibrate
from skincal.calib.consistency import (
    EXCITATION_WINDOW_S,
    PART_STD_LIMIT,
    SPLITS,
    apply,
    axis_inflation,
    block_inflation,
    compare,
    judge,
    lively_windows,
    part_masks,
)
from skincal.data.result import UnitResult
from skincal.sim import simulate
from skincal.skin.pose import SkinUnitPose
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
    lively = np.arange(10) % 3 == 0  # 10 windows of 2 s, 4 of them lively
    masks = part_masks(t, 0.0, 20.0, lively)
    assert set(masks) == set(SPLITS)
    for a, b in masks.values():
        assert not np.any(a & b) and np.all(a | b)
        assert 0.35 < a.mean() < 0.65
    assert np.array_equal(masks["excitation"][1], lively[np.minimum((t // 2.0).astype(int), 9)])
    assert "excitation" not in part_masks(t, 0.0, 20.0)  # no ranking: no excitation split


def test_block_inflation_is_one_below_the_quantile_and_the_excess_above():
    assert block_inflation(np.ones(6))[2] == 1.0  # chi2 6 on 6 dof
    c2, dof, f = block_inflation(np.full(6, 4.0))  # every component 4 std apart
    assert (c2, dof) == (96.0, 6) and f == pytest.approx(4.0)
    assert block_inflation(np.array([np.nan, 10.0]))[1] == 1  # undetermined components do not count


def test_the_disagreeing_axis_is_inflated_not_the_block():
    """A lever arm that disagrees along z only (4 std in each split) inflates z by 4, x and y not at all;
    a consistent block inflates nothing."""
    z = np.array([[0.3, -0.5, 4.0], [0.1, 0.4, -4.0], [np.nan, 0.2, 4.0]])
    c2, dof, f = block_inflation(z)
    assert f > 1.0 and dof == 8
    assert axis_inflation(z, f) == pytest.approx((1.0, 1.0, 4.0))
    assert axis_inflation(z, 1.0) == (1.0, 1.0, 1.0)


def _unit(p_mm, std_mm, std_deg=0.1):
    pose = SkinUnitPose(link=2, R_link_su=np.eye(3), p_link_su=1e-3 * np.asarray(p_mm, dtype=float))
    std = 1e-3 * np.asarray(std_mm, dtype=float)
    return UnitResult(pose=pose, position_std_m=std, rotation_std_deg=np.full(3, std_deg))


def test_the_warning_names_what_disagrees_or_says_none_alone_does():
    """Two std on every component of every split inflate the block (chi2 72 on 18 dof) with no component
    beyond Z_NAMED: the warning says so instead of printing empty parentheses."""
    unit = _unit([0, 0, 0], [1.0, 1.0, 1.0])
    jointly = apply(unit, judge(np.full((len(SPLITS), 6), 2.0), [], []))
    (warning,) = [w for w in jointly.warnings if "disagree" in w]
    assert "()" not in warning and "jointly" in warning
    assert np.allclose(jointly.position_std_m, 2e-3)
    named = apply(unit, judge(np.full((len(SPLITS), 6), 2.0), ["position z +4.0 mm (4.0 std, time)"], []))
    assert "(position z +4.0 mm (4.0 std, time))" in [w for w in named.warnings if "disagree" in w][0]


def test_a_part_in_another_basin_is_warned_of_and_a_part_with_too_little_data_is_not():
    """A streamed part whose rotation fit lies 30 deg or more from the whole's is not compared; it was only in the
    consistency block (a dead gyroscope's unit on the wrong link, 304 mm off, had one and no warning)."""
    from skincal.calib.consistency import ANOTHER_BASIN

    unit = _unit([0, 0, 0], [1.0, 1.0, 1.0])
    z = np.full((len(SPLITS), 6), np.nan)
    far = apply(unit, judge(z, [], [f"time part 2: {ANOTHER_BASIN} (41 deg away)"]))
    (warning,) = [w for w in far.warnings if "far from the whole" in w]
    assert "time part 2: its fit is another basin (41 deg away)" in warning
    assert far.extras["consistency"]["failed"] == ["time part 2: its fit is another basin (41 deg away)"]
    short = apply(unit, judge(z, [], ["time part 1: too little data"]))
    assert short.warnings == ()


def test_a_part_that_does_not_determine_a_component_is_not_compared():
    """The calm half of a recording may not turn the unit's only joint: its position along x comes out
    1000 mm off with a 500 mm std (a 2-std difference that means nothing); the component is left out
    beyond PART_STD_LIMIT times the full result's std, the others compared."""
    full = _unit([0, 0, 0], [1.0, 1.0, 1.0])
    calm, lively = _unit([1000.0, 0.5, 0.0], [500.0, 1.0, 1.0]), _unit([0.0, 0.0, 0.0], [1.2, 1.2, 1.2])
    z, _ = compare({"excitation": (calm, lively)}, full)
    row = z[SPLITS.index("excitation")]
    assert np.isnan(row[0]) and row[1] == pytest.approx(-0.5 / np.hypot(1.0, 1.2))
    assert 500.0 > PART_STD_LIMIT * 1.0
    z_all, _ = compare({"excitation": (calm, lively)})  # without the full result every component counts
    assert np.isfinite(z_all[SPLITS.index("excitation"), 0])


def test_lively_windows_rank_the_links_own_motion(honest):
    """The excitation split's livelier half: the windows where the unit's link turns faster than in the
    median window, from the joint stream (half the windows, and every one of them faster than every calm one)."""
    ds, result = honest
    link = result.units["su6"].pose.link
    lively = lively_windows(ds, link)
    j = ds.joints
    speed = np.linalg.norm(ds.robot.link_motion(j.q, j.qd, np.zeros_like(j.q), upto=link).omega[:, link], axis=1)
    index = np.floor((np.asarray(j.t) - j.t[0]) / EXCITATION_WINDOW_S).astype(int)
    mean = np.array([speed[index == k].mean() for k in range(lively.size)])
    assert lively.size == index.max() + 1 and abs(lively.mean() - 0.5) <= 1.0 / lively.size
    assert mean[lively].min() > mean[~lively].max() * 0.999  # thinned to 50 Hz: ranks, not exact means


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
    full = 6 * len(SPLITS) * len(result.units)  # components a part does not determine are not compared
    assert 0.9 * full <= dof <= full, (dof, full)
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
