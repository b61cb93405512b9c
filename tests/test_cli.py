"""The command line as a user meets it: the main path end to end, and one-line errors."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys

import pytest

from skincal.cli import main


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    path = tmp_path_factory.mktemp("cli") / "data.h5"
    assert main(["simulate", "--out", str(path), "--protocol", "fast", "--noise", "realistic", "--seed", "3"]) == 0
    return path


def digest(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_simulate_calibrate_evaluate(dataset, tmp_path, capsys):
    before = digest(dataset)
    result = tmp_path / "result.json"
    assert main(["calibrate", str(dataset), "--out", str(result)]) == 0
    doc = json.loads(result.read_text())
    assert doc["format"] == "skincal-result" and doc["method"] == "mle" and len(doc["units"]) == 6
    assert doc["dataset_sha256"] == before
    capsys.readouterr()
    assert main(["evaluate", str(result), "--truth", str(dataset), "--json"]) == 0
    ev = json.loads(capsys.readouterr().out)
    assert ev["links_correct"] == 6 and ev["mean_position_error_mm"] < 1.0
    assert digest(dataset) == before  # input files are never modified


def test_calibrate_with_a_links_file(dataset, tmp_path):
    links = tmp_path / "links.yaml"
    links.write_text("su1: 2\nsu2: 3\n")
    out = tmp_path / "r.json"
    assert main(["calibrate", str(dataset), "--out", str(out), "--links", str(links), "--unit", "su1"]) == 0
    assert json.loads(out.read_text())["units"]["su1"]["link"] == 2


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["simulate", "--out", "{tmp}/x.h5", "--robot", "kuka"], "unknown robot 'kuka'"),
        (["simulate", "--out", "{tmp}/x.h5", "--noise", "loud"], "loud"),
        (["simulate", "--out", "{tmp}/x.h5", "--units", "0", "--placement", "random"], "--units"),
        (["info", "{tmp}/missing.h5"], "missing.h5"),
        (["calibrate", "{data}", "--out", "{tmp}/r.json", "--method", "magic"], "unknown method 'magic'"),
        (["calibrate", "{data}", "--out", "{tmp}/r.json", "--unit", "nope"], "unknown unit 'nope'"),
        (["calibrate", "{data}", "--out", "{tmp}/r.json", "--links", "{tmp}/links.yaml"], "links file"),
        (["evaluate", "{tmp}/missing.json", "--truth", "{data}"], "missing.json"),
    ],
)
def test_errors_are_one_line_with_exit_code(args, message, dataset, tmp_path, capsys):
    (tmp_path / "links.yaml").write_text("- not a mapping\n")
    argv = [a.format(tmp=tmp_path, data=dataset) for a in args]
    code = main(argv)
    err = capsys.readouterr().err.strip()
    assert code != 0
    assert message in err
    assert len(err.splitlines()) == 1 and "Traceback" not in err


def test_console_script_demo_runs():
    proc = subprocess.run(
        [sys.executable, "-m", "skincal.cli", "demo", "--protocol", "fast"], capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stderr
    assert "6/6 correct" in proc.stdout
