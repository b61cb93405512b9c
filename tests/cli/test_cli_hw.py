"""``skincal record`` (:mod:`skincal.cli.hw`) on bad options and on a recording that received nothing."""

from __future__ import annotations

from pathlib import Path

import pytest
from cli_subprocess import one_line_error, run_cli


@pytest.mark.adversarial
@pytest.mark.parametrize("option", [["--duration", "nan"], ["--duration", "inf"], ["--duration", "-1"],
                                    ["--flush-every", "nan"], ["--flush-every", "inf"], ["--flush-every", "1e308"]])
def test_record_refuses_nan_durations(tmp_path: Path, option: list[str]) -> None:
    """``--duration nan`` stopped at once and ``--flush-every nan`` never flushed, both with exit 0;
    ``--duration inf`` and ``--flush-every 1e308`` were accepted (never stopped, never flushed by time)."""
    one_line_error(run_cli(["record", "--port", "0", "--out", "rec.h5", *option], tmp_path))
    assert not (tmp_path / "rec.h5").exists()


def test_record_says_when_nothing_was_received(tmp_path: Path) -> None:
    """An empty recording was announced as "an IMU-only dataset (calibrate it with --reference UNIT)",
    though it holds no stream at all (``skincal info`` refuses it: ``/imu is missing``)."""
    proc = run_cli(["record", "--port", "0", "--out", "rec.h5", "--duration", "0.3"], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "nothing was received" in proc.stdout
    assert "IMU-only" not in proc.stdout


def test_record_without_robot_stops_at_the_first_joint_state(tmp_path: Path) -> None:
    """Issue 27: joint states without --robot were recorded for the whole session into a file that
    ``info`` and ``calibrate`` refuse (a dataset with joints needs its robot), said only at the end.
    Now the first joint state stops the recording: one line naming --robot, nothing kept."""
    import socket
    import subprocess
    import time

    import numpy as np
    from cli_subprocess import CLI

    from skincal.hw.packet import encode_joint_packet, encode_packet

    proc = subprocess.Popen([*CLI, "record", "--port", "0", "--out", "rec.h5", "--duration", "60"], cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        line = proc.stdout.readline()
        assert "listening on" in line, proc.stderr.read()
        port = int(line.strip().rsplit(":", 1)[1])
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            for seq in range(5):
                sock.sendto(encode_packet(1, seq, [10_000 * seq], accel=[[0.0, 0.0, 9.81]]), ("127.0.0.1", port))
            for seq in range(3):
                sock.sendto(encode_joint_packet(7, seq, [10_000 * seq], np.zeros((1, 7)), np.zeros((1, 7))),
                            ("127.0.0.1", port))
                time.sleep(0.05)
        out, err = proc.communicate(timeout=30)  # long before --duration 60
    finally:
        proc.kill()
    proc.stdout.close()
    proc.stderr.close()
    assert proc.returncode == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: joint states arrived (robot id 7) but no --robot"), err
    assert "record again with --robot" in lines[0]
    assert not (tmp_path / "rec.h5").exists() and "wrote" not in out
