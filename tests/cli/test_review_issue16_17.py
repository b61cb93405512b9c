"""Review of the issue-16/17 commands as a new and as a careless user: the problems found and fixed.

Each test runs the real ``skincal`` command in a subprocess (its own stdout, stderr and exit code)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

_CLI = [sys.executable, "-c", "import sys; from skincal.cli import main; sys.exit(main(sys.argv[1:]))"]


def _run(argv: list[str], cwd: Path, timeout: float = 120.0) -> subprocess.CompletedProcess:
    return subprocess.run([*_CLI, *argv], cwd=cwd, capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, "COLUMNS": "200"})  # fmt: skip


def _one_line_error(proc: subprocess.CompletedProcess) -> str:
    assert proc.returncode == 2, (proc.returncode, proc.stdout, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), proc.stderr
    assert "Traceback" not in proc.stderr
    return lines[0]


SCENARIO_WITH_MARKUP = """\
name: "[bold red]EVIL [blink]y"
description: "desc [bold]z[/bold] [link=http:x]q"
duration: 0.05
people:
  - name: "[red]hand"
    shape: sphere
    radius: 0.05
    speed: 0.5
    relative_to: flange
    waypoints:
      - {p: [0.5, 0.0, 0.0]}
      - {p: [0.2, 0.0, 0.0]}
"""


@pytest.mark.adversarial
def test_avoid_prints_scenario_names_and_descriptions_as_written(tmp_path: Path) -> None:
    """A scenario file's name and description are shown as stored, never read as rich markup (the tags
    were swallowed: ``scenario EVIL y (desc z q)``)."""
    (tmp_path / "mk.yaml").write_text(SCENARIO_WITH_MARKUP)
    proc = _run(["avoid", "--scenario", "mk.yaml"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    first = proc.stdout.splitlines()[0]
    assert first.startswith("scenario [bold red]EVIL [blink]y (desc [bold]z[/bold] [link=http:x]q) on panda"), first


@pytest.mark.adversarial
@pytest.mark.parametrize("duration", ["1e-9", "0.0005"])
def test_avoid_refuses_a_run_too_short_to_have_a_step(tmp_path: Path, duration: str) -> None:
    """``--duration`` below one control step gave exit 3 (``internal error (ValueError: zero-size array
    ...)``); it is a one-line usage error."""
    line = _one_line_error(_run(["avoid", "--scenario", "hand", "--duration", duration], tmp_path))
    assert "duration" in line and "0.02" in line


@pytest.mark.adversarial
def test_scenario_file_duration_too_short_is_refused_naming_the_field(tmp_path: Path) -> None:
    (tmp_path / "short.yaml").write_text(SCENARIO_WITH_MARKUP.replace("duration: 0.05", "duration: 0.0001"))
    line = _one_line_error(_run(["avoid", "--scenario", "short.yaml"], tmp_path))
    assert line.startswith("error: short.yaml: duration: "), line


@pytest.mark.adversarial
@pytest.mark.parametrize("option", [["--duration", "nan"], ["--flush-every", "nan"], ["--flush-every", "inf"]])
def test_record_refuses_nan_durations(tmp_path: Path, option: list[str]) -> None:
    """``--duration nan`` stopped at once and ``--flush-every nan`` never flushed, both with exit 0."""
    _one_line_error(_run(["record", "--port", "0", "--out", "rec.h5", *option], tmp_path))
    assert not (tmp_path / "rec.h5").exists()


def test_record_says_when_nothing_was_received(tmp_path: Path) -> None:
    """An empty recording was announced as "an IMU-only dataset (calibrate it with --reference UNIT)",
    though it holds no stream at all (``skincal info`` refuses it: ``/imu is missing``)."""
    proc = _run(["record", "--port", "0", "--out", "rec.h5", "--duration", "0.3"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "nothing was received" in proc.stdout
    assert "IMU-only" not in proc.stdout


def test_view_follow_duration_stops_the_replay(tmp_path: Path) -> None:
    """``view --follow --duration`` ("stop after this many seconds") was not checked during the replay: at
    real speed it ran the whole 77 s recording first."""
    from skincal.data.hdf5 import write_dataset
    from skincal.workflows.session import simulate_dataset

    write_dataset(simulate_dataset("panda", "paper", noise="realistic", protocol="fast", seed=1), tmp_path / "d.h5")
    proc = _run(["view", "--follow", "d.h5", "--speed", "1", "--duration", "1"], tmp_path, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert "--duration 1 s over during the replay: stopped" in proc.stdout
    assert "/77.5 s" not in proc.stdout.splitlines()[-1]


@pytest.mark.adversarial
def test_adaptive_force_leaves_no_segment_of_an_earlier_run(tmp_path: Path) -> None:
    """``protocol --adaptive --force`` overwrote segments 1..k of an earlier run and left its k+1.. beside
    them: a robot executing the files in order ran stale motion. The earlier run's segments go first."""
    stale = [tmp_path / f"m_{k:03d}.json" for k in (1, 2, 7)]
    for path in stale:
        path.write_text("stale")
    keep = tmp_path / "m_notes.json"
    keep.write_text("user file")
    proc = _run(["protocol", "--robot", "panda", "--adaptive", "--simulate", "--out", "m.json", "--max-motion",
                 "0.001", "--force"], tmp_path)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    segments = sorted(p.name for p in tmp_path.glob("m_[0-9][0-9][0-9].json"))
    assert segments == ["m_001.json"], segments
    assert (tmp_path / "m_001.json").read_text() != "stale"
    assert keep.read_text() == "user file"
    assert "inf mm" not in proc.stdout


@pytest.mark.adversarial
def test_adaptive_force_refuses_a_folder_named_like_a_segment(tmp_path: Path) -> None:
    (tmp_path / "m_001.json").mkdir()
    line = _one_line_error(_run(["protocol", "--robot", "panda", "--adaptive", "--simulate", "--out", "m.json",
                                 "--max-motion", "0.001", "--force"], tmp_path))  # fmt: skip
    assert "m_001.json" in line
    assert (tmp_path / "m_001.json").is_dir()


@pytest.mark.adversarial
def test_avoid_clips_a_long_description(tmp_path: Path) -> None:
    """A scenario description of any length (a 16 MB one was printed whole) is shown clipped to one line."""
    old = 'description: "desc [bold]z[/bold] [link=http:x]q"'
    text = SCENARIO_WITH_MARKUP.replace(old, f"description: {'x' * 5000}")
    (tmp_path / "long.yaml").write_text(text)
    proc = _run(["avoid", "--scenario", "long.yaml"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    shown = proc.stdout.replace("\n", "")  # rich wraps the long line in a pipe
    assert "x" * 197 + "..." in shown and "x" * 198 not in shown, shown[:300]


@pytest.mark.adversarial
@pytest.mark.parametrize("degrade", ["1e308,5", "0.05,1e308"])
def test_avoid_refuses_an_absurd_degradation_on_one_line(tmp_path: Path, degrade: str) -> None:
    """``--degrade 1e308,5`` printed a numpy overflow warning (3 lines on stderr) before the error."""
    line = _one_line_error(_run(["avoid", "--degrade", degrade, "--duration", "0.05"], tmp_path))
    assert "at most" in line
