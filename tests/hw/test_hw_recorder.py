"""HDF5 recorder: layout and values, final clock remapping, dataset validation, and crash safety
(a recording process killed with SIGKILL after some flushes; ``skincal record`` stopped by SIGTERM)."""

from __future__ import annotations

import asyncio
import os
import signal
import socket
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from skincal.errors import ConfigError
from skincal.hw.clock import ClockFit
from skincal.hw.emulator import SkinEmulator
from skincal.hw.packet import decode_packet, encode_joint_packet, encode_packet
from skincal.hw.receiver import Delivery
from skincal.hw.recorder import Recorder
from skincal.hw.session import record
from skincal.hw.synthetic import traffic_dataset
from skincal.kinematics.presets import get_robot


def _delivery(data: bytes, host_s: float) -> Delivery:
    p = decode_packet(data)
    key = ("joints", p.source_id) if hasattr(p, "q") else ("skin", p.unit_id)
    return Delivery(key, p, host_s)


def test_layout_gyro_flush_thresholds_and_final_remap(tmp_path):
    path = tmp_path / "r.h5"
    flushes: list[int] = []
    rec = Recorder(path, flush_every_samples=4, flush_every_s=1e9, t_origin_s=100.0, host_clock=lambda: 0.0,
                   unit_names={7: "forearm"}, on_flush=flushes.append, robot=get_robot("panda"))
    a = np.arange(9.0).reshape(3, 3)
    rec.add(_delivery(encode_packet(7, 0, [1_000_000, 1_010_000, 1_020_000], accel=a, gyro=-a), 101.0))
    # no gyro in a group with gyro: the contract wants gyro finite, so the IMU sample is ignored (range kept)
    rec.add(_delivery(encode_packet(7, 1, [1_030_000], accel=a[:1], range=[0.5]), 101.1))
    rec.add(_delivery(encode_packet(7, 2, [1_040_000], gyro=a[:1]), 101.2))  # gyro only: no place, ignored
    rec.add(_delivery(encode_joint_packet(0, 0, [5, 6], np.zeros((2, 7)), np.ones((2, 7))), 101.3))
    rec.add(_delivery(encode_joint_packet(0, 1, [7], np.zeros((1, 3)), np.ones((1, 3))), 101.4))  # other robot
    provisional = {("skin", 7): ClockFit(99.0, 0.0, 1.0), ("joints", 0): ClockFit(100.0, 0.0, 0.0)}
    assert rec.maybe_flush(provisional) and flushes == [6]  # 3 imu + 1 tof + 2 joints samples
    with h5py.File(path, "r") as f:  # readable while the recorder still has it open
        np.testing.assert_allclose(f["imu/forearm/t"][...], [0.0, 0.01, 0.02], atol=1e-9)
    final = {("skin", 7): ClockFit(99.5, 1e-3, 1.0), ("joints", 0): ClockFit(100.0, 0.0, 0.0)}
    summary = rec.finish(final)
    assert summary.samples == {"imu/forearm": 3, "tof/forearm": 1, "joints": 2} and summary.ignored_samples == 3
    assert {k: v for k, v in summary.ignored.items() if v} == {"no_gyro": 1, "no_place": 1, "other_robot": 1}
    with h5py.File(path, "r") as f:
        assert f.attrs["recording_complete"] and f.attrs["format"] == "skincal-dataset"
        assert f.attrs["ignored_no_gyro_samples"] == 1 and f.attrs["ignored_samples"] == 3
        g = f["imu/forearm"]
        np.testing.assert_array_equal(g["accel"][...], a)
        np.testing.assert_array_equal(g["gyro"][...], -a)
        d = np.array([1.0, 1.01, 1.02])
        np.testing.assert_allclose(g["t"][...], d + 99.5 + 1e-3 * (d - 1.0) - 100.0, atol=1e-9)
        np.testing.assert_allclose(g["host_receive_t"][...], [1.0, 1.0, 1.0])
        np.testing.assert_array_equal(g["device_t_us"][...], (d * 1e6).round())
        assert g["t"].chunks is not None and g["t"].maxshape == (None,)
        assert f["tof/forearm/range"][0] == 0.5
        assert f["joints/q"].shape == (2, 7) and f["robot"].attrs["name"] == "panda"
        assert f["clock/skin_7"].attrs["drift"] == 1e-3
    assert [p.name for p in tmp_path.iterdir()] == ["r.h5"]  # no temporary left behind
    with pytest.raises(ConfigError, match="exists"):
        Recorder(path)


def test_emulated_recording_matches_dataset_and_validates(tmp_path):
    """No faults, real time: every sample arrives, values equal the dataset's (f32), times keep their
    spacing, and the file reads back through skincal's validating reader."""
    from skincal.data.hdf5 import read_dataset

    ds = traffic_dataset(2, 1.2, np.random.default_rng(11))
    path = tmp_path / "rec.h5"

    async def main():
        stop = asyncio.Event()
        port: list[int] = []
        task = asyncio.create_task(record(path, stop=stop, robot=ds.robot, flush_every_s=0.2,
                                          on_start=port.append, reorder_timeout_s=0.1))
        while not port:
            await asyncio.sleep(0.01)
        report = await SkinEmulator(ds, port[0], rng=np.random.default_rng(12)).run_async(max_wall_s=10)
        await asyncio.sleep(0.3)
        stop.set()
        return report, await task

    report, (summary, stats) = asyncio.run(asyncio.wait_for(main(), 30))
    assert report.completed and stats.malformed_total == 0
    assert all(s.lost == 0 and s.duplicates == 0 for s in stats.streams.values())
    back = read_dataset(path)
    for unit, st in ds.imu.items():
        got = back.imu[unit]
        np.testing.assert_array_equal(got.accel, st.accel.astype(np.float32))
        np.testing.assert_array_equal(got.gyro, st.gyro.astype(np.float32))
        np.testing.assert_allclose(np.diff(got.t), np.diff(st.t), atol=2e-6)  # µs timestamps, no drift
    np.testing.assert_array_equal(back.tof["su1"].range, ds.tof["su1"].range.astype(np.float32))
    np.testing.assert_array_equal(back.joints.q, ds.joints.q)
    # one clock: joint and IMU times are mutually consistent, like in the dataset
    assert abs((back.imu["su1"].t[0] - back.joints.t[0]) - (ds.imu["su1"].t[0] - ds.joints.t[0])) < 3e-3


_KILLED_RECORDER = textwrap.dedent("""
    import asyncio, sys, time
    from skincal.hw.session import record
    from skincal.kinematics.presets import get_robot

    def flushed(n):
        print("flushed", n, flush=True)
        if n >= int(sys.argv[2]):  # hold here (between two flushes, loop blocked) until killed
            time.sleep(120)

    asyncio.run(record(sys.argv[1], robot=get_robot("panda"), flush_every_s=0.05, flush_every_samples=10**9,
                       reorder_timeout_s=0.05, on_start=lambda p: print("port", p, flush=True), on_flush=flushed))
""")


_CLI = [sys.executable, "-c", "import sys; from skincal.cli import main; sys.exit(main(sys.argv[1:]))"]


def _readline(proc: subprocess.Popen, deadline: float) -> str:
    line = proc.stdout.readline()
    if not line or time.monotonic() > deadline:
        proc.kill()
        raise AssertionError(f"recorder subprocess ended or stalled: {proc.stderr.read()}")
    return line


def test_recording_killed_mid_way_keeps_flushed_samples(tmp_path):
    """SIGKILL while packets still arrive, between two flushes: the file holds every flushed sample in
    order and passes the validating reader and ``skincal info`` (no timing is asserted here: the
    latency of the provisional times is measured in benchmarks/bench_receiver.py)."""
    from skincal.data.hdf5 import read_dataset

    path = tmp_path / "killed.h5"
    proc = subprocess.Popen([sys.executable, "-c", _KILLED_RECORDER, str(path), "300"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    try:
        port = int(_readline(proc, deadline).split()[1])
        flushed = 0
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            seq = stamp_us = 0
            while flushed < 300:  # keep sending until the recorder holds after a flush with >= 300 samples
                for _ in range(20):
                    stamp_us = max(stamp_us + 1, time.monotonic_ns() // 1000 + 7_000_000)  # a device clock
                    sock.sendto(encode_packet(3, seq, [stamp_us], accel=[[0.0, 1.0, float(seq)]]),
                                ("127.0.0.1", port))
                    sock.sendto(encode_joint_packet(0, seq, [stamp_us], np.full((1, 7), 0.1), np.zeros((1, 7))),
                                ("127.0.0.1", port))
                    seq += 1
                time.sleep(0.01)
                os.set_blocking(proc.stdout.fileno(), False)
                lines = proc.stdout.readlines()
                os.set_blocking(proc.stdout.fileno(), True)
                counts = [int(x.split()[1]) for x in lines if x.startswith("flushed")]
                flushed = max([flushed, *counts])
                assert time.monotonic() < deadline and seq < 100_000
            for _ in range(50):  # packets still arriving when the kill comes
                sock.sendto(encode_packet(3, seq, [stamp_us + 1000], accel=[[0.0, 1.0, float(seq)]]),
                            ("127.0.0.1", port))
                seq, stamp_us = seq + 1, stamp_us + 1000
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait(10)
    assert proc.returncode == -signal.SIGKILL
    with h5py.File(path, "r") as f:
        assert not f.attrs["recording_complete"] and f.attrs["flushed_samples"] == flushed
    ds = read_dataset(path)  # the contract's checks: strictly increasing times, shapes, finite values
    accel = ds.imu["su3"].accel
    assert accel.shape[0] + ds.joints.t.shape[0] == flushed >= 300
    np.testing.assert_array_equal(accel[:, 2], np.arange(accel.shape[0]))  # in order, none lost
    info = subprocess.run([*_CLI, "info", str(path)], capture_output=True, text=True, timeout=60)
    assert info.returncode == 0 and "su3" in info.stdout, info.stderr


def test_cli_record_stops_cleanly_on_sigterm(tmp_path):
    path = tmp_path / "cli.h5"
    proc = subprocess.Popen([*_CLI, "record", "--port", "0", "--out", str(path),
                             "--flush-every", "0.1"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 30
        line = ""
        while "listening on" not in line:
            line = _readline(proc, deadline)
        port = int(line.strip().rsplit(":", 1)[1])
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            for seq in range(200):
                sock.sendto(encode_packet(1, seq, [10_000 * seq], accel=[[0.0, 0.0, float(seq)]], range=[0.3]),
                            ("127.0.0.1", port))
                if seq % 50 == 49:
                    time.sleep(0.01)
        time.sleep(0.5)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=20)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    assert "wrote" in out and "200 samples" not in err
    with h5py.File(path, "r") as f:
        assert f.attrs["recording_complete"]
        np.testing.assert_array_equal(f["imu/su1/accel"][:, 2], np.arange(200))
        assert f["tof/su1/range"].shape == (200,)
    rc = subprocess.run([*_CLI, "record", "--port", "0", "--out", str(path)],
                        capture_output=True, text=True, timeout=30)
    assert rc.returncode == 2 and rc.stderr.startswith("error:") and len(rc.stderr.strip().splitlines()) == 1


def test_recorder_refuses_bad_options(tmp_path):
    with pytest.raises(ConfigError):
        Recorder(tmp_path / "x.h5", flush_every_s=0)
    assert not Path(tmp_path / "x.h5").exists()


def test_cli_emulate_sends_dataset_with_faults(tmp_path, capsys):
    from skincal.cli import main
    from skincal.data.hdf5 import write_dataset
    from skincal.hw.receiver import SkinReceiver

    data = tmp_path / "syn.h5"
    write_dataset(traffic_dataset(2, 0.5, np.random.default_rng(13)), data)

    async def go():
        async with SkinReceiver(reorder_timeout_s=0.05) as rx:
            argv = ["emulate", str(data), "--port", str(rx.port), "--loss", "0.1", "--corrupt", "0.05",
                    "--speed", "5", "--seed", "3"]
            code = await asyncio.to_thread(main, argv)
            await asyncio.sleep(0.2)
        return code, rx.stats()

    code, st = asyncio.run(asyncio.wait_for(go(), 30))
    out = capsys.readouterr().out
    assert code == 0 and "sending" in out and "sent" in out
    planned = int(out.split("sending ")[1].split()[0])
    assert st.datagrams == planned and st.malformed_total > 0 and sum(s.lost for s in st.streams.values()) > 0
    assert main(["emulate", str(data), "--port", "1", "--loss", "2"]) == 2  # bad probability: one-line error


def test_final_remap_only_since_device_restart(tmp_path):
    rec = Recorder(tmp_path / "r.h5", t_origin_s=0.0, host_clock=lambda: 0.0)
    before = ClockFit(-4.0, 0.0, 5.0)  # before the reboot: host = device - 4 s
    rec.add(_delivery(encode_packet(1, 0, [5_000_000, 5_010_000], accel=np.ones((2, 3))), 1.0))
    rec.flush({("skin", 1): before})
    rec.add(_delivery(encode_packet(1, 1, [5_020_000], accel=np.ones((1, 3))), 1.02))  # pending at the reboot
    rec.restart(("skin", 1), before)  # what the receiver reports once the reboot is confirmed
    rec.add(_delivery(encode_packet(1, 0, [0, 10_000], accel=2 * np.ones((2, 3))), 2.0))  # rebooted clock
    summary = rec.finish({("skin", 1): ClockFit(2.0, 0.0, 0.0)})  # the fit after the reboot
    assert summary.samples == {"imu/su1": 5} and summary.ignored_samples == 0
    with h5py.File(tmp_path / "r.h5", "r") as f:
        np.testing.assert_allclose(f["imu/su1/t"][...], [1.0, 1.01, 1.02, 2.0, 2.01], atol=1e-9)


def test_device_time_going_back_without_restart_is_ignored(tmp_path):
    """Without a confirmed restart, samples not after the previous device time (a replay that got
    through, a crafted time) are ignored, so ``t`` stays strictly increasing."""
    rec = Recorder(tmp_path / "r.h5", t_origin_s=0.0, host_clock=lambda: 0.0)
    fit = {("skin", 1): ClockFit(0.0, 0.0, 0.0)}
    rec.add(_delivery(encode_packet(1, 0, [1_000_000, 1_010_000], accel=np.ones((2, 3))), 1.0))
    rec.add(_delivery(encode_packet(1, 1, [1_005_000, 1_010_000, 1_020_000], accel=np.ones((3, 3))), 1.0))
    rec.flush(fit)
    rec.add(_delivery(encode_packet(1, 2, [0, 1_030_000], accel=np.ones((2, 3))), 1.0))
    summary = rec.finish(fit)
    assert summary.samples == {"imu/su1": 4} and summary.ignored == {**summary.ignored, "not_increasing": 3}
    with h5py.File(tmp_path / "r.h5", "r") as f:
        np.testing.assert_array_equal(f["imu/su1/device_t_us"][...], [1_000_000, 1_010_000, 1_020_000, 1_030_000])
        assert np.all(np.diff(f["imu/su1/t"][...]) > 0)


def test_unit_names_go_through_the_one_name_rule(tmp_path):
    for bad in ("a/b", "", "..", "x\x1b[31m", " pad"):
        with pytest.raises(ConfigError, match="name of unit 3"):
            Recorder(tmp_path / "n.h5", unit_names={3: bad})
    with pytest.raises(ConfigError, match="'arm' is given to two units"):
        Recorder(tmp_path / "n.h5", unit_names={3: "arm", 4: "arm"})
    assert not (tmp_path / "n.h5").exists()


def test_a_group_belongs_to_one_unit(tmp_path):
    """Unit 1 mapped to the name unit 2 has by default: unit 2's samples are not mixed into the group."""
    rec = Recorder(tmp_path / "g.h5", t_origin_s=0.0, host_clock=lambda: 0.0, unit_names={1: "su2"})
    rec.add(_delivery(encode_packet(1, 0, [1_000_000], accel=np.ones((1, 3))), 1.0))
    rec.add(_delivery(encode_packet(2, 0, [2_000_000], accel=np.zeros((1, 3))), 1.0))
    summary = rec.finish({("skin", 1): ClockFit(0.0, 0.0, 0.0), ("skin", 2): ClockFit(0.0, 0.0, 0.0)})
    assert summary.samples == {"imu/su2": 1} and summary.ignored["group_taken"] == 1
    with h5py.File(tmp_path / "g.h5", "r") as f:
        assert f["imu/su2"].attrs["source_id"] == 1 and f["imu/su2/accel"][0, 0] == 1.0


def test_provisional_times_never_step_back_when_the_fit_does(tmp_path):
    """The clock fit at a flush can move back by more than a sample period (a faster delivery lowers
    the envelope): the provisional t of a killed recording still increases strictly (shifted, spacing
    kept), and finish() maps the whole epoch with the final fit."""
    key = ("skin", 1)
    for finish in (False, True):
        path = tmp_path / f"p{finish}.h5"
        rec = Recorder(path, t_origin_s=0.0, host_clock=lambda: 0.0)
        d = 1_000_000 + 10_000 * np.arange(6)
        rec.add(_delivery(encode_packet(1, 0, d[:3], accel=np.ones((3, 3))), 1.0))
        rec.flush({key: ClockFit(0.0, 0.0, 0.0)})
        rec.add(_delivery(encode_packet(1, 1, d[3:], accel=np.ones((3, 3))), 1.0))
        rec.flush({key: ClockFit(-0.05, 0.0, 0.0)})  # 50 ms back: 5 sample periods
        if finish:
            rec.finish({key: ClockFit(-0.05, 0.0, 0.0)})
        else:
            rec.close()
        with h5py.File(path, "r") as f:
            t = f["imu/su1/t"][...]
        if finish:
            np.testing.assert_allclose(t, d * 1e-6 - 0.05, atol=1e-12)
        else:  # the second flush follows the first at half the device spacing, then keeps the spacing
            np.testing.assert_allclose(t, [1.0, 1.01, 1.02, 1.025, 1.035, 1.045], atol=1e-9)
