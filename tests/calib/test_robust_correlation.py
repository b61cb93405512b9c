"""Integrated autocorrelation of a noise seen only in short runs about their own means
(``skincal.calib.robust.run_correlation``, what the rest-pose test of ``mle`` scales the rest noise by)
against the closed form of AR(1) noise: ``rho_k = phi^k``, so the truncated sum the estimators form
is ``1 + 2 sum_(k < K) phi^k`` with ``K`` the first lag at which ``phi^K <= 0.05`` (simulated noise)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from skincal.calib.robust import RHO_CUTOFF, residual_correlation, run_correlation


def ar1_runs(rng: np.random.Generator, phi: float, runs: int, length: int) -> list[np.ndarray]:
    """``runs`` independent stationary AR(1) runs ``(length, 3)`` of unit variance."""
    out = []
    for _ in range(runs):
        w = rng.normal(0.0, np.sqrt(1.0 - phi**2), (length, 3))
        out.append(lfilter([1.0], [1.0, -phi], w, axis=0, zi=phi * rng.normal(0.0, 1.0, (1, 3)))[0])
    return out


def truncated_tau(phi: float) -> float:
    """``1 + 2 sum phi^k`` over the lags before the first with ``phi^k <=`` :data:`RHO_CUTOFF`."""
    k = np.arange(1, 200)
    rho = phi**k
    end = int(np.flatnonzero(rho <= RHO_CUTOFF)[0]) if phi > 0 else 0
    return 1.0 + 2.0 * float(np.sum(rho[:end]))


@pytest.mark.parametrize(("phi", "length"), [(0.6, 40), (0.6, 100), (0.8, 80)])
def test_short_runs_give_the_noise_correlation(phi, length):
    """Many short runs: the corrected estimate is the closed form within 6 %; the deviations' plain
    autocorrelation (each run's mean taking some correlation away) is low by more than 10 %."""
    rng = np.random.default_rng(3)
    runs = ar1_runs(rng, phi, 4000 // length * 10, length)
    expected = truncated_tau(phi)
    tau = run_correlation(runs)
    plain = residual_correlation(np.concatenate([r - r.mean(axis=0) for r in runs]))
    assert tau == pytest.approx(expected, rel=0.06), (tau, expected)
    assert plain < 0.9 * expected, (plain, expected)


def test_few_runs_of_a_rest_session_are_unbiased_on_average():
    """Five runs of 28 samples (a short protocol's rests): over 300 draws the median estimate is the closed
    form within 10 % (the plain estimate: 0.69 of it)."""
    rng = np.random.default_rng(4)
    taus = [run_correlation(ar1_runs(rng, 0.6, 5, 28)) for _ in range(300)]
    assert np.median(taus) == pytest.approx(truncated_tau(0.6), rel=0.10), np.median(taus)


def test_white_noise_gives_one_and_long_runs_agree_with_the_plain_estimate():
    rng = np.random.default_rng(5)
    assert run_correlation([rng.normal(size=(60, 3)) for _ in range(20)]) == pytest.approx(1.0, abs=0.05)
    long = ar1_runs(rng, 0.6, 1, 20000)
    assert run_correlation(long) == pytest.approx(residual_correlation(long[0]), rel=0.01)


def test_too_few_samples_give_one():
    """Below 50 samples (5 lags of 10 samples each) there is nothing to estimate: white is assumed."""
    rng = np.random.default_rng(6)
    assert run_correlation(ar1_runs(rng, 0.9, 4, 12)) == 1.0
    assert run_correlation([]) == 1.0
    assert run_correlation([np.zeros((100, 3))]) == 1.0
