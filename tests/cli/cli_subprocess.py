"""The real ``skincal`` command in a subprocess (its own stdout, stderr and exit code), for the CLI tests."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

CLI = [sys.executable, "-c", "import sys; from skincal.cli import main; sys.exit(main(sys.argv[1:]))"]


def run_cli(argv: list[str], cwd: Path, timeout: float = 120.0) -> subprocess.CompletedProcess:
    """``skincal *argv`` run in ``cwd`` (a wide terminal, so rich does not wrap)."""
    return subprocess.run([*CLI, *argv], cwd=cwd, capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, "COLUMNS": "200"})  # fmt: skip


def one_line_error(proc: subprocess.CompletedProcess) -> str:
    """The single ``error: ...`` line of a command that ended with exit 2 (no traceback)."""
    assert proc.returncode == 2, (proc.returncode, proc.stdout, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), proc.stderr
    assert "Traceback" not in proc.stderr
    return lines[0]
