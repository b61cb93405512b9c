"""Hostile input to the hardware path (issue 19): crafted and fuzzed packets, replays, floods of unit ids,
NaN samples and ``--bind`` beyond loopback. Receivers run on real UDP sockets on 127.0.0.1 and every
recording is read back with :func:`skincal.data.hdf5.read_dataset`."""

from __future__ import annotations

import asyncio
import socket
import struct
import subprocess
import sys
import time
import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from skincal.data.hdf5 import read_dataset
from skincal.hw.packet import (
    FLAG_ACCEL,
    FLAG_GYRO,
    FLAG_RANGE,
    HEADER,
    MAGIC_JOINTS,
    MAGIC_SKIN,
    MAX_T0_US,
    BadFieldError,
    BadValueError,
    JointPacket,
    PacketError,
    SkinPacket,
    decode_packet,
    encode_joint_packet,
    encode_packet,
    joint_sample_dtype,
    skin_sample_dtype,
)

pytestmark = pytest.mark.adversarial

_FUZZ = settings(max_examples=400, deadline=None, derandomize=True, database=None,
                 suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def _seal(body: bytes) -> bytes:
    """``body`` followed by its correct CRC-32: what a sender that means harm can always produce."""
    return body + struct.pack("<I", zlib.crc32(body))


def _check_decoded(p: SkinPacket | JointPacket) -> None:
    """What a decoded packet promises to the receiver and the recorder."""
    assert p.t_us.dtype == np.int64 and p.t_us.ndim == 1 and p.n_samples >= 1
    assert np.all(p.t_us >= 0)
    if isinstance(p, JointPacket):
        assert np.isfinite(p.q).all() and np.isfinite(p.qd).all()
        return
    for arr in (p.accel, p.gyro):
        assert arr is None or np.isfinite(arr).all()
    assert p.range is None or not np.any(np.isinf(p.range) | (p.range < 0))


def _decode_or_malformed(data: bytes) -> None:
    try:
        p = decode_packet(data)
    except PacketError as exc:  # the only exception allowed out, with a reason the receiver counts
        assert exc.reason in {"short", "bad_magic", "bad_checksum", "unknown_version", "bad_field", "bad_length",
                              "bad_value"}
        return
    _check_decoded(p)


@_FUZZ
@given(st.binary(max_size=400))
def test_decoder_fuzz_arbitrary_bytes(data):
    _decode_or_malformed(data)
    _decode_or_malformed(b"SU" + data)
    _decode_or_malformed(_seal(b"SU\x01" + data))


@st.composite
def _valid_crc_frames(draw) -> bytes:
    """Frames with a correct CRC and arbitrary header fields; the body has the length the header implies
    (so decoding gets past every length check) or, sometimes, any length."""
    magic = draw(st.sampled_from([MAGIC_SKIN, MAGIC_JOINTS, b"SX"]))
    version = draw(st.sampled_from([1, 1, 1, 0, 2, 255]))
    flags = draw(st.integers(1, 7) | st.integers(0, 255))
    source = draw(st.integers(0, 0xFFFF))
    n = draw(st.integers(0, 6) | st.integers(0, 0xFFFF))
    seq = draw(st.integers(0, 0xFFFFFFFF))
    t0 = draw(st.integers(0, (1 << 64) - 1) | st.integers(MAX_T0_US - 5, MAX_T0_US + 5) | st.integers(0, 10**12))
    header = HEADER.pack(magic, version, flags, source, n, seq, t0)
    itemsize = 0
    if magic == MAGIC_SKIN and flags and not flags & ~(FLAG_ACCEL | FLAG_GYRO | FLAG_RANGE):
        itemsize = skin_sample_dtype(flags).itemsize
    elif magic == MAGIC_JOINTS and 1 <= flags <= 32:
        itemsize = joint_sample_dtype(flags).itemsize
    size = itemsize * n if itemsize and n <= 6 and draw(st.booleans()) else draw(st.integers(0, 300))
    body = draw(st.binary(min_size=size, max_size=size))
    return _seal(header + body)


@_FUZZ
@given(_valid_crc_frames())
def test_decoder_fuzz_valid_crc_frames_with_arbitrary_fields(frame):
    _decode_or_malformed(frame)


@_FUZZ
@given(
    t0=st.integers(0, MAX_T0_US),
    samples=st.lists(st.tuples(st.integers(0, 0xFFFFFFFF), st.floats(width=32), st.floats(width=32),
                               st.floats(width=32)), min_size=1, max_size=5),
    flags=st.integers(1, 7),
)
def test_decoder_fuzz_encoded_frames_with_arbitrary_values(t0, samples, flags):
    """Frames built field by field (any float32 including NaN, inf, -0, subnormals; any dt): decode, or
    refuse with bad_value exactly when a value is non-finite (range: infinite or negative)."""
    dtype = skin_sample_dtype(flags)
    rec = np.zeros(len(samples), dtype=dtype)
    rec["dt_us"] = [s[0] for s in samples]
    vals = np.array([s[1:] for s in samples], dtype=np.float32)
    if flags & FLAG_ACCEL:
        rec["accel"] = vals
    if flags & FLAG_GYRO:
        rec["gyro"] = vals[:, ::-1]
    if flags & FLAG_RANGE:
        rec["range"] = vals[:, 0]
    frame = _seal(HEADER.pack(MAGIC_SKIN, 1, flags, 9, len(samples), 1, t0) + rec.tobytes())
    bad = bool(flags & (FLAG_ACCEL | FLAG_GYRO)) and not np.isfinite(vals).all()
    if flags & FLAG_RANGE:
        bad |= bool(np.any(np.isinf(vals[:, 0]) | (vals[:, 0] < 0)))
    if bad:
        with pytest.raises(BadValueError):
            decode_packet(frame)
    else:
        p = decode_packet(frame)
        _check_decoded(p)
        np.testing.assert_array_equal(p.t_us, t0 + rec["dt_us"].astype(np.int64))


def test_t0_beyond_int64_is_a_bad_field_not_an_overflow():
    body = bytearray(encode_packet(1, 0, [0], accel=[[0.0, 0.0, 9.81]])[:-4])
    for t0 in (1 << 63, (1 << 64) - 1, MAX_T0_US + 1):
        body[12:20] = struct.pack("<Q", t0)
        with pytest.raises(BadFieldError, match="t0_us"):
            decode_packet(_seal(bytes(body)))
    body[12:20] = struct.pack("<Q", MAX_T0_US)
    body[20:24] = struct.pack("<I", 0xFFFFFFFF)
    assert decode_packet(_seal(bytes(body))).t_us[0] == (1 << 63) - 1  # the largest time still decodes


@pytest.mark.parametrize("field", ["accel", "gyro", "range", "q", "qd"])
@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_non_finite_values_are_bad_values(field, value):
    if field in ("q", "qd"):
        q, qd = np.zeros((2, 7)), np.zeros((2, 7))
        (q if field == "q" else qd)[1, 3] = value
        data = encode_joint_packet(0, 0, [0, 10], q, qd)
    else:
        arr = np.zeros((2, 3)) if field != "range" else np.ones(2)
        arr[1] = value
        data = encode_packet(1, 0, [0, 10], **{field: arr})
    if field == "range" and np.isnan(value):
        assert np.isnan(decode_packet(data).range[1])  # NaN range: "no target", part of the format
        return
    with pytest.raises(BadValueError) as e:
        decode_packet(data)
    assert e.value.reason == "bad_value"


def test_negative_range_is_a_bad_value():
    with pytest.raises(BadValueError):
        decode_packet(encode_packet(1, 0, [0], range=[-0.5]))


# -- receiver and recorder on real UDP sockets ---------------------------------------------------------

_PANDA_J = 7


def _live(seq: int, unit: int = 1, period_us: int = 10_000, t0_us: int = 10**9) -> list[bytes]:
    """Packet ``seq`` of a live device: one IMU sample of unit ``unit`` (accel z = seq) and one joint sample."""
    t = [t0_us + period_us * seq]
    return [encode_packet(unit, seq % 2**32, t, accel=[[0.0, 1.0, float(seq)]], gyro=[[0.0, 0.0, 0.01]]),
            encode_joint_packet(0, seq % 2**32, t, np.full((1, _PANDA_J), 0.001 * seq), np.zeros((1, _PANDA_J)))]


async def _record_traffic(path, send, **options):
    """Run :func:`skincal.hw.session.record` on 127.0.0.1 with the panda, let ``send(sock, port)`` (async)
    send its datagrams, wait until the receiver has handled all of them, stop; return summary, stats and
    anything the event loop's exception handler saw."""
    from skincal.hw.session import record
    from skincal.kinematics.presets import get_robot

    loop_errors: list[dict] = []
    asyncio.get_running_loop().set_exception_handler(lambda _loop, ctx: loop_errors.append(ctx))
    stop, port, latest = asyncio.Event(), [], []
    task = asyncio.create_task(record(path, stop=stop, robot=get_robot("panda"), flush_every_s=0.1, tick_s=0.02,
                                      reorder_timeout_s=0.05, on_start=port.append,
                                      on_tick=lambda st, _rec, _rx: latest.append(st), **options))
    while not port:
        await asyncio.sleep(0.005)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sent = await send(sock, port[0])
    t_end = time.monotonic() + 20
    while not latest or latest[-1].datagrams < sent:
        assert time.monotonic() < t_end, "the receiver did not see every datagram"
        await asyncio.sleep(0.02)
    await asyncio.sleep(0.15)  # reorder timeout: everything delivered
    stop.set()
    summary, stats = await task
    return summary, stats, loop_errors


def _sender(datagrams: list[bytes | list[bytes]], pace_every: int = 40, pause_s: float = 0.002):
    """Send on loopback, pausing every ``pace_every`` datagrams so the receiver (same event loop) drains
    the socket; an item that is a list is a burst, sent back to back without a pause inside."""
    async def send(sock: socket.socket, port: int) -> int:
        sent = since_pause = 0
        for item in datagrams:
            for d in [item] if isinstance(item, bytes) else item:
                sock.sendto(d, ("127.0.0.1", port))
            n = 1 if isinstance(item, bytes) else len(item)
            sent, since_pause = sent + n, since_pause + n
            if since_pause >= pace_every:
                await asyncio.sleep(pause_s)
                since_pause = 0
        return sent

    return send


def _run(coro):
    return asyncio.run(asyncio.wait_for(coro, 60))


def _skin(stats, unit: int = 1):
    return stats.streams[("skin", unit)]


def test_replayed_old_packets_are_stale_not_restarts(tmp_path):
    """The attack: packets older than 6 s replayed into a live stream (7 single ones, then a burst of 20
    consecutive ones). Each is counted as stale; no restart, no phantom loss, no duplicate row, and
    the recording passes the validating reader (it used to be refused: t not strictly increasing)."""
    n = 900  # 9 s of device time at 100 Hz (sent faster than real time)
    datagrams: list[bytes | list[bytes]] = []
    for i in range(n):
        datagrams += _live(i)
        if i in range(700, 840, 20):  # 7 single replays of packets 6..6.2 s old
            datagrams += _live(i - 600 - i % 7)[:1]
        if i == 850:  # a burst of 20 consecutive old packets, back to back
            datagrams.append([_live(k)[0] for k in range(100, 120)])
    path = tmp_path / "replay.h5"
    summary, stats, errors = _run(_record_traffic(path, _sender(datagrams)))
    s = _skin(stats)
    assert (s.restarts, s.stale, s.lost, s.duplicates, s.received) == (0, 27, 0, 0, n)
    assert stats.streams[("joints", 0)].restarts == 0 and not errors
    ds = read_dataset(path)
    np.testing.assert_array_equal(ds.imu["su1"].accel[:, 2], np.arange(n))
    assert ds.joints.t.shape == (n,) and summary.ignored_samples == 0
    import h5py

    with h5py.File(path, "r") as f:
        assert (f.attrs["stale_packets"], f.attrs["restarts"], f.attrs["lost_packets"]) == (27, 0, 0)


def test_crafted_sequence_jump_is_stale_not_a_phantom_loss(tmp_path):
    """One packet whose sequence number jumps 2^30 ahead (current timestamp) used to be buffered, then
    skipped to: a billion phantom losses and the live stream taken for duplicates."""
    datagrams: list[bytes] = []
    for i in range(200):
        datagrams += _live(i)
        if i in (100, 150):
            jump = 2**30 if i == 100 else 2**31 - 5
            t = [10**9 + 10_000 * i + 5_000]
            datagrams.append(encode_packet(1, (i + jump) % 2**32, t, accel=[[0.0, 0.0, -1.0]]))
    path = tmp_path / "jump.h5"
    summary, stats, errors = _run(_record_traffic(path, _sender(datagrams)))
    s = _skin(stats)
    assert (s.lost, s.stale, s.restarts, s.duplicates, s.received) == (0, 2, 0, 0, 200) and not errors
    np.testing.assert_array_equal(read_dataset(path).imu["su1"].accel[:, 2], np.arange(200))


def test_real_reboot_is_one_restart_and_the_recording_stays_valid(tmp_path):
    """A device that really reboots (sequence numbers and clock start again, packets keep coming in real
    time) is one restart after a consistent run; every sample is kept, times strictly increasing."""
    before, after = 300, 40

    async def send(sock: socket.socket, port: int) -> int:
        sent = 0
        for i in range(before):
            for d in _live(i):
                sock.sendto(d, ("127.0.0.1", port))
                sent += 1
            if i % 20 == 19:
                await asyncio.sleep(0.002)
        await asyncio.sleep(0.05)
        for i in range(after):  # rebooted: seq from 0, clock from 5 ms; joints keep going
            sock.sendto(encode_packet(1, i, [5_000 + 10_000 * i], accel=[[0.0, 2.0, float(before + i)]],
                                      gyro=[[0.0, 0.0, 0.01]]), ("127.0.0.1", port))
            sock.sendto(_live(before + i)[1], ("127.0.0.1", port))
            sent += 2
            await asyncio.sleep(0.01)  # real time: the run spans more than restart_confirm_s
        return sent

    path = tmp_path / "reboot.h5"
    summary, stats, errors = _run(_record_traffic(path, send))
    s = _skin(stats)
    assert (s.restarts, s.stale, s.lost, s.received) == (1, 0, 0, before + after) and not errors
    ds = read_dataset(path)
    np.testing.assert_array_equal(ds.imu["su1"].accel[:, 2], np.arange(before + after))
    assert summary.ignored_samples == 0


def test_nan_and_inf_samples_are_malformed_and_never_stored(tmp_path):
    bad_values = [np.nan, np.inf, -np.inf]
    datagrams: list[bytes] = []
    n_bad = 0
    for i in range(200):
        if i % 10 == 5:  # this seq carries a NaN/inf in accel, gyro or q: dropped, its number lost
            v = bad_values[n_bad % 3]
            t = [10**9 + 10_000 * i]
            datagrams.append(encode_packet(1, i, t, accel=[[0.0, v, 1.0]]) if n_bad % 2 else
                             encode_packet(1, i, t, accel=[[0.0, 0.0, 1.0]], gyro=[[v, 0.0, 0.0]]))
            datagrams.append(encode_joint_packet(0, i, t, np.full((1, 7), v), np.zeros((1, 7))))
            n_bad += 1
        else:
            datagrams += _live(i)
    path = tmp_path / "nan.h5"
    summary, stats, errors = _run(_record_traffic(path, _sender(datagrams)))
    assert stats.malformed == {"bad_value": 2 * n_bad} and not errors
    assert _skin(stats).lost == n_bad and _skin(stats).received == 200 - n_bad
    ds = read_dataset(path)  # it used to be refused: non-finite values
    assert np.isfinite(ds.imu["su1"].accel).all() and np.isfinite(ds.imu["su1"].gyro).all()
    assert ds.imu["su1"].t.shape == (200 - n_bad,) and np.isfinite(ds.joints.q).all()


def test_t0_overflow_is_counted_not_a_traceback(tmp_path):
    """Valid-CRC packets with t0_us >= 2^63 used to raise OverflowError out of datagram_received (one
    asyncio traceback per packet, not counted); now each is a bad_field and the stream goes on."""
    crafted = []
    for k, t0 in enumerate([1 << 63, (1 << 64) - 1, MAX_T0_US + 1] * 10):
        body = bytearray(encode_packet(1, 10_000 + k, [0], accel=[[0.0, 0.0, 9.81]])[:-4])
        body[12:20] = struct.pack("<Q", t0)
        crafted.append(_seal(bytes(body)))
    datagrams = [d for i in range(100) for d in _live(i)] + crafted + [d for i in range(100, 150) for d in _live(i)]
    path = tmp_path / "overflow.h5"
    summary, stats, errors = _run(_record_traffic(path, _sender(datagrams)))
    assert errors == [] and stats.malformed == {"bad_field": 30}
    assert _skin(stats).received == 150 and read_dataset(path).imu["su1"].t.shape == (150,)


def test_flood_of_new_unit_ids_is_refused_beyond_the_cap(tmp_path):
    """1,265 one-sample packets from new unit ids used to make a 166 MB recording: ids beyond max_units
    (64, the live unit included) are refused and the file stays small and valid."""
    datagrams = [d for i in range(50) for d in _live(i)]
    datagrams += [encode_packet(1000 + k, 0, [10**9], accel=[[0.0, 0.0, 9.81]]) for k in range(1265)]
    datagrams += [d for i in range(50, 100) for d in _live(i)]
    path = tmp_path / "ids.h5"
    summary, stats, errors = _run(_record_traffic(path, _sender(datagrams)))
    assert stats.refused == 1265 - 63 and len([k for k in stats.streams if k[0] == "skin"]) == 64
    size_mb = path.stat().st_size / 1e6
    assert size_mb < 12, f"{size_mb:.1f} MB"
    ds = read_dataset(path)
    assert len(ds.imu) == 64 and ds.imu["su1"].t.shape == (100,)
    import h5py

    with h5py.File(path, "r") as f:
        assert f.attrs["refused_datagrams"] == 1265 - 63


def test_samples_per_unit_are_capped(tmp_path):
    """One unit sending 100-sample packets cannot grow its group beyond max_unit_samples."""
    datagrams = [d for i in range(20) for d in _live(i)]
    for k in range(20):  # 2000 samples of unit 2
        t = 10**9 + 100_000 * k + 1000 * np.arange(100)
        datagrams.append(encode_packet(2, k, t, accel=np.tile([0.0, 0.0, 9.81], (100, 1))))
    path = tmp_path / "cap.h5"
    summary, stats, errors = _run(_record_traffic(path, _sender(datagrams), max_unit_samples=500))
    assert summary.samples["imu/su2"] == 500 and summary.ignored["over_cap"] == 1500
    assert read_dataset(path).imu["su2"].t.shape == (500,)


def test_crafted_valid_crc_flood_on_udp_counts_every_datagram(tmp_path):
    """Frames with correct CRCs and random header fields (including t0_us beyond int64) and random
    payloads: each is malformed with the reason the decoder gives, or accepted; the receiver lives on."""
    rng = np.random.default_rng(19)
    frames = []
    for _ in range(600):
        magic = [MAGIC_SKIN, MAGIC_JOINTS][int(rng.integers(2))]
        flags = int(rng.integers(1, 8)) if magic == MAGIC_SKIN else 7
        n = int(rng.integers(0, 3))
        t0 = int(rng.integers(0, 2**63)) * int(rng.integers(1, 3))  # up to 2^64
        size = n * (skin_sample_dtype(flags) if magic == MAGIC_SKIN else joint_sample_dtype(7)).itemsize
        size += int(rng.integers(-1, 2)) * int(rng.random() < 0.3)
        header = HEADER.pack(magic, 1, flags, int(rng.integers(1, 4)), n, int(rng.integers(2**32)), t0)
        frames.append(_seal(header + rng.bytes(max(size, 0))))
    expected: dict[str, int] = {}
    for frame in frames:
        try:
            decode_packet(frame)
        except PacketError as exc:
            expected[exc.reason] = expected.get(exc.reason, 0) + 1
    datagrams = [d for i in range(30) for d in _live(i)] + frames + [d for i in range(30, 60) for d in _live(i)]
    path = tmp_path / "crafted.h5"
    summary, stats, errors = _run(_record_traffic(path, _sender(datagrams)))
    assert not errors and stats.malformed == expected and stats.malformed_total < len(frames)
    assert {"bad_field", "bad_length", "bad_value"} <= set(expected)
    ds = read_dataset(path)  # whatever got through, the recording is valid
    assert ds.imu["su1"].t.shape[0] >= 60


# -- binding beyond loopback -----------------------------------------------------------------------------


def test_loopback_check():
    from skincal.hw.net import check_bind, is_loopback

    assert all(is_loopback(h) for h in ("127.0.0.1", "127.0.0.2", "localhost", "::1"))
    assert not any(is_loopback(h) for h in ("0.0.0.0", "::", "192.168.1.5", "example.com", ""))
    check_bind("0.0.0.0", public=True)
    with pytest.raises(Exception, match="not a loopback address; add --public"):
        check_bind("0.0.0.0", public=False)


def test_record_refuses_a_public_bind_without_public(tmp_path):
    out = tmp_path / "r.h5"
    cli = [sys.executable, "-c", "import sys; from skincal.cli import main; sys.exit(main(sys.argv[1:]))"]
    for bind in ("0.0.0.0", "::", "10.1.2.3"):
        rc = subprocess.run([*cli, "record", "--port", "0", "--out", str(out), "--bind", bind],
                            capture_output=True, text=True, timeout=60)
        assert rc.returncode == 2 and rc.stderr.startswith("error: --bind") and "--public" in rc.stderr
        assert len(rc.stderr.strip().splitlines()) == 1 and not out.exists()
    rc = subprocess.run([*cli, "record", "--port", "0", "--out", str(out), "--max-units", "0"],
                        capture_output=True, text=True, timeout=60)
    assert rc.returncode == 2 and rc.stderr.startswith("error: --max-units 0") and not out.exists()
