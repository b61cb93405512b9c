"""Fixtures of the calibration tests: the Monte Carlo sessions of the reported std (``monte_carlo.py``),
simulated and calibrated once per test run."""

from __future__ import annotations

import pytest
from monte_carlo import McSession, coloured_session, white_session


@pytest.fixture(scope="session")
def mc_white() -> McSession:
    """300 units (100 replicas on each of links 2, 3, 4), ``realistic`` IMUs, white noise (simulated)."""
    return white_session()


@pytest.fixture(scope="session")
def mc_coloured() -> McSession:
    """80 units (40 replicas on links 3 and 4), AR(1) accelerometer noise (simulated)."""
    return coloured_session()
