"""The gyroscope scale check (skincal.calib.gyro) against a closed form and Monte Carlo."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from skincal.calib.gyro import gyro_scale


def _readings(rng, A, noise=0.0, M=2000):
    R = Rotation.random(random_state=rng).as_matrix()
    w = rng.normal(scale=1.0, size=(M, 3))
    b = rng.normal(scale=0.01, size=3)
    g = w @ R @ A.T + b + rng.normal(scale=noise, size=(M, 3)) if noise else w @ R @ A.T + b
    return R, w, g, b


def test_symmetric_scale_recovered_whatever_the_rotation():
    rng = np.random.default_rng(0)
    A = np.diag([1.045, 0.97, 1.02]) + 0.004 * np.array([[0, 1, -1], [1, 0, 2], [-1, 2, 0]])
    R, w, g, b = _readings(rng, A)
    est = gyro_scale(w, g)
    assert est is not None
    assert np.abs(est.A - A).max() < 1e-9
    assert np.abs(est.bias - b).max() < 1e-9
    # corrected readings are those of a perfect gyroscope: R^T w (+ the bias, scaled)
    assert np.abs((g - b) @ np.linalg.inv(est.A).T - w @ R).max() < 1e-9
    assert est.off


def test_diagonal_std_matches_monte_carlo_and_an_ideal_gyro_is_not_off():
    rng = np.random.default_rng(1)
    diag, pred = [], []
    for _ in range(200):
        _, w, g, _ = _readings(rng, np.eye(3), noise=0.01, M=400)
        est = gyro_scale(w, g)
        diag.append(np.diag(est.A))
        pred.append(est.diag_std)
    emp = np.std(diag, axis=0)
    assert np.allclose(emp, np.mean(pred, axis=0), rtol=0.2), (emp, np.mean(pred, axis=0))
    draws = (_readings(np.random.default_rng(k), np.eye(3), noise=0.01, M=400) for k in range(50))
    offs = sum(gyro_scale(w, g).off for _, w, g, _ in draws)
    assert offs <= 2


def test_motion_about_one_axis_does_not_determine_the_scale():
    rng = np.random.default_rng(2)
    w = np.zeros((500, 3))
    w[:, 2] = rng.normal(size=500)
    assert gyro_scale(w, w.copy()) is None
