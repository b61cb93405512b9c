"""Calibration result JSON: contract example, round trip, extras, validation, atomic write, sha256."""

from __future__ import annotations

import hashlib
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from skincal.data import CalibrationResult, UnitResult, read_result, result_to_dict, sha256_file, write_result
from skincal.data.events import MoveEvent
from skincal.data.imu_calibration import IMU_KEYS, IMU_SHAPES, ImuCalibration
from skincal.errors import DatasetError
from skincal.kinematics import rotation_angle
from skincal.skin.pose import SkinUnitPose

# The example of docs/interfaces.md, verbatim apart from a real digest.
CONTRACT_EXAMPLE = """
{"format": "skincal-result", "version": 1, "method": "mle", "robot": "panda",
 "dataset_sha256": "%s", "runtime_s": 0.41,
 "units": {"su1": {"link": 3, "position_m": [0.05, 0.0, 0.12], "quaternion_wxyz": [1, 0, 0, 0],
                   "observable": true, "position_std_m": [1e-5, 1e-5, 2e-5],
                   "rotation_std_deg": [0.01, 0.01, 0.02], "warnings": []}}}
""" % ("ab" * 32)


def make_result() -> CalibrationResult:
    su1 = SkinUnitPose.from_dh6(3, [0.3, -0.08, 1.2, 0.05, 0.01, 1.4])
    su0 = SkinUnitPose.from_dh6(1, [1.571, 0.06, -1.571, 0.06, 0.0, 1.571])
    return CalibrationResult(
        method="mle",
        robot="panda",
        dataset_sha256=hashlib.sha256(b"dataset").hexdigest(),
        runtime_s=0.1 + 0.2,  # 0.30000000000000004: full precision must survive
        units={
            "su1": UnitResult(
                pose=su1,
                observable=True,
                position_std_m=np.array([1e-5, 1.5e-5, 2.123456789012345e-5]),
                rotation_std_deg=np.array([0.01, 0.01, 0.02]),
                warnings=(),
                extras={
                    "accel_scale": np.array([1.001, 0.999, 1.0]),
                    "dh6": su1.dh6(),
                    "iterations": np.int64(17),
                    "note": "converged",
                },
                imu=ImuCalibration(accel_bias_mps2=np.array([0.01, -0.02, np.nan]), time_offset_s=np.float64(0.0042)),
                link_confidence=0.987654321,
                notes=("clock re-synced 3 times",),
            ),
            "base_unit": UnitResult(
                pose=su0,
                observable=False,
                warnings=("link 1: yaw about and offset along the joint-1 axis are unobservable",),
            ),
        },
        extras={"options": {"robust_loss": "huber", "f_scale": 0.5}, "skincal_version": "0.1.0"},
    )


def test_reads_the_contract_example(tmp_path: Path) -> None:
    path = tmp_path / "result.json"
    path.write_text(CONTRACT_EXAMPLE)
    result = read_result(path)
    assert (result.method, result.robot, result.runtime_s) == ("mle", "panda", 0.41)
    unit = result.units["su1"]
    assert unit.pose.link == 3 and unit.observable and unit.warnings == () and unit.extras == {}
    np.testing.assert_array_equal(unit.pose.p_link_su, [0.05, 0.0, 0.12])
    np.testing.assert_array_equal(unit.pose.R_link_su, np.eye(3))
    np.testing.assert_array_equal(unit.position_std_m, [1e-5, 1e-5, 2e-5])
    np.testing.assert_array_equal(unit.rotation_std_deg, [0.01, 0.01, 0.02])
    # Writing it back gives the same document (contract fields only, same values).
    write_result(result, tmp_path / "again.json")
    assert json.loads((tmp_path / "again.json").read_text()) == json.loads(CONTRACT_EXAMPLE)


def test_round_trip(tmp_path: Path) -> None:
    original = make_result()
    path = tmp_path / "result.json"
    write_result(original, path)
    back = read_result(path)
    assert (back.method, back.robot, back.dataset_sha256) == (original.method, original.robot, original.dataset_sha256)
    assert back.runtime_s == 0.30000000000000004
    assert back.extras == original.extras
    assert list(back.units) == list(original.units)
    for name, unit in original.units.items():
        got = back.units[name]
        assert got.pose.link == unit.pose.link and got.observable == unit.observable
        assert got.warnings == unit.warnings
        np.testing.assert_array_equal(got.pose.p_link_su, unit.pose.p_link_su)
        assert rotation_angle(got.pose.R_link_su, unit.pose.R_link_su) < 1e-15
        for key in ("position_std_m", "rotation_std_deg"):
            a, b = getattr(unit, key), getattr(got, key)
            assert (a is None and b is None) or np.array_equal(a, b)
        assert (got.imu is None) == (unit.imu is None)
        if unit.imu is not None:
            for key in IMU_KEYS:
                a, b = getattr(unit.imu, key), getattr(got.imu, key)
                assert (a is None and b is None) or np.array_equal(a, b, equal_nan=True), key
        assert set(got.extras) == set(unit.extras)
        for key, value in unit.extras.items():
            if isinstance(value, np.ndarray):
                assert isinstance(got.extras[key], np.ndarray)
                np.testing.assert_array_equal(got.extras[key], value)  # NaN -> null -> NaN
            else:  # NumPy scalars come back as the matching Python number
                plain = value.item() if isinstance(value, np.generic) else value
                assert got.extras[key] == plain and type(got.extras[key]) is type(plain)


def test_json_layout(tmp_path: Path) -> None:
    path = tmp_path / "result.json"
    write_result(make_result(), path)
    doc = json.loads(path.read_text())
    assert list(doc)[:6] == ["format", "version", "method", "robot", "dataset_sha256", "runtime_s"]
    assert doc["format"] == "skincal-result" and doc["version"] == 1
    base = doc["units"]["base_unit"]
    assert base["position_std_m"] is None and base["rotation_std_deg"] is None and base["observable"] is False
    su1 = doc["units"]["su1"]
    assert su1["accel_bias_mps2"] == [0.01, -0.02, None]
    assert su1["position_std_m"][2] == 2.123456789012345e-05
    assert doc["options"] == {"robust_loss": "huber", "f_scale": 0.5}
    q = np.array(su1["quaternion_wxyz"])
    assert abs(np.linalg.norm(q) - 1) < 1e-15 and q[0] >= 0
    assert "NaN" not in path.read_text()


# A result written by mle before the IMU calibration had a type (su1: the writer's own output for a
# simulated Panda unit, ``skincal calibrate`` of the realistic IMU model; su2: the same layout with the
# fields mle writes as null when it does not estimate them, time offset and clock drift).
OLD_MLE_RESULT = """
{"format": "skincal-result", "version": 1, "method": "mle", "robot": "panda", "dataset_sha256": "",
 "runtime_s": 0.6772303540001303, "seed": 0,
 "units": {
  "su1": {
    "link": 2,
    "position_m": [0.03574409215337423, -0.009045915070273748, -0.048428459244416945],
    "quaternion_wxyz": [0.12428259566577707, -0.871745067774284, 0.3765341329989869, -0.28781316841396815],
    "observable": true,
    "position_std_m": [0.00016433496345790366, 0.00012566182289675996, 0.00020808519536212624],
    "rotation_std_deg": [0.005817467408037891, 0.005183746150113648, 0.006258376627342006],
    "warnings": [],
    "link_confidence": 0.9756406632117663,
    "link_residual_mps2": {},
    "accel_bias_mps2": [-0.040822642844165966, -0.25821553598015123, 0.12018947294937052],
    "accel_scale_misalignment": [
        [0.9778518157132822, 0.008302305405266596, 0.0032600073962667907],
        [0.009663885436694391, 1.0008967884635795, -0.004939743502833981],
        [-0.005137201590618791, 0.005651135673563817, 0.9982850061405634]
    ],
    "accel_bias_std_mps2": [0.0011489921074755896, 0.0011487362364387447, 0.0011486316634818899],
    "time_offset_s": 0.014985033764840661,
    "time_offset_std_s": 2.8794695104459353e-05,
    "time_offset_coarse_s": 0.014971247729732455,
    "time_reference_s": 0.0,
    "clock_drift_ppm": 0.10999763787414828,
    "clock_drift_std_ppm": 0.23424495063410414,
    "residual_std_mps2": 0.030974887830805004,
    "residual_correlation": 1.0,
    "n_static_runs": 48,
    "n_static_dropped": 0,
    "n_moving_samples": 12239,
    "iterations": 1,
    "scale_estimated": true,
    "rest_source": "segments",
    "gyro_bias_rps": [-0.35313925257692313, 0.06183311748045054, -0.18024025271416344],
    "gyro_bias_std_rps": [3.055934675878544e-05, 3.057183634032596e-05, 3.056961869165549e-05],
    "gyro_residual_std_rps": 0.00431295058398401,
    "gravity_mps2": 9.809650530547678,
    "gravity_std_mps2": 0.01957381371176707,
    "accel_bias_drift_mps3": [3.1224160263599105e-06, 2.1177919227972295e-06, -5.419828382194456e-06],
    "accel_bias_drift_std_mps3": [3.498745204806452e-06, 3.4989172641159012e-06, 3.499254627133855e-06],
    "accel_scale_misalignment_std": [
        [0.003560706583002541, 0.0031666761764162954, 0.005867446998556289],
        [0.0030385221552240386, 0.0037925293122422236, 0.005978549902661455],
        [0.0031164807233617768, 0.0033082672519981456, 0.006440247006027855]
    ],
    "accel_scale": [0.9778518157132822, 1.0008967884635795, 0.9982850061405634],
    "accel_misalignment_sym": [
        [0.0, 0.008983095420980493, -0.0009385970971760001],
        [0.008983095420980493, 0.0, 0.0003556960853649182],
        [-0.0009385970971760001, 0.0003556960853649182, 0.0]
    ],
    "link_name": "link2"
  },
  "su2": {
    "link": 3,
    "position_m": [0.03574409215337423, -0.009045915070273748, -0.048428459244416945],
    "quaternion_wxyz": [1.0, 0.0, 0.0, 0.0],
    "observable": true,
    "position_std_m": [0.00016433496345790366, 0.00012566182289675996, 0.00020808519536212624],
    "rotation_std_deg": [0.005817467408037891, 0.005183746150113648, 0.006258376627342006],
    "warnings": ["only 2 distinct static orientation(s)"],
    "accel_bias_mps2": [0.01, -0.02, 0.03],
    "accel_scale_misalignment": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
    "accel_bias_std_mps2": [0.001, 0.001, 0.002],
    "time_offset_s": 0.0,
    "time_offset_std_s": null,
    "time_offset_coarse_s": null,
    "time_reference_s": 0.0,
    "clock_drift_ppm": null,
    "clock_drift_std_ppm": null,
    "residual_std_mps2": 0.03,
    "scale_estimated": false,
    "link_name": "link3"
  }}}
"""


def test_a_result_written_before_the_typed_imu_calibration_reads_identically(tmp_path: Path) -> None:
    """Old code: ``UnitResult`` has no ``imu``; the IMU fields sat in ``extras`` under the same keys."""
    path = tmp_path / "old.json"
    path.write_text(OLD_MLE_RESULT)
    doc = json.loads(OLD_MLE_RESULT)
    result = read_result(path)
    for name, entry in doc["units"].items():
        unit = result.units[name]
        assert isinstance(unit.imu, ImuCalibration)
        assert not set(unit.extras) & set(IMU_KEYS)  # read into the typed field, not left in extras
        for key in IMU_KEYS:
            value = getattr(unit.imu, key)
            if entry.get(key) is None:
                assert value is None, (name, key)
            elif isinstance(value, float):
                assert type(value) is float and value == entry[key], (name, key)
            else:
                assert value.dtype == float and np.array_equal(value, np.array(entry[key])), (name, key)
        if "accel_scale" in entry:  # derived summaries of A stay extras
            assert unit.extras["accel_scale"].tolist() == entry["accel_scale"]
        assert unit.extras["time_offset_coarse_s"] == entry["time_offset_coarse_s"]
    su1, su2 = result.units["su1"].imu, result.units["su2"].imu
    assert su1.clock_drift_ppm == 0.10999763787414828 and su1.gravity_mps2 == 9.809650530547678
    assert su1.accel_scale_misalignment.shape == (3, 3) and su1.accel_scale_misalignment[1, 0] == 0.009663885436694391
    assert su2.clock_drift_ppm is None and su2.gyro_bias_rps is None and su2.accel_scale_misalignment_std is None
    # Written again: the same document (the same keys, the same numbers; the quaternion's last bit may
    # move through the rotation matrix, as it always did).
    write_result(result, tmp_path / "again.json")
    again = json.loads((tmp_path / "again.json").read_text())
    assert set(again) == set(doc) and {k: again[k] for k in doc if k != "units"} == {
        k: doc[k] for k in doc if k != "units"
    }
    for name, entry in doc["units"].items():
        got = again["units"][name]
        assert set(got) == set(entry), name
        assert {k: v for k, v in got.items() if k != "quaternion_wxyz"} == {
            k: v for k, v in entry.items() if k != "quaternion_wxyz"
        }
        np.testing.assert_allclose(got["quaternion_wxyz"], entry["quaternion_wxyz"], rtol=0, atol=1e-15)


def test_imu_calibration_round_trip_keeps_every_field(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    values = {}
    for key in IMU_KEYS:
        shape = IMU_SHAPES[key]
        values[key] = float(rng.normal()) if shape == () else rng.normal(size=shape)
    values["clock_resync_steps"] = 87  # a count: a whole number in the file
    values["accel_bias_mps2"][1] = np.nan  # undetermined: null in the file, NaN again on read
    imu = ImuCalibration(**values)
    result = make_result()
    units = {**result.units, "su1": UnitResult(result.units["su1"].pose, imu=imu)}
    write_result(CalibrationResult("mle", "panda", "", 0.0, units), tmp_path / "r.json")
    back = read_result(tmp_path / "r.json").units["su1"]
    assert back.extras == {}
    for key in IMU_KEYS:
        np.testing.assert_array_equal(getattr(back.imu, key), getattr(imu, key), err_msg=key)
    # A unit without one: no IMU field written, None read.
    assert read_result(tmp_path / "r.json").units["base_unit"].imu is None
    assert not set(json.loads((tmp_path / "r.json").read_text())["units"]["base_unit"]) & set(IMU_KEYS)


@pytest.mark.adversarial
@pytest.mark.parametrize(
    ("key", "value", "problem"),
    [
        ("accel_bias_mps2", [0.1, 0.2], "must be a list of 3 finite numbers or null"),
        ("accel_bias_mps2", "0.1 0.2 0.3", "must be a list of 3 finite numbers or null"),
        ("accel_scale_misalignment", [1.0, 0.0, 0.0], "must be a list of 3 finite numbers or null"),
        ("accel_scale_misalignment", [[1.0, 0.0, 0.0]], "must be 3 rows of 3 numbers"),
        ("time_offset_s", "0.01", "must be a finite number or null"),
        ("time_offset_s", True, "must be a finite number or null"),
        ("time_offset_s", 1e309, None),  # JSON overflow: refused by the reader before
        ("clock_resync_steps", 2.5, "must be a whole number >= 0 or null"),
        ("clock_resync_steps", -3, "must be a whole number >= 0 or null"),
    ],
)
def test_malformed_imu_fields_are_refused_on_one_line(tmp_path: Path, key, value, problem) -> None:
    doc = json.loads(OLD_MLE_RESULT)
    doc["units"]["su1"][key] = value
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(DatasetError) as info:
        read_result(path)
    message = str(info.value)
    assert "\n" not in message and str(path) in message
    if problem is not None:
        assert f"units.su1.{key}" in message and problem in message, message


def test_imu_fields_in_extras_are_refused_on_write(tmp_path: Path) -> None:
    """The IMU calibration has one place, ``UnitResult.imu``: a writer that still puts it in extras is
    told so (old code wrote it, and a report reading ``imu`` would silently not see it)."""
    result = make_result()
    unit = result.units["su1"]
    bad = CalibrationResult("mle", "panda", "", 0.0, {"su1": UnitResult(unit.pose, extras={"time_offset_s": 0.01})})
    with pytest.raises(DatasetError, match=r"units\.su1 extras may not hold time_offset_s: .*UnitResult\.imu"):
        write_result(bad, tmp_path / "r.json")
    assert not (tmp_path / "r.json").exists()


def test_sha256_file(tmp_path: Path) -> None:
    path = tmp_path / "blob.bin"
    data = np.random.default_rng(0).bytes(300_000)
    path.write_bytes(data)
    assert sha256_file(path) == hashlib.sha256(data).hexdigest()
    with pytest.raises(DatasetError, match="nothing.bin: cannot read file"):
        sha256_file(tmp_path / "nothing.bin")


def _doc() -> dict:
    return json.loads(CONTRACT_EXAMPLE)


def _set(path: str, value: object) -> dict:
    doc = _doc()
    *parents, last = path.split(".")
    node = doc
    for key in parents:
        node = node[key]
    if value is KeyError:
        del node[last]
    else:
        node[last] = value
    return doc


BAD_DOCS = {
    "wrong format": (_set("format", "skincal-dataset"), "format is 'skincal-dataset', expected 'skincal-result'"),
    "wrong version": (_set("version", 2), "version is 2; this skincal reads version 1"),
    "bool version": (_set("version", True), "version must be an integer"),
    "missing units": (_set("units", KeyError), "units is missing"),
    "missing method": (_set("method", KeyError), "method is missing"),
    "bad sha": (_set("dataset_sha256", "xyz"), "dataset_sha256 must be 64 hex digits"),
    "negative runtime": (_set("runtime_s", -1), "runtime_s must be a non-negative number"),
    "link zero": (_set("units.su1.link", 0), "units.su1.link must be a positive integer"),
    "float link": (_set("units.su1.link", 3.0), "units.su1.link must be a positive integer"),
    "short position": (_set("units.su1.position_m", [0.0, 1.0]), "units.su1.position_m must be a list of 3 finite"),
    "string in position": (_set("units.su1.position_m", [0, "1", 2]), "units.su1.position_m must be a list of 3"),
    "not unit quaternion": (_set("units.su1.quaternion_wxyz", [1, 1, 0, 0]), "is not a unit quaternion"),
    "missing quaternion": (_set("units.su1.quaternion_wxyz", KeyError), "units.su1.quaternion_wxyz is missing"),
    "observable string": (_set("units.su1.observable", "yes"), "units.su1.observable must be true or false"),
    "negative std": (_set("units.su1.position_std_m", [1, -1, 0]), "units.su1.position_std_m must not be negative"),
    "string in std": (_set("units.su1.position_std_m", [1e-5, "2e-5", None]),
                      "units.su1.position_std_m must be a list of 3 finite numbers or null (undetermined)"),
    "negative std beside null": (_set("units.su1.rotation_std_deg", [None, -0.1, 0.0]),
                                 "units.su1.rotation_std_deg must not be negative"),
    "bool in std": (_set("units.su1.rotation_std_deg", [True, None, 0.0]), "units.su1.rotation_std_deg must be a list"),
    "short std with null": (_set("units.su1.position_std_m", [None, None]), "units.su1.position_std_m must be a list"),
    "null link with a pose": (_set("units.su1.link", None), "units.su1.link must be a positive integer (1-based link), "
                                                            "got None"),
    "no pose but observable": (_set("units.su1.position_m", None),
                               "units.su1.observable must be false for a unit without a pose"),
    "no pose, link zero": (_set("units.su1", {**json.loads(CONTRACT_EXAMPLE)["units"]["su1"], "link": 0,
                                              "quaternion_wxyz": None, "observable": False}),
                           "units.su1.link must be a positive integer (1-based link) or null"),
    "no pose, bad partial quaternion": (_set("units.su1", {**json.loads(CONTRACT_EXAMPLE)["units"]["su1"],
                                                           "position_m": None, "quaternion_wxyz": [2, 0, 0, 0],
                                                           "observable": False}), "is not a unit quaternion"),
    "warnings not list": (_set("units.su1.warnings", "bad"), "units.su1.warnings must be a list of strings"),
    "unit not object": (_set("units.su1", [1, 2]), "units.su1 must be an object"),
}


@pytest.mark.parametrize("case", list(BAD_DOCS))
def test_bad_result_gives_one_line_error(tmp_path: Path, case: str) -> None:
    doc, expected = BAD_DOCS[case]
    path = tmp_path / "r.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(DatasetError) as info:
        read_result(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ") and "\n" not in message
    assert expected in message


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (CONTRACT_EXAMPLE[: len(CONTRACT_EXAMPLE) // 2], "not valid JSON (line"),
        ('{"format": NaN}', "contains NaN, which is not valid JSON"),
        ("[1, 2]", "top level must be a JSON object"),
        ("", "not valid JSON (line 1, column 1"),
    ],
)
def test_unreadable_result_files(tmp_path: Path, text: str, expected: str) -> None:
    path = tmp_path / "r.json"
    path.write_text(text)
    with pytest.raises(DatasetError) as info:
        read_result(path)
    assert expected in str(info.value) and "\n" not in str(info.value)
    with pytest.raises(DatasetError, match="r2.json: no such file"):
        read_result(tmp_path / "r2.json")
    (tmp_path / "bin.json").write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(DatasetError, match="not valid UTF-8"):
        read_result(tmp_path / "bin.json")


def test_write_validates_and_keeps_old_file(tmp_path: Path) -> None:
    path = tmp_path / "result.json"
    write_result(make_result(), path)
    old = path.read_bytes()
    good = make_result()
    bad_unit = UnitResult(pose=good.units["su1"].pose, position_std_m=np.array([np.nan, -1e-3, 0.0]))
    cases = [
        (CalibrationResult("mle", "p", "", 1.0, {"su1": bad_unit}), "units.su1.position_std_m must not be negative"),
        (CalibrationResult("", "panda", "", 1.0, {}), "method is empty"),
        (CalibrationResult("mle", "p", "", 1.0, {}, extras={"units": 1}), "may not redefine contract field(s) units"),
        (
            CalibrationResult("mle", "p", "", 1.0, {"a": UnitResult(good.units["su1"].pose, extras={"link": 2})}),
            "units.a extras may not redefine contract field(s) link",
        ),
        (CalibrationResult("mle", "p", "", 1.0, {}, extras={"when": object()}), "extras.when has a value of type"),
    ]
    for result, expected in cases:
        with pytest.raises(DatasetError) as info:
            write_result(result, path)
        assert expected in str(info.value), str(info.value)
        assert path.read_bytes() == old
    assert sorted(p.name for p in tmp_path.iterdir()) == ["result.json"]


def test_result_to_dict_is_plain_json() -> None:
    doc = result_to_dict(make_result())
    assert json.loads(json.dumps(doc, allow_nan=False)) == doc


# ---------------------------------------------------------------------- never lose a result
def _with_undetermined_and_failed() -> CalibrationResult:
    pose = SkinUnitPose.from_quaternion(1, [0.05, 0.0, 0.12], [1, 0, 0, 0])
    su1 = UnitResult(pose, observable=False, position_std_m=np.array([0.00016, 0.00066, np.nan]),
                     rotation_std_deg=np.array([0.01, np.nan, np.nan]), warnings=("yaw about joint 1 undetermined",))
    return CalibrationResult("mle", "panda", "", 1.0, {"su1": su1}, extras={"seed": 0},
                             failed_units={"su2": "no motion excited it", "su3": "diverged"})


def test_undetermined_std_components_write_as_null_and_read_back_as_nan(tmp_path: Path) -> None:
    path = tmp_path / "result.json"
    write_result(_with_undetermined_and_failed(), path)
    text = path.read_text()
    assert "NaN" not in text
    su1 = json.loads(text)["units"]["su1"]
    assert su1["position_std_m"] == [0.00016, 0.00066, None] and su1["rotation_std_deg"] == [0.01, None, None]
    back = read_result(path).units["su1"]
    np.testing.assert_array_equal(back.position_std_m, [0.00016, 0.00066, np.nan])
    np.testing.assert_array_equal(back.rotation_std_deg, [0.01, np.nan, np.nan])
    assert back.position_std_m.dtype == np.float64 and not back.observable


def test_hand_written_file_with_null_std_components(tmp_path: Path) -> None:
    doc = _doc()
    doc["units"]["su1"].update(observable=False, position_std_m=[1e-5, 2e-5, None],
                               rotation_std_deg=[None, None, None], warnings=["yaw undetermined"])
    path = tmp_path / "r.json"
    path.write_text(json.dumps(doc))
    unit = read_result(path).units["su1"]
    np.testing.assert_array_equal(unit.position_std_m, [1e-5, 2e-5, np.nan])
    assert np.isnan(unit.rotation_std_deg).all()
    write_result(read_result(path), tmp_path / "again.json")
    assert json.loads((tmp_path / "again.json").read_text()) == doc


def test_failed_units_are_listed_under_units(tmp_path: Path) -> None:
    original = _with_undetermined_and_failed()
    path = tmp_path / "result.json"
    write_result(original, path)
    doc = json.loads(path.read_text())
    assert list(doc["units"]) == ["su1", "su2", "su3"]
    assert doc["units"]["su2"] == {"link": None, "position_m": None, "quaternion_wxyz": None, "observable": False,
                                   "position_std_m": None, "rotation_std_deg": None,
                                   "warnings": ["no motion excited it"]}
    assert doc["failed_units"] == {"su2": "no motion excited it", "su3": "diverged"}  # kept (backwards compatible)
    back = read_result(path)
    assert list(back.units) == ["su1"]  # units in result.units always have a pose
    assert back.extras == original.extras == {"seed": 0}
    assert back.failed_units == original.failed_units


def test_hand_written_units_without_a_pose(tmp_path: Path) -> None:
    doc = _doc()
    base = {"observable": False, "position_std_m": None, "rotation_std_deg": None}
    doc["units"]["su2"] = {**base, "link": None, "position_m": None, "quaternion_wxyz": None,
                           "warnings": ["no data", "IMU silent"]}
    doc["units"]["su3"] = {**base, "link": 2, "position_m": [0.0, 0.1, 0.0], "quaternion_wxyz": None,
                           "position_std_m": [1e-3, None, None], "warnings": []}  # best partial pose
    path = tmp_path / "r.json"
    path.write_text(json.dumps(doc))
    result = read_result(path)
    assert list(result.units) == ["su1"]
    assert result.extras == {}
    assert result.failed_units == {"su2": "no data; IMU silent", "su3": "no pose (the result file gives no reason)"}
    # A top-level failed_units is merged (the unit entries' warnings win for units they list).
    doc["failed_units"] = {"su2": "old reason", "su9": "elsewhere"}
    path.write_text(json.dumps(doc))
    assert read_result(path).failed_units == {
        "su2": "no data; IMU silent", "su9": "elsewhere", "su3": "no pose (the result file gives no reason)"}
    doc["failed_units"] = ["su2"]
    path.write_text(json.dumps(doc))
    with pytest.raises(DatasetError) as info:
        read_result(path)
    assert "failed_units must be an object of unit name -> reason" in str(info.value)
    assert "\n" not in str(info.value)


def test_old_file_with_only_top_level_failed_units_reads_unchanged(tmp_path: Path) -> None:
    doc = _doc()
    doc["failed_units"] = {"su2": "diverged"}
    path = tmp_path / "r.json"
    path.write_text(json.dumps(doc))
    result = read_result(path)
    assert list(result.units) == ["su1"] and result.extras == {} and result.failed_units == {"su2": "diverged"}
    # a hand-written list of names (no unit entry without a pose): each "not calibrated"
    doc["failed_units"] = ["su2", "su3"]
    path.write_text(json.dumps(doc))
    assert read_result(path).failed_units == {"su2": "not calibrated", "su3": "not calibrated"}
    doc["failed_units"] = 3
    path.write_text(json.dumps(doc))
    with pytest.raises(DatasetError, match=r"failed_units must be an object of unit name -> reason, got 3$"):
        read_result(path)


def test_a_failed_unit_that_also_has_a_pose_is_written_once() -> None:
    result = _with_undetermined_and_failed()
    result = replace(result, failed_units={**result.failed_units, "su1": "partly failed"})
    doc = result_to_dict(result)
    assert doc["units"]["su1"]["link"] == 1 and doc["units"]["su1"]["observable"] is False
    assert doc["failed_units"]["su1"] == "partly failed"


# ---------------------------------------------------------------------- the facts every method gives: typed fields
def _old_document() -> dict:
    """A result as skincal wrote it before these facts had fields: the same keys in the same places
    (top level: ``reference``, ``failed_units``, ``notes``, ``events``; per unit: ``link_confidence``,
    ``notes``, ``pose_covariance``, ``moved_at_s``) next to method-specific extras."""
    doc = _doc()
    cov = (np.diag([1e-8, 2e-8, 3e-8, 1e-6, 2e-6, 3e-6]) + 1e-10 * np.ones((6, 6))).tolist()
    cov[2] = [None] * 6  # undetermined z: null row and column
    for row in cov:
        row[2] = None
    T_after = np.eye(4)
    T_after[:3, 3] = [0.05, 0.001, 0.12]
    doc["units"]["su1"].update(link_confidence=0.93, link_residual_mps2={"3": 0.01, "4": 0.2}, iterations=7,
                               notes=["clock drifts +40 ppm; stamps corrected"], pose_covariance=cov,
                               moved_at_s=[12.5])  # fmt: skip
    doc["units"]["su2"] = {"link": None, "position_m": None, "quaternion_wxyz": None, "observable": False,
                           "position_std_m": None, "rotation_std_deg": None, "warnings": ["diverged"]}  # fmt: skip
    doc.update(seed=0, failed_units={"su2": "diverged"}, notes=["no segments in the dataset: 3 static found"],
               events=[{"unit": "su1", "t_change_s": 12.5, "t_detected_s": 13.0, "statistic": 14.2, "threshold": 10.0,
                        "link": 3, "t_recalibrated_s": 20.0, "T_link_su_before": np.eye(4).tolist(),
                        "T_link_su_after": T_after.tolist(), "source": "monitor"}])  # fmt: skip
    return doc


def test_a_file_written_before_reads_into_the_typed_fields_and_writes_back_identically(tmp_path: Path) -> None:
    doc = _old_document()
    path = tmp_path / "old.json"
    path.write_text(json.dumps(doc))
    result = read_result(path)
    assert result.extras == {"seed": 0}  # only the method's own output stays in extras
    assert result.failed_units == {"su2": "diverged"} and result.notes == tuple(doc["notes"])
    assert result.reference is None
    (event,) = result.events
    assert (event.unit, event.t_change_s, event.t_detected_s, event.link) == ("su1", 12.5, 13.0, 3)
    assert event.extra == {"source": "monitor"} and event.T_link_su_after.shape == (4, 4)
    unit = result.units["su1"]
    assert set(unit.extras) == {"link_residual_mps2", "iterations"}
    assert unit.link_confidence == 0.93 and unit.notes == tuple(doc["units"]["su1"]["notes"])
    assert unit.moved_at_s == (12.5,)
    assert unit.pose_covariance.shape == (6, 6) and np.isnan(unit.pose_covariance[2]).all()
    assert unit.pose_covariance[0, 0] == doc["units"]["su1"]["pose_covariance"][0][0]
    write_result(result, tmp_path / "again.json")
    assert json.loads((tmp_path / "again.json").read_text()) == doc


def test_a_relative_result_reads_its_reference_into_the_field(tmp_path: Path) -> None:
    doc = _doc()
    doc["reference"] = "su1"
    doc["units"]["su1"].update(link=0, position_m=[0.0, 0.0, 0.0])
    path = tmp_path / "rel.json"
    path.write_text(json.dumps(doc))
    result = read_result(path)
    assert result.reference == "su1" and "reference" not in result.extras
    write_result(result, tmp_path / "again.json")
    assert json.loads((tmp_path / "again.json").read_text()) == doc


def test_typed_fields_round_trip_from_memory(tmp_path: Path) -> None:
    pose = SkinUnitPose.from_quaternion(3, [0.05, 0.0, 0.12], [1, 0, 0, 0])
    cov = np.diag([1e-8, 2e-8, 3e-8, 1e-6, 2e-6, 3e-6])
    unit = UnitResult(pose, link_confidence=np.float64(np.nan), pose_covariance=cov, notes=["a"], moved_at_s=[1])
    original = CalibrationResult("mle", "panda", "", 0.1, {"su1": unit}, failed_units={"su2": "no data"},
                                 notes=("n",), events=(MoveEvent("su1", 1, 2.5, link=3),))  # fmt: skip
    write_result(original, tmp_path / "r.json")
    doc = json.loads((tmp_path / "r.json").read_text())
    assert doc["units"]["su1"]["link_confidence"] is None  # NaN: null, kept as NaN on read
    assert doc["events"] == [{"unit": "su1", "t_change_s": 1.0, "t_detected_s": 2.5, "link": 3}]
    back = read_result(tmp_path / "r.json")
    got = back.units["su1"]
    assert np.isnan(got.link_confidence) and got.notes == ("a",) and got.moved_at_s == (1.0,)
    np.testing.assert_array_equal(got.pose_covariance, cov)
    assert not got.pose_covariance.flags.writeable
    assert (back.failed_units, back.notes, back.events[0].t_detected_s) == ({"su2": "no data"}, ("n",), 2.5)


@pytest.mark.parametrize(
    ("top", "key"),
    [(True, "failed_units"), (True, "notes"), (True, "events"), (True, "reference"), (False, "link_confidence"),
     (False, "notes"), (False, "pose_covariance"), (False, "moved_at_s")],
)  # fmt: skip
def test_a_typed_fact_in_extras_is_refused_on_write(tmp_path: Path, top: bool, key: str) -> None:
    """Each fact has one place, its field: a writer that still puts it in ``extras`` is refused."""
    pose = SkinUnitPose.from_quaternion(3, [0.05, 0.0, 0.12], [1, 0, 0, 0])
    unit = UnitResult(pose, extras={} if top else {key: 1})
    result = CalibrationResult("mle", "panda", "", 0.1, {"su1": unit}, extras={key: 1} if top else {})
    owner = "CalibrationResult" if top else "UnitResult"
    with pytest.raises(DatasetError, match=rf"may not hold {key}: they go in {owner}\.{key}$"):
        write_result(result, tmp_path / "r.json")
    assert not (tmp_path / "r.json").exists()


@pytest.mark.adversarial
@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("link_confidence", 1.5, "units.su1.link_confidence must be a number in [0, 1] or null"),
        ("link_confidence", "high", "units.su1.link_confidence must be a number in [0, 1] or null"),
        ("notes", "one note", "units.su1.notes must be a list of strings"),
        ("notes", [1], "units.su1.notes must be a list of strings"),
        ("pose_covariance", [[1.0] * 6] * 5, "units.su1.pose_covariance must be a 6x6 matrix"),
        ("pose_covariance", (-np.eye(6)).tolist(), "units.su1.pose_covariance must be symmetric"),
    ],
)
def test_a_bad_typed_unit_field_in_a_file_is_one_line(tmp_path: Path, key: str, value: object, message: str) -> None:
    doc = _doc()
    doc["units"]["su1"][key] = value
    path = tmp_path / "r.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(DatasetError) as info:
        read_result(path)
    assert str(info.value).startswith(f"{path}: {message}") and "\n" not in str(info.value)


def test_a_computed_covariance_with_rounding_asymmetry_is_accepted(tmp_path: Path) -> None:
    """Asymmetry is measured against ``sqrt(C_ii C_jj)``: an off-diagonal element near zero that differs from
    its transpose by rounding (1e-24 against a 1e-9 variance; relatively 1e-8 of itself) is a covariance;
    an asymmetry of 1e-6 of the std product is not."""
    pose = SkinUnitPose.from_quaternion(3, [0.05, 0.0, 0.12], [1, 0, 0, 0])
    cov = np.diag([1e-9] * 6)
    cov[0, 1], cov[1, 0] = 1e-16, 1e-16 + 1e-24
    write_result(CalibrationResult("online", "panda", "", 0.1, {"su1": UnitResult(pose, pose_covariance=cov)}),
                 tmp_path / "r.json")  # fmt: skip
    np.testing.assert_array_equal(read_result(tmp_path / "r.json").units["su1"].pose_covariance, cov)
    cov[1, 0] = 1e-16 + 1e-15
    with pytest.raises(DatasetError, match=r"units\.su1\.pose_covariance must be symmetric"):
        write_result(CalibrationResult("online", "panda", "", 0.1, {"su1": UnitResult(pose, pose_covariance=cov)}),
                     tmp_path / "r.json")  # fmt: skip
