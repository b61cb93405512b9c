"""Readers that trust nothing (issue 19): crafted HDF5 datasets, result JSON and configuration files.

Every file here is real (h5py, FIFOs, character devices); every refusal must be a one-line
``SkincalError`` naming the file, raised before anything large is read or anything can block.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import stat
import tempfile
import threading
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_data_hdf5 import make_dataset
from test_data_result import make_result

from skincal.cli import main
from skincal.data import CalibrationResult, Dataset, read_dataset, read_result, write_dataset, write_result
from skincal.data import hdf5_reader as hdf5_module
from skincal.data.hdf5 import open_dataset
from skincal.errors import ConfigError, DatasetError, SkincalError
from skincal.io.jsonio import MAX_DEPTH, MAX_TEXT_BYTES, load_json, load_yaml
from skincal.kinematics import load_chain

pytestmark = pytest.mark.adversarial

DEV_ZERO = Path("/dev/zero")
Reader = Callable[[Path], Dataset]


def read_streamed(path: Path) -> Dataset:
    """The streaming reader (:func:`open_dataset`), every unit read through its lazy ``imu``."""
    with open_dataset(path) as ds:
        return replace(ds, imu=dict(ds.imu))


@pytest.fixture(params=["read_dataset", "open_dataset"])
def read(request: pytest.FixtureRequest) -> Reader:
    """Both dataset readers: every hostile HDF5 file is refused by each, with the same message."""
    return read_dataset if request.param == "read_dataset" else read_streamed


# ---------------------------------------------------------------------- helpers
@pytest.fixture(scope="module")
def good_h5(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("good") / "good.h5"
    write_dataset(make_dataset(), path)
    return path


def crafted(good: Path, tmp_path: Path, change: Callable[[h5py.File], None], name: str = "crafted.h5") -> Path:
    """A copy of ``good`` edited with h5py (the way an attacker would)."""
    path = tmp_path / name
    shutil.copyfile(good, path)
    with h5py.File(path, "a") as f:
        change(f)
    return path


def refused(read: Callable[[], object], *fragments: str, error: type[SkincalError] = DatasetError) -> str:
    with pytest.raises(error) as info:
        read()
    message = str(info.value)
    assert "\n" not in message, message
    for fragment in fragments:
        assert fragment in message, message
    return message


def cli_one_line(argv: list[str], capsys: pytest.CaptureFixture[str], *fragments: str) -> None:
    code = main(argv)
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err and "internal error" not in err, err
    for fragment in fragments:
        assert fragment in err, err


def without_blocking(read: Callable[[], object], fifo: Path) -> BaseException | object:
    """Run ``read`` in a thread; if it blocks on the FIFO (old code), unblock it by opening the write end,
    so the test fails instead of hanging. Returns what ``read`` raised or returned."""
    outcome: list[object] = []

    def run() -> None:
        try:
            outcome.append(read())
        except BaseException as exc:  # noqa: BLE001 - handed to the test
            outcome.append(exc)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(30)
    blocked = thread.is_alive()
    while thread.is_alive():  # release a reader stuck in open(): give it a writer that closes at once
        with contextlib.suppress(OSError):
            os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
        thread.join(0.2)
    assert not blocked, f"reading {fifo} blocked"
    return outcome[0]


# ---------------------------------------------------------------------- HDF5: links and storage
def test_external_link_to_a_host_file_is_refused(read: Reader, good_h5: Path, tmp_path: Path, capsys) -> None:
    host = tmp_path / "host.h5"  # any file the attacker wants read: here another dataset's samples
    shutil.copyfile(good_h5, host)

    def link(f: h5py.File) -> None:
        del f["imu/su1/accel"]
        f["imu/su1/accel"] = h5py.ExternalLink(str(host), "/imu/su1/accel")

    path = crafted(good_h5, tmp_path, link)
    refused(lambda: read(path), str(path), "/imu/su1/accel is an external link", str(host))
    cli_one_line(["info", str(path)], capsys, "external link")


def test_external_link_to_a_group_is_refused(read: Reader, good_h5: Path, tmp_path: Path) -> None:
    def link(f: h5py.File) -> None:
        del f["joints"]
        f["joints"] = h5py.ExternalLink(str(good_h5), "/joints")

    path = crafted(good_h5, tmp_path, link)
    refused(lambda: read(path), "/joints is an external link")


def test_soft_link_duplicating_a_unit_is_refused(read: Reader, good_h5: Path, tmp_path: Path, capsys) -> None:
    """/imu/su1 -> /imu/forearm_left: su1 would be calibrated from another unit's samples."""

    def link(f: h5py.File) -> None:
        del f["imu/su1"]
        f["imu/su1"] = h5py.SoftLink("/imu/forearm_left")

    path = crafted(good_h5, tmp_path, link)
    refused(lambda: read(path), str(path), "/imu/su1 is a soft link to /imu/forearm_left")
    cli_one_line(["info", str(path)], capsys, "soft link")


def test_soft_link_to_a_dataset_is_refused(read: Reader, good_h5: Path, tmp_path: Path) -> None:
    def link(f: h5py.File) -> None:
        del f["joints/qd"]
        f["joints/qd"] = h5py.SoftLink("/joints/q")

    refused(lambda: read(crafted(good_h5, tmp_path, link)), "/joints/qd is a soft link to /joints/q")


def test_hard_link_making_two_units_one_object_is_refused(read: Reader, good_h5: Path, tmp_path: Path, capsys) -> None:
    def link(f: h5py.File) -> None:
        del f["imu/su1"]
        f["imu/su1"] = f["imu/forearm_left"]  # a second hard link to the same group
        del f["tof"]  # keep the rest of the file consistent

    path = crafted(good_h5, tmp_path, link)
    message = refused(lambda: read(path), str(path), "is the same HDF5 object as")
    assert "/imu/su1" in message and "/imu/forearm_left" in message
    cli_one_line(["info", str(path)], capsys, "same HDF5 object")


def test_hard_linked_dataset_reused_as_another_stream_is_refused(read: Reader, good_h5: Path, tmp_path: Path) -> None:
    def link(f: h5py.File) -> None:
        del f["imu/su1/gyro"]
        f["imu/su1/gyro"] = f["imu/su1/accel"]  # same shape: only the object identity gives it away

    refused(lambda: read(crafted(good_h5, tmp_path, link)), "/imu/su1/", "same HDF5 object")


def test_dataset_with_external_raw_data_is_refused(read: Reader, good_h5: Path, tmp_path: Path) -> None:
    raw = tmp_path / "host.bin"
    raw.write_bytes(np.zeros((117, 3)).tobytes())

    def external(f: h5py.File) -> None:
        del f["imu/su1/accel"]
        f.create_dataset("imu/su1/accel", shape=(117, 3), dtype="f8", external=[(str(raw), 0, 117 * 3 * 8)])

    refused(lambda: read(crafted(good_h5, tmp_path, external)), "/imu/su1/accel", "external file")


def test_virtual_dataset_is_refused(read: Reader, good_h5: Path, tmp_path: Path) -> None:
    def virtual(f: h5py.File) -> None:
        layout = h5py.VirtualLayout(shape=(117, 3), dtype="f8")
        layout[:] = h5py.VirtualSource(str(good_h5), "/imu/su1/accel", shape=(117, 3))
        del f["imu/su1/accel"]
        f["imu"]["su1"].create_virtual_dataset("accel", layout)

    refused(lambda: read(crafted(good_h5, tmp_path, virtual)), "/imu/su1/accel", "virtual dataset")


# ---------------------------------------------------------------------- HDF5: declared sizes
def test_huge_declared_shape_in_a_tiny_file_is_refused_before_reading(
    read: Reader, good_h5: Path, tmp_path: Path, capsys
) -> None:
    """2e9 samples declared, nothing written: 48 GB would be allocated (and filled with zeros)."""

    def huge(f: h5py.File) -> None:
        del f["imu/su1/accel"]
        f.create_dataset("imu/su1/accel", shape=(2_000_000_000, 3), dtype="f8", chunks=True, compression="gzip")

    path = crafted(good_h5, tmp_path, huge)
    assert path.stat().st_size < 200_000
    refused(lambda: read(path), str(path), "/imu/su1/accel declares shape (2000000000, 3)", "stores 0 bytes")
    cli_one_line(["info", str(path)], capsys, "refused before reading")


def test_huge_shape_with_a_few_real_chunks_is_refused(read: Reader, good_h5: Path, tmp_path: Path) -> None:
    """Some compressed chunks written, so the stored size is not zero; the ratio is still impossible."""

    def huge(f: h5py.File) -> None:
        del f["joints/q"]
        ds = f.create_dataset("joints/q", shape=(300_000_000, 7), dtype="f8", chunks=(65536, 7), compression="gzip")
        ds[:65536] = np.random.default_rng(0).normal(size=(65536, 7))

    path = crafted(good_h5, tmp_path, huge)
    refused(lambda: read(path), "/joints/q declares shape (300000000, 7)")


def test_unwritten_uncompressed_chunks_are_refused(read: Reader, good_h5: Path, tmp_path: Path) -> None:
    def sparse(f: h5py.File) -> None:
        del f["joints/t"]
        f.create_dataset("joints/t", shape=(50_000_000,), dtype="f8", chunks=(1024,))

    refused(lambda: read(crafted(good_h5, tmp_path, sparse)), "/joints/t declares shape (50000000,)")


def test_total_declared_bytes_are_bounded_by_the_file_size(
    read: Reader, good_h5: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Each array may be plausible on its own; all together may not exceed the per-file budget
    (here made small so the test needs no gigabytes)."""
    monkeypatch.setattr(hdf5_module, "MAX_READ_BYTES", 4096)
    monkeypatch.setattr(hdf5_module, "READ_BYTES_PER_FILE_BYTE", 0)
    refused(lambda: read(good_h5), "more than a", "refused before reading")


def test_a_legitimately_compressed_dataset_reads(read: Reader, good_h5: Path, tmp_path: Path) -> None:
    """Compression another writer may use (gzip, shuffle, highly compressible zeros) is accepted."""
    ds = make_dataset()

    def gzip(f: h5py.File) -> None:
        del f["imu/su1/gyro"]
        f.create_dataset("imu/su1/gyro", data=np.zeros_like(ds.imu["su1"].gyro), compression="gzip", shuffle=True)

    back = read(crafted(good_h5, tmp_path, gzip))
    assert np.array_equal(back.imu["su1"].gyro, np.zeros_like(ds.imu["su1"].gyro))
    assert np.array_equal(back.imu["su1"].accel, ds.imu["su1"].accel)


def test_huge_attribute_is_refused(read: Reader, good_h5: Path, tmp_path: Path) -> None:
    def big(f: h5py.File) -> None:
        f["robot"].attrs.create("gravity", np.zeros(300_000))

    refused(lambda: read(crafted(good_h5, tmp_path, big)), "/robot attr 'gravity' declares 2400000 bytes")


def test_string_dataset_is_refused_before_reading(read: Reader, good_h5: Path, tmp_path: Path) -> None:
    def strings(f: h5py.File) -> None:
        del f["joints/t"]
        f.create_dataset("joints/t", data=np.array([b"x" * 10] * 3), dtype=h5py.string_dtype())

    refused(lambda: read(crafted(good_h5, tmp_path, strings)), "/joints/t has dtype", "expected real numbers")


# ---------------------------------------------------------------------- HDF5: names
@pytest.mark.parametrize(
    ("bad", "problem"),
    [
        ("su\x1b[31mred", "control character"),
        ("su1\n", "control character"),
        (" su1", "white space"),
        ("x" * 129, "129 characters"),
        ("\u202eevil", "control character"),
    ],
)
def test_unit_names_follow_the_one_rule(read: Reader, good_h5: Path, tmp_path: Path, bad: str, problem: str) -> None:
    def rename(f: h5py.File) -> None:
        f.move("imu/forearm_left", f"imu/{bad}")
        f.move("truth/forearm_left", f"truth/{bad}")

    message = refused(lambda: read(crafted(good_h5, tmp_path, rename)), "/imu has an invalid unit name", problem)
    assert "\x1b" not in message and "\u202e" not in message  # shown escaped


@pytest.mark.parametrize(
    ("bad", "problem"), [("", "empty"), ("pan\nda", "control"), ("a/b", "'/'"), ("panda ", "white")]
)
def test_robot_name_follows_the_one_rule(read: Reader, good_h5: Path, tmp_path: Path, bad: str, problem: str) -> None:
    def rename(f: h5py.File) -> None:
        f["robot"].attrs["name"] = bad

    path = crafted(good_h5, tmp_path, rename)
    refused(lambda: read(path), "/robot attr 'name'", "not a valid robot name", problem)


# ---------------------------------------------------------------------- non-regular files
def test_dataset_path_that_is_a_device_or_fifo_is_refused(read: Reader, tmp_path: Path, capsys) -> None:
    refused(lambda: read(DEV_ZERO), "/dev/zero: is a character device")
    fifo = tmp_path / "pipe.h5"
    os.mkfifo(fifo)
    outcome = without_blocking(lambda: read(fifo), fifo)
    assert isinstance(outcome, DatasetError) and "is a FIFO" in str(outcome), outcome
    cli_one_line(["info", str(DEV_ZERO)], capsys, "character device")


def test_result_path_that_is_a_device_or_fifo_is_refused(tmp_path: Path, good_h5: Path, capsys) -> None:
    refused(lambda: read_result(DEV_ZERO), "/dev/zero: is a character device")
    fifo = tmp_path / "pipe.json"
    os.mkfifo(fifo)
    outcome = without_blocking(lambda: read_result(fifo), fifo)
    assert isinstance(outcome, DatasetError) and "is a FIFO" in str(outcome), outcome
    assert stat.S_ISFIFO(fifo.stat().st_mode)  # untouched
    cli_one_line(["evaluate", str(DEV_ZERO), "--truth", str(good_h5)], capsys, "character device")


# ---------------------------------------------------------------------- result JSON
@pytest.fixture
def result_doc(tmp_path: Path) -> dict:
    path = tmp_path / "ok.json"
    write_result(make_result(), path)
    return json.loads(path.read_text())


def write_text(tmp_path: Path, text: str, name: str = "r.json") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_deeply_nested_json_is_refused_without_recursion(tmp_path: Path, good_h5: Path, capsys) -> None:
    path = write_text(tmp_path, "[" * 100_000 + "]" * 100_000)
    refused(lambda: read_result(path), str(path), "nested 100000 levels deep")
    for argv in (
        ["evaluate", str(path), "--truth", str(good_h5)],
        ["export", str(path), "-f", "csv", "-o", str(tmp_path / "o.csv")],
    ):
        cli_one_line(argv, capsys, "nested")
    assert not (tmp_path / "o.csv").exists()


def test_nesting_inside_extras_is_refused_but_brackets_in_strings_are_not(tmp_path: Path, result_doc: dict) -> None:
    deep: list = []
    for _ in range(MAX_DEPTH + 5):
        deep = [deep]
    result_doc["units"]["su1"]["deep"] = deep
    refused(lambda: read_result(write_text(tmp_path, json.dumps(result_doc))), "levels deep")
    result_doc["units"]["su1"]["deep"] = "[" * 10_000 + "{" * 10_000
    back = read_result(write_text(tmp_path, json.dumps(result_doc)))
    assert back.units["su1"].extras["deep"].startswith("[[[")


def test_duplicate_keys_are_refused(tmp_path: Path, result_doc: dict) -> None:
    text = json.dumps(result_doc)
    doubled = text.replace('"method": "mle"', '"method": "mle", "method": "om"', 1)
    refused(lambda: read_result(write_text(tmp_path, doubled)), "has the key 'method' twice")
    unit = json.dumps(result_doc["units"]["su1"])
    twice = text.replace('"units": {', f'"units": {{"su1": {unit}, ', 1)
    refused(lambda: read_result(write_text(tmp_path, twice)), "has the key 'su1' twice")


@pytest.mark.parametrize(
    ("literal", "fragment"),
    [
        ("NaN", "contains NaN"),
        ("-Infinity", "contains -Infinity"),
        ("1e400", "out of range"),
        ("9" * 5000, "5000 digits"),
    ],
)
def test_non_finite_and_oversized_numbers_are_refused(
    tmp_path: Path, result_doc: dict, literal: str, fragment: str
) -> None:
    text = json.dumps(result_doc).replace('"link_confidence": 0.987654321', f'"link_confidence": {literal}', 1)
    assert literal in text
    refused(lambda: read_result(write_text(tmp_path, text)), fragment)


def test_invalid_utf8_and_oversized_files_are_refused(tmp_path: Path) -> None:
    path = tmp_path / "bin.json"
    path.write_bytes(b'{"format": "\xff\xfe"}')
    refused(lambda: read_result(path), "not valid UTF-8")
    big = tmp_path / "big.json"
    with open(big, "wb") as fh:  # sparse: no disk used
        fh.truncate(MAX_TEXT_BYTES + 1)
    refused(lambda: read_result(big), f"{MAX_TEXT_BYTES + 1} bytes", f"at most {MAX_TEXT_BYTES} bytes")


def test_link_beyond_the_robot_is_refused(tmp_path: Path, result_doc: dict, good_h5: Path, capsys) -> None:
    result_doc["units"]["su1"]["link"] = 99
    del result_doc["units"]["base_unit"]  # the truth dataset knows su1 and forearm_left
    path = write_text(tmp_path, json.dumps(result_doc))
    refused(lambda: read_result(path), "units.su1.link is 99; robot 'panda' has links 1..7")
    cli_one_line(["evaluate", str(path), "--truth", str(good_h5)], capsys, "links 1..7")
    result_doc["robot"] = "myarm"  # not a preset: checked where the result meets the dataset's chain
    path = write_text(tmp_path, json.dumps(result_doc), "custom.json")
    assert read_result(path).units["su1"].pose.link == 99
    from skincal.calib.metrics import evaluate

    refused(lambda: evaluate(read_result(path), read_dataset(good_h5)), "units.su1.link is 99", "links 1..7")


@pytest.mark.parametrize("position", [[1e308, 0.0, 0.0], [0.0, -1e300, 0.0], [2e3, 0.0, 0.0]])
def test_absurd_positions_are_refused(tmp_path: Path, result_doc: dict, good_h5: Path, position, capsys) -> None:
    result_doc["units"]["su1"]["position_m"] = position
    path = write_text(tmp_path, json.dumps(result_doc))
    refused(lambda: read_result(path), "units.su1.position_m has a component beyond 1000 m")
    cli_one_line(["evaluate", str(path), "--truth", str(good_h5)], capsys, "beyond 1000 m")


def test_empty_units_are_refused(tmp_path: Path, result_doc: dict) -> None:
    result_doc["units"] = {}
    refused(lambda: read_result(write_text(tmp_path, json.dumps(result_doc))), "units is empty")


@pytest.mark.parametrize(
    ("where", "bad", "fragment"),
    [
        ("unit", "su\x1b]0;pwned\x07", "control character"),
        ("unit", "", "is empty"),
        ("unit", "a/b", "contains '/'"),
        ("robot", "panda\n", "robot"),
        ("robot", "", "robot"),
        ("method", "mle\x1b[2J", "method"),
    ],
)
def test_result_names_follow_the_one_rule(
    tmp_path: Path, result_doc: dict, where: str, bad: str, fragment: str
) -> None:
    if where == "unit":
        result_doc["units"][bad] = result_doc["units"].pop("su1")
    else:
        result_doc[where] = bad
    message = refused(lambda: read_result(write_text(tmp_path, json.dumps(result_doc))), fragment)
    assert "\x1b" not in message
    with pytest.raises(DatasetError):  # the writer applies the same rule
        write_result(result_from_doc_unchecked(result_doc), tmp_path / "out.json")


def result_from_doc_unchecked(doc: dict) -> CalibrationResult:
    """The result ``doc`` describes, built without the reader's checks (as calling code could)."""
    good = make_result()
    units = {name: good.units["su1"] for name in doc["units"]}
    return CalibrationResult(doc["method"], doc["robot"], "", 0.1, units)


# ---------------------------------------------------------------------- the other JSON/YAML readers
def test_chain_links_and_topic_map_files_share_the_guards(tmp_path: Path) -> None:
    from skincal.cli.calibrate import read_links_file
    from skincal.data.ros import topic_map

    bomb = tmp_path / "bomb.yaml"
    bomb.write_text(
        "a: &a [x, x, x, x, x, x, x, x]\nb: &b [*a, *a, *a, *a, *a, *a, *a, *a]\n"
        "c: &c [*b, *b, *b, *b, *b, *b, *b, *b]\nconvention: modified\ndh: [[0, 0.1, 0, 0]]\n"
    )
    refused(lambda: load_chain(bomb), "alias", error=ConfigError)
    dup = tmp_path / "dup.yaml"
    dup.write_text("su1: 2\nsu2: 3\nsu1: 5\n")
    refused(lambda: read_links_file(dup), "has the key 'su1' twice", error=ConfigError)
    deep = tmp_path / "deep.json"
    deep.write_text('{"convention": "modified", "dh": ' + "[" * 50_000 + "]" * 50_000 + "}")
    refused(lambda: load_chain(deep), "levels deep", error=ConfigError)
    deep_yaml = tmp_path / "deep.yaml"
    deep_yaml.write_text("imu: " + "[" * 50_000 + "]" * 50_000 + "\n")
    refused(lambda: topic_map(path=deep_yaml), "nested more than", error=ConfigError)
    refused(lambda: topic_map(path=DEV_ZERO), "character device", error=ConfigError)
    fifo = tmp_path / "links.yaml"
    os.mkfifo(fifo)
    outcome = without_blocking(lambda: read_links_file(fifo), fifo)
    assert isinstance(outcome, ConfigError) and "is a FIFO" in str(outcome), outcome


def test_shared_loaders_accept_ordinary_files(tmp_path: Path) -> None:
    y = tmp_path / "ok.yaml"
    y.write_text("name: arm\nconvention: standard\ndh:\n  - [0, 0.3, 0, 1.5707963]\n  - [0, 0, 0.4, 0]\n")
    assert load_yaml(y)["dh"][1] == [0, 0, 0.4, 0]
    assert load_chain(y).n_joints == 2
    j = tmp_path / "ok.json"
    j.write_text('{"a": [1, 2.5, {"b": null, "s": "[{"}], "t": true}')
    assert load_json(j) == {"a": [1, 2.5, {"b": None, "s": "[{"}], "t": True}


def test_yaml_reads_exponent_floats_as_json_does(tmp_path: Path) -> None:
    """YAML 1.1 wants a dot in a float: ``sigma: 5e-2`` in a scenario stayed the string '5e-2' and was refused
    as not a number. Read as YAML 1.2 and JSON read it; ints, dotted floats and quoted strings unchanged."""
    y = tmp_path / "numbers.yaml"
    y.write_text("a: 5e-2\nb: -1E3\nc: .5e+1\nd: 1.5\ne: 1_000\nf: '5e-2'\ng: 1e\nh: e5\n")
    got = load_yaml(y)
    assert got == {"a": 0.05, "b": -1000.0, "c": 5.0, "d": 1.5, "e": 1000, "f": "5e-2", "g": "1e", "h": "e5"}
    assert isinstance(got["a"], float) and isinstance(got["e"], int)
    for key in "abcd":  # as JSON reads the same numbers
        assert got[key] == json.loads(str(got[key]))


# ---------------------------------------------------------------------- fuzzing
@pytest.fixture(scope="module")
def valid_result_bytes(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    path = tmp_path_factory.mktemp("res") / "r.json"
    write_result(make_result(), path)
    return path.read_bytes()


_BYTE_EDITS = st.lists(
    st.tuples(
        st.sampled_from(["replace", "insert", "delete"]), st.integers(0, 10**6), st.binary(min_size=1, max_size=4)
    ),
    min_size=1,
    max_size=6,
)


def _mutate(data: bytes, edits: list[tuple[str, int, bytes]]) -> bytes:
    out = bytearray(data)
    for kind, where, chunk in edits:
        i = where % max(len(out), 1)
        if kind == "replace":
            out[i : i + len(chunk)] = chunk
        elif kind == "insert":
            out[i:i] = chunk
        else:
            del out[i : i + len(chunk)]
    return bytes(out)


@settings(max_examples=200, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(edits=_BYTE_EDITS)
def test_fuzz_read_result_bytes(valid_result_bytes: bytes, edits) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "r.json"
        path.write_bytes(_mutate(valid_result_bytes, edits))
        try:
            out = read_result(path)
        except SkincalError as exc:
            assert "\n" not in str(exc)
        else:
            assert isinstance(out, CalibrationResult)


_JSON_LEAF = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(10**30), 10**30),
    st.floats(allow_nan=False, allow_infinity=False),
    st.text(max_size=8),
    st.sampled_from([0, 1, 7, 8, 99, -1, 1e308, -1e308, 5e-324, "", "/", "..", "\x1b[0m", "su1"]),
)
_JSON_VALUE = st.recursive(
    _JSON_LEAF,
    lambda inner: st.one_of(st.lists(inner, max_size=5), st.dictionaries(st.text(max_size=6), inner, max_size=4)),
    max_leaves=12,
)
_RESULT_PATHS = [
    ("format",),
    ("version",),
    ("method",),
    ("robot",),
    ("dataset_sha256",),
    ("runtime_s",),
    ("units",),
    ("failed_units",),
    ("options",),
    ("units", "su1"),
    ("units", "su1", "link"),
    ("units", "su1", "position_m"),
    ("units", "su1", "quaternion_wxyz"),
    ("units", "su1", "observable"),
    ("units", "su1", "position_std_m"),
    ("units", "su1", "rotation_std_deg"),
    ("units", "su1", "warnings"),
    ("units", "su1", "accel_bias_mps2"),
    ("units", "base_unit", "link"),
    ("units", "base_unit", "position_m"),
    ("units", "base_unit", "observable"),
]


@settings(max_examples=200, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(
    changes=st.lists(st.tuples(st.sampled_from(_RESULT_PATHS), _JSON_VALUE | st.just(KeyError)), min_size=1, max_size=3)
)
def test_fuzz_read_result_fields(valid_result_bytes: bytes, changes) -> None:
    doc = json.loads(valid_result_bytes)
    for where, value in changes:
        node = doc
        for key in where[:-1]:
            node = node.get(key) if isinstance(node, dict) else None
        if not isinstance(node, dict):
            continue
        if value is KeyError:
            node.pop(where[-1], None)
        else:
            node[where[-1]] = value
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "r.json"
        path.write_text(json.dumps(doc))
        try:
            out = read_result(path)
        except SkincalError as exc:
            assert "\n" not in str(exc)
        else:
            assert isinstance(out, CalibrationResult)
            for unit in out.units.values():
                assert np.all(np.abs(unit.pose.p_link_su) <= 1e3)


@pytest.fixture(scope="module")
def small_h5_bytes(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    path = tmp_path_factory.mktemp("small") / "small.h5"
    write_dataset(make_dataset(n_samples=20), path)
    return path.read_bytes()


_NODES = [
    "robot/dh",
    "joints/t",
    "joints/q",
    "joints/qd",
    "joints/qdd",
    "imu/su1/t",
    "imu/su1/accel",
    "imu/su1/gyro",
    "imu/forearm_left/t",
    "tof/su1/range",
    "segments/kind",
    "segments/joint",
    "segments/t_end",
    "robot/joint_lower",
]
_GROUPS = ["/", "robot", "truth/su1", "imu", "imu/su1", "joints", "segments", "tof"]
_ATTRS = [
    "format",
    "version",
    "name",
    "convention",
    "gravity",
    "link",
    "position",
    "quaternion_wxyz",
    "accel_bias",
    "time_offset_s",
    "description",
]
_ARRAY = st.one_of(
    st.builds(
        lambda shape, fill: np.full(shape, fill),
        st.lists(st.integers(0, 4), max_size=3).map(tuple),
        st.sampled_from([0.0, 1.0, -1.0, np.nan, np.inf, 1e308, 3]),
    ),
    st.builds(lambda n, seed: np.random.default_rng(seed).normal(size=n), st.integers(0, 30), st.integers(0, 9)),
    st.sampled_from(
        [
            np.array([b"abc"]),
            np.array(7, dtype=np.int8),
            np.array([True, False]),
            np.array([1 + 2j]),
            np.int64(2**62),
            np.array("text", dtype=h5py.string_dtype()),
        ]
    ),
)
_H5_EDIT = st.one_of(
    st.tuples(st.just("dataset"), st.sampled_from(_NODES), _ARRAY),
    st.tuples(st.just("attr"), st.sampled_from(_GROUPS), st.tuples(st.sampled_from(_ATTRS), _ARRAY)),
    st.tuples(st.just("attr"), st.sampled_from(_GROUPS), st.tuples(st.sampled_from(_ATTRS), st.text(max_size=6))),
    st.tuples(st.just("delete"), st.sampled_from(_NODES + _GROUPS[1:]), st.none()),
    st.tuples(st.just("soft"), st.sampled_from(_NODES), st.sampled_from(_NODES)),
    st.tuples(st.just("hard"), st.sampled_from(_NODES), st.sampled_from(_NODES)),
    st.tuples(
        st.just("rename"),
        st.sampled_from(["imu/su1", "imu/forearm_left", "truth/su1"]),
        st.text(min_size=1, max_size=6).filter(lambda s: "/" not in s and s not in (".", "..")),
    ),
    st.tuples(st.just("declare"), st.sampled_from(_NODES), st.integers(10**6, 10**12)),
)


def _apply_h5(f: h5py.File, edit) -> None:
    kind, where, value = edit
    with contextlib.suppress(KeyError, ValueError, TypeError, OSError, RuntimeError):
        if kind == "dataset":
            if where in f:
                del f[where]
            f[where] = value
        elif kind == "attr":
            name, attr_value = value
            f[where].attrs[name] = attr_value
        elif kind == "delete":
            del f[where]
        elif kind in ("soft", "hard"):
            target = value
            if where in f:
                del f[where]
            f[where] = h5py.SoftLink("/" + target) if kind == "soft" else f[target]
        elif kind == "rename":
            f.move(where, where.rsplit("/", 1)[0] + "/" + value)
        elif kind == "declare":
            if where in f:
                del f[where]
            f.create_dataset(where, shape=(value, 3), dtype="f8", chunks=True, compression="gzip")


@settings(max_examples=200, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(edits=st.lists(_H5_EDIT, min_size=1, max_size=3))
def test_fuzz_read_dataset(small_h5_bytes: bytes, edits) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "d.h5"
        path.write_bytes(small_h5_bytes)
        with h5py.File(path, "a") as f:
            for edit in edits:
                _apply_h5(f, edit)
        try:
            out = read_dataset(path)
        except SkincalError as exc:
            assert "\n" not in str(exc)
        else:
            assert isinstance(out, Dataset)


@pytest.mark.adversarial
def test_a_true_position_of_1e308_is_refused(tmp_path):
    """A /truth position must be within 1000 m, as result positions are (evaluate printed inf)."""
    from skincal.data.hdf5 import read_dataset, write_dataset
    from skincal.workflows.session import simulate_dataset

    path = tmp_path / "d.h5"
    write_dataset(simulate_dataset("panda", "random", 1, "none", "fast", seed=1), path)
    with h5py.File(path, "r+") as f:
        f["truth/su1"].attrs["position"] = [1e308, 0.0, 0.0]
    with pytest.raises(DatasetError, match="/truth/su1 attr 'position' has a component beyond 1000 m"):
        read_dataset(path)
