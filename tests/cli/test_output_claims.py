"""An output that did not exist when a command checked it (``check_output`` without ``--force``) is
claimed as new: a file that another process puts there while the command works is never replaced at
the end; the command's output goes beside it and the one-line error names both (issue 27)."""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path

import pytest

from skincal.cli import main
from skincal.errors import ConfigError
from skincal.io.atomic import check_output, forget_claims, write_bytes_atomic


@pytest.fixture(autouse=True)
def _fresh_claims():
    forget_claims()
    yield
    forget_claims()


def _debris(folder: Path) -> list[str]:
    return [p.name for p in folder.iterdir() if p.name.endswith(".tmp")]


def test_a_file_that_appears_after_the_check_is_kept_and_the_output_goes_beside_it(tmp_path):
    out = tmp_path / "result.json"
    check_output(out)
    out.write_text("someone else's\n")
    (tmp_path / "result-1.json").write_text("also someone else's\n")
    with pytest.raises(ConfigError, match=r"result\.json appeared while this command ran.*result-2\.json"):
        write_bytes_atomic(out, b"ours\n")
    assert out.read_text() == "someone else's\n"
    assert (tmp_path / "result-1.json").read_text() == "also someone else's\n"
    assert (tmp_path / "result-2.json").read_text() == "ours\n"
    assert _debris(tmp_path) == []


def test_force_and_library_writes_replace_as_before(tmp_path):
    out = tmp_path / "a.bin"
    check_output(out, force=True)
    out.write_bytes(b"old")
    write_bytes_atomic(out, b"new")
    assert out.read_bytes() == b"new"
    other = tmp_path / "b.bin"
    other.write_bytes(b"old")
    write_bytes_atomic(other, b"new")  # no check_output: a library call replaces
    assert other.read_bytes() == b"new"


def test_a_claimed_output_once_written_is_the_commands_own(tmp_path):
    """A recorder flushes the same output again and again: after the first write it replaces its own file."""
    out = tmp_path / "rec.h5"
    check_output(out)
    write_bytes_atomic(out, b"first")
    write_bytes_atomic(out, b"second")
    assert out.read_bytes() == b"second"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.h5"]


def test_a_dangling_symlink_is_replaced_as_before(tmp_path):
    out = tmp_path / "link.json"
    out.symlink_to(tmp_path / "nowhere.json")
    check_output(out)
    write_bytes_atomic(out, b"{}")
    assert not out.is_symlink() and out.read_bytes() == b"{}"


def test_calibrate_does_not_clobber_a_file_made_while_it_ran(files, tmp_path, capsys):
    """A real ``skincal calibrate``: once it has claimed ``-o`` (during its check, before any work) a
    thread writes a file there; the command exits 2, that file is intact and the result is in ``-1``."""
    _, data, _ = files
    out = tmp_path / "out.json"
    key = os.path.abspath(out)
    from skincal.io import atomic

    def intrude():
        end = time.monotonic() + 60.0
        while key not in atomic._CLAIMED and time.monotonic() < end:
            time.sleep(0.001)
        out.write_text("precious\n")

    thread = threading.Thread(target=intrude)
    thread.start()
    code = main(["calibrate", str(data), "--out", str(out)])
    thread.join()
    err = capsys.readouterr().err
    assert code == 2, err
    assert "appeared while this command ran" in err and "out-1.json" in err
    assert out.read_text() == "precious\n"
    assert json.loads((tmp_path / "out-1.json").read_text())["units"]
    assert _debris(tmp_path) == []
