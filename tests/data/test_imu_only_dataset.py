"""IMU-only datasets (issue 18): skin without encoders. A dataset without ``/joints`` (and maybe without
``/robot``) validates, reads, round-trips; every command that needs joint states refuses it on one
line (exit 2), ``info`` shows it; a bag without JointState and a recording without joints import."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import h5py
import numpy as np
import pytest

from skincal.cli import main
from skincal.data.dataset import Dataset, ImuStream, JointStates
from skincal.data.hdf5 import read_dataset, write_dataset
from skincal.data.ros import read_bag, write_bag
from skincal.errors import DatasetError
from skincal.kinematics import get_robot
from skincal.skin.pose import SkinUnitPose

RATE_HZ = 100.0
N = 300
T_SU2 = np.array([[0.0, -1.0, 0.0, 0.05], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.01], [0.0, 0.0, 0.0, 1.0]])


def _streams(seed: int = 5) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(seed)
    out = {}
    for k, unit in enumerate(("su1", "su2")):
        t = np.arange(N) / RATE_HZ + 0.003 * k  # each unit its own instants
        accel = np.array([0.0, 0.0, 9.81]) + 0.02 * rng.normal(size=(N, 3))
        gyro = 0.3 * np.sin(np.outer(t, [1.0, 2.0, 3.0])) + 0.001 * rng.normal(size=(N, 3))
        out[unit] = (t, accel, gyro)
    return out


def _write_by_hand(path: Path, *, gravity: bool = True, truth: bool = True) -> Path:
    """An IMU-only file written with h5py alone: no /joints, no /robot."""
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "skincal-dataset"
        f.attrs["version"] = 2
        f.attrs["description"] = "hand-held patch"
        if gravity:
            f.attrs["gravity"] = [0.0, 0.0, -9.80]
        for unit, (t, accel, gyro) in _streams().items():
            g = f.create_group(f"imu/{unit}")
            g["t"], g["accel"], g["gyro"] = t, accel, gyro
        if truth:
            f.create_group("truth/su1").attrs.update(body="patch", T_body_su=np.eye(4))
            f.create_group("truth/su2").attrs.update(body="patch", T_body_su=T_SU2, accel_bias=[0.01, 0.0, -0.02])
    return path


@pytest.fixture
def imu_file(tmp_path: Path) -> Path:
    return _write_by_hand(tmp_path / "imu.h5")


def test_hand_written_imu_only_file_validates_and_reads(imu_file: Path) -> None:
    ds = read_dataset(imu_file)
    assert ds.joints is None and ds.robot is None and not ds.has_joints
    assert ds.units == ["su1", "su2"]
    np.testing.assert_array_equal(ds.gravity, [0.0, 0.0, -9.80])
    np.testing.assert_array_equal(ds.imu["su2"].gyro, _streams()["su2"][2])
    assert ds.truth == {}
    assert ds.truth_body["su2"].body == "patch"
    np.testing.assert_array_equal(ds.truth_body["su2"].T_body_su, T_SU2)
    assert ds.truth_sensor["su2"]["accel_bias"].tolist() == [0.01, 0.0, -0.02]  # T_body_su is no sensor error
    assert "T_body_su" not in ds.truth_sensor.get("su1", {})
    assert ds.duration == pytest.approx((N - 1) / RATE_HZ + 0.003)  # the IMU span
    with pytest.raises(DatasetError, match="imu.h5: this dataset has no joint states: segment needs"):
        ds.require_joints("segment", source=str(imu_file))


def test_gravity_defaults_without_robot_and_is_checked(tmp_path: Path) -> None:
    ds = read_dataset(_write_by_hand(tmp_path / "g.h5", gravity=False))
    np.testing.assert_array_equal(ds.gravity, [0.0, 0.0, -9.81])
    bad = _write_by_hand(tmp_path / "bad.h5")
    with h5py.File(bad, "r+") as f:
        f.attrs["gravity"] = [0.0, 0.0, 0.0]
    with pytest.raises(DatasetError, match=r"root attr 'gravity' has magnitude 0"):
        read_dataset(bad)


def test_round_trip_through_the_writer(imu_file: Path, tmp_path: Path) -> None:
    ds = read_dataset(imu_file)
    out = tmp_path / "again.h5"
    write_dataset(ds, out)
    with h5py.File(out, "r") as f:
        assert "joints" not in f and "robot" not in f
        assert f["truth/su2"].attrs["body"] == "patch"
    back = read_dataset(out)
    assert back.joints is None and back.robot is None and back.units == ds.units
    for unit in ds.units:
        np.testing.assert_array_equal(back.imu[unit].t, ds.imu[unit].t)
        np.testing.assert_array_equal(back.imu[unit].accel, ds.imu[unit].accel)
        np.testing.assert_array_equal(back.truth_body[unit].T_body_su, ds.truth_body[unit].T_body_su)
    np.testing.assert_array_equal(back.gravity, ds.gravity)
    assert list(back.truth_sensor) == ["su2"]
    np.testing.assert_array_equal(back.truth_sensor["su2"]["accel_bias"], [0.01, 0.0, -0.02])


def test_imu_only_with_a_robot_keeps_it(imu_file: Path, tmp_path: Path) -> None:
    """A robot whose joints could not be read: /robot without /joints; link truth is then allowed."""
    ds = read_dataset(imu_file)
    chain = get_robot("panda")
    pose = SkinUnitPose.from_dh6(3, [0.0, 0.02, 0.0, 0.05, 0.0, 1.5])
    with_robot = Dataset(robot=chain, joints=None, imu=ds.imu, truth={"su1": pose}, truth_body=ds.truth_body)
    out = tmp_path / "robot.h5"
    write_dataset(with_robot, out)
    back = read_dataset(out)
    assert back.joints is None and back.robot is not None and back.robot.name == "panda"
    assert back.truth["su1"].link == 3 and back.truth_body["su1"].body == "patch"  # both poses of su1


@pytest.mark.adversarial
@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda f: f["truth/su2"].attrs.__setitem__("T_body_su", 2 * np.eye(4)), "is not a rigid transform"),
        (lambda f: f["truth/su2"].attrs.__setitem__("T_body_su", np.diag([1.0, 1.0, -1.0, 1.0])), "is a reflection"),
        (lambda f: f["truth/su2"].attrs.__setitem__("T_body_su", np.eye(3)), "attr 'T_body_su' has shape (3, 3)"),
        (lambda f: f["truth/su2"].attrs.__setitem__("body", "a/b"), "attr 'body' 'a/b' is not a valid body name"),
        (lambda f: f["truth/su2"].attrs.__delitem__("T_body_su"), "/truth/su2 attr 'T_body_su' is missing"),
        (lambda f: f["truth/su2"].attrs.__setitem__("link", 2), "/truth/su2 attr 'position' is missing"),
        (
            lambda f: f["truth/su2"].attrs.update(link=2, position=[0.0, 0, 0], quaternion_wxyz=[1.0, 0, 0, 0]),
            "/truth/su2 attr 'link' needs a /robot",
        ),
        (lambda f: f["imu"].__delitem__("su1"), "/truth/su1 names unit 'su1' which has no /imu/su1 stream"),
        (lambda f: (f.__delitem__("imu"), f.create_group("imu")), "/imu is empty and there are no /joints"),
        (lambda f: f.create_group("joints").create_dataset("t", data=[0.0]), "/robot is missing (a dataset with"),
    ],
)
def test_bad_imu_only_files_are_refused_on_one_line(tmp_path: Path, edit, message: str) -> None:
    path = _write_by_hand(tmp_path / "bad.h5")
    with h5py.File(path, "r+") as f:
        edit(f)
    with pytest.raises(DatasetError) as info:
        read_dataset(path)
    text = str(info.value)
    assert text.startswith(f"{path}: ") and "\n" not in text
    assert message in text


def test_joints_without_robot_refused_in_memory(tmp_path: Path) -> None:
    t = np.arange(10) / 100.0
    ds = Dataset(robot=None, joints=JointStates(t, np.zeros((10, 7)), np.zeros((10, 7))),
                 imu={"su1": ImuStream(t, np.tile([0.0, 0.0, 9.81], (10, 3)))})  # fmt: skip
    with pytest.raises(DatasetError, match=r"x.h5: /robot is missing \(a dataset with /joints needs its robot\)"):
        write_dataset(ds, tmp_path / "x.h5")
    assert not (tmp_path / "x.h5").exists()


# --------------------------------------------------------------------------- the commands


def _result(path: Path, data: Path) -> Path:
    unit = {"link": 3, "position_m": [0.0, 0.0, 0.05], "quaternion_wxyz": [1.0, 0.0, 0.0, 0.0], "observable": True,
            "position_std_m": None, "rotation_std_deg": None, "warnings": []}  # fmt: skip
    digest = hashlib.sha256(data.read_bytes()).hexdigest()
    doc = {"format": "skincal-result", "version": 1, "method": "mle", "robot": "panda", "runtime_s": 0.1,
           "dataset_sha256": digest, "units": {"su1": unit, "su2": unit}}  # fmt: skip
    path.write_text(json.dumps(doc))
    return path


NO_JOINTS = "this dataset has no joint states"


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (
            ["calibrate", "{data}", "-o", "{tmp}/r.json"],
            f"{NO_JOINTS}: calibrate it unit-to-unit with --reference UNIT",
        ),
        (["segment", "{data}", "-o", "{tmp}/s.h5"], f"{{data}}: {NO_JOINTS}: segment"),
        (["segment", "{data}", "-o", "{tmp}/s.h5", "--protocol", "{tmp}/p.json"], f"{{data}}: {NO_JOINTS}: segment"),
        (["evaluate", "{result}", "--truth", "{data}"], f"{{data}}: {NO_JOINTS}: evaluate"),
        (["report", "{result}", "--dataset", "{data}"], f"{{data}}: {NO_JOINTS}: report"),
        (["report", "{result}", "--dataset", "{data}", "-o", "{tmp}/r.html"], f"{{data}}: {NO_JOINTS}: report"),
        (["view", "{result}", "--truth", "{data}", "--duration", "0"], f"{{data}}: {NO_JOINTS}: view --truth"),
        (["view", "{result}", "--play", "{data}", "--duration", "0"], f"{{data}}: {NO_JOINTS}: view --play"),
        (["export", "{result}", "-f", "urdf", "-o", "{tmp}/x.urdf", "--robot", "{data}"], "unknown robot"),
    ],
)
def test_commands_that_need_joints_refuse_on_one_line(
    imu_file: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], message: str
) -> None:
    result = _result(tmp_path / "result.json", imu_file)
    before = imu_file.read_bytes()
    fill = {"tmp": tmp_path, "data": imu_file, "result": result}
    code = main([a.format(**fill) for a in args])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert message.format(**fill) in err and err.startswith("error: ")
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert imu_file.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["imu.h5", "result.json"]  # nothing written


def test_info_shows_an_imu_only_dataset(imu_file: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["info", str(imu_file)]) == 0
    out = capsys.readouterr().out
    assert "none: IMU-only (calibrate with --reference UNIT)" in out
    assert "robot" in out and "none" in out.split("robot", 1)[1].splitlines()[0]
    assert "2.993 s (IMU t = 0.000 .. 2.993 s)" in out and "9.8 m/s^2" in out
    rows = {line.split()[1]: line.split()[2:] for line in out.splitlines() if line.startswith("│ su")}
    assert rows["su1"] == ["│", "300", "│", "100", "│", "yes", "│", "no", "│", "-", "│", "patch", "│"]


# --------------------------------------------------------------------------- ROS bags and recordings


@pytest.fixture
def shared_topic_bag(imu_file: Path, tmp_path: Path) -> Path:
    """A ROS 2 bag with only IMU messages: both units on one topic, told apart by frame_id."""
    bag = tmp_path / "bag"
    write_bag(read_dataset(imu_file), bag, imu_topic="/skin/imus")
    return bag


def test_bag_with_only_imu_topics_imports_into_two_units(imu_file: Path, shared_topic_bag: Path) -> None:
    with pytest.raises(DatasetError, match=r"no sensor_msgs/JointState topic.*--imu-only"):
        read_bag(shared_topic_bag)  # the library's default still wants joint states
    ds, report = read_bag(shared_topic_bag, imu_only=None)
    assert ds.joints is None and ds.robot is None and report.imu_only and report.joint_topic == ""
    assert sorted(ds.units) == ["su1", "su2"]
    assert any("no sensor_msgs/JointState topic: an IMU-only dataset" in n for n in report.notes)
    truth = read_dataset(imu_file)
    for unit in ("su1", "su2"):  # time 0 at the first IMU stamp (su1's, at 0 s)
        np.testing.assert_allclose(ds.imu[unit].t, truth.imu[unit].t, atol=1e-9)
        np.testing.assert_allclose(ds.imu[unit].accel, truth.imu[unit].accel, atol=1e-12)
        np.testing.assert_allclose(ds.imu[unit].gyro, truth.imu[unit].gyro, atol=1e-12)


def test_import_command_writes_an_imu_only_dataset(
    shared_topic_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "imported.h5"
    assert main(["import", str(shared_topic_bag), "-o", str(out)]) == 0
    text = " ".join(capsys.readouterr().out.split())  # the console wraps long lines
    assert "no robot, IMU-only (no joint states), units su1 <- /skin/imus su1, su2 <- /skin/imus su2" in text
    assert "note: no sensor_msgs/JointState topic" in text
    back = read_dataset(out)
    assert back.joints is None and back.robot is None and back.segments is None and back.units == ["su1", "su2"]
    assert main(["import", str(shared_topic_bag), "-o", str(tmp_path / "p.h5"), "--imu-only", "--protocol",
                 str(tmp_path / "p.json")]) == 2  # fmt: skip
    assert "--imu-only import has none" in capsys.readouterr().err


def test_imu_only_ignores_the_joint_states_of_a_bag(tmp_path: Path) -> None:
    chain = get_robot("panda")
    t = np.arange(200) / RATE_HZ
    ds = Dataset(robot=chain, joints=JointStates(t + 0.5, np.zeros((200, 7)), np.zeros((200, 7))),
                 imu={"su1": ImuStream(t, np.tile([0.0, 0.0, 9.81], (200, 1)), np.zeros((200, 3)))})  # fmt: skip
    bag = tmp_path / "b"
    write_bag(ds, bag)
    joint_based, _ = read_bag(bag, robot="panda")
    assert joint_based.joints is not None and joint_based.imu["su1"].t[0] == pytest.approx(-0.5)
    imu_only, report = read_bag(bag, robot="panda", imu_only=True)
    assert imu_only.joints is None and imu_only.robot is not None and imu_only.robot.name == "panda"
    assert imu_only.imu["su1"].t[0] == 0.0  # time from the first IMU stamp
    assert any("IMU-only: joint states on /joint_states not read" in n for n in report.notes)


def test_recording_without_joints_reads_back(tmp_path: Path) -> None:
    from skincal.hw.clock import ClockFit
    from skincal.hw.packet import decode_packet, encode_packet
    from skincal.hw.receiver import Delivery
    from skincal.hw.recorder import Recorder

    a = np.array([[0.0, 0.0, 9.8], [0.1, 0.0, 9.8], [0.0, 0.1, 9.8]])
    for robot in (None, get_robot("panda")):
        path = tmp_path / f"rec_{robot is not None}.h5"
        rec = Recorder(path, robot=robot, t_origin_s=0.0, host_clock=lambda: 0.0, unit_names={4: "patch"})
        for seq, start in enumerate((1_000_000, 1_030_000)):
            p = decode_packet(encode_packet(4, seq, [start, start + 10_000, start + 20_000], accel=a, gyro=0.1 * a))
            rec.add(Delivery(("skin", 4), p, 1.0))
        summary = rec.finish({("skin", 4): ClockFit(0.0, 0.0, 0.0)})
        assert summary.samples == {"imu/patch": 6}
        back = read_dataset(path)  # before: "/joints is missing"
        assert back.joints is None and (back.robot is None) == (robot is None)
        np.testing.assert_allclose(back.imu["patch"].t, [1.0, 1.01, 1.02, 1.03, 1.04, 1.05], atol=1e-9)
        np.testing.assert_array_equal(back.imu["patch"].accel, np.vstack([a, a]).astype(np.float32))


def test_emulator_plays_an_imu_only_dataset(imu_file: Path) -> None:
    from skincal.hw.emulator import SkinEmulator

    emu = SkinEmulator(read_dataset(imu_file), 9, rng=np.random.default_rng(0))  # not run: the plan only
    assert set(emu.plan.unit_ids) == {"su1", "su2"} and emu.plan.datagrams_planned > 0
    assert not emu.joints
