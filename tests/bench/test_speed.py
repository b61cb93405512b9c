"""``skincal benchmark speed --quick``: one run of every figure, on a small simulated session (seconds)."""

from __future__ import annotations

import json

import pytest

from skincal.bench import speed
from skincal.bench.harness import parse
from skincal.cli import main
from skincal.errors import ConfigError


@pytest.fixture(scope="module")
def quick(tmp_path_factory) -> dict:
    out = tmp_path_factory.mktemp("speed") / "speed.json"
    assert main(["benchmark", "speed", "--quick", "--json", str(out)]) == 0
    return json.loads(out.read_text())


def test_om_and_mle_are_timed_on_one_session_in_one_run(quick):
    om = quick["om_vs_mle"]
    assert quick["simulated"] is True and om["units"] == 2 and 30 < om["data_s"] < 60
    assert om["om_cpu_s"] > 0 and om["mle_cpu_s"] > 0
    assert om["om_over_mle"] == pytest.approx(om["om_cpu_s"] / om["mle_cpu_s"], rel=0.01, abs=0.01)
    assert om["mle_cpu_s_per_unit"] == pytest.approx(om["mle_cpu_s"] / 2, abs=1e-3)
    # both calibrated what they were timed on: mle finds the links and is accurate on 40 s of realistic data
    assert om["mle"]["links_correct"] == om["mle"]["units"] == om["om"]["units"] == 2
    assert om["mle"]["mean_position_error_mm"] < 2.0
    cmd = om["calibrate_command"]
    assert cmd["exit_code"] == 0 and cmd["wall_s"] > 0 and cmd["cpu_s"] > 0


def test_scale_figure_has_its_own_process_memory_and_workers(quick):
    (scale,) = quick["scale"]
    assert scale["units"] == scale["calibrated"] == 4 and scale["failed"] == 0 and scale["workers"] == 2
    assert scale["cpu_s"] > 0 and scale["cpu_s_per_unit"] == pytest.approx(scale["cpu_s"] / 4, abs=1e-3)
    assert 0 < scale["rss_at_start_mb"] <= scale["rss_after_simulation_mb"] <= scale["peak_rss_mb"]
    assert scale["worker_peak_rss_mb"] > 0


def test_startup_and_streaming_figures(quick):
    st = quick["startup"]
    assert st["runs"] == 2
    assert st["help"]["exit_code"] == 0 and st["failing_calibrate"]["exit_code"] == 2
    assert all(st[k]["median_wall_s"] > 0 and st[k]["median_cpu_s"] > 0 for k in ("help", "failing_calibrate"))
    on = quick["online"]
    assert on["units"] == 2 and on["imu_samples"] > 2 * 35 * 90 and on["cpu_s"] > 0 and on["latency_s"] >= 0
    assert on["cpu_us_per_imu_sample"] == pytest.approx(1e6 * on["cpu_s"] / on["imu_samples"], rel=0.01)


def test_full_adds_the_thousand_unit_figure_and_quick_excludes_it():
    full = speed.HARNESS.config(parse("t", speed.HARNESS.options, ["--full"]))
    assert full.scale == ((100, "paper-sim"), (1000, "fast")) and [j.kind for j in speed.jobs(full)] == [
        "om-vs-mle", "scale", "scale", "startup", "online"]  # fmt: skip
    with pytest.raises(ConfigError, match="exclude each other"):
        speed.HARNESS.config(parse("t", speed.HARNESS.options, ["--quick", "--full"]))


def test_refuses_an_existing_json_without_force(tmp_path, capsys):
    out = tmp_path / "speed.json"
    out.write_text("{}")
    assert main(["benchmark", "speed", "--quick", "--json", str(out)]) == 2
    assert out.read_text() == "{}" and "exists" in capsys.readouterr().err


def test_a_pipe_sees_the_progress_of_long_work(tmp_path, capsys):
    """Off a terminal (as here) the spinner is replaced by plain lines on stderr once the work has lasted
    2 s: the start, then what finished (a benchmark of minutes is never silent in a log; a command that
    fails at once prints its one-line error alone); stdout keeps only the table."""
    assert main(["benchmark", "speed", "--quick", "--json", str(tmp_path / "s.json")]) == 0
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    assert lines[0] == "benchmarking speed...", captured.err
    assert any(line.startswith("done: ") for line in lines[1:]), captured.err
    assert "benchmarking" not in captured.out
