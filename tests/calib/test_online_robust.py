"""The streaming calibrator's robust loss: once a unit is settled its samples are Huber-weighted by their
residual, as ``mle``'s Gauss-Newton weights them (:func:`skincal.calib.online.fit.robust_weights`)."""

from __future__ import annotations

from collections import deque

import numpy as np
import pytest

from skincal.calib.online import OnlineCalibrator, fit, replay


@pytest.fixture(scope="module")
def clean():
    """A simulated Panda session (``fast``, ``realistic`` IMUs), its first four units (links 2-5)."""
    from dataclasses import replace

    from skincal.workflows.session import simulate_dataset

    ds = simulate_dataset("panda", "paper", noise="realistic", protocol="fast", seed=1)
    units = ("su1", "su2", "su3", "su4")
    return replace(ds, imu={u: ds.imu[u] for u in units}, truth={u: ds.truth[u] for u in units})


def _spiky(ds):
    """``ds`` whose accelerometers read a spike of 0.5 m/s^2 (about 16 noise std of ``realistic``'s 0.031 m/s^2) in a
    random direction in 5 % of their samples away from the rails: heavy tails, above the 6-std gate at rest, under
    it in the moving class's larger std."""
    from dataclasses import replace

    rng = np.random.default_rng(7)
    imu = {}
    for name, stream in ds.imu.items():
        a = stream.accel.copy()
        hit = (rng.random(len(a)) < 0.05) & (np.abs(a) < 15.0).all(axis=1)  # a clipped reading stays at its rail
        d = rng.normal(size=(int(hit.sum()), 3))
        a[hit] += 0.5 * d / np.linalg.norm(d, axis=1, keepdims=True)
        imu[name] = replace(stream, accel=a)
    return replace(ds, imu=imu)


def _positions(ds) -> np.ndarray:
    cal = OnlineCalibrator(ds.robot, list(ds.imu), ds.gravity)
    replay(ds, cal, chunk_s=0.1)
    result = cal.result()
    return np.array([result.units[u].pose.p_link_su for u in ds.imu])


def test_huber_weights_keep_heavy_tailed_readings_from_moving_the_estimate(clean, monkeypatch):
    """SIMULATED. The same session with and without spikes: the streamed positions move by the spikes at
    most 0.7 times as much with the Huber weights as without them (measured: 0.52)."""
    spiky = _spiky(clean)
    reference = _positions(clean)
    robust = np.linalg.norm(_positions(spiky) - reference, axis=1)
    monkeypatch.setattr(fit, "HUBER", False)
    plain = np.linalg.norm(_positions(spiky) - reference, axis=1)
    print("moved by the spikes, mm: robust", 1e3 * robust, "plain", 1e3 * plain)
    assert robust.mean() <= 0.7 * plain.mean()


def test_robust_weights_gate_and_weigh_only_a_settled_unit():
    rn = np.array([[0.5, 0.0, 0.0], [0.0, 4.0, 0.0], [20.0, 0.0, 0.0], [0.0, 0.0, -6.0]])
    unsettled = deque([1.5382] * 500)
    keep, w = fit.robust_weights(rn, False, unsettled)
    assert keep.all() and w is None and len(unsettled) == 500  # not settled: every sample in full, no scale
    keep, w = fit.robust_weights(rn, True, deque(maxlen=100))
    assert keep.tolist() == [True, True, False, True] and w is None  # 20 > 6 sqrt(3); no scale yet
    recent = deque([1.5382] * 500, maxlen=4096)  # norms whose median gives a scale of 1 class std
    keep, w = fit.robust_weights(rn, True, recent)
    np.testing.assert_allclose(w, [1.0, 3.0 / 4.0, 3.0 / 6.0], rtol=1e-3)  # min(1, 3 c / |rn|), c = 1
    assert len(recent) == 504  # the new norms join the scale's sample
    _, w = fit.robust_weights(rn, True, deque([0.0] * 500))  # exact fits so far: the scale's floor, no NaN
    np.testing.assert_allclose(w, [0.6, 0.3 / 4.0, 0.3 / 6.0])
