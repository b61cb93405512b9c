"""``skincal benchmark mle`` (issue 27): ``--quick`` is a smoke test of every part on every robot."""

from __future__ import annotations

import pytest

from skincal.bench.mle import QUICK_RUNS, run_mle_benchmark
from skincal.cli import main


def test_runs_below_one_is_a_usage_error(capsys):
    assert main(["benchmark", "mle", "--quick", "--runs", "0"]) == 2
    assert "--runs must be at least 1" in capsys.readouterr().err


@pytest.mark.slow
def test_quick_runs_two_placements_per_robot_and_finishes_on_every_robot():
    """It failed on the Sawyer's second placement (no collision-free static pose) and ran 20 placements."""
    doc = run_mle_benchmark(quick=True, with_om=False)
    assert doc["runs"] == QUICK_RUNS == 2 and doc["quick"] is True
    for robot in ("panda", "sawyer", "ur5e"):
        assert doc[f"realistic_{robot}"]["runs"] == QUICK_RUNS, doc[f"realistic_{robot}"]
