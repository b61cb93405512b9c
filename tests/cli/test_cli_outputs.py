"""Outputs are never clobbered silently: every command that writes a file refuses its own input,
an existing file (unless --force), a folder and a missing folder, before doing any work."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from skincal.cli import main


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    root = tmp_path_factory.mktemp("outputs")
    data = root / "data.h5"
    assert main(["simulate", "--robot", "panda", "--placement", "random", "--units", "2", "--protocol", "fast",
                 "--out", str(data)]) == 0
    result = root / "result.json"
    assert main(["calibrate", str(data), "--out", str(result)]) == 0
    return root, data, result


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
