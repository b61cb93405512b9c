"""The issue-17 benchmark matrix at CI size: one robot, one scenario, short runs."""

from __future__ import annotations

import numpy as np
import pytest

from skincal.bench.avoid import run_iso_benchmark

pytest.importorskip("mujoco")


def test_iso_matrix_rows_and_the_degraded_margin_grows():
    seen = []
    rows = run_iso_benchmark(
        robots=("ur5e",),
        scenarios=("walk-at",),
        modes=("kinematic",),
        labels=("truth", "degraded 5cm/5deg"),
        duration=2.6,
        report=lambda text: None,
        on_run=lambda row, log: seen.append(log.t.size),
    )
    assert [r["poses"] for r in rows] == ["truth", "degraded 5cm/5deg"] and seen == [2600, 2600]
    truth, bad = rows
    for r in rows:
        assert r["robot"] == "ur5e" and r["v_h"] == 1.6 and r["mode"] == "kinematic" and r["units"] == 43
        assert r["task_time_lost_s"] is not None and r["margin_terms"] is not None
    assert bad["degraded_std"] == "2.9 cm / 2.9 deg per axis" and truth["degraded_std"] == ""

    # the degradation's covariance widens Z_d and so S_p (the margin grows) at the same robot speed (the speed
    # terms differ: the degraded run retreats from what it misplaces, and a retreating robot's S_h is smaller)
    def still_part(r):
        return sum(r["margin_terms"][k] for k in ("C", "Z_d", "Z_r"))

    assert still_part(bad) > still_part(truth) + 0.03 and bad["margin_max_m"] > truth["margin_max_m"]
    assert bad["margin_terms"]["Z_d"] > 0.05 > truth["margin_terms"]["Z_d"]
    assert np.isclose(truth["S_p_still_m"], bad["S_p_still_m"])  # the same still-robot S_p before any point
