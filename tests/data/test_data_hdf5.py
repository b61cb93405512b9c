"""Dataset HDF5 files: round trip, contract layout, validation catalogue, atomic writes."""

from __future__ import annotations

import dataclasses
import hashlib
import os
from collections.abc import Callable
from pathlib import Path

import h5py
import numpy as np
import pytest

from skincal.data import (
    DYNAMIC,
    STATIC,
    Dataset,
    ImuStream,
    JointStates,
    Segments,
    TofStream,
    read_dataset,
    validate_dataset,
    write_dataset,
)
from skincal.errors import DatasetError
from skincal.kinematics import SerialChain, panda
from skincal.skin.pose import SkinUnitPose


def make_dataset(seed: int = 0, n_samples: int = 120) -> Dataset:
    """A small Panda dataset with every optional field filled."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_samples) * 0.01
    q = rng.uniform(-1, 1, size=(n_samples, 7))
    imu_t = t[: n_samples - 3] + 0.0031
    tof_range = rng.uniform(0.05, 1.5, size=40)
    tof_range[[3, 17]] = np.nan
    return Dataset(
        robot=panda(),
        joints=JointStates(t=t, q=q, qd=rng.normal(size=q.shape), qdd=rng.normal(size=q.shape)),
        imu={
            "su1": ImuStream(imu_t, rng.normal(size=(len(imu_t), 3)), rng.normal(size=(len(imu_t), 3))),
            "forearm_left": ImuStream(t[::2] + 1e-4, rng.normal(size=(len(t[::2]), 3))),
        },
        tof={"su1": TofStream(np.linspace(0.0, 1.0, 40), tof_range)},
        segments=Segments(
            t_start=np.array([0.0, 0.3, 0.6]),
            t_end=np.array([0.25, 0.55, 1.1]),
            kind=np.array([STATIC, DYNAMIC, DYNAMIC], dtype=np.int8),
            pose=np.array([0, 0, 1], dtype=np.int32),
            joint=np.array([-1, 6, 0], dtype=np.int32),
        ),
        truth={
            "su1": SkinUnitPose.from_dh6(3, [0.3, -0.08, 1.2, 0.05, 0.01, 1.4]),
            "forearm_left": SkinUnitPose.from_dh6(5, [-1.57, 0.03, 1.57, 0.05, 0.0, 1.57]),
        },
        gravity=np.array([0.0, 0.0, -9.80665]),
        description="unit test dataset",
        truth_sensor={
            "su1": {
                "accel_bias": np.array([0.01, -0.02, 0.03]),
                "accel_scale": np.array([1.01, 0.99, 1.0]),
                "accel_misalignment": np.eye(3) + 1e-3 * rng.normal(size=(3, 3)),
                "time_offset_s": 0.004,
            }
        },
    )


def assert_datasets_equal(a: Dataset, b: Dataset) -> None:
    for key in ("name", "convention", "dh", "joint_lower", "joint_upper", "velocity_limit", "T_link_flange"):
        va, vb = getattr(a.robot, key), getattr(b.robot, key)
        assert (va is None and vb is None) or np.array_equal(va, vb), key
    assert np.array_equal(a.gravity, b.gravity)
    assert a.description == b.description
    for key in ("t", "q", "qd", "qdd"):
        va, vb = getattr(a.joints, key), getattr(b.joints, key)
        assert (va is None and vb is None) or np.array_equal(va, vb), key
    assert list(a.imu) == list(b.imu)
    for unit in a.imu:
        for key in ("t", "accel", "gyro"):
            va, vb = getattr(a.imu[unit], key), getattr(b.imu[unit], key)
            assert (va is None and vb is None) or np.array_equal(va, vb), (unit, key)
    assert set(a.tof) == set(b.tof)
    for unit in a.tof:
        assert np.array_equal(a.tof[unit].t, b.tof[unit].t)
        assert np.array_equal(a.tof[unit].range, b.tof[unit].range, equal_nan=True)
    assert (a.segments is None) == (b.segments is None)
    if a.segments is not None:
        for f in dataclasses.fields(Segments):
            assert np.array_equal(getattr(a.segments, f.name), getattr(b.segments, f.name)), f.name
    assert set(a.truth) == set(b.truth)
    for unit, pose in a.truth.items():
        assert b.truth[unit].link == pose.link
        assert np.array_equal(b.truth[unit].p_link_su, pose.p_link_su)
        # Stored as a quaternion: the rotation comes back to rounding error.
        np.testing.assert_allclose(b.truth[unit].R_link_su, pose.R_link_su, atol=1e-15)
    assert set(a.truth_sensor) == set(b.truth_sensor)
    for unit, errors in a.truth_sensor.items():
        assert set(errors) == set(b.truth_sensor[unit])
        for key, value in errors.items():
            assert np.array_equal(value, b.truth_sensor[unit][key]), (unit, key)


@pytest.fixture
def good_file(tmp_path: Path) -> Path:
    path = tmp_path / "data.h5"
    write_dataset(make_dataset(), path)
    return path


# ---------------------------------------------------------------------- round trips and layout
def test_round_trip_all_fields(good_file: Path) -> None:
    assert_datasets_equal(make_dataset(), read_dataset(good_file))


def test_round_trip_minimal_standard_chain(tmp_path: Path) -> None:
    chain = SerialChain.from_dh("two-link", "standard", np.array([[0, 0.2, 0.3, 0.0], [0.1, 0, 0.25, 0]]))
    t = np.linspace(0, 1, 11)
    ds = Dataset(
        robot=chain,
        joints=JointStates(t, np.zeros((11, 2)), np.zeros((11, 2))),
        imu={"a": ImuStream(t, np.tile([0, 0, 9.81], (11, 1)))},
    )
    write_dataset(ds, tmp_path / "min.h5")
    back = read_dataset(tmp_path / "min.h5")
    assert_datasets_equal(ds, back)
    assert back.joints.qdd is None and back.segments is None and back.tof == {} and back.truth == {}
    assert back.robot.joint_lower is None and back.robot.velocity_limit is None


def test_file_layout_follows_contract(good_file: Path) -> None:
    """Checked with raw h5py against the field table of docs/interfaces.md."""
    with h5py.File(good_file, "r") as f:
        assert f.attrs["format"] == "skincal-dataset" and int(f.attrs["version"]) == 2
        assert f["robot"].attrs["name"] == "panda" and f["robot"].attrs["convention"] == "modified"
        assert f["robot"].attrs["gravity"].shape == (3,)
        assert f["robot/dh"].dtype == np.float64 and f["robot/dh"].shape == (7, 4)
        assert f["joints/q"].shape == (120, 7) and f["joints/t"].dtype == np.float64
        assert f["imu/su1/accel"].shape == (117, 3)
        assert f["segments/kind"].dtype == np.int8
        assert f["segments/pose"].dtype == np.int32 and f["segments/joint"].dtype == np.int32
        truth = f["truth/su1"].attrs
        assert int(truth["link"]) == 3
        assert truth["position"].shape == (3,) and truth["quaternion_wxyz"].shape == (4,)
        assert truth["accel_misalignment"].shape == (3, 3)


def test_reads_a_file_written_by_hand(tmp_path: Path) -> None:
    """A file built with plain h5py from the contract (float32 times, identity truth) reads correctly."""
    path = tmp_path / "hand.h5"
    t = np.arange(5, dtype=np.float32) * 0.5
    with h5py.File(path, "w") as f:
        f.attrs.update({"format": "skincal-dataset", "version": 1})
        robot = f.create_group("robot")
        robot.attrs.update({"name": "arm", "convention": "modified", "gravity": [0.0, 0.0, -9.81]})
        robot["dh"] = [[0.0, 0.3, 0.0, 0.0]]
        f["joints/t"] = t
        f["joints/q"] = np.zeros((5, 1))
        f["joints/qd"] = np.zeros((5, 1))
        f["imu/u/t"] = t
        f["imu/u/accel"] = np.tile([0.0, 0.0, 9.81], (5, 1))
        f.create_group("truth/u").attrs.update({"link": 1, "position": [0.1, 0, 0], "quaternion_wxyz": [1, 0, 0, 0]})
    ds = read_dataset(path)
    assert ds.robot.n_joints == 1 and ds.joints.t.dtype == np.float64
    np.testing.assert_array_equal(ds.joints.t, [0, 0.5, 1, 1.5, 2])
    np.testing.assert_array_equal(ds.truth["u"].R_link_su, np.eye(3))
    assert ds.truth_sensor == {}


def test_reading_does_not_modify_the_file(good_file: Path) -> None:
    before = (hashlib.sha256(good_file.read_bytes()).hexdigest(), good_file.stat().st_mtime_ns)
    os.chmod(good_file, 0o444)  # a read-write open would fail
    read_dataset(good_file)
    assert (hashlib.sha256(good_file.read_bytes()).hexdigest(), good_file.stat().st_mtime_ns) == before


# ---------------------------------------------------------------------- bad files
def _edit(path: Path, change: Callable[[h5py.File], None]) -> Path:
    with h5py.File(path, "r+") as f:
        change(f)
    return path


def _replace(f: h5py.File, name: str, value: np.ndarray) -> None:
    del f[name]
    f[name] = value


def _nan_in_q(f: h5py.File) -> None:
    q = f["joints/q"][()]
    q[7, 2] = np.nan
    f["joints/q"][...] = q


def _unsorted_t(f: h5py.File) -> None:
    t = f["imu/su1/t"][()]
    t[[40, 41]] = t[[41, 40]]
    f["imu/su1/t"][...] = t


def _repeated_t(f: h5py.File) -> None:
    t = f["imu/su1/t"][()]
    t[41] = t[40]  # two samples with one stamp: as a bag or a driver may repeat one
    f["imu/su1/t"][...] = t


def _repeated_joint_t(f: h5py.File) -> None:
    t = f["joints/t"][()]
    t[10] = t[9]
    f["joints/t"][...] = t


BAD_EDITS = {
    "nan in q": (_nan_in_q, "/joints/q contains NaN or infinite values (sample 7, column 2)"),
    "unsorted time": (_unsorted_t, "/imu/su1/t is not strictly increasing (sample 41)"),
    "repeated stamp": (_repeated_t, "/imu/su1/t is not strictly increasing (sample 41)"),
    "repeated joint stamp": (_repeated_joint_t, "/joints/t is not strictly increasing (sample 10)"),
    "wrong shape q": (lambda f: _replace(f, "joints/q", np.zeros((120, 6))), "/joints/q has shape (120, 6)"),
    "wrong shape accel": (lambda f: _replace(f, "imu/su1/accel", np.zeros((117, 2))), "/imu/su1/accel has shape"),
    "accel rows": (lambda f: _replace(f, "imu/su1/accel", np.zeros((116, 3))), "expected (117, 3)"),
    "string data": (lambda f: _replace(f, "joints/qd", np.array([b"x"] * 3)), "/joints/qd has dtype"),
    "unknown convention": (lambda f: f["robot"].attrs.__setitem__("convention", "craig"), "'convention' is 'craig'"),
    "dh shape": (lambda f: _replace(f, "robot/dh", np.zeros((7, 3))), "/robot/dh has shape (7, 3)"),
    "wrong version": (
        lambda f: f.attrs.__setitem__("version", 3),
        "root attr 'version' is 3; this skincal reads versions 1, 2",
    ),
    "float version": (lambda f: f.attrs.__setitem__("version", 1.0), "root attr 'version' must be an integer, got 1.0"),
    "wrong format": (lambda f: f.attrs.__setitem__("format", "other"), "root attr 'format' is 'other'"),
    "no format": (lambda f: f.attrs.__delitem__("format"), "root attr 'format' is missing"),
    "missing robot": (lambda f: f.__delitem__("robot"), "/robot is missing (a dataset with /joints needs its robot)"),
    "missing qd": (lambda f: f.__delitem__("joints/qd"), "/joints/qd is missing"),
    "missing gravity": (lambda f: f["robot"].attrs.__delitem__("gravity"), "/robot attr 'gravity' is missing"),
    "truth unit not in imu": (
        lambda f: f.copy(f["truth/su1"], "truth/ghost"),
        "/truth/ghost names unit 'ghost' which has no /imu/ghost stream",
    ),
    "truth link out of range": (lambda f: f["truth/su1"].attrs.__setitem__("link", 8), "/truth/su1 attr 'link' is 8"),
    "truth bad quaternion": (
        lambda f: f["truth/su1"].attrs.__setitem__("quaternion_wxyz", [2.0, 0, 0, 0]),
        "/truth/su1 attr 'quaternion_wxyz' is not a unit quaternion",
    ),
    "truth sensor shape": (
        lambda f: f["truth/su1"].attrs.__setitem__("accel_bias", [0.0, 0.0]),
        "/truth/su1 attr 'accel_bias' has shape (2,)",
    ),
    "tof inf": (lambda f: f["tof/su1/range"].__setitem__(5, np.inf), "/tof/su1/range contains infinite values"),
    "tof negative": (
        lambda f: f["tof/su1/range"].__setitem__(7, -0.25),
        "/tof/su1/range contains negative ranges (sample 7)",
    ),
    "segment order": (lambda f: f["segments/t_end"].__setitem__(1, 0.3), "/segments/t_end is not after t_start"),
    "segment kind": (lambda f: f["segments/kind"].__setitem__(0, 2), "/segments/kind must be 0 (static) or 1"),
    "static with joint": (lambda f: f["segments/joint"].__setitem__(0, 3), "/segments/joint must be -1 for a static"),
    "dynamic joint range": (lambda f: f["segments/joint"].__setitem__(2, 7), "/segments/joint must be in 0..6"),
    "segment lengths": (lambda f: _replace(f, "segments/pose", np.zeros(2, np.int32)), "/segments/pose has shape (2,)"),
    "float kind": (lambda f: _replace(f, "segments/kind", np.zeros(3)), "/segments/kind has dtype float64"),
    "imu is a dataset": (lambda f: (f.__delitem__("imu"), f.__setitem__("imu", [1.0])), "/imu must be a group"),
}


@pytest.mark.parametrize("case", list(BAD_EDITS))
def test_bad_file_gives_one_line_error_naming_the_field(good_file: Path, case: str) -> None:
    change, expected = BAD_EDITS[case]
    _edit(good_file, change)
    with pytest.raises(DatasetError) as info:
        read_dataset(good_file)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(f"{good_file}: ") and message.count(str(good_file)) == 1
    assert expected in message


def test_truncated_file(good_file: Path, tmp_path: Path) -> None:
    cut = tmp_path / "cut.h5"
    data = good_file.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(DatasetError, match=r"cut\.h5: not a readable HDF5 file \(.*truncated") as info:
        read_dataset(cut)
    assert "\n" not in str(info.value)


def test_flipped_data_byte_is_detected_by_checksum(good_file: Path) -> None:
    """Datasets are written with Fletcher-32 checksums: silent bit rot in samples becomes an error."""
    with h5py.File(good_file, "r") as f:
        chunk = f["joints/q"].id.get_chunk_info(0)
    data = bytearray(good_file.read_bytes())
    data[chunk.byte_offset + 100] ^= 0x01
    good_file.write_bytes(bytes(data))
    with pytest.raises(DatasetError, match=r"data\.h5: /joints/q cannot be read \("):
        read_dataset(good_file)


def test_not_hdf5_and_missing(tmp_path: Path) -> None:
    text = tmp_path / "notes.h5"
    text.write_text("time,q1\n0,0\n")
    with pytest.raises(DatasetError, match=r"notes\.h5: not a readable HDF5 file"):
        read_dataset(text)
    with pytest.raises(DatasetError, match=r"nothere\.h5: no such file"):
        read_dataset(tmp_path / "nothere.h5")
    with pytest.raises(DatasetError, match="is a directory"):
        read_dataset(tmp_path)


# ---------------------------------------------------------------------- validation before write
@pytest.mark.parametrize(
    ("change", "expected"),
    [
        (lambda ds: {"joints": dataclasses.replace(ds.joints, t=ds.joints.t[::-1])}, "/joints/t is not strictly"),
        (lambda ds: {"imu": {**ds.imu, "a/b": ds.imu["su1"]}}, "invalid unit name 'a/b'"),
        (lambda ds: {"tof": {"nobody": ds.tof["su1"]}}, "/tof/nobody names unit 'nobody'"),
        (lambda ds: {"truth_sensor": {"nobody": {"accel_bias": np.zeros(3)}}}, "/truth/nobody has sensor errors"),
        (lambda ds: {"gravity": np.array([0.0, -9.81])}, "/robot attr 'gravity' has shape (2,)"),
    ],
)
def test_write_validates_first(tmp_path: Path, change: Callable, expected: str) -> None:
    good = make_dataset()
    bad = dataclasses.replace(good, **change(good))
    path = tmp_path / "out.h5"
    with pytest.raises(DatasetError) as info:
        write_dataset(bad, path)
    assert expected in str(info.value) and str(info.value).startswith(f"{path}: ")
    assert list(tmp_path.iterdir()) == []


def test_validate_dataset_accepts_good_and_names_source() -> None:
    ds = make_dataset()
    validate_dataset(ds)
    bad = dataclasses.replace(ds, joints=dataclasses.replace(ds.joints, qd=ds.joints.qd[:, :3]))
    with pytest.raises(DatasetError, match=r"^mem: /joints/qd has shape \(120, 3\), expected \(120, 7\)$"):
        validate_dataset(bad, source="mem")


# ---------------------------------------------------------------------- atomic writes
def test_failed_write_keeps_old_file_and_leaves_no_temporary(
    good_file: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    old_bytes = good_file.read_bytes()
    calls = {"n": 0}
    real = h5py.Group.create_dataset

    def failing(self: h5py.Group, *args: object, **kwargs: object) -> object:
        calls["n"] += 1
        if calls["n"] == 4:  # after /robot/dh and limits: a half-written file exists on disk
            raise OSError(28, "No space left on device (simulated)")
        return real(self, *args, **kwargs)

    monkeypatch.setattr(h5py.Group, "create_dataset", failing)
    new = make_dataset(seed=1)
    with pytest.raises(OSError, match="simulated"):
        write_dataset(new, good_file)
    assert calls["n"] == 4
    assert good_file.read_bytes() == old_bytes
    assert sorted(p.name for p in good_file.parent.iterdir()) == ["data.h5"]
    monkeypatch.undo()
    assert_datasets_equal(make_dataset(), read_dataset(good_file))


def test_failed_first_write_leaves_nothing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def failing(self: h5py.Group, *args: object, **kwargs: object) -> object:
        raise KeyboardInterrupt

    monkeypatch.setattr(h5py.Group, "create_dataset", failing)
    with pytest.raises(KeyboardInterrupt):
        write_dataset(make_dataset(), tmp_path / "new.h5")
    assert list(tmp_path.iterdir()) == []


def test_overwrite_replaces_content(good_file: Path) -> None:
    new = make_dataset(seed=5)
    write_dataset(new, good_file)
    assert_datasets_equal(new, read_dataset(good_file))
    assert sorted(p.name for p in good_file.parent.iterdir()) == ["data.h5"]
    assert good_file.stat().st_mode & 0o777 == 0o666 & ~_umask()


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _write_v1_by_hand(path: Path, chain_dh: np.ndarray) -> None:
    """A version-1 file as the version-1 contract describes it, with raw h5py (no skincal writer)."""
    t = np.linspace(0.0, 1.0, 11)
    n = chain_dh.shape[0]
    with h5py.File(path, "w") as f:
        f.attrs["format"], f.attrs["version"] = "skincal-dataset", 1
        robot = f.create_group("robot")
        robot.attrs["name"], robot.attrs["convention"] = "two-link", "standard"
        robot.attrs["gravity"] = [0.0, 0.0, -9.81]
        robot["dh"] = chain_dh
        robot["joint_lower"], robot["joint_upper"] = -np.ones(n), np.ones(n)
        f["joints/t"], f["joints/q"], f["joints/qd"] = t, np.zeros((11, n)), np.zeros((11, n))
        f["imu/su1/t"], f["imu/su1/accel"] = t, np.tile([0.0, 0.0, 9.81], (11, 1))


def test_a_version_1_file_written_by_hand_still_reads(tmp_path: Path) -> None:
    dh = np.array([[0.0, 0.2, 0.3, 0.5], [0.1, 0.0, 0.25, 0.0]])
    _write_v1_by_hand(tmp_path / "v1.h5", dh)
    back = read_dataset(tmp_path / "v1.h5")
    ref = SerialChain.from_dh("two-link", "standard", dh)
    q = np.random.default_rng(0).uniform(-1, 1, (5, 2))
    np.testing.assert_allclose(back.robot.link_frames(q), ref.link_frames(q), atol=1e-15)
    assert back.robot.convention == "standard" and back.robot.link_name(2) == "link2"


def test_a_urdf_robot_round_trips_with_its_names_text_and_continuous_joints(tmp_path: Path) -> None:
    """Version 2 stores the general chain: joint origins, axes, types, names, +-inf limits of a
    continuous joint and the URDF text come back exactly."""
    from skincal.kinematics.urdf import chain_from_urdf

    urdf = """<robot name="arm"><link name="base"/><link name="upper"/><link name="fore"/><link name="tool"/>
      <joint name="shoulder" type="continuous"><parent link="base"/><child link="upper"/>
        <origin xyz="0 0 0.3" rpy="0.1 0.2 0.3"/><axis xyz="0 1 1"/><limit velocity="2" effort="10"/></joint>
      <joint name="slide" type="prismatic"><parent link="upper"/><child link="fore"/>
        <origin xyz="0.2 0 0"/><axis xyz="1 0 0"/><limit lower="0" upper="0.4" velocity="0.5" effort="100"/></joint>
      <joint name="flange" type="fixed"><parent link="fore"/><child link="tool"/><origin xyz="0 0 0.05"/></joint>
    </robot>"""
    chain = chain_from_urdf(text=urdf)
    t = np.linspace(0.0, 1.0, 11)
    ds = Dataset(
        robot=chain,
        joints=JointStates(t, np.zeros((11, 2)), np.zeros((11, 2))),
        imu={"a": ImuStream(t, np.tile([0, 0, 9.81], (11, 1)))},
    )
    write_dataset(ds, tmp_path / "urdf.h5")
    back = read_dataset(tmp_path / "urdf.h5").robot
    for key in ("T_parent_joint", "axis", "T_joint_link", "joint_lower", "joint_upper", "velocity_limit",
                "effort_limit", "T_link_flange"):
        np.testing.assert_array_equal(getattr(back, key), getattr(chain, key), err_msg=key)
    assert back.joint_type == ("revolute", "prismatic") and back.convention == "urdf" and back.dh is None
    assert back.link_names == ("base", "upper", "fore") and back.joint_names == ("shoulder", "slide")
    assert back.source == urdf and back.joint_lower[0] == -np.inf


def test_a_dh_table_that_disagrees_with_the_general_chain_is_refused(good_file: Path, tmp_path: Path) -> None:
    import shutil

    bad = tmp_path / "bad.h5"
    shutil.copy(good_file, bad)
    with h5py.File(bad, "r+") as f:
        f["robot/dh"][0, 1] += 0.01
    with pytest.raises(DatasetError, match="/robot/T_parent_joint disagrees with /robot/dh|/robot/T_joint_link"):
        read_dataset(bad)


def test_a_bad_link_name_is_refused(good_file: Path, tmp_path: Path) -> None:
    import shutil

    bad = tmp_path / "bad.h5"
    shutil.copy(good_file, bad)
    with h5py.File(bad, "r+") as f:
        names = [str(x) for x in f["robot"].attrs["link_names"]]
        names[3] = "fore\x1b[2Jarm"
        f["robot"].attrs["link_names"] = np.array(names, dtype=h5py.string_dtype())
    with pytest.raises(DatasetError, match="link_names.*not a valid name"):
        read_dataset(bad)


def test_a_recording_and_a_written_dataset_read_identically(tmp_path):
    """The recorder and ``write_dataset`` share one layout writer (:class:`skincal.data.writer.DatasetWriter`):
    a recording reads back as a dataset that, written and read again, is the same, and the two files hold
    the same layout paths (the recorder's own fields, ``device_t_us``, ``host_receive_t``, ``/clock``, aside)."""
    from skincal.hw.clock import ClockFit
    from skincal.hw.packet import decode_packet, encode_joint_packet, encode_packet
    from skincal.hw.receiver import Delivery
    from skincal.hw.recorder import Recorder

    def delivery(data: bytes, host_s: float) -> Delivery:
        p = decode_packet(data)
        return Delivery(("joints", p.source_id) if hasattr(p, "q") else ("skin", p.unit_id), p, host_s)

    rng = np.random.default_rng(5)
    rec_path, ds_path = tmp_path / "rec.h5", tmp_path / "ds.h5"
    rec = Recorder(rec_path, flush_every_samples=5, flush_every_s=1e9, t_origin_s=100.0, host_clock=lambda: 0.0,
                   unit_names={7: "forearm", 8: "upper"}, robot=panda(), description="two units")
    fits = {("skin", 7): ClockFit(99.0, 0.0, 1.0), ("skin", 8): ClockFit(99.0, 2e-5, 1.0),
            ("joints", 0): ClockFit(100.0, 0.0, 0.0)}
    for k in range(4):
        t_us = 1_000_000 + 10_000 * (3 * k + np.arange(3))
        rec.add(delivery(encode_packet(7, k, t_us, accel=rng.normal(size=(3, 3)), gyro=rng.normal(size=(3, 3)),
                                       range=rng.uniform(0.1, 1.0, 3)), 101.0 + k))
        rec.add(delivery(encode_packet(8, k, t_us, accel=rng.normal(size=(3, 3))), 101.0 + k))
        rec.add(delivery(encode_joint_packet(0, k, 3 * k + np.arange(3), rng.normal(size=(3, 7)),
                                             rng.normal(size=(3, 7))), 101.0 + k))
        rec.maybe_flush(fits)
    rec.finish(fits)
    recorded = read_dataset(rec_path)
    write_dataset(recorded, ds_path)
    assert_datasets_equal(recorded, read_dataset(ds_path))
    assert recorded.description == "two units" and list(recorded.imu) == ["forearm", "upper"]

    def layout(path: Path) -> set[str]:
        names: set[str] = set()
        with h5py.File(path, "r") as f:
            f.visit(names.add)
            names |= {f"@{key}" for key in ("format", "version", "description") if key in f.attrs}
            assert (f.attrs["format"], int(f.attrs["version"])) == ("skincal-dataset", 2)
        return {n for n in names if not n.startswith("clock") and not n.endswith(("device_t_us", "host_receive_t"))}

    assert layout(rec_path) == layout(ds_path)


def test_a_description_over_the_contracts_1_mib_is_refused_before_anything_is_written(tmp_path: Path) -> None:
    """A 2 MiB description was written although every reader refuses an attribute over 1 MiB; the file
    at the path stays as it was. 1 MiB exactly is written and read back."""
    path = tmp_path / "d.h5"
    path.write_bytes(b"earlier file")
    big = dataclasses.replace(make_dataset(), description="x" * (2 << 20))
    with pytest.raises(DatasetError, match=r"root attr 'description'.*2097152 bytes \(at most 1048576"):
        write_dataset(big, path)
    assert path.read_bytes() == b"earlier file" and sorted(p.name for p in tmp_path.iterdir()) == ["d.h5"]
    limit = dataclasses.replace(make_dataset(), description="y" * (1 << 20))
    out = tmp_path / "limit.h5"
    write_dataset(limit, out)
    assert read_dataset(out).description == limit.description


def test_a_compressed_stream_of_the_wrong_length_is_refused_before_it_is_decompressed(tmp_path: Path) -> None:
    """A gzip bomb of zeros (200 MB declared, a few hundred kB stored) whose row count is not its stamps'
    was decompressed whole and only then refused: the declared shape is now checked first."""
    import tracemalloc

    path = tmp_path / "bomb.h5"
    write_dataset(make_dataset(), path)
    with h5py.File(path, "a") as f:
        unit = next(iter(f["imu"]))
        del f[f"imu/{unit}/accel"]
        rows = 200_000_000 // 24
        bomb = f.create_dataset(f"imu/{unit}/accel", shape=(rows, 3), dtype="f8", chunks=(1 << 17, 3),
                                compression="gzip", compression_opts=9)  # fmt: skip
        zeros = np.zeros((1 << 17, 3))
        for start in range(0, rows, 1 << 17):
            bomb[start : start + zeros.shape[0]] = zeros[: rows - start]
    tracemalloc.start()
    try:
        with pytest.raises(DatasetError, match=rf"/imu/{unit}/accel has shape \({rows}, 3\), expected \(\d+, 3\)"):
            read_dataset(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 20e6, peak  # nothing near the 200 MB was allocated
