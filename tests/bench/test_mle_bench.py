"""``skincal benchmark mle`` (issue 27): ``--quick`` is a smoke test of every part on every robot, one
placement each, and a placement whose session cannot be made is replaced by the next seed, never a failure."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from skincal.bench import mle as bench_mle
from skincal.bench.mle import EXTRA_DRAWS, QUICK_RUNS, run_mle_benchmark
from skincal.cli import main
from skincal.errors import ConfigError


def test_runs_below_one_is_a_usage_error(capsys):
    assert main(["benchmark", "mle", "--quick", "--runs", "0"]) == 2  # the older name of --placements
    assert "--placements must be at least 1" in capsys.readouterr().err
    assert main(["benchmark", "mle", "--quick", "--placements", "0"]) == 2
    assert "--placements must be at least 1" in capsys.readouterr().err


@pytest.fixture
def fake_work(monkeypatch):
    """Simulation and calibration replaced by stand-ins that record what was asked (the benchmark's plan,
    not its figures); the Sawyer's seeds 100 and 101 have no protocol, as its seed 101 had none before."""
    made, calibrated = [], []

    def simulate_session(robot, placement, n_units, noise, protocol, seed, joints="ideal", clock="ideal"):
        if robot == "sawyer" and seed in (100, 101):
            raise ConfigError(f"robot 'sawyer', protocol '{protocol}': no collision-free static pose 3 found")
        made.append((robot, protocol, seed, noise, clock))
        return SimpleNamespace(robot=robot, duration=80.0)

    def calibrate(ds, method, **kwargs):
        calibrated.append((ds.robot, method))
        return SimpleNamespace(method=method)

    monkeypatch.setattr(bench_mle, "simulate_session", simulate_session)
    monkeypatch.setattr(bench_mle, "calibrate", calibrate)
    monkeypatch.setattr(bench_mle, "_summary", lambda ds, result: {
        "mean_position_error_mm": 1.0, "max_position_error_mm": 1.0, "mean_rotation_error_deg": 0.1,
        "mean_position_std_mm": 1.0, "max_time_offset_error_ms": None, "max_clock_drift_error_ppm": None,
        "links_correct": 6, "units_total": 6, "units_warned": 0, "runtime_s": 1.0, "z_rms": 1.0})  # fmt: skip
    return made, calibrated


def test_quick_is_one_placement_per_robot_on_the_fast_protocol_and_survives_a_robot_without_a_protocol(fake_work):
    made, calibrated = fake_work
    doc = run_mle_benchmark(quick=True)
    assert doc["runs"] == QUICK_RUNS == 1 and doc["quick"] is True
    assert {p for _, p, *_ in made} == {"fast"}
    for robot in ("panda", "sawyer", "ur5e"):
        assert doc[f"realistic_{robot}"]["runs"] == 1 and doc[f"real_clock_{robot}"]["runs"] == 1
    assert ("sawyer", "fast", 102, "realistic", "ideal") in made  # the next seed instead of a failure
    assert [s.split(":")[0] for s in doc["skipped"]] == ["sawyer seed 100", "sawyer seed 101"]
    assert "fast_protocol_panda" not in doc  # under --quick that is realistic_panda
    # paper config once (mle, reused for OM vs mle), 3 robots x 2 parts, the run time (1 and 2 workers), OM
    assert len(calibrated) == 1 + 6 + 2 + 1 and calibrated.count(("panda", "om")) == 1
    assert doc["om_vs_mle"]["mle"] == doc["noise_free_paper"]


def test_a_robot_with_no_protocol_at_all_gives_an_empty_part_not_a_failure(fake_work, monkeypatch):
    made, _ = fake_work

    def never(robot, *args, **kwargs):
        raise ConfigError("no collision-free static pose")

    real = bench_mle.simulate_session
    monkeypatch.setattr(bench_mle, "simulate_session", lambda robot, *a, **k: never(robot) if robot == "ur5e"
                        else real(robot, *a, **k))  # fmt: skip
    doc = run_mle_benchmark(runs=2, with_om=False)
    assert doc["realistic_ur5e"]["runs"] == 0 and doc["realistic_ur5e"]["worst_mean_position_error_mm"] is None
    # every seed tried, a bounded number: 2 placements + the extra draws, 1 real-clock placement + the extra draws
    assert sum(s.startswith("ur5e seed") for s in doc["skipped"]) == (2 + EXTRA_DRAWS) + (1 + EXTRA_DRAWS)
    assert doc["realistic_panda"]["runs"] == 2 and doc["fast_protocol_panda"]["runs"] == 2


@pytest.mark.slow
def test_quick_finishes_on_every_robot():
    """It failed on the Sawyer's second placement (no collision-free static pose) and ran 20 placements."""
    doc = run_mle_benchmark(quick=True, with_om=False)
    assert doc["runs"] == QUICK_RUNS and doc["quick"] is True
    for robot in ("panda", "sawyer", "ur5e"):
        assert doc[f"realistic_{robot}"]["runs"] == QUICK_RUNS, doc[f"realistic_{robot}"]
