"""``skincal view`` (:mod:`skincal.cli.viz`): ``--follow`` with ``--duration``."""

from __future__ import annotations

from pathlib import Path

from cli_subprocess import run_cli


def test_view_follow_duration_stops_the_replay(tmp_path: Path) -> None:
    """``view --follow --duration`` ("stop after this many seconds") was not checked during the replay: at
    real speed it ran the whole 77 s recording first."""
    from skincal.data.hdf5 import write_dataset
    from skincal.workflows.session import simulate_dataset

    write_dataset(simulate_dataset("panda", "paper", noise="realistic", protocol="fast", seed=1), tmp_path / "d.h5")
    proc = run_cli(["view", "--follow", "d.h5", "--speed", "1", "--duration", "1"], tmp_path, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert "--duration 1 s over during the replay: stopped" in proc.stdout
    assert "/77.5 s" not in proc.stdout.splitlines()[-1]
