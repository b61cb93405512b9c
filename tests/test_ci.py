"""CI runs the README's test command verbatim (``.ci/run``): the two may not drift apart."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_ci_runs_the_readme_test_command_verbatim():
    install = 'pip install -e ".[all,test]" && '
    lines = [ln for ln in (ROOT / "README.md").read_text(encoding="utf-8").splitlines() if install in ln]
    assert len(lines) == 1, lines  # the one "Install and run the tests" command
    command = lines[0].split(install, 1)[1].strip()
    assert command.startswith("python -m pytest -q")
    ci = [ln.strip() for ln in (ROOT / ".ci" / "run").read_text(encoding="utf-8").splitlines()]
    assert command in ci, f"{command!r} is not a line of .ci/run"
