"""What the data say of a unit's position, for every method (``calib.position.judge_position``,
``weak_position``): rests
alone never determine it (written as null even when a fit's priors left a number), and a std beyond
``POSITION_WEAK_STD_M`` on some axis is named in a warning with the estimate kept."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skincal.calib.position import POSITION_WEAK_STD_M, judge_position, weak_position
from skincal.data.result import UnitResult, has_position
from skincal.skin.pose import SkinUnitPose


def _unit(pos_std_m, cov: bool = False) -> UnitResult:
    pose = SkinUnitPose(4, np.eye(3), np.array([0.01, 0.02, 0.03]))
    covariance = np.diag(np.r_[np.square(pos_std_m), 1e-6, 1e-6, 1e-6]) if cov else None
    return UnitResult(
        pose=pose, observable=True, position_std_m=np.asarray(pos_std_m, dtype=float),
        rotation_std_deg=np.array([0.1, 0.1, 0.1]), pose_covariance=covariance,
    )  # fmt: skip


def test_rests_only_null_the_position_even_when_a_fit_left_a_finite_std():
    # a prior-held position of a rests-only fit looks observable; rests hold no lever arm
    unit = replace(_unit([0.002, 0.002, 0.002], cov=True), warnings=(
        "unobservable: offset along the direction [1.0, 0.0, 0.0] and offset along the joint-3 axis (left at the "
        "closed-form start)", "unobservable: rotation (yaw) about the joint-1 axis and offset along the direction "
        "[0.0, 1.0, 0.0] (left at the closed-form start)", "rest poses disagree with the model",
    ))  # fmt: skip
    out = judge_position(unit, rests_only=True, static_only=True)
    # the positions-only null-space warning gives way to "not determined"; one naming a rotation stays
    assert out.warnings[:2] == unit.warnings[1:] and out.warnings[2].startswith("position not determined")
    assert not out.observable and not has_position(out)
    assert np.all(np.isnan(out.position_std_m))
    assert np.all(np.isnan(out.pose_covariance[:3, :])) and np.all(np.isnan(out.pose_covariance[:, :3]))
    np.testing.assert_allclose(out.pose_covariance[3:, 3:], 1e-6 * np.eye(3))  # the rotation is kept
    assert np.allclose(out.rotation_std_deg, 0.1)
    assert out.warnings[-1].startswith("position not determined (static poses only)")


def test_a_weak_position_is_named_with_its_axis_and_kept():
    out = weak_position(_unit([0.005, 0.364, 0.05]))
    assert out.observable and has_position(out)
    np.testing.assert_array_equal(out.pose.p_link_su, [0.01, 0.02, 0.03])
    weak = [w for w in out.warnings if w.startswith("position weakly determined")]
    assert len(weak) == 1 and "364 mm along the link's y axis" in weak[0]


@pytest.mark.parametrize("std", [POSITION_WEAK_STD_M * 0.99, np.nan])
def test_a_determined_position_gets_no_warning(std):
    unit = _unit([0.001, std, 0.002])
    assert weak_position(unit).warnings == () and judge_position(unit, rests_only=False, static_only=False) is unit
