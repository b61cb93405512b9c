"""The report streams its dataset (issue 19, item 7): the joint stream once, then one unit's IMU data
at a time (:func:`skincal.data.hdf5.open_dataset`), optionally in forked workers; the page is the one
the whole-file reader gives, byte for byte."""

from __future__ import annotations

import dataclasses
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from test_viz_report import report_dataset

from skincal.calib import calibrate
from skincal.calib.residuals import unit_residuals
from skincal.cli import main
from skincal.data.hdf5 import LazyImu, open_dataset, read_dataset, write_dataset
from skincal.data.result import write_result
from skincal.errors import DatasetError
from skincal.skin.imu import get_imu_model
from skincal.viz.content import collect
from skincal.viz.report import write_report


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    """A small simulated dataset (with truth), the same without truth, and a calibration result."""
    ds = report_dataset(get_imu_model("datasheet"), seed=5, n_poses=3)
    result = calibrate(ds, "mle")
    result = dataclasses.replace(result, units={k: result.units[k] for k in list(result.units)[:4]})
    work = tmp_path_factory.mktemp("streaming")
    truth, real, res = work / "truth.h5", work / "real.h5", work / "res.json"
    write_dataset(ds, truth)
    write_dataset(dataclasses.replace(ds, truth={}, truth_sensor={}), real)
    write_result(result, res)
    return truth, real, res


@pytest.mark.parametrize("which", ["truth", "real"])
@pytest.mark.parametrize("fmt", ["html", "md"])
def test_streamed_report_is_identical_to_the_whole_file_one(files, tmp_path: Path, which: str, fmt: str) -> None:
    """Ranked by the truth or (no truth) by the residual RMS, one worker or two: the same text."""
    from skincal.data.result import read_result

    truth, real, res_path = files
    path = truth if which == "truth" else real
    result = read_result(res_path)
    whole = tmp_path / f"whole.{fmt}"
    write_report(result, read_dataset(path), whole, fmt, worst=2)
    expected = whole.read_text()
    marker = "position error against the truth [mm]" if fmt == "html" else "## Errors against truth"
    assert (marker in expected) == (which == "truth")  # both ranking paths are exercised
    for workers in (1, 2):
        streamed = tmp_path / f"streamed-{workers}.{fmt}"
        with open_dataset(path) as ds:
            write_report(result, ds, streamed, fmt, worst=2, workers=workers)
        assert streamed.read_text() == expected, f"workers={workers}"


def test_cli_report_is_the_same_with_one_or_two_workers(files, tmp_path: Path) -> None:
    truth, _real, res_path = files
    pages = []
    for workers in (1, 2):
        out = tmp_path / f"r{workers}.html"
        argv = ["report", str(res_path), "--dataset", str(truth), "-o", str(out), "--workers", str(workers)]
        assert main(argv) == 0
        pages.append(out.read_text())
    assert pages[0] == pages[1] and pages[0].startswith("<!DOCTYPE html>")


def test_the_report_reads_each_unit_once_after_the_validation(files, monkeypatch: pytest.MonkeyPatch) -> None:
    """The validation reads every unit once; the report then reads each unit once more, alone (the
    whole-file reader's residuals used to copy every unit's stream into each unit's dataset)."""
    from skincal.data.result import read_result

    truth, _real, res_path = files
    result = read_result(res_path)
    reads: Counter[str] = Counter()
    original = LazyImu.__getitem__

    def counted(self: LazyImu, unit: str):
        reads[unit] += 1
        return original(self, unit)

    monkeypatch.setattr(LazyImu, "__getitem__", counted)
    with open_dataset(truth) as ds:
        units = list(ds.imu)
        assert reads == Counter(dict.fromkeys(units, 1))  # the validation
        reads.clear()
        collect(result, ds, shown=2)
    assert reads == Counter(dict.fromkeys(result.units, 1))
    assert len(units) > len(result.units)  # the units not in the result were not read at all
    name = next(iter(result.units))
    with open_dataset(truth) as ds:
        reads.clear()
        unit_residuals(ds, name, result.units[name])  # alone, too: the other units' streams are not read
    assert reads == Counter({name: 1})


def test_streamed_units_equal_the_whole_file_and_end_with_the_file(files) -> None:
    truth, _real, _res = files
    whole = read_dataset(truth)
    with open_dataset(truth) as ds:
        assert list(ds.imu) == list(whole.imu) and len(ds.imu) == len(whole.imu)
        for unit, stream in whole.imu.items():
            for key in ("t", "accel", "gyro"):
                assert np.array_equal(getattr(ds.imu[unit], key), getattr(stream, key))
        assert "nope" not in ds.imu
        with pytest.raises(KeyError):
            ds.imu["nope"]
        assert np.array_equal(ds.joints.q, whole.joints.q) and ds.truth.keys() == whole.truth.keys()
    with pytest.raises(DatasetError, match="after the file was closed") as info:
        ds.imu[next(iter(whole.imu))]
    assert "\n" not in str(info.value)
