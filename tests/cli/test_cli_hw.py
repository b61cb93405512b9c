"""``skincal record`` (:mod:`skincal.cli.hw`) on bad options and on a recording that received nothing."""

from __future__ import annotations

from pathlib import Path

import pytest
from cli_subprocess import one_line_error, run_cli


@pytest.mark.adversarial
@pytest.mark.parametrize("option", [["--duration", "nan"], ["--flush-every", "nan"], ["--flush-every", "inf"]])
def test_record_refuses_nan_durations(tmp_path: Path, option: list[str]) -> None:
    """``--duration nan`` stopped at once and ``--flush-every nan`` never flushed, both with exit 0."""
    one_line_error(run_cli(["record", "--port", "0", "--out", "rec.h5", *option], tmp_path))
    assert not (tmp_path / "rec.h5").exists()


def test_record_says_when_nothing_was_received(tmp_path: Path) -> None:
    """An empty recording was announced as "an IMU-only dataset (calibrate it with --reference UNIT)",
    though it holds no stream at all (``skincal info`` refuses it: ``/imu is missing``)."""
    proc = run_cli(["record", "--port", "0", "--out", "rec.h5", "--duration", "0.3"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "nothing was received" in proc.stdout
    assert "IMU-only" not in proc.stdout
