"""Which methods write ``pose_covariance`` (issue 27: docs/interfaces.md said both that none does and that
``online`` does, and that mle's report-spacing term is in it): ``mle`` and the paper's methods give per-axis
std only, ``online`` the full 6x6; the contract text says so and nothing else."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from skincal.calib import calibrate
from skincal.workflows.session import simulate_dataset

INTERFACES = Path(__file__).resolve().parents[2] / "docs" / "interfaces.md"


@pytest.fixture(scope="module")
def small():
    """Panda, 2 random units, ``fast``, ``realistic`` IMUs (simulated)."""
    return simulate_dataset("panda", "random", 2, "realistic", "fast", seed=5)


@pytest.mark.parametrize("method", ["mle", "om"])
def test_batch_methods_write_no_pose_covariance(small, method):
    result = calibrate(small, method, use_truth_links=method == "om")
    assert result.units
    for unit in result.units.values():
        assert unit.pose_covariance is None
        assert (unit.position_std_m is not None) == (method == "mle")  # the paper's OM gives no std at all


def test_the_contract_names_online_as_the_only_writer():
    text = INTERFACES.read_text(encoding="utf-8")
    assert "of the methods only the streaming\n  calibrator `online` writes one" in text
    assert "`pose_covariance` (written by `online` only)" in text
    assert not re.search(r"no method writes `?pose_covariance", text)
    assert "`b b^T` is in `pose_covariance`" not in text  # mle's report-spacing term is in the std
