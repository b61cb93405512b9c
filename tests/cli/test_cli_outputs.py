"""Outputs are never clobbered silently: every command that writes a file refuses its own input (also through
a symlink), an existing file (unless --force), a folder and a missing folder, before doing any work, and
never replaces a FIFO or a device node even with --force (each a real file: FIFOs by ``os.mkfifo``, device
nodes by ``os.mknod`` when allowed). The ``files`` fixture is in ``conftest.py``."""

from __future__ import annotations

import hashlib
import os
import shutil
import stat
from pathlib import Path

import pytest

from skincal.cli import main

from registry_robots import registry_urdf


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_calibrate_refuses_its_input_an_existing_file_and_bad_folders(files, capsys):
    root, data, result = files
    before_data, before_result = _digest(data), _digest(result)
    capsys.readouterr()
    assert main(["calibrate", str(data), "--out", str(data)]) == 2
    assert main(["calibrate", str(data), "--out", str(data), "--force"]) == 2  # the input, even with --force
    assert main(["calibrate", str(data), "--out", str(result)]) == 2
    assert main(["calibrate", str(data), "--out", str(root)]) == 2
    assert main(["calibrate", str(data), "--out", str(root / "nowhere" / "r.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 5 and all(line.startswith("error:") for line in err)
    assert "is the input" in err[0] and "is the input" in err[1] and "pass --force" in err[2]
    assert "folder" in err[3] and "does not exist" in err[4]
    for workers in ("0", "-1"):  # a usage error, with the usage message
        assert main(["calibrate", str(data), "--out", str(root / "w.json"), "--workers", workers]) == 2
        out = capsys.readouterr()
        assert "Invalid value for '--workers'" in out.err and "internal error" not in out.err + out.out
    assert _digest(data) == before_data and _digest(result) == before_result
    assert not (root / "w.json").exists()
    assert main(["calibrate", str(data), "--out", str(result), "--force"]) == 0  # asked for: replaced


@pytest.mark.parametrize(
    "command",
    [
        ["simulate", "--protocol", "fast", "--out", "{data}"],
        ["segment", "{data}", "--out", "{data}"],
        ["export", "{result}", "-f", "csv", "-o", "{result}"],
        ["export", "{result}", "-f", "csv", "-o", "{data}"],
        ["report", "{result}", "--dataset", "{data}", "--out", "{data}"],
        ["report", "{result}", "--dataset", "{data}", "--out", "{result}"],
        ["benchmark", "core", "--json", "{data}"],  # refused before minutes of work
        ["benchmark", "mle", "--quick", "--json", "{result}"],
        ["benchmark", "table1", "--quick", "--json", "{result}"],
        ["benchmark", "robustness", "--quick", "--out", "{result}"],
    ],
)
def test_other_writers_keep_existing_files(files, command, capsys):
    _, data, result = files
    before = {p: _digest(p) for p in (data, result)}
    args = [a.format(data=data, result=result) for a in command]
    assert main(args) == 2
    assert capsys.readouterr().err.startswith("error:")
    assert {p: _digest(p) for p in (data, result)} == before


@pytest.mark.parametrize("name", ["data.json", "arm.urdf", "data"])
def test_simulate_writes_only_a_dataset_name(tmp_path, name, capsys):
    """Issue 27: ``simulate --out x.json`` wrote HDF5 under a JSON name (and ``-o arm.urdf --force`` could
    replace the robot it read); the name must say HDF5 (.h5, .hdf5), checked before any work."""
    out = tmp_path / name
    for extra in ([], ["--handheld"]):
        assert main(["simulate", "--protocol", "fast", *extra, "--out", str(out)]) == 2
        assert "a dataset is an HDF5 file; name it .h5" in capsys.readouterr().err
        assert not out.exists()


@pytest.mark.parametrize("command", [
    ["segment", "{data}", "-o", "{out}.h5"],
    ["calibrate", "{data}", "-o", "{out}.json"],
    ["record", "--port", "0", "--duration", "0.5", "--out", "{out}.h5"],
], ids=lambda c: c[0])
def test_a_name_too_long_with_its_temporary_is_refused_before_any_work(files, command, tmp_path, capsys):
    """Issue 27: a 240-byte name fits NAME_MAX (255) but its temporary (.<name>.<pid>.<hex>.tmp) does not:
    segment and calibrate failed at the write after all the work, record after the whole session (its
    recording left half-finished under the name)."""
    _, data, _ = files
    stem = tmp_path / ("n" * 234)
    args = [a.format(data=data, out=stem) for a in command]
    assert main(args) == 2
    captured = capsys.readouterr()
    assert "listening" not in captured.out and "mle:" not in captured.out
    assert captured.err.startswith("error: ") and captured.err.count("\n") == 1
    assert f"the file name is {len(Path(args[-1]).name)} bytes" in captured.err
    assert "give a name of at most 229 bytes" in captured.err
    assert list(tmp_path.iterdir()) == []


def test_simulate_says_the_paper_placement_is_the_pandas(tmp_path, capsys):
    """Issue 27: ``--placement paper`` (the default) reused the Panda's Table II offsets on any robot silently."""
    assert main(["simulate", "--robot", "ur5e", "--protocol", "fast", "-o", str(tmp_path / "u.h5")]) == 0
    out = capsys.readouterr().out
    assert "note: --placement paper is the paper's Table II on the Panda; on ur5e" in out and "links 2..6" in out
    assert main(["simulate", "--protocol", "fast", "-o", str(tmp_path / "p.h5")]) == 0
    assert "note:" not in capsys.readouterr().out


def test_robustness_in_a_pipe_says_each_finished_job(tmp_path):
    """Issue 27: ``benchmark robustness --quick`` ran 5 minutes without a line when its output was a pipe
    (the progress bar is drawn on terminals only): now one stderr line per finished job."""
    from cli_subprocess import run_cli

    proc = run_cli(["benchmark", "robustness", "--quick", "--robots", "panda", "--backends", "analytic",
                    "--faults", "qd-1e-3", "--workers", "1"], tmp_path)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "1/1 robustness: panda analytic qd-1e-3" in proc.stderr.splitlines()


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


@pytest.mark.skipif(os.name != "posix", reason="FIFOs and device nodes are POSIX")
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


@pytest.mark.skipif(os.name != "posix", reason="FIFOs and device nodes are POSIX")
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
