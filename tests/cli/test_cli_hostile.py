"""Issue 27, "Hostile input": outputs that are not regular files, inputs given as outputs, control
characters in free text, absurd numbers. Each case is a real file (FIFOs by ``os.mkfifo``, device
nodes by ``os.mknod`` when allowed) and the command's real exit code and stderr."""

from __future__ import annotations

import hashlib
import os
import shutil
import stat
from pathlib import Path

import pytest

from skincal.cli import main

from registry_robots import registry_urdf

pytestmark = pytest.mark.skipif(os.name != "posix", reason="FIFOs and device nodes are POSIX")


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    root = tmp_path_factory.mktemp("hostile")
    data = root / "data.h5"
    assert main(["simulate", "--robot", "panda", "--placement", "random", "--units", "2", "--protocol", "fast",
                 "--out", str(data)]) == 0
    result = root / "result.json"
    assert main(["calibrate", str(data), "--out", str(result)]) == 0
    return root, data, result


def _special_outputs(root: Path, suffix: str) -> list[tuple[str, Path]]:
    """A FIFO, a symlink to ``/dev/null`` (with wrong code only the link would be replaced, never the
    system's ``/dev/null``) and, when this process may create one, a character device node (1, 3)."""
    fifo, null, node = (root / f"{name}{suffix}" for name in ("pipe", "null", "node"))
    os.mkfifo(fifo)
    null.symlink_to("/dev/null")
    cases = [("FIFO", fifo), ("device", null)]
    try:
        os.mknod(node, 0o600 | stat.S_IFCHR, os.makedev(1, 3))
        cases.append(("device", node))
    except OSError:  # not root (or no CAP_MKNOD): the symlink covers the device case
        pass
    return cases


COMMANDS = [
    (".h5", ["simulate", "--protocol", "fast", "--out", "{out}"]),
    (".h5", ["simulate", "--handheld", "--out", "{out}"]),
    (".json", ["calibrate", "{data}", "--out", "{out}"]),
    (".json", ["segment", "{data}", "--out", "{out}"]),
    (".csv", ["export", "{result}", "-f", "csv", "-o", "{out}"]),
    (".html", ["report", "{result}", "--dataset", "{data}", "--out", "{out}"]),
    (".json", ["protocol", "--robot", "panda", "--rate", "10", "--out", "{out}"]),
    (".h5", ["record", "--out", "{out}", "--duration", "0.1", "--port", "0"]),
]


IDS = [c[0] + ("-handheld" if "--handheld" in c else "") for _, c in COMMANDS]


@pytest.mark.parametrize(("suffix", "command"), COMMANDS, ids=IDS)
def test_force_never_replaces_a_fifo_or_a_device(suffix, command, files, tmp_path, capsys):
    """``--out X --force`` replaced a FIFO or a device node with a regular file (as root ``-o /dev/null
    --force`` would replace the system's ``/dev/null``): only regular files are overwritten."""
    _, data, result = files
    for kind, out in _special_outputs(tmp_path, suffix):
        args = [a.format(data=data, result=result, out=out) for a in command]
        capsys.readouterr()
        assert main([*args, "--force"]) == 2, (kind, args)
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error:"), err
        assert f"is a {kind}" in err[0] and "regular files only" in err[0], err
        mode = os.stat(out).st_mode
        assert stat.S_ISFIFO(mode) if kind == "FIFO" else stat.S_ISCHR(mode), (kind, out)
    assert not [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_atomic_write_refuses_a_fifo_even_without_check_output(tmp_path):
    """The writer itself (not only the CLI's early check) never renames over a FIFO."""
    from skincal.errors import ConfigError
    from skincal.io.atomic import write_bytes_atomic

    fifo = tmp_path / "p.json"
    os.mkfifo(fifo)
    with pytest.raises(ConfigError, match="is a FIFO"):
        write_bytes_atomic(fifo, b"{}")
    assert stat.S_ISFIFO(os.stat(fifo).st_mode) and os.listdir(tmp_path) == ["p.json"]


def test_an_input_is_never_an_output_even_with_force(files, tmp_path, capsys):
    """``calibrate --links L.yaml -o L.yaml --force`` overwrote the links file; ``simulate --robot arm.urdf``
    into a name that is (through a symlink) the URDF it reads would replace the robot."""
    _, data, _ = files
    links = tmp_path / "links.yaml"
    links.write_text("su1: 3\nsu2: 5\n")
    alias = tmp_path / "alias.json"
    alias.symlink_to(links)
    before = _digest(links)
    for out in (links, alias):
        capsys.readouterr()
        assert main(["calibrate", str(data), "--links", str(links), "-o", str(out), "--force"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "is the input" in err[0], err
    assert _digest(links) == before and alias.is_symlink()

    urdf = tmp_path / "arm.urdf"
    shutil.copy(registry_urdf("ur5"), urdf)
    before = _digest(urdf)
    as_h5 = tmp_path / "arm.h5"
    as_h5.symlink_to(urdf)
    capsys.readouterr()
    assert main(["simulate", "--robot", str(urdf), "--protocol", "fast", "-o", str(as_h5), "--force"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is the input" in err[0], err
    assert _digest(urdf) == before and as_h5.is_symlink()


OSC = "\x1b]0;owned\x07"
"""An OSC sequence: a terminal that receives it raw sets its window title (and worse sequences exist)."""


def _raw_control(text: str) -> bool:
    return any(ord(ch) < 0x20 and ch not in "\n" or 0x7F <= ord(ch) < 0xA0 for ch in text)


def test_report_shows_control_characters_in_free_text_as_escapes(files, tmp_path):
    """A result's warning with ``ESC ] 0;title BEL`` reached the terminal raw through ``report``
    (markdown on stdout) and the HTML table raw; ``evaluate`` and ``export`` already escaped it."""
    import json

    from cli_subprocess import run_cli

    _, data, result = files
    doc = json.loads(result.read_text())
    unit = next(iter(doc["units"]))
    doc["units"][unit]["warnings"] = [f"poor fit {OSC}\rcleared"]
    hostile = tmp_path / "hostile.json"
    hostile.write_text(json.dumps(doc))
    proc = run_cli(["report", str(hostile), "--dataset", str(data)], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "poor fit \\x1b]0;owned\\x07\\rcleared" in proc.stdout
    assert not _raw_control(proc.stdout + proc.stderr)
    page = tmp_path / "r.html"
    proc = run_cli(["report", str(hostile), "--dataset", str(data), "--out", str(page)], tmp_path)
    assert proc.returncode == 0, proc.stderr
    html = page.read_text()
    assert "poor fit \\x1b]0;owned\\x07\\rcleared" in html and not _raw_control(html)


ABSURD = [
    (["simulate", "--protocol", "fast", "--seed", "-1", "-o", "{tmp}/s.h5"], "--seed -1: a seed is an integer >= 0"),
    (["simulate", "--handheld", "--seed", "-1", "-o", "{tmp}/s.h5"], "--seed -1: a seed is an integer >= 0"),
    (["protocol", "--robot", "panda", "--seed", "-1", "-o", "{tmp}/p.json"], "--seed -1: a seed is an integer >= 0"),
    (["avoid", "--seed", "-1"], "--seed -1: a seed is an integer >= 0"),
    (["calibrate", "{data}", "--seed", "-1", "-o", "{tmp}/c.json"], "--seed -1: a seed is an integer >= 0"),
    (["emulate", "{data}", "--port", "9", "--seed", "-1"], "--seed -1: a seed is an integer >= 0"),
    (["emulate", "{data}", "--port", "9", "--jitter", "inf"], "--jitter inf s must be a mean delay in [0, 60] s"),
    (["emulate", "{data}", "--port", "9", "--jitter", "1e308"], "--jitter 1e+308 s must be a mean delay in [0, 60]"),
    (["emulate", "{data}", "--port", "9", "--jitter", "nan"], "--jitter nan s must be a mean delay in [0, 60] s"),
    (["record", "--out", "{tmp}/r.h5", "--port", "0", "--max-unit-samples", str(10**20)],
     "--max-unit-samples 100000000000000000000 must be at most 2^40"),
]


@pytest.mark.parametrize(("command", "message"), ABSURD, ids=[" ".join(c[:1] + c[-2:]) for c, _ in ABSURD])
def test_absurd_numbers_are_one_line_usage_errors(command, message, files, tmp_path, capsys):
    """``--seed -1``, ``emulate --jitter inf / 1e308`` and ``record --max-unit-samples 1e20`` were internal
    errors (exit 3, NumPy's or h5py's exception) after the work had started: now exit 2, one line, nothing written."""
    _, data, _ = files
    args = [a.format(data=data, tmp=tmp_path) for a in command]
    capsys.readouterr()
    assert main(args) == 2
    out = capsys.readouterr()
    err = out.err.strip().splitlines()
    assert err == [f"error: {message}"] or (len(err) == 1 and message in err[0]), out.err
    assert "sending" not in out.out and not list(tmp_path.iterdir())
