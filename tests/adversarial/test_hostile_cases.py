"""Every case of :mod:`hostile_cases` against the command line's promise (docs/guide.md): a one-line error,
exit 2, nothing written under an output name, no input changed."""

from __future__ import annotations

import hashlib
import os
import signal

import pytest
from hostile_cases import FINDINGS, NO_TABLE, TABLES, Case

from skincal.cli import main

pytestmark = pytest.mark.adversarial

CASES = [(command, case) for command, table in TABLES.items() for case in table]


CASE_TIMEOUT_S = 120
"""A case that has not ended by then fails (a FIFO written to, a run without end) instead of hanging the run."""


def _within(seconds: float, fn, *args):
    """``fn(*args)``, failing the test when it runs beyond ``seconds`` (a POSIX interval timer; elsewhere no limit)."""
    if not hasattr(signal, "setitimer"):
        return fn(*args)

    def expired(signum, frame):
        raise TimeoutError(f"still running after {seconds} s")

    previous = signal.signal(signal.SIGALRM, expired)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        return fn(*args)
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def _digest(path) -> str:
    if path.is_fifo() or path.is_dir():
        return path.stat().st_mode.__str__()
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.parametrize(("command", "case"), CASES, ids=[c.argv.split(" -")[0][:40] + "|" + c.argv[-30:]
                                                          for _, c in CASES])  # fmt: skip
def test_a_hostile_command_line_is_a_one_line_usage_error(command, case: Case, hostile, tmp_path, capsys):
    if "{fifo" in case.argv and "fifo" not in hostile:
        pytest.skip("FIFOs are POSIX")
    before = {name: _digest(path) for name, path in hostile.items()}
    folder = sorted(next(iter(hostile.values())).parent.iterdir())
    argv = case.argv.format(tmp=tmp_path, long="x" * 300, **hostile).split(" ")
    assert argv[0] == command
    capsys.readouterr()
    code = _within(CASE_TIMEOUT_S, main, argv)
    out = capsys.readouterr()
    lines = out.err.strip().splitlines() or ["(nothing on stderr)"]
    assert code == 2, (code, out.err[-2000:])
    # one line, or typer's usage form: "Usage: ...", "Try ... --help", "Error: <the reason>"
    assert lines[-1].lower().startswith("error: ") and (len(lines) == 1 or lines[0].startswith("Usage: ")), out.err
    assert case.message in lines[-1], lines[-1]
    assert "Traceback" not in out.err and "internal error" not in out.err
    assert not list(tmp_path.iterdir()), "something was written"
    assert sorted(next(iter(hostile.values())).parent.iterdir()) == folder, "something was written beside the inputs"
    assert {name: _digest(path) for name, path in hostile.items()} == before, "an input was changed"
    assert all(path.is_fifo() for name, path in hostile.items() if name.startswith("fifo"))


def test_every_command_has_a_table_and_every_finding_a_case():
    from typer.main import get_command

    from skincal.cli.app import app

    commands = set(get_command(app).commands)  # type: ignore[attr-defined]
    assert commands == set(TABLES) | set(NO_TABLE), commands ^ (set(TABLES) | set(NO_TABLE))
    assert {case.finding for table in TABLES.values() for case in table} == set(FINDINGS)
    assert all(case.message for table in TABLES.values() for case in table)  # each names what it refuses
    assert all(case.argv.split(" ")[0] == command for command, table in TABLES.items() for case in table)
    assert os.path.basename(__file__).startswith("test_")


def test_an_overflowing_covariance_is_exported_as_unknown_not_as_nan(hostile, tmp_path):
    """``export -f json`` of a result whose ``pose_covariance`` is 1e308 overflowed to NaN in the JSON (exit 3).
    A covariance that is no covariance is exported as ROS's "unknown" (-1 on the diagonal), every figure finite."""
    import json
    import math

    out = tmp_path / "e.json"
    assert main(["export", str(hostile["overflow_result"]), "-f", "json", "-o", str(out)]) == 0
    text = out.read_text()
    assert "NaN" not in text and "Infinity" not in text
    doc = json.loads(text)
    covariances = [u["covariance"] for u in doc["units"].values()]
    assert any(all(c[i][i] == -1.0 for i in range(6)) for c in covariances)
    assert all(math.isfinite(x) for c in covariances for row in c for x in row)
