"""The command line as a user meets it: the main path end to end, and one-line errors."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys

import numpy as np
import pytest
from rich.console import Console

from skincal.cli import main
from skincal.cli.calibrate import std_cell, unit_table
from skincal.data.result import CalibrationResult, UnitResult
from skincal.skin.pose import SkinUnitPose


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


def test_evaluate_lists_a_unit_the_result_could_not_calibrate(dataset, tmp_path, capsys):
    """A failed unit stays in evaluate's table ("not calibrated"), not only in --json's units_failed."""
    result = tmp_path / "result.json"
    assert main(["calibrate", str(dataset), "--out", str(result), "--unit", "su1", "--unit", "su2"]) == 0
    doc = json.loads(result.read_text())
    doc["units"]["su2"] = {"link": None, "position_m": None, "quaternion_wxyz": None, "observable": False,
                           "position_std_m": None, "rotation_std_deg": None, "warnings": ["no motion excites it"]}
    result.write_text(json.dumps(doc))
    capsys.readouterr()
    assert main(["evaluate", str(result), "--truth", str(dataset)]) == 0
    out = capsys.readouterr().out
    assert "su2 (not calibrated)" in out and "su1" in out


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


def test_std_cell_leaves_out_undetermined_components():
    assert std_cell(None) == "-"
    assert std_cell([1.6e-4, 6.6e-4, 2e-4], 1e3) == "0.660"
    assert std_cell(np.array([1.6e-4, 6.6e-4, np.nan]), 1e3) == "0.660 (1 undetermined)"
    assert std_cell([np.nan, np.nan, np.nan]) == "- (3 undetermined)"


def test_calibrate_table_with_an_undetermined_std_and_a_failed_unit():
    pose = SkinUnitPose.from_quaternion(1, [0.05, 0.0, 0.12], [1, 0, 0, 0])
    su1 = UnitResult(pose, observable=False, position_std_m=[0.00016, 0.00066, np.nan],
                     rotation_std_deg=[0.02, np.nan, np.nan], warnings=("yaw about joint 1 undetermined",))
    result = CalibrationResult("mle", "panda", "", 1.0, {"su1": su1}, failed_units={"su2": "diverged"})
    console = Console(width=250, record=True)
    console.print(unit_table(result, "t"))
    text = console.export_text()
    row1 = next(line for line in text.splitlines() if "su1" in line)
    assert "0.660 (1 undetermined)" in row1 and "0.020 (2 undetermined)" in row1 and "unobservable" in row1
    row2 = next(line for line in text.splitlines() if "su2" in line)
    assert "not calibrated: diverged" in row2
    assert "nan" not in text.lower()


def test_calibrate_table_names_the_link_and_heads_the_warnings_as_such():
    """Issue 27: the table showed link indices only (not the URDF's link names) and headed the warnings
    'notes' (the notes, found and corrected, are not in it)."""
    pose = SkinUnitPose.from_quaternion(3, [0.05, 0.0, 0.12], [1, 0, 0, 0])
    su1 = UnitResult(pose, position_std_m=[1e-4] * 3, rotation_std_deg=[0.01] * 3, warnings=("bias drifts",),
                     extras={"link_name": "forearm_link"}, notes=("clock drifts: +20 ppm",))  # fmt: skip
    result = CalibrationResult("mle", "ur5", "", 1.0, {"su1": su1})
    console = Console(width=250, record=True)
    console.print(unit_table(result, "t"))
    text = console.export_text()
    assert "warnings" in text and "notes" not in text
    row = next(line for line in text.splitlines() if "su1" in line)
    assert "3 (forearm_link)" in row and "bias drifts" in row and "clock drifts" not in row
