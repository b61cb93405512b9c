"""Joint-state preprocessing against closed forms: qdd estimate, interpolation, nearest samples."""

from __future__ import annotations

import numpy as np
import pytest

from skincal.calib.preprocess import JointInterpolator, estimate_qdd, tag_segments
from skincal.data.dataset import JointStates, Segments
from skincal.errors import CalibrationError

W = 2 * np.pi * 0.7


def sine_stream(rate_hz: float = 1000.0, seconds: float = 4.0) -> JointStates:
    t = np.arange(0.0, seconds, 1.0 / rate_hz)
    A = np.array([0.3, -0.5])
    q = np.sin(W * t)[:, None] * A
    qd = W * np.cos(W * t)[:, None] * A
    return JointStates(t=t, q=q, qd=qd)


def exact(t):
    A = np.array([0.3, -0.5])
    return (np.sin(W * t)[:, None] * A, W * np.cos(W * t)[:, None] * A, -(W**2) * np.sin(W * t)[:, None] * A)


def test_qdd_estimate_matches_the_closed_form():
    js = sine_stream()
    _, _, qdd = estimate_qdd(js)
    inner = slice(100, -100)
    np.testing.assert_allclose(qdd[inner], exact(js.t)[2][inner], atol=2e-3)


def test_interpolation_at_arbitrary_instants():
    js = sine_stream()
    ip = JointInterpolator(js)
    t = np.random.default_rng(0).uniform(0.2, 3.8, 500)
    for got, want, tol in zip(ip(t), exact(t), (1e-9, 1e-6, 2e-3), strict=True):
        np.testing.assert_allclose(got, want, atol=tol)


def test_nearest_and_grid_use_the_same_fit_as_the_full_estimate():
    js = sine_stream()
    ip = JointInterpolator(js)
    _, _, full = estimate_qdd(js)
    t = js.t[::13] + 1e-4
    q, qd, qdd = ip.nearest(t)
    i = np.arange(0, js.t.size, 13)
    np.testing.assert_array_equal(q, js.q[i])
    np.testing.assert_allclose(qdd[5:-5], full[i][5:-5], atol=1e-10)
    tg, _, _, qdd_g = ip.on_grid(8)
    np.testing.assert_array_equal(tg, js.t[::8])
    np.testing.assert_allclose(qdd_g[5:-5], full[::8][5:-5], atol=1e-10)


def test_uneven_streams_are_resampled_and_outside_instants_rejected():
    js = sine_stream()
    keep = np.ones(js.t.size, dtype=bool)
    keep[1000:1003] = False  # a small gap
    uneven = JointStates(t=js.t[keep], q=js.q[keep], qd=js.qd[keep])
    ip = JointInterpolator(uneven)
    t = np.linspace(0.5, 3.5, 50)
    np.testing.assert_allclose(ip(t)[0], exact(t)[0], atol=1e-8)
    with pytest.raises(CalibrationError, match="outside the joint stream"):
        ip(np.array([5.0]))


def test_segment_tags():
    seg = Segments(np.array([0.0, 2.0]), np.array([1.0, 3.0]), np.array([0, 1]), np.array([0, 0]), np.array([-1, 1]))
    np.testing.assert_array_equal(tag_segments(np.array([-0.5, 0.5, 1.5, 2.5, 3.5]), seg), [-1, 0, -1, 1, -1])
