"""Usage errors are usage errors: exit 2 with typer's message, never an "internal error"."""

from __future__ import annotations

import pytest

import skincal
from skincal.cli import main


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["calibrate", "--nosuch", "x.h5"], "No such option: --nosuch"),
        (["calibrate"], "Missing argument"),
        (["calibrate", "x.h5", "-o", "y.json", "--workers", "abc"], "Invalid value for '--workers'"),
        (["nosuchcommand"], "No such command"),
    ],
)
def test_usage_errors_exit_2_with_the_usage_message(args, needle, capsys):
    assert main(args) == 2
    out = capsys.readouterr()
    text = out.out + out.err
    assert needle in text and "internal error" not in text and "Traceback" not in text


def test_bare_command_shows_help_and_exits_2(capsys):
    assert main([]) == 2
    out = capsys.readouterr()
    assert "calibrate" in out.out + out.err and "internal error" not in out.out + out.err


def test_version_option_and_command(capsys):
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == skincal.__version__
    assert main(["version"]) == 0
    assert capsys.readouterr().out.strip() == skincal.__version__
