"""``skincal protocol``: the calibration motion written for a robot controller (CSV, JSON, ROS YAML)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from cli_subprocess import one_line_error, run_cli

from skincal.cli import main
from skincal.kinematics import get_robot
from skincal.protocol import read_trajectory_csv, read_trajectory_json
from skincal.protocol.collision import CollisionModel

from registry_robots import registry_urdf


def _run(capsys, *args: str) -> tuple[int, str, str]:
    code = main(["protocol", *args])
    out, err = capsys.readouterr()
    return code, out, err


def test_yaml_is_a_joint_trajectory_message(tmp_path, capsys):
    """ROS JointTrajectory fields: joint names from the URDF, one point per 1/rate s with positions,
    velocities, accelerations, time_from_start {sec, nanosec}; the motion is within the limits and
    collision-free, and it starts and ends at rest."""
    path = registry_urdf("panda")
    out = tmp_path / "motion.yaml"
    code, text, _ = _run(capsys, "--robot", str(path), "--protocol", "fast", "--rate", "20", "--out", str(out))
    assert code == 0 and "wrote" in text
    msg = yaml.load(out.read_text(), Loader=yaml.CSafeLoader)
    assert set(msg) == {"header", "joint_names", "points"}
    assert msg["joint_names"] == [f"panda_joint{i}" for i in range(1, 8)]
    points = msg["points"]
    assert set(points[0]) == {"positions", "velocities", "accelerations", "effort", "time_from_start"}
    t = np.array([p["time_from_start"]["sec"] + 1e-9 * p["time_from_start"]["nanosec"] for p in points])
    assert all(0 <= p["time_from_start"]["nanosec"] < 1_000_000_000 for p in points)
    np.testing.assert_allclose(np.diff(t), 0.05, atol=1e-9)
    q = np.array([p["positions"] for p in points])
    qd = np.array([p["velocities"] for p in points])
    qdd = np.array([p["accelerations"] for p in points])
    assert q.shape == qd.shape == qdd.shape == (len(points), 7)
    chain = get_robot(str(path))
    assert np.all(q >= chain.joint_lower) and np.all(q <= chain.joint_upper)
    assert np.all(np.abs(qd) <= chain.velocity_limit)
    assert np.all(CollisionModel(chain).free(q))
    assert np.all(qd[[0, -1]] == 0)
    assert t[-1] > 60  # the whole fast protocol (~80 s), not a part


def test_csv_and_json_agree_and_json_carries_the_segments(tmp_path, capsys):
    csv, js = tmp_path / "m.csv", tmp_path / "m.json"
    assert _run(capsys, "--robot", "ur5e", "--seed", "3", "--out", str(csv))[0] == 0
    assert _run(capsys, "--robot", "ur5e", "--seed", "3", "--out", str(js))[0] == 0
    t, q, qd = read_trajectory_csv(csv)
    np.testing.assert_allclose(np.diff(t), 0.01, atol=1e-12)  # default --rate 100 Hz
    traj = read_trajectory_json(js)
    np.testing.assert_allclose(traj.q, q, atol=1e-12)  # the JSON's definition rebuilds the CSV stream
    doc = json.loads(js.read_text())
    assert doc["rate_hz"] == 100.0 and len(doc["joint_names"]) == 6
    assert doc["config"]["collision_check"] is True
    seg = doc["segments"]
    assert len(seg["t_start"]) == 6 * 7 and sorted(set(seg["kind"])) == [0, 1]  # 6 static + 36 dynamic


def test_seed_changes_poses_and_same_seed_repeats(tmp_path, capsys):
    a, b, c = (tmp_path / f"{k}.csv" for k in "abc")
    for path, seed in ((a, "1"), (b, "1"), (c, "2")):
        assert _run(capsys, "--robot", "xarm7", "--seed", seed, "--out", str(path))[0] == 0
    assert a.read_bytes() == b.read_bytes()
    assert a.read_bytes() != c.read_bytes()


def test_refuses_existing_out_without_force(tmp_path, capsys):
    out = tmp_path / "m.csv"
    out.write_text("keep me")
    code, _, err = _run(capsys, "--robot", "panda", "--out", str(out))
    assert code == 2 and err.count("\n") == 1 and "--force" in err
    assert out.read_text() == "keep me"
    assert _run(capsys, "--robot", "panda", "--out", str(out), "--force")[0] == 0
    assert out.read_text().startswith("t,q1,")


@pytest.mark.adversarial
@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--robot", "no-such-robot"], "unknown robot 'no-such-robot'"),
        (["--robot", "panda", "--protocol", "slow"], "unknown protocol 'slow'"),
        (["--robot", "panda", "--rate", "0"], "--rate must be a sample rate of 10 to 10000 Hz"),
        (["--robot", "panda", "--rate", "nan"], "--rate must be a sample rate of 10 to 10000 Hz"),
        (["--robot", "panda", "--poses", "best"], "--poses must be one of uniform, diverse"),
    ],
)
def test_bad_input_is_one_line_exit_2(tmp_path, capsys, args, message):
    out = tmp_path / "m.yaml"
    code, _, err = _run(capsys, *args, "--out", str(out))
    assert code == 2
    assert err.startswith("error: ") and err.count("\n") == 1 and message in err
    assert not out.exists() and list(tmp_path.iterdir()) == []


@pytest.mark.adversarial
def test_unknown_suffix_is_refused_before_any_work(tmp_path, capsys):
    code, _, err = _run(capsys, "--robot", "panda", "--out", str(tmp_path / "m.txt"))
    assert code == 2 and "use .csv, .json, .yaml, .bag" in err and err.count("\n") == 1


@pytest.mark.parametrize("name", ["motion.bag", "motion_bag"])
def test_bags_hold_one_joint_trajectory(tmp_path, capsys, name):
    """A ROS 1 .bag file or a new ROS 2 bag folder (no suffix): one JointTrajectory on /joint_trajectory
    that the rosbags reader deserialises to the same points as the YAML; an existing bag folder is
    refused in one line."""
    from rosbags.highlevel import AnyReader

    out, ref = tmp_path / name, tmp_path / "ref.yaml"
    assert _run(capsys, "--robot", "panda", "--rate", "10", "--out", str(out))[0] == 0
    assert _run(capsys, "--robot", "panda", "--rate", "10", "--out", str(ref))[0] == 0
    with AnyReader([out]) as reader:
        (conn,) = reader.connections
        assert conn.topic == "/joint_trajectory" and conn.msgtype == "trajectory_msgs/msg/JointTrajectory"
        (msg,) = [reader.deserialize(raw, conn.msgtype) for _, _, raw in reader.messages()]
    expect = yaml.load(ref.read_text(), Loader=yaml.CSafeLoader)
    assert list(msg.joint_names) == expect["joint_names"]
    assert len(msg.points) == len(expect["points"])
    np.testing.assert_array_equal([p.positions for p in msg.points], [p["positions"] for p in expect["points"]])
    last = msg.points[-1].time_from_start
    assert (last.sec, last.nanosec) == tuple(expect["points"][-1]["time_from_start"].values())
    if out.suffix == "":
        code, _, err = _run(capsys, "--robot", "panda", "--out", str(out), "--force")
        assert code == 2 and err.count("\n") == 1 and "folder" in err
    assert [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")] == []


# --out onto what exists


@pytest.mark.adversarial
@pytest.mark.parametrize("force", [[], ["--force"]])
def test_an_existing_bag_folder_is_named_as_such_and_kept(tmp_path, capsys, force):
    """It used to say "is a folder; give a file name", though a folder is what a ROS 2 bag is."""
    out = tmp_path / "motion"
    out.mkdir()
    (out / "keep.db3").write_bytes(b"mine")
    code = main(["protocol", "--robot", "panda", "--rate", "10", "--out", str(out), *force])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert "exists; a ROS 2 bag folder is never overwritten" in err
    assert [p.name for p in out.iterdir()] == ["keep.db3"] and (out / "keep.db3").read_bytes() == b"mine"


@pytest.mark.adversarial
def test_an_existing_dataset_is_not_a_protocol_output(tmp_path, capsys):
    data = tmp_path / "data.h5"
    data.write_bytes(b"dataset")
    code = main(["protocol", "--robot", "panda", "--out", str(data), "--force"])
    assert code == 2 and "unknown trajectory format '.h5'" in capsys.readouterr().err
    assert data.read_bytes() == b"dataset"


# --adaptive --force


@pytest.mark.adversarial
def test_adaptive_force_leaves_no_segment_of_an_earlier_run(tmp_path: Path) -> None:
    """``protocol --adaptive --force`` overwrote segments 1..k of an earlier run and left its k+1.. beside
    them: a robot executing the files in order ran stale motion. The earlier run's segments go first."""
    stale = [tmp_path / f"m_{k:03d}.json" for k in (1, 2, 7)]
    for path in stale:
        path.write_text("stale")
    keep = tmp_path / "m_notes.json"
    keep.write_text("user file")
    proc = run_cli(["protocol", "--robot", "panda", "--adaptive", "--simulate", "--out", "m.json", "--max-motion",
                 "0.001", "--force"], tmp_path)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    segments = sorted(p.name for p in tmp_path.glob("m_[0-9][0-9][0-9].json"))
    assert segments == ["m_001.json"], segments
    assert (tmp_path / "m_001.json").read_text() != "stale"
    assert keep.read_text() == "user file"
    assert "inf mm" not in proc.stdout


@pytest.mark.adversarial
def test_adaptive_force_refuses_a_folder_named_like_a_segment(tmp_path: Path) -> None:
    (tmp_path / "m_001.json").mkdir()
    line = one_line_error(run_cli(["protocol", "--robot", "panda", "--adaptive", "--simulate", "--out", "m.json",
                                 "--max-motion", "0.001", "--force"], tmp_path))  # fmt: skip
    assert "m_001.json" in line
    assert (tmp_path / "m_001.json").is_dir()


def test_imu_range_fits_the_motion_to_the_imus(tmp_path, capsys):
    """``--imu-range`` (issue 27): SO-101's fast motion at +-2 g / +-245 deg/s keeps every joint speed
    below the gyroscope's range and says what it changed; a malformed range is a one-line error."""
    from skincal.protocol.imu_range import ImuRange, imu_bounds

    path = registry_urdf("so101")
    out = tmp_path / "motion.json"
    code, text, _ = _run(capsys, "--robot", str(path), "--imu-range", "2g,245dps", "--out", str(out))
    assert code == 0, text
    assert "95% of the gyroscope's range" in text
    traj = read_trajectory_json(out)
    assert np.max(np.abs(traj.qd)) <= 0.95 * np.radians(245) + 1e-9  # 9 rad/s without the range
    chain = get_robot(str(path))
    assert not imu_bounds(chain, traj).exceeds(ImuRange.parse("2g,245dps"), 0.951)
    for bad, message in (("2g", "--imu-range must be ACCEL,GYRO"), ("0.5g,245dps", "needs more than 1 g")):
        code, _, err = _run(capsys, "--robot", "panda", "--imu-range", bad, "--out", str(tmp_path / "x.json"))
        assert code == 2 and message in err, err
        assert not (tmp_path / "x.json").exists()


def test_floor_can_be_moved_or_switched_off_for_an_arm_not_on_the_floor(tmp_path, capsys):
    """Issue 27: TALOS's arm hangs from its shoulder (the chain's base): below z = 0 of it in every pose, so
    the floor check found no pose. ``--floor none`` (or a floor below the hand) gives the motion, stored in its
    JSON; the refusal says how."""
    from skincal.protocol.collision import CollisionModel

    from registry_robots import robots_dir

    arm = str(robots_dir() / "talos_data/robots/talos_left_arm.urdf")
    out = tmp_path / "talos.json"
    code, _, err = _run(capsys, "--robot", arm, "--out", str(out))
    assert code == 2 and "no collision-free static pose" in err and "--floor moves it" in err
    assert not out.exists()
    for floor, stored in (("none", None), ("-1.5", -1.5)):
        code, text, err = _run(capsys, "--robot", arm, "--floor", floor, "--out", str(out), "--force")
        assert code == 0, err
        doc = json.loads(out.read_text())
        assert doc["config"]["floor_z"] == stored
        traj = read_trajectory_json(out)
        assert CollisionModel(get_robot(arm), floor_z=stored).free(traj.q[::20]).all()
    code, _, err = _run(capsys, "--robot", "panda", "--floor", "low", "--out", str(tmp_path / "x.json"))
    assert code == 2 and "--floor must be a height in m or none" in err
    code, _, err = _run(capsys, "--robot", "panda", "--floor", "nan", "--out", str(tmp_path / "x.json"))
    assert code == 2 and "floor_z must be a height" in err
