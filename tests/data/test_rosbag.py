"""ROS bag import: real ROS 1 and ROS 2 (sqlite3, mcap) bags written with rosbags in the tests."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from skincal.calib import calibrate, evaluate
from skincal.cli import main
from skincal.data.dataset import JointStates, TofStream
from skincal.data.hdf5 import read_dataset, write_dataset
from skincal.data.ros import PROGRESS_EVERY, ROBOT_DESCRIPTION, read_bag, topic_map, write_bag
from skincal.data.segment import segment_dataset
from skincal.errors import ConfigError, DatasetError
from skincal.kinematics import get_robot
from skincal.kinematics.presets import UR_JOINT_NAMES
from skincal.protocol import ProtocolConfig, build_trajectory
from skincal.sim.analytic import simulate
from skincal.skin.imu import STANDARD_GRAVITY, get_imu_model
from skincal.skin.placement import paper_placement
from skincal.workflows.session import simulate_dataset

from registry_robots import registry_urdf

T0_NS = 1_700_000_000_000_000_000
PANDA_JOINTS = [f"panda_joint{i}" for i in range(1, 8)]


def _session(n_poses: int, excited_joints: tuple[int, ...] | None, seed: int = 7):
    """A realistic session: Panda, 3 units (links 3-5), 100 Hz joints, 100 Hz IMUs, ToF on 2 units."""
    chain = get_robot("panda")
    rng = np.random.default_rng(seed)
    cfg = ProtocolConfig(n_poses=n_poses, rest_duration=2.0, static_duration=1.0, rate_hz=100.0,
                         excited_joints=excited_joints)
    placements = dict(list(paper_placement(chain).items())[2:5])
    ds = simulate(chain, placements, build_trajectory(chain, cfg, rng), get_imu_model("realistic"), rng)
    units = ds.units
    t = np.arange(0.01, ds.duration, 0.02)
    r = 0.3 + 0.1 * np.sin(t)
    r[::7] = np.nan  # no target
    return replace(ds, tof={units[0]: TofStream(t, r), units[2]: TofStream(t + 0.005, r + 0.2)})


@pytest.fixture(scope="module")
def small():
    return _session(2, (1, 3, 4))


@pytest.fixture(scope="module")
def sim():
    return _session(4, (1, 2, 3, 4, 5))


BAGS = [(1, "sqlite3", "rec.bag", "g", "deg"), (2, "sqlite3", "rec_sqlite", "mps2", "rad"),
        (2, "mcap", "rec_mcap", "g", "rad")]


@pytest.mark.parametrize("ros,storage,name,accel_unit,gyro_unit", BAGS)
def test_bag_round_trip_equals_hdf5_path(small, tmp_path, ros, storage, name, accel_unit, gyro_unit):
    sim = small
    bag = tmp_path / name
    write_bag(sim, bag, ros_version=ros, storage=storage, accel_unit=accel_unit, gyro_unit=gyro_unit)
    ds, report = read_bag(bag, "panda")
    write_dataset(replace(sim, segments=None), tmp_path / "ref.h5")
    ref = read_dataset(tmp_path / "ref.h5")
    assert report.ros_version == ros and report.joint_topic == "/joint_states"
    assert ds.units == ref.units and set(ds.tof) == set(ref.tof)
    assert report.time_origin_ns == T0_NS + round(ref.joints.t[0] * 1e9)
    np.testing.assert_allclose(ds.joints.t, ref.joints.t - ref.joints.t[0], atol=1e-9)
    np.testing.assert_array_equal(ds.joints.q, ref.joints.q)
    np.testing.assert_array_equal(ds.joints.qd, ref.joints.qd)
    for u in ref.units:
        np.testing.assert_allclose(ds.imu[u].t, ref.imu[u].t, atol=1e-9)
        np.testing.assert_allclose(ds.imu[u].accel, ref.imu[u].accel, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(ds.imu[u].gyro, ref.imu[u].gyro, rtol=1e-12, atol=1e-12)
    for u, tof in ref.tof.items():
        np.testing.assert_allclose(ds.tof[u].t, tof.t, atol=1e-9)
        np.testing.assert_array_equal(np.isnan(ds.tof[u].range), np.isnan(tof.range))
        np.testing.assert_allclose(ds.tof[u].range, tof.range, rtol=1e-6, equal_nan=True)  # float32 field
    notes = " | ".join(report.notes)
    assert notes.count("accelerometer in g") == (3 if accel_unit == "g" else 0)
    assert notes.count("gyroscope in deg/s") == (3 if gyro_unit == "deg" else 0)
    # segmentation of the imported bag equals that of the HDF5 recording
    seg_bag, seg_ref = segment_dataset(ds)[1].segments, segment_dataset(ref)[1].segments
    for a, b in zip((seg_bag.t_start, seg_bag.t_end), (seg_ref.t_start, seg_ref.t_end), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-9)
    np.testing.assert_array_equal(seg_bag.joint, seg_ref.joint)


def test_written_bag_holds_standard_messages(small, tmp_path):
    """Read the raw messages back with rosbags alone: g units, frame ids, stamps, REP 117 +inf."""
    sim = small
    write_bag(sim, tmp_path / "b.bag", ros_version=1, accel_unit="g")
    unit = sim.units[0]
    with AnyReader([tmp_path / "b.bag"]) as reader:
        conns = {c.topic: c for c in reader.connections}
        assert conns[f"/skin/{unit}/imu"].msgtype == "sensor_msgs/msg/Imu"
        _, ns, raw = next(reader.messages(connections=[conns[f"/skin/{unit}/imu"]]))
        msg = reader.deserialize(raw, "sensor_msgs/msg/Imu")
        assert msg.header.frame_id == unit
        assert msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec == ns == T0_NS + round(sim.imu[unit].t[0] * 1e9)
        np.testing.assert_allclose(msg.linear_acceleration.x * STANDARD_GRAVITY, sim.imu[unit].accel[0, 0], rtol=1e-14)
        ranges = [reader.deserialize(r, c.msgtype).range for c, _, r in
                  reader.messages(connections=[conns[f"/skin/{unit}/range"]])]
        assert np.isposinf(ranges[0]) and np.isnan(sim.tof[unit].range[0])


def test_bag_then_mle_matches_hdf5_accuracy(sim, tmp_path):
    """The benchmark target in small: bag -> import -> auto segments -> mle vs HDF5 + protocol segments."""
    write_bag(sim, tmp_path / "b", ros_version=2, storage="mcap", accel_unit="g", gyro_unit="deg")
    imported, _ = read_bag(tmp_path / "b", "panda")
    imported, _ = segment_dataset(imported)
    write_dataset(sim, tmp_path / "ref.h5")
    ev_ref = evaluate(calibrate(read_dataset(tmp_path / "ref.h5"), "mle"), sim)
    shifted = replace(sim, joints=replace(sim.joints, t=sim.joints.t - sim.joints.t[0]))  # same time origin
    ev_bag = evaluate(calibrate(imported, "mle"), shifted)
    assert ev_bag.links_correct == ev_ref.links_correct == 3
    for key in ("mean_position_error_mm", "mean_rotation_error_deg"):
        bag, ref = getattr(ev_bag, key), getattr(ev_ref, key)
        assert bag <= 1.1 * ref + 1e-6, (key, bag, ref)
    assert ev_ref.mean_position_error_mm < 2.0


# ---------------------------------------------------------------- small hand-made bags
def _write(path: Path, ros: int, topics: dict[str, tuple[str, list]], storage: str = "sqlite3") -> Path:
    """Write ``{topic: (msgtype, [(bag_ns, msg), ...])}`` with the rosbags writers."""
    ts = _store(ros)
    writer = Writer1(path) if ros == 1 else Writer2(
        path, version=9, storage_plugin=StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3)
    ser = ts.serialize_ros1 if ros == 1 else ts.serialize_cdr
    with writer:
        for topic, (kind, msgs) in topics.items():
            conn = writer.add_connection(topic, kind, typestore=ts)
            for ns, msg in msgs:
                writer.write(conn, ns, ser(msg, kind))
    return path


def _store(ros: int):
    return get_typestore(Stores.ROS1_NOETIC if ros == 1 else Stores.ROS2_HUMBLE)


def _header(ts, ns: int, frame: str = "", ros: int = 2):
    stamp = ts.types["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
    return ts.types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame, **({"seq": 0} if ros == 1 else {}))


def _joint_msgs(ts, t: np.ndarray, names=PANDA_JOINTS, velocity: bool = True, ros: int = 2, zero_stamp=False):
    """JointState with q_j = 0.1 sin(t + j) (in ``names`` order by the joint number in the name)."""
    idx = [int(n[-1]) - 1 if n in PANDA_JOINTS else -1 for n in names]
    out = []
    for tk in t:
        ns = T0_NS + round(tk * 1e9)
        q = np.array([0.1 * np.sin(tk + j) if j >= 0 else 0.04 for j in idx])
        qd = np.array([0.1 * np.cos(tk + j) if j >= 0 else 0.0 for j in idx])
        out.append((ns, ts.types["sensor_msgs/msg/JointState"](
            header=_header(ts, 0 if zero_stamp else ns, "", ros), name=list(names), position=q,
            velocity=qd if velocity else np.zeros(0), effort=np.zeros(0))))
    return "sensor_msgs/msg/JointState", out


def _imu_msgs(ts, t: np.ndarray, accel: np.ndarray, frame: str = "su1", ros: int = 2):
    V = ts.types["geometry_msgs/msg/Vector3"]
    out = []
    for tk, a in zip(t, accel, strict=True):
        ns = T0_NS + round(tk * 1e9)
        out.append((ns, ts.types["sensor_msgs/msg/Imu"](
            header=_header(ts, ns, frame, ros),
            orientation=ts.types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=np.zeros(9), angular_velocity=V(x=0.0, y=0.0, z=0.0),
            angular_velocity_covariance=np.zeros(9), linear_acceleration=V(x=a[0], y=a[1], z=a[2]),
            linear_acceleration_covariance=np.zeros(9))))
    return "sensor_msgs/msg/Imu", out


T = np.arange(0, 2.0, 0.01)
UP_G = np.tile([0.0, 0.0, 1.0], (len(T), 1))


@pytest.mark.parametrize("ros", [1, 2])
def test_bag_without_joint_states(tmp_path, ros):
    ts = _store(ros)
    bag = _write(tmp_path / ("b.bag" if ros == 1 else "b"), ros, {"/su1/imu": _imu_msgs(ts, T, UP_G, ros=ros)})
    with pytest.raises(DatasetError, match=r"no sensor_msgs/JointState topic.*/su1/imu \(sensor_msgs/msg/Imu\)"):
        read_bag(bag)


def test_nan_samples_dropped_with_count_or_error_when_all_nan(tmp_path):
    ts = _store(2)
    accel = UP_G.copy()
    accel[[5, 50, 51], 1] = np.nan
    bag = _write(tmp_path / "b", 2, {"/joint_states": _joint_msgs(ts, T), "/su1/imu": _imu_msgs(ts, T, accel)})
    ds, report = read_bag(bag, "panda")
    assert "/su1/imu: dropped 3 sample(s) containing NaN" in report.notes
    assert len(ds.imu["su1"].t) == len(T) - 3
    np.testing.assert_allclose(ds.imu["su1"].accel, np.delete(UP_G, [5, 50, 51], axis=0) * STANDARD_GRAVITY)
    bag2 = _write(tmp_path / "c", 2, {"/joint_states": _joint_msgs(ts, T),
                                      "/su1/imu": _imu_msgs(ts, T, np.full_like(UP_G, np.nan))})
    with pytest.raises(DatasetError, match=f"topic /su1/imu: all {len(T)} samples contain NaN"):
        read_bag(bag2, "panda")


def test_joint_states_with_fewer_positions_than_names_say_so(tmp_path):
    """Every JointState names the Panda's 7 joints but carries 6 positions (a malformed publisher): the
    error says that, instead of naming a blank joint as missing."""
    ts = _store(2)
    kind, msgs = _joint_msgs(ts, T)
    for _, m in msgs:
        m.position = m.position[:6]
    bag = _write(tmp_path / "b", 2, {"/joint_states": (kind, msgs), "/su1/imu": _imu_msgs(ts, T, UP_G)})
    with pytest.raises(DatasetError, match=r"carry 6 position\(s\) for 7 joint name\(s\)"):
        read_bag(bag, "panda")


def test_unknown_topic_wrong_type_and_empty_bag(tmp_path):
    ts = _store(2)
    bag = _write(tmp_path / "b", 2, {"/joint_states": _joint_msgs(ts, T), "/su1/imu": _imu_msgs(ts, T, UP_G)})
    with pytest.raises(DatasetError, match="IMU topic '/nope' is not in the bag"):
        read_bag(bag, tmap=topic_map(imu=["/nope"]))
    with pytest.raises(DatasetError, match="topic '/joint_states' is sensor_msgs/msg/JointState, expected"):
        read_bag(bag, tmap=topic_map(imu=["/joint_states"]))
    empty = _write(tmp_path / "e.bag", 1, {"/joint_states": ("sensor_msgs/msg/JointState", [])})
    with pytest.raises(DatasetError, match="the bag is empty"):
        read_bag(empty)
    with pytest.raises(DatasetError, match="no such bag"):
        read_bag(tmp_path / "missing.bag")


@pytest.mark.parametrize("ros,storage,name", [(1, "", "b.bag"), (2, "mcap", "b"), (2, "sqlite3", "b")])
def test_truncated_bag_is_one_clear_error(tmp_path, ros, storage, name):
    ts = _store(ros)
    bag = _write(tmp_path / name, ros, {"/joint_states": _joint_msgs(ts, T, ros=ros),
                                        "/su1/imu": _imu_msgs(ts, T, UP_G, ros=ros)}, storage=storage)
    files = [bag] if ros == 1 else [p for p in bag.iterdir() if p.suffix in (".mcap", ".db3")]
    data = files[0].read_bytes()
    files[0].write_bytes(data[: len(data) // 2])
    with pytest.raises(DatasetError, match=r"cannot (open|read) the bag .*truncated") as info:
        read_bag(bag)
    assert "\n" not in str(info.value)


def test_joint_names_mapped_velocity_differentiated_stamps_fallback(tmp_path):
    ts = _store(1)
    shuffled = ["panda_finger_joint1", *PANDA_JOINTS[::-1], "panda_finger_joint2"]
    _, joints = _joint_msgs(ts, T, names=shuffled, velocity=False, ros=1, zero_stamp=True)
    _, gripper = _joint_msgs(ts, T[:10] + 0.005, names=["panda_finger_joint1"], ros=1)
    bag = _write(tmp_path / "b.bag", 1, {"/joint_states": ("sensor_msgs/msg/JointState", joints + gripper),
                                         "/su1/imu": _imu_msgs(ts, T, UP_G * STANDARD_GRAVITY, ros=1)})
    ds, report = read_bag(bag, "panda")
    notes = " | ".join(report.notes)
    assert "skipped 10 message(s) without the robot's joints" in notes
    assert "header.stamp is zero" in notes and "central differences" in notes
    assert "accelerometer in g" not in notes  # m/s^2 stays as is
    np.testing.assert_allclose(ds.imu["su1"].accel[:, 2], STANDARD_GRAVITY)
    t = ds.joints.t
    j = np.arange(7)
    np.testing.assert_allclose(ds.joints.q, 0.1 * np.sin(t[:, None] + j), atol=1e-12)
    inner = slice(1, -1)  # central differences: error h^2/6 max|q'''| = 1.7e-6 rad/s
    np.testing.assert_allclose(ds.joints.qd[inner], 0.1 * np.cos(t[inner, None] + j), atol=3e-6)


def test_range_and_laserscan_to_tof(tmp_path):
    ts = _store(2)
    R, S = ts.types["sensor_msgs/msg/Range"], ts.types["sensor_msgs/msg/LaserScan"]
    values = [0.5, np.inf, 5.0, np.nan, 0.7]
    rng_msgs = [(T0_NS + k * 10**7, R(header=_header(ts, T0_NS + k * 10**7, "tof_a"), radiation_type=1,
                                       field_of_view=0.47, min_range=0.01, max_range=4.0, range=v))
                for k, v in enumerate(values)]
    beams = [[0.9, 0.4, np.inf], [np.inf, np.inf, np.inf], [0.005, 2.0, 3.0]]
    scan_msgs = [(T0_NS + k * 10**7, S(header=_header(ts, T0_NS + k * 10**7, "other"), angle_min=-0.1, angle_max=0.1,
                                       angle_increment=0.1, time_increment=0.0, scan_time=0.0, range_min=0.01,
                                       range_max=4.0, ranges=np.array(b, np.float32),
                                       intensities=np.zeros(0, np.float32)))
                 for k, b in enumerate(beams)]
    bag = _write(tmp_path / "b", 2, {
        "/joint_states": _joint_msgs(ts, T), "/skin/a/imu": _imu_msgs(ts, T, UP_G, frame="a"),
        "/skin/b/imu": _imu_msgs(ts, T, UP_G, frame="b"), "/skin/a/range": ("sensor_msgs/msg/Range", rng_msgs),
        "/scanner": ("sensor_msgs/msg/LaserScan", scan_msgs)})
    ds, report = read_bag(bag, "panda", tmap=topic_map(range_=["/skin/a/range", "/scanner=b"]))
    assert report.range_topics == {"/skin/a/range": "a", "/scanner": "b"}  # namespace match, explicit name
    np.testing.assert_allclose(ds.tof["a"].range, [0.5, np.nan, np.nan, 0.7], equal_nan=True)  # NaN reading dropped
    np.testing.assert_allclose(ds.tof["a"].t, [0.0, 0.01, 0.02, 0.04], atol=1e-9)
    np.testing.assert_allclose(ds.tof["b"].range, [0.4, np.nan, 2.0], equal_nan=True)
    assert "/skin/a/range: dropped 1 sample(s) containing NaN" in report.notes


def test_cli_import(small, tmp_path, capsys):
    sim = small
    write_bag(sim, tmp_path / "b.bag", ros_version=1)
    assert main(["import", str(tmp_path / "b.bag"), "--robot", "panda", "--out", str(tmp_path / "d.h5")]) == 0
    captured = capsys.readouterr()
    out = captured.out
    assert captured.err == ""  # the progress bar is transient and on stderr: nothing left in a log
    assert "segments found" in out and "multi-joint motion" in out
    ds = read_dataset(tmp_path / "d.h5")
    assert ds.segments is not None and len(ds.segments) > 0 and ds.units == sim.units
    ts = _store(1)
    _write(tmp_path / "nj.bag", 1, {"/su1/imu": _imu_msgs(ts, T, UP_G, ros=1)})
    assert main(["import", str(tmp_path / "nj.bag"), "--out", str(tmp_path / "x.h5")]) == 0  # IMU-only (issue 18)
    assert "no sensor_msgs/JointState topic: an IMU-only dataset" in " ".join(capsys.readouterr().out.split())
    assert read_dataset(tmp_path / "x.h5").joints is None
    assert main(["import", str(tmp_path / "nj.bag"), "--joint-topic", "/js", "--out", str(tmp_path / "y.h5")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "joint state topic '/js' is not in the bag" in err and "\n" not in err
    assert not (tmp_path / "y.h5").exists()


@pytest.mark.parametrize("ros,storage", [(1, "sqlite3"), (2, "mcap")])
def test_progress_counts_the_messages_read(small, tmp_path, ros, storage):
    """``progress(read, total)``: starts at 0, every PROGRESS_EVERY messages, ends at total; the
    total is the messages of the selected topics only (from the bag's index)."""
    bag = tmp_path / ("b.bag" if ros == 1 else "b")
    write_bag(small, bag, ros_version=ros, storage=storage)
    calls: list[tuple[int, int]] = []
    _, report = read_bag(bag, "panda", progress=lambda done, total: calls.append((done, total)))
    total = sum(report.counts.values())
    assert total > 2 * PROGRESS_EVERY  # the bag is long enough for intermediate calls
    assert calls[0] == (0, total) and calls[-1] == (total, total)
    assert [c[0] for c in calls[1:-1]] == list(range(PROGRESS_EVERY, total, PROGRESS_EVERY))
    assert all(t == total for _, t in calls)
    unit = small.units[0]
    calls.clear()
    _, one = read_bag(bag, "panda", topic_map([f"/skin/{unit}/imu"], "/joint_states"),
                      progress=lambda done, total: calls.append((done, total)))
    assert one.counts["/joint_states"] == len(small.joints.t) and one.counts[f"/skin/{unit}/imu"] == len(
        small.imu[unit].t)
    selected = sum(one.counts.values())  # joints, one IMU and the (automatically selected) range topics
    assert calls[0] == (0, selected) and calls[-1] == (selected, selected) and selected < total


# ---------------------------------------------------------------- robot, joint names, shared IMU topics
def _thin(ds, k: int = 10):
    """``ds`` with every ``k``-th joint state (bags of 1 kHz joints are slow to write in a test)."""
    js = ds.joints
    return replace(ds, joints=JointStates(js.t[::k], js.q[::k], js.qd[::k]))


@pytest.fixture(scope="module")
def ur5_urdf_session():
    """Two units on the registry UR5 (a URDF chain: joint names and source text from the file)."""
    chain = get_robot(str(registry_urdf("ur5")))
    return _thin(simulate_dataset(chain, "random", 2, "none", "fast", seed=1))


@pytest.mark.parametrize("ros", [1, 2])
def test_robot_from_the_bags_robot_description(ur5_urdf_session, tmp_path, ros):
    """No robot given: the URDF on /robot_description (latched std_msgs/String) is the robot, its
    joint names find the joints; with a robot given, the description is left alone (noted)."""
    sim = ur5_urdf_session
    bag = tmp_path / ("b.bag" if ros == 1 else "b")
    write_bag(sim, bag, ros_version=ros, robot_description=sim.robot.source)
    ds, report = read_bag(bag)
    assert report.robot == "ur5" and report.robot_source == ROBOT_DESCRIPTION
    assert ds.robot.convention == "urdf" and ds.robot.source == sim.robot.source
    assert ds.robot.joint_names == sim.robot.joint_names == UR_JOINT_NAMES
    np.testing.assert_array_equal(ds.joints.q, sim.joints.q)
    np.testing.assert_allclose(ds.robot.link_frames(sim.joints.q[:50]), sim.robot.link_frames(sim.joints.q[:50]))
    assert any("robot 'ur5' from /robot_description: 6 joints world -> wrist_3_link" in n for n in report.notes)
    # a tip link picks a shorter chain out of the description
    short, rep = read_bag(bag, tip_link="forearm_link")
    assert short.robot.n_joints == 3 and rep.robot_source == ROBOT_DESCRIPTION
    np.testing.assert_array_equal(short.joints.q, sim.joints.q[:, :3])
    # a robot given wins over the bag's description
    ds2, report2 = read_bag(bag, "ur5")
    assert ds2.robot.convention == "standard" and report2.robot_source == "ur5"
    assert "/robot_description in the bag not used (robot given: ur5)" in report2.notes


def test_robot_description_that_is_not_urdf_is_one_line_error(small, tmp_path):
    write_bag(small, tmp_path / "b", robot_description="<robot name='x'><link name='a'/>")
    with pytest.raises(DatasetError, match=r"/robot_description: .*") as info:
        read_bag(tmp_path / "b")
    assert "\n" not in str(info.value)


def test_no_robot_and_no_description_asks_for_robot(small, tmp_path, capsys):
    """Issue 27: a bag without /robot_description became a Panda, said only in a note."""
    write_bag(small, tmp_path / "b")  # a real ROS 2 bag (rosbags), the Panda's joint names, no description
    with pytest.raises(ConfigError, match=r"b has no /robot_description: give the robot with --robot .*; its joint "
                       r"names are those of 'panda': e.g. --robot panda$") as info:  # fmt: skip
        read_bag(tmp_path / "b")
    assert "\n" not in str(info.value)
    with pytest.raises(ConfigError, match="--base-link/--tip-link need a URDF"):
        read_bag(tmp_path / "b", tip_link="panda_link5")
    ds, report = read_bag(tmp_path / "b", "panda")  # named: read as before
    assert ds.robot.name == "panda" and report.robot_source == "panda"
    capsys.readouterr()
    out = tmp_path / "d.h5"
    assert main(["import", str(tmp_path / "b"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and "--robot" in err, err
    assert not out.exists()


PRESET_JOINTS = {
    "panda": PANDA_JOINTS,
    "ur5e": list(UR_JOINT_NAMES),
    "ur10e": [f"ur_{n}" for n in UR_JOINT_NAMES],  # a tf_prefix: matched as a suffix
    "xarm7": [f"joint{i}" for i in range(1, 8)],
    "iiwa14": [f"lbr_A{i}" for i in range(1, 8)],  # lbr_fri_ros2_stack's default robot_name
    "sawyer": [f"right_j{i}" for i in range(7)],
}


def _named_joint_msgs(ts, t: np.ndarray, names: list[str], ros: int):
    """JointState with joint ``k`` of ``names`` at ``q = 0.1 k + 0.01 t`` (in the message order given)."""
    out = []
    for tk in t:
        ns = T0_NS + round(tk * 1e9)
        q = np.array([0.1 * k + 0.01 * tk for k in range(len(names))])
        out.append((ns, ts.types["sensor_msgs/msg/JointState"](
            header=_header(ts, ns, "", ros), name=list(names), position=q, velocity=np.full(len(names), 0.01),
            effort=np.zeros(0))))  # fmt: skip
    return "sensor_msgs/msg/JointState", out


@pytest.mark.parametrize("robot", sorted(PRESET_JOINTS))
@pytest.mark.parametrize("ros", [1, 2])
def test_preset_joint_names_found_in_any_order_among_extra_joints(tmp_path, robot, ros):
    """The drivers' own names, shuffled, with two gripper fingers in between: each joint by name."""
    ts = _store(ros)
    own = PRESET_JOINTS[robot]
    rng = np.random.default_rng(3)
    names = [*own, "gripper_finger_joint1", "gripper_finger_joint2"]
    names = [names[i] for i in rng.permutation(len(names))]
    topics = {"/joint_states": _named_joint_msgs(ts, T, names, ros), "/su1/imu": _imu_msgs(ts, T, UP_G, ros=ros)}
    bag = _write(tmp_path / ("b.bag" if ros == 1 else "b"), ros, topics)
    ds, _ = read_bag(bag, robot)
    column = [names.index(n) for n in own]  # where each robot joint sits in the message
    np.testing.assert_allclose(ds.joints.q, 0.1 * np.array(column) + 0.01 * ds.joints.t[:, None], atol=1e-12)


@pytest.mark.parametrize("ros", [1, 2])
def test_missing_joint_is_one_line_error_naming_it(tmp_path, ros, capsys):
    ts = _store(ros)
    bag = _write(tmp_path / ("b.bag" if ros == 1 else "b"), ros, {
        "/joint_states": _named_joint_msgs(ts, T, [*PANDA_JOINTS[:6], "panda_finger_joint1"], ros),
        "/su1/imu": _imu_msgs(ts, T, UP_G, ros=ros)})  # fmt: skip
    with pytest.raises(DatasetError, match=r"topic /joint_states: joint panda_joint7 of robot 'panda' missing") as e:
        read_bag(bag, "panda")
    assert "\n" not in str(e.value)
    out = tmp_path / "d.h5"
    assert main(["import", str(bag), "--robot", "panda", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "joint panda_joint7" in err and err.count("\n") == 1
    assert not out.exists()


def test_joint_matching_several_names_is_refused(tmp_path):
    ts = _store(2)
    names = ["left_joint1", "right_joint1", *[f"joint{i}" for i in range(2, 8)]]
    bag = _write(tmp_path / "b", 2, {"/joint_states": _named_joint_msgs(ts, T, names, 2),
                                     "/su1/imu": _imu_msgs(ts, T, UP_G)})  # fmt: skip
    with pytest.raises(DatasetError, match=r"joint 'joint1' matches several names .*left_joint1, right_joint1"):
        read_bag(bag, "xarm7")


@pytest.mark.parametrize("ros,storage", [(1, "sqlite3"), (2, "sqlite3"), (2, "mcap")])
def test_shared_imu_topic_becomes_one_unit_per_frame_id(small, tmp_path, ros, storage):
    """Every unit's Imu on /skin/imu, told apart by header.frame_id: the same units and samples as
    one topic per unit."""
    shared, own = tmp_path / ("s.bag" if ros == 1 else "s"), tmp_path / ("o.bag" if ros == 1 else "o")
    write_bag(small, shared, ros_version=ros, storage=storage, imu_topic="/skin/imu")
    write_bag(small, own, ros_version=ros, storage=storage)
    ds, report = read_bag(shared, "panda")
    ref, _ = read_bag(own, "panda")
    assert ds.units == ref.units == small.units
    assert report.imu_topics == {f"/skin/imu {u}": u for u in small.units}
    assert any(n.startswith("/skin/imu: 3 frame_ids (") for n in report.notes)
    for u in small.units:
        np.testing.assert_array_equal(ds.imu[u].t, ref.imu[u].t)
        np.testing.assert_array_equal(ds.imu[u].accel, ref.imu[u].accel)
        np.testing.assert_array_equal(ds.imu[u].gyro, ref.imu[u].gyro)
    assert set(ds.tof) == set(small.tof)  # the Range topics find their units by frame_id
    with pytest.raises(DatasetError, match=r"/skin/imu carries 3 frame_ids .* a single unit name 'u' cannot"):
        read_bag(shared, "panda", topic_map(imu=["/skin/imu=u"]))


@pytest.mark.adversarial
def test_frame_id_that_is_not_a_valid_unit_name_is_refused(tmp_path):
    ts = _store(2)
    _, a = _imu_msgs(ts, T, UP_G, frame="good")
    _, b = _imu_msgs(ts, T + 0.005, UP_G, frame="bad\x1b[31m")
    bag = _write(tmp_path / "b", 2, {"/joint_states": _joint_msgs(ts, T), "/imu": ("sensor_msgs/msg/Imu", a + b)})
    with pytest.raises(DatasetError, match=r"unit name 'bad\\x1b\[31m' \(from the frame_id\) contains") as info:
        read_bag(bag, "panda")
    assert "\x1b" not in str(info.value)


def _tilted(t: np.ndarray, angle: float) -> np.ndarray:
    """Gravity in g seen by a unit tilted by ``angle`` about x."""
    return np.tile([0.0, np.sin(angle), np.cos(angle)], (len(t), 1))


@pytest.mark.adversarial
@pytest.mark.parametrize("ros", [1, 2])
def test_two_imus_interleaved_under_one_frame_id_are_refused(tmp_path, ros):
    """Two IMUs publishing on one topic with the same frame_id: never merged into one unit."""
    ts = _store(ros)
    _, a = _imu_msgs(ts, T, _tilted(T, 0.0), frame="imu_link", ros=ros)
    # the same instants (synchronised sampling): every stamp comes twice
    _, b = _imu_msgs(ts, T, _tilted(T, 1.2), frame="imu_link", ros=ros)
    joints = _joint_msgs(ts, T, ros=ros)
    same = _write(tmp_path / ("s.bag" if ros == 1 else "s"), ros,
                  {"/joint_states": joints, "/imu": ("sensor_msgs/msg/Imu", a + b)})  # fmt: skip
    # (repeated stamps alone are a coarse clock; the alternating samples give the two sources away)
    with pytest.raises(DatasetError, match=r"/imu: \d+ of \d+ samples jump away from both neighbours: samples of "
                       "several sources interleaved") as info:  # fmt: skip
        read_bag(same, "panda")
    assert "\n" not in str(info.value)
    # offset instants: stamps increase, the samples alternate between the two orientations
    _, c = _imu_msgs(ts, T + 0.005, _tilted(T, 1.2), frame="imu_link", ros=ros)
    offset = _write(tmp_path / ("o.bag" if ros == 1 else "o"), ros,
                    {"/joint_states": joints, "/imu": ("sensor_msgs/msg/Imu", sorted(a + c, key=lambda m: m[0]))})
    with pytest.raises(DatasetError, match=r"/imu: \d+ of \d+ samples jump away from both neighbours"):
        read_bag(offset, "panda")


def test_coarse_stamps_that_repeat_often_are_not_taken_for_two_sources(tmp_path):
    """A driver whose clock ticks slower than its samples repeats half the stamps: one source, not two."""
    ts = _store(2)
    rng = np.random.default_rng(6)
    accel = UP_G + 0.02 * rng.standard_normal(UP_G.shape)
    coarse = np.repeat(T[::2], 2)  # every stamp twice
    _, msgs = _imu_msgs(ts, coarse, accel)
    bag = _write(tmp_path / "c", 2, {"/joint_states": _joint_msgs(ts, T), "/su1/imu": ("sensor_msgs/msg/Imu", msgs)})
    ds, _ = read_bag(bag, "panda")
    assert list(ds.imu) == ["su1"]


def test_one_imu_with_a_few_repeated_stamps_and_noise_is_not_refused(tmp_path):
    """One source: a repeated stamp now and then (a driver re-publishing) is dropped with a count, and
    white noise or a single outlier is no sign of a second source."""
    ts = _store(2)
    rng = np.random.default_rng(5)
    accel = UP_G + 0.02 * rng.standard_normal(UP_G.shape)
    accel[100] = [0.0, 0.8, 0.6]  # one knock
    _, msgs = _imu_msgs(ts, T, accel)
    msgs = msgs[:50] + [msgs[49]] + msgs[50:]
    bag = _write(tmp_path / "b", 2, {"/joint_states": _joint_msgs(ts, T), "/su1/imu": ("sensor_msgs/msg/Imu", msgs)})
    ds, report = read_bag(bag, "panda")
    assert "/su1/imu: dropped 1 message(s) with a repeated time stamp" in report.notes
    assert len(ds.imu["su1"].t) == len(T)


def test_cli_import_robot_urdf_and_robot_description(ur5_urdf_session, tmp_path, capsys):
    """`skincal import --robot ur5.urdf` (a registry URDF): the dataset holds the URDF chain; without
    --robot the bag's /robot_description is used."""
    sim = ur5_urdf_session
    urdf = registry_urdf("ur5")
    write_bag(replace(sim, robot=get_robot("ur5")), tmp_path / "plain.bag", ros_version=1)  # the preset's names
    out = tmp_path / "a.h5"
    assert main(["import", str(tmp_path / "plain.bag"), "--robot", str(urdf), "--tip-link", "wrist_3_link",
                 "--no-segment", "--out", str(out)]) == 0  # fmt: skip
    text = capsys.readouterr().out.replace("\n", "")  # rich wraps long lines
    assert f"robot ur5 ({urdf})" in text
    ds = read_dataset(out)
    assert ds.robot.convention == "urdf" and ds.robot.joint_names == UR_JOINT_NAMES
    assert ds.robot.source == urdf.read_text()
    np.testing.assert_array_equal(ds.joints.q, sim.joints.q)
    write_bag(sim, tmp_path / "desc", robot_description=sim.robot.source)
    assert main(["import", str(tmp_path / "desc"), "--no-segment", "--out", str(tmp_path / "b.h5")]) == 0
    assert "robot ur5 (/robot_description)" in capsys.readouterr().out.replace("\n", "")
    assert read_dataset(tmp_path / "b.h5").robot.source == sim.robot.source
    assert main(["import", str(tmp_path / "desc"), "--robot", "panda", "--base-link", "x", "--out",
                 str(tmp_path / "c.h5")]) == 2  # fmt: skip
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "--base-link and --tip-link apply to a URDF robot only" in err


@pytest.mark.parametrize(("text", "message"), [
    ("imu:\n  /skin/a/imu: 3\n", "'imu' entry 3 is a int, not a unit name; quote it"),
    ("imu:\n  - 3\n", "'imu' entry 3 is a int, not a topic"),
    ("range:\n  /skin/a/range: yes\n", "'range' entry True is a bool, not a unit name"),
    ("joints: 7\n", "'joints' must be the joint-state topic, got 7"),
    ("joint_names: [1, 2]\n", "'joint_names' must be a list of the robot's joint names"),
])
def test_a_topic_map_entry_that_yaml_reads_as_a_number_is_refused(tmp_path, text, message):
    """``/skin/a/imu: 3`` became a unit named "3" (YAML reads 3 as a number): a name is never made from one."""
    path = tmp_path / "map.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=f"^{path}: .*") as info:
        topic_map(path=path)
    assert message in str(info.value) and "\n" not in str(info.value)
    path.write_text("imu:\n  /skin/a/imu: '3'\njoints: /joint_states\njoint_names: [j1, j2]\n")  # quoted: fine
    tmap = topic_map(path=path)
    assert tmap.imu == {"/skin/a/imu": "3"} and tmap.joints == "/joint_states" and tmap.joint_names == ("j1", "j2")
