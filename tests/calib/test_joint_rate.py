"""The report-spacing check (:mod:`skincal.calib.joint_rate`): Richardson's extrapolation of the error a
low-rate joint stream leaves in the pose, against closed forms and simulated streams."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skincal.calib import joint_rate as jr
from skincal.data.result import UnitResult
from skincal.skin.pose import SkinUnitPose

P_TRUE = np.array([0.01, -0.02, 0.09])
R_TRUE = Rotation.from_rotvec([0.1, -0.2, 0.3]).as_matrix()
C = np.array([0.4, -0.2, 1.5, 0.3, 0.1, -0.6])
"""Error coefficients per pose component (position m, rotation rad) at a report spacing of 1 s."""


def _unit(k: int, h: float, p: float, link: int = 6, std: float = 1e-3) -> UnitResult:
    """A unit result off the truth by ``C (k h)^p`` (position, then a rotation vector about the link axes)."""
    e = C * (k * h) ** p
    R = Rotation.from_rotvec(e[3:]).as_matrix() @ R_TRUE
    return UnitResult(
        SkinUnitPose(link, R, P_TRUE + e[:3]), position_std_m=np.full(3, std), rotation_std_deg=np.full(3, 0.1),
        pose_covariance=np.diag(np.r_[np.full(3, std**2), np.full(3, np.radians(0.1) ** 2)]),
    )  # fmt: skip


@pytest.mark.parametrize("p", [1.2, 2.0, 3.0, 3.9])
def test_order_from_ratio_inverts_the_closed_form(p):
    ratio = (2.0**p - 1.0) / (3.0**p - 1.0)
    assert jr.order_from_ratio(ratio) == pytest.approx(p, abs=1e-5)


def test_order_from_ratio_clips_to_its_range():
    assert jr.order_from_ratio(0.5) == jr.ORDER_RANGE[0] and jr.order_from_ratio(0.9) == jr.ORDER_RANGE[0]
    assert jr.order_from_ratio(0.05) == jr.ORDER_RANGE[1] and jr.order_from_ratio(float("nan")) == jr.ORDER_RANGE[0]


@pytest.mark.parametrize("p", [1.5, 2.0, 3.0])
def test_the_term_recovers_the_full_fits_error_when_it_follows_a_power_of_the_spacing(p):
    """Small errors ``C (k h)^p`` for ``k = 1, 2, 3``: ``b`` is the full fit's own error (the rotation to
    second order of the small rotations composed)."""
    h = 0.01
    full = _unit(1, h, p)
    half, third = [_unit(2, h, p)] * 2, [_unit(3, h, p)] * 3
    t, why = jr.term(full, half, third, rate_hz=1.0 / h)
    assert t is not None, why
    assert t.order == pytest.approx(p, abs=0.02)
    e = C * h**p
    assert np.allclose(t.bias_position_m, e[:3], rtol=1e-6, atol=1e-12)
    assert np.allclose(np.radians(t.bias_rotation_deg), e[3:], rtol=0.02)
    assert t.fits == 5 and t.report_rate_hz == pytest.approx(100.0)


def test_no_term_outside_richardsons_regime_or_on_another_link():
    """Thinned fits that jump (ratio 0.5 or more: p <= 1) or move the unit to another link give no
    term, and say why."""
    h = 0.01
    full = _unit(1, h, 2.0)
    t, why = jr.term(full, [_unit(2, h, 0.5)] * 2, [_unit(3, h, 0.5)] * 3, 100.0)
    assert t is None and "do not resolve the motion" in why and "ratio" in why
    t, why = jr.term(full, [_unit(2, h, 2.0, link=5)] * 2, [_unit(3, h, 2.0)] * 3, 100.0)
    assert t is None and "could not be calibrated" in why
    t, why = jr.term(full, [_unit(2, h, 2.0)], [_unit(3, h, 2.0)] * 3, 100.0)  # one half-rate fit failed
    assert t is None


def test_apply_adds_the_term_in_quadrature_and_to_the_covariance():
    full = _unit(1, 0.01, 2.0)
    t = jr.JointRateTerm(14.0, 2.0, 0.375, (0.0, 0.002, -0.0005), (0.05, 0.0, 0.0), 5)
    out = jr.apply(full, t)
    b = np.r_[t.bias_position_m, np.radians(t.bias_rotation_deg)]
    assert np.allclose(out.pose_covariance, np.asarray(full.pose_covariance) + np.outer(b, b), rtol=1e-12)
    assert np.allclose(out.position_std_m, np.sqrt(1e-6 + np.square(t.bias_position_m)), rtol=1e-12)
    assert np.allclose(out.rotation_std_deg, np.sqrt(0.01 + np.square(t.bias_rotation_deg)), rtol=1e-12)
    assert np.allclose(np.sqrt(np.diag(out.pose_covariance))[:3], out.position_std_m, rtol=1e-12)
    # the pose is not moved; the one component whose term exceeds its std is named
    assert np.array_equal(out.pose.p_link_su, full.pose.p_link_su)
    said = [w for w in out.warnings if "14 Hz reports limit this pose" in w]
    assert len(said) == 1 and "position y +2.0 mm" in said[0] and "position z" not in said[0]
    assert out.extras["joint_rate"]["order"] == 2.0 and out.extras["joint_rate"]["fits"] == 5


def test_thinned_keeps_every_kth_report():
    from skincal.data.dataset import Dataset, JointStates

    t = np.arange(20) * 0.07
    q = np.c_[np.sin(t), np.cos(t)]
    ds = Dataset(robot=None, joints=JointStates(t, q, np.gradient(q, t, axis=0)), imu={})
    for every, phase in ((2, 0), (2, 1), (3, 2)):
        th = jr.thinned(ds, every, phase).joints
        assert np.array_equal(th.t, t[phase::every]) and np.array_equal(th.q, q[phase::every])
        assert th.qdd is None
    assert ds.joints.t.size == 20  # the input is not modified


def test_the_thinnings_are_those_that_keep_enough_reports():
    """Every second and every third report while each keeps MIN_THINNED_REPORTS; a shorter stream only the
    thinnings that still do (what the progress line names and counts)."""
    assert jr.thinnings(np.arange(90)) == (2, 3)
    assert jr.thinnings(np.arange(89)) == (2,)
    assert jr.thinnings(np.arange(59)) == ()
