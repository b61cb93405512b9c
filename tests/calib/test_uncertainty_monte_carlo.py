"""Every std ``mle`` reports, pinned to a Monte Carlo of its own estimates (issue 27, item 3).

Replica sessions (``monte_carlo.py``, fixtures in ``conftest.py``): 100 units at each of three poses
(links 2, 3, 4 of the Panda), each with its own IMU errors and noise (simulated). For every
component the errors divided by the reported std must have ``mean(z^2)`` inside the chi-square
interval of their sample count (``ALPHA = 2e-4`` two-sided): per axis at each pose (100 dof:
spread/std within 0.75-1.27) and over all poses (300 dof: 0.85-1.15), per quantity (about 900 dof:
0.91-1.09) and all together (about 2800 dof: 0.95-1.05, so every std scaled by 1.11 fails).

Rotation errors are rotation vectors about the *link* axes (``rotvec(R_est R_true^T)``, what
``rotation_std_deg``, ``Z_d`` and the exports read); the session's static poses give a narrow cone of
gravity directions, so the rotation std differ per axis by up to 1.8x and the same std about the
unit's axes fail at each pose (measured: spread/std 0.65-1.50). The coloured-noise session (AR(1)
accelerometer noise, integrated autocorrelation 4) checks the factor the covariance is inflated by.
Measured on this session (white): spread/std 0.91-1.04 per axis over all poses, 0.993 all together.
"""

from __future__ import annotations

import numpy as np
import pytest
from monte_carlo import AR1_PHI, QUANTITIES, normalised_errors, variance_ratio

AXES = {"position": "xyz", "rotation": "xyz", "accel_bias": "xyz", "time_offset": ("",)}


@pytest.mark.parametrize(
    ("quantity", "axis"), [(q, i) for q in QUANTITIES for i in range(len(AXES[q]))],
    ids=[f"{q}{a}" for q in QUANTITIES for a in AXES[q]],
)
def test_each_std_component_matches_the_spread(mc_white, quantity, axis):
    """Each component's std (position x/y/z in the link frame, rotation about the link's x/y/z, bias
    x/y/z, time offset) against the spread of the 100 estimates at each pose and of all 300
    (simulated)."""
    lines, ok = [], True
    for group in (*mc_white.groups, mc_white.units):
        z = normalised_errors(mc_white.result, mc_white.dataset, list(group))[quantity][:, axis]
        ratio = variance_ratio(z)
        ok &= ratio.ok
        where = "all" if len(group) > len(mc_white.groups[0]) else f"link {mc_white.result.units[group[0]].pose.link}"
        lines.append(f"{where}: {ratio}")
    assert ok, f"{quantity} {AXES[quantity][axis]}:\n" + "\n".join(lines)


@pytest.mark.parametrize("quantity", QUANTITIES)
def test_each_quantity_std_matches_the_spread(mc_white, quantity):
    """All components of a quantity pooled (dof by Satterthwaite from their correlation)."""
    ratio = variance_ratio(normalised_errors(mc_white.result, mc_white.dataset, mc_white.units)[quantity])
    assert ratio.ok, f"{quantity}: {ratio}"


def test_all_std_together_match_the_spread(mc_white):
    """All ten components of 300 units at once: a common scale of every std by 1.11 fails."""
    errors = normalised_errors(mc_white.result, mc_white.dataset, mc_white.units)
    ratio = variance_ratio(np.hstack([errors[q] for q in QUANTITIES]))
    assert ratio.ok, str(ratio)
    assert ratio.dof > 2000  # the pool is as sharp as the docstring says


def test_white_session_has_no_autocorrelation_inflation(mc_white):
    """White accelerometer noise on an exact joint stream: the residuals' factor is 1 (the control of the
    coloured session below)."""
    factors = [mc_white.result.units[u].extras["residual_correlation"] for u in mc_white.units]
    assert max(factors) < 1.2, max(factors)


def test_autocorrelation_factor_measures_coloured_noise(mc_coloured):
    """AR(1) accelerometer noise with lag-1 correlation 0.6: integrated autocorrelation ``(1 + phi) /
    (1 - phi) = 4``; the factor the covariance is inflated by is that, not 1.00 (the estimator sums
    the lags until one is below 0.05: 3.77 for this noise; measured median 3.74, range 3.38-4.17)."""
    factors = np.array([mc_coloured.result.units[u].extras["residual_correlation"] for u in mc_coloured.units])
    expected = (1 + AR1_PHI) / (1 - AR1_PHI)
    assert 0.85 * expected < np.median(factors) < 1.05 * expected, np.median(factors)
    assert np.all((factors > 0.7 * expected) & (factors < 1.3 * expected)), (factors.min(), factors.max())


def test_coloured_noise_std_covers_the_spread(mc_coloured):
    """With correlated residuals the reported std is never smaller than the spread (the upper end of the
    interval, per quantity and pooled): without the autocorrelation inflation it is (by sqrt(3.7))."""
    errors = normalised_errors(mc_coloured.result, mc_coloured.dataset, mc_coloured.units)
    for quantity in QUANTITIES:
        ratio = variance_ratio(errors[quantity])
        assert ratio.value <= ratio.high, f"{quantity}: {ratio}"
    ratio = variance_ratio(np.hstack([errors[q] for q in QUANTITIES]))
    assert ratio.value <= ratio.high, str(ratio)


def test_coloured_noise_std_matches_the_spread(mc_coloured):
    """Two-sided: with correlated residuals the std match the spread as they do with white noise (the rest
    means' noise credited with the correlation measured inside 28-55 sample rest runs, corrected for each
    run's own mean: pooled spread/std 1.00, 0.81 with the plain estimate; measured, simulated)."""
    errors = normalised_errors(mc_coloured.result, mc_coloured.dataset, mc_coloured.units)
    ratio = variance_ratio(np.hstack([errors[q] for q in QUANTITIES]))
    assert ratio.ok, str(ratio)
