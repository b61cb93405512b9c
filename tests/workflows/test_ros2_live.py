"""``skincal ros2-play`` and ``skincal ros2`` on real DDS (loopback only, multicast off, a random domain
per test), each in its own process, with this test process as the third participant: it listens to
``/tf_static`` and ``/diagnostics`` and sends hostile messages (malformed, oversized, an unknown topic).
The live result is compared with the batch ``mle`` calibration of the same (simulated) data."""

from __future__ import annotations

import dataclasses
import json
import os
import random
import subprocess
import sys
import time

import numpy as np
import pytest

pytest.importorskip("cyclonedds")

from skincal.data.ros2 import messages as m  # noqa: E402
from skincal.data.ros2 import qos  # noqa: E402
from skincal.data.ros2.participant import join  # noqa: E402

CLI = [sys.executable, "-c", "import sys; from skincal.cli import main; sys.exit(main(sys.argv[1:]))"]
UNITS = ("su4", "su5", "su6")


def fresh_domain() -> int:
    """A domain id no other test of this run uses (random: other test runs on the machine too)."""
    return random.Random(os.getpid() * 1_000_003 + time.time_ns()).randint(1, 200)


@pytest.fixture(scope="module")
def short(tmp_path_factory):
    """40 s of the fast protocol on panda, three units (realistic IMUs, controller joint states), and its
    batch ``mle`` result."""
    from skincal.calib import calibrate
    from skincal.data.hdf5 import write_dataset
    from skincal.workflows.monitoring import crop
    from skincal.workflows.session import simulate_dataset

    ds = crop(simulate_dataset("panda", "paper", noise="realistic", protocol="fast", seed=1), 0.0, 40.0)
    pick = lambda d: {u: v for u, v in d.items() if u in UNITS}  # noqa: E731
    ds = dataclasses.replace(ds, imu=pick(ds.imu), truth=pick(ds.truth), truth_sensor=pick(ds.truth_sensor))
    path = tmp_path_factory.mktemp("ros2") / "short.h5"
    write_dataset(ds, path)
    return path, ds, calibrate(ds, "mle")


def _reader(p, topic: str, kind, profile):
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    return DataReader(p.participant, Topic(p.participant, m.dds_topic(topic), kind), profile)


def _writer(p, topic: str, kind, profile):
    from cyclonedds.pub import DataWriter
    from cyclonedds.topic import Topic

    return DataWriter(p.participant, Topic(p.participant, m.dds_topic(topic), kind), profile)


def test_live_calibration_of_a_played_session_publishes_the_result_it_writes(short, tmp_path):
    from skincal.data.result import read_result
    from skincal.data.ros import read_bag
    from skincal.kinematics.transforms import matrix_from_quat_wxyz, rotation_angle
    from tests.registry_robots import registry_urdf

    path, ds, batch = short
    domain = fresh_domain()
    env = {**os.environ, "ROS_DOMAIN_ID": str(domain), "COLUMNS": "200"}
    me = join(domain)  # the third participant
    tf = _reader(me, "/tf_static", m.TFMessage, qos.tf_static_listener())
    diag = _reader(me, "/diagnostics", m.DiagnosticArray, qos.default(100))
    bad_joints = _writer(me, "/joint_states", m.JointState, qos.sensor_data())
    bad_imu = _writer(me, "/skin/bad/imu", m.Imu, qos.sensor_data())
    chatter = _writer(me, "/chatter", m.String, qos.default())
    out, bag = tmp_path / "live.json", tmp_path / "bag"
    live = subprocess.Popen([*CLI, "ros2", "--result", str(out), "--record", str(bag), "--idle", "1.5",
                             "--imu-topic", "/skin/*/imu"], cwd=tmp_path, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip
    play = subprocess.Popen([*CLI, "ros2-play", str(path), "--rate", "16", "--domain", str(domain),
                             "--robot-description", str(registry_urdf("panda"))], cwd=tmp_path, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    tf_messages, diagnostics, hostile_sent = [], [], False
    deadline = time.monotonic() + 60
    while live.poll() is None and time.monotonic() < deadline:
        if not hostile_sent and bad_imu.get_publication_matched_status().current_count > 0 \
                and bad_joints.get_publication_matched_status().current_count > 0:  # fmt: skip
            bad_joints.write(m.JointState(name=["a", "b"], position=[1.0], velocity=[], effort=[]))  # 2 names, 1 value
            bad_imu.write(m.Imu(header=m.Header(frame_id="x" * 5000)))  # beyond the 4 kB an Imu may have
            chatter.write(m.String(data="hello"))
            hostile_sent = True
        tf_messages += [x for x in tf.take(N=100) if isinstance(x, m.TFMessage)]  # (not the writer's end)
        diagnostics += [x for x in diag.take(N=100) if isinstance(x, m.DiagnosticArray)]
        time.sleep(0.05)
    play_out, play_err = play.communicate(timeout=30)
    live_out, live_err = live.communicate(timeout=30)
    tf_messages += [x for x in tf.take(N=100) if isinstance(x, m.TFMessage)]
    diagnostics += [x for x in diag.take(N=100) if isinstance(x, m.DiagnosticArray)]
    me.close()
    assert play.returncode == 0, play_err
    assert live.returncode == 0, (live_out, live_err)
    assert f"joined ROS 2 domain {domain} on the loopback interface (127.0.0.1), multicast off" in live_out
    assert hostile_sent

    doc = json.loads(out.read_text())
    info = doc["ros2"]
    assert info["domain"] == domain and info["ended"] == "idle" and info["robot_source"] == "/robot_description"
    assert info["imu_topics"] == ["/skin/bad/imu", *(f"/skin/{u}/imu" for u in UNITS)]
    assert info["units"] == {f"/skin/{u}/imu {u}": u for u in UNITS}  # unit = frame_id, as import names them
    assert info["dropped"] == {"/joint_states": {"malformed": 1}, "/skin/bad/imu": {"oversized": 1}}
    assert "/chatter" in info["ignored_topics"]
    assert info["messages"]["/joint_states"] == len(ds.joints.t)  # nothing lost on loopback
    assert all(info["messages"][f"/skin/{u}/imu"] == len(ds.imu[u].t) for u in UNITS)

    # the last /tf_static message is the result file, unit for unit (parent: the URDF's link frame)
    result = read_result(out)
    assert sorted(result.units) == list(UNITS)
    final = {t.child_frame_id: t for t in tf_messages[-1].transforms}
    assert sorted(final) == list(UNITS)
    for u, r in result.units.items():
        t = final[u]
        assert t.header.frame_id == f"panda_link{r.pose.link}"
        v, q = t.transform.translation, t.transform.rotation
        np.testing.assert_allclose([v.x, v.y, v.z], r.pose.p_link_su, atol=1e-12)
        R = matrix_from_quat_wxyz(np.array([q.w, q.x, q.y, q.z]))
        assert rotation_angle(R, r.pose.T_link_su[:3, :3]) < 1e-9
    assert len(tf_messages) == info["tf_messages"] >= 1  # every one received: when decided (if), and the final

    # close to the batch mle of the same data: every axis within the reported std (measured: <= 0.5 std)
    for u, r in result.units.items():
        b = batch.units[u]
        assert r.pose.link == b.pose.link
        dp = np.abs(r.pose.p_link_su - b.pose.p_link_su)
        assert np.all(dp <= np.asarray(r.position_std_m)), (u, dp, r.position_std_m)
        d_deg = np.degrees(rotation_angle(r.pose.T_link_su[:3, :3], b.pose.T_link_su[:3, :3]))
        assert d_deg <= float(np.min(r.rotation_std_deg)), (u, d_deg, r.rotation_std_deg)

    # /diagnostics: one status per unit and the session's; the last says calibrated
    last = {s.name: s for s in diagnostics[-1].status}
    assert set(last) == {f"skincal: {u}" for u in UNITS} | {"skincal: session"}
    for u in UNITS:
        s = last[f"skincal: {u}"]
        values = {kv.key: kv.value for kv in s.values}
        assert s.hardware_id == u and values["published"] == "yes", values
        assert values["link"] == f"panda_link{result.units[u].pose.link}"
    session_values = {kv.key: kv.value for kv in last["skincal: session"].values}
    assert session_values["dropped"] == "2"

    # --record: the bag holds what was received, read back by the bag importer
    recorded, report = read_bag(bag, "panda")
    assert sorted(recorded.imu) == list(UNITS)
    assert all(len(recorded.imu[u].t) == len(ds.imu[u].t) for u in UNITS)
    np.testing.assert_allclose(recorded.imu["su5"].accel, ds.imu["su5"].accel, rtol=0, atol=0)


@pytest.mark.slow
def test_a_unit_knocked_mid_stream_is_re_published_on_tf_static(tmp_path):
    """280 s of teleoperation with su4 turned 2 deg at 240 s, played at 5x: the moved-unit monitor flags
    it, it is re-calibrated from the data after the knock and published again before the end."""
    from skincal.data.hdf5 import write_dataset
    from skincal.kinematics.transforms import matrix_from_quat_wxyz, rotation_angle
    from skincal.workflows.monitoring import knocked_dataset, work_session

    path = tmp_path / "knock.h5"
    write_dataset(knocked_dataset(work_session("panda", "realistic", "teleop", 280.0, seed=0), "su4", 240.0, 0.0, 2.0,
                                  seed=0), path)  # fmt: skip
    domain = fresh_domain()
    me = join(domain)
    tf = _reader(me, "/tf_static", m.TFMessage, qos.tf_static_listener())
    out = tmp_path / "live.json"
    live = subprocess.Popen(
        [
            *CLI,
            "ros2",
            "--robot",
            "panda",
            "--domain",
            str(domain),
            "--result",
            str(out),
            "--target",
            "1mm,0.2deg",
            "--idle",
            "2",
        ],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    play = subprocess.Popen([*CLI, "ros2-play", str(path), "--rate", "5", "--domain", str(domain)], cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    messages = []
    deadline = time.monotonic() + 240
    while live.poll() is None and time.monotonic() < deadline:
        messages += [x for x in tf.take(N=100) if isinstance(x, m.TFMessage)]
        time.sleep(0.1)
    play.communicate(timeout=30)
    live_out, live_err = live.communicate(timeout=30)
    messages += [x for x in tf.take(N=100) if isinstance(x, m.TFMessage)]
    me.close()
    assert live.returncode == 0, live_err
    assert "moved: unit su4" in live_out
    doc = json.loads(out.read_text())
    (event,) = doc["events"]
    assert event["unit"] == "su4" and abs(event["t_change_s"] - 240.0) < 1.0, (event, doc["ros2"])

    def su4(msg):
        (t,) = [t for t in msg.transforms if t.child_frame_id == "su4"] or [None]
        if t is None:
            return None
        q = t.transform.rotation
        return matrix_from_quat_wxyz(np.array([q.w, q.x, q.y, q.z]))

    poses = [R for R in (su4(x) for x in messages) if R is not None]
    before, after = np.asarray(event["T_link_su_before"])[:3, :3], np.asarray(event["T_link_su_after"])[:3, :3]
    assert np.degrees(rotation_angle(poses[0], before)) < 0.1  # first published: the pose before the knock
    # re-published before the end (not only in the final message), nearer the pose after the knock than before
    assert any(rotation_angle(R, after) < rotation_angle(R, before) for R in poses[1:-1]), len(poses)
    assert np.degrees(rotation_angle(poses[-1], after)) < 1e-6


@pytest.mark.slow
@pytest.mark.parametrize("how", ["sigterm", "until-decided"])
def test_the_result_is_written_at_sigterm_or_at_the_target(short, tmp_path, how):
    import signal

    path, ds, _batch = short
    domain = fresh_domain()
    out = tmp_path / "live.json"
    extra = ["--until-decided", "--target", "1mm,0.1deg"] if how == "until-decided" else []
    live = subprocess.Popen([*CLI, "ros2", "--robot", "panda", "--domain", str(domain), "--result", str(out), *extra],
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    play = subprocess.Popen([*CLI, "ros2-play", str(path), "--rate", "4", "--domain", str(domain)], cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    if how == "sigterm":
        time.sleep(8.0)  # the stream is flowing (the play takes 10 s)
        live.send_signal(signal.SIGTERM)
    live_out, live_err = live.communicate(timeout=60)
    play.communicate(timeout=60)
    assert live.returncode == 0, live_err
    doc = json.loads(out.read_text())
    assert doc["ros2"]["ended"] == ("stopped" if how == "sigterm" else "target reached")
    assert sum(doc["ros2"]["messages"].values()) < len(ds.joints.t) + sum(len(s.t) for s in ds.imu.values())
    if how == "until-decided":
        for u in UNITS:
            assert max(doc["units"][u]["position_std_m"]) <= 1e-3 and max(doc["units"][u]["rotation_std_deg"]) <= 0.1


@pytest.mark.adversarial
def test_hostile_decoded_messages_are_dropped_and_counted_never_fatal():
    """Well-formed CDR with hostile content, fed through the session as the receiver would: NaN and inf
    readings, another robot's joints, an empty and a control-character frame_id, thousands of frame_ids,
    stamps at the int32 ends. Nothing raises; the units that remain are the real ones."""
    from skincal.kinematics import panda
    from skincal.workflows import ros2_live
    from skincal.workflows.ros2_live import Ros2Calibration, Ros2Options

    me = join(fresh_domain())
    session = Ros2Calibration(me.participant, panda(), options=Ros2Options(warmup_s=0.0))
    names = [f"panda_joint{i}" for i in range(1, 8)]
    js = lambda ns, names=names, q=None: m.JointState(  # noqa: E731
        header=m.Header(m.Time.from_ns(ns)), name=names, position=q or [0.1] * len(names), velocity=[])
    imu = lambda ns, frame, a=(0.0, 0.0, 9.81): m.Imu(  # noqa: E731
        header=m.Header(m.Time.from_ns(ns), frame), linear_acceleration=m.Vector3(*a))
    t0 = 1_700_000_000 * 10**9
    inbox = [("/joint_states", js(1), b"")]  # a stray first stamp (1970): not time 0, dropped as far behind
    inbox += [("/joint_states", js(t0 + k * 2_000_000), b"") for k in range(50)]
    inbox += [("/joint_states", js(t0, names=["other_joint"] * 7), b""),  # another robot
              ("/joint_states", js(t0, q=[float("nan")] * 7), b""),
              ("/joint_states", js((2**31 - 1) * 10**9), b"")]  # fmt: skip
    inbox += [("/skin/su1/imu", imu(t0 + k * 10_000_000, "su1"), b"") for k in range(10)]
    inbox += [("/skin/su1/imu", imu(t0, "su1", (float("nan"), float("inf"), 1e308)), b""),
              ("/skin/esc/imu", imu(t0, "\x1b[2J"), b""),  # a control character: named by the topic
              ("/skin/x/imu", imu(t0, ""), b"")]  # fmt: skip
    inbox += [("/skin/imus", imu(t0 + k * 10_000_000, f"arm{k % 2}"), b"") for k in range(20)]  # 2 units, 1 topic
    inbox += [("/skin/many/imu", imu(t0, f"f{k}"), b"") for k in range(ros2_live.MAX_SOURCES + 50)]
    session.deliver(inbox)
    session.poll()
    session.poll()
    outcome = session.finish()
    me.close()
    assert outcome is not None
    dropped = session.drops.as_dict()
    assert dropped["/joint_states"] == {"not the robot's joints": 1, "not finite": 1, "stamp jump": 2}
    assert dropped["/skin/su1/imu"] == {"not finite": 1}  # counted, not taken in silently
    assert dropped["/skin/many/imu"]["no unit name"] >= 50  # beyond MAX_SOURCES sources
    units = session.stats.units
    assert units["/skin/su1/imu su1"] == "su1" and units["/skin/esc/imu \x1b[2J"] == "skin_esc"
    assert units["/skin/x/imu"] == "skin_x"
    assert units["/skin/imus arm0"] == "arm0" and units["/skin/imus arm1"] == "arm1"  # one unit per frame_id
    assert len(units) <= ros2_live.MAX_SOURCES
