"""UDP receiver on real loopback sockets: malformed input, duplicates, reordering, exact gaps, clock
offset/drift recovery, and end-to-end counts against what the emulator reports it did."""

from __future__ import annotations

import asyncio
import socket
import time

import numpy as np
import pytest

from skincal.hw.clock import ClockEstimator, fit_lower_envelope
from skincal.hw.emulator import DeviceClock, Faults, SkinEmulator
from skincal.hw.packet import encode_packet
from skincal.hw.receiver import Delivery, SkinReceiver
from skincal.hw.synthetic import traffic_dataset


def _pkt(seq: int, unit: int = 1) -> bytes:
    return encode_packet(unit, seq % 2**32, [1000 * seq + 10**9], accel=[[0.0, 0.0, float(seq)]])


async def _until(cond, timeout_s: float = 5.0) -> None:
    t_end = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > t_end:
            raise AssertionError("timed out waiting for the receiver")
        await asyncio.sleep(0.005)


async def _send_all(port: int, datagrams: list[bytes], rx: SkinReceiver, pace_every: int = 50) -> None:
    """Send on loopback, pausing so the receive buffer never overflows; wait until all were processed."""
    before = rx.stats().datagrams
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        for i, d in enumerate(datagrams):
            sock.sendto(d, ("127.0.0.1", port))
            if i % pace_every == pace_every - 1:
                await asyncio.sleep(0.002)
    await _until(lambda: rx.stats().datagrams >= before + len(datagrams))


def _run(coro):
    return asyncio.run(asyncio.wait_for(coro, 30))


def test_binds_loopback_free_port():
    async def main():
        async with SkinReceiver() as rx:
            assert rx.host == "127.0.0.1" and 0 < rx.port < 65536
            assert rx.bound_address == ("127.0.0.1", rx.port)

    _run(main())


def test_malformed_counted_by_reason_and_receiver_survives():
    good = _pkt(0)
    bad_crc = bytearray(good)
    bad_crc[25] ^= 0xFF
    v2 = bytearray(good[:-4])
    v2[2] = 9
    import struct
    import zlib

    v2 = bytes(v2) + struct.pack("<I", zlib.crc32(bytes(v2)))
    cut = good[:-8]
    cut = cut + struct.pack("<I", zlib.crc32(cut))
    got: list[Delivery] = []

    async def main():
        async with SkinReceiver(on_packet=got.append, reorder_timeout_s=0.05) as rx:
            await _send_all(rx.port, [b"", good[:10], b"XY" + good[2:], bytes(bad_crc), v2, cut, _pkt(1)], rx)
            await _until(lambda: len(got) == 1)
            return rx.stats()

    st = _run(main())
    assert st.malformed == {"short": 2, "bad_magic": 1, "bad_checksum": 1, "unknown_version": 1, "bad_length": 1}
    assert got[0].packet.seq == 1 and st.streams[("skin", 1)].received == 1


def test_random_flood_all_counted_receiver_alive():
    """Random bytes, the right magic with garbage after it, and frames with a *valid* CRC-32 whose
    header fields and payload are random (t0_us up to 2^64, any flags and sample count, sizes that match
    or not): every datagram is counted, malformed ones by the decoder's reason, and the receiver lives on."""
    import struct
    import zlib

    from skincal.hw.packet import HEADER, PacketError, decode_packet, joint_sample_dtype, skin_sample_dtype

    rng = np.random.default_rng(4)
    flood = [rng.bytes(int(n)) for n in rng.integers(0, 300, 3000)]
    flood += [b"SU" + rng.bytes(int(n)) for n in rng.integers(22, 120, 500)]  # right magic, garbage after
    for _ in range(1500):  # valid CRC, random fields
        magic = (b"SU", b"SJ")[int(rng.integers(2))]
        flags = int(rng.integers(1, 8) if rng.random() < 0.8 else rng.integers(256))
        n = int(rng.integers(0, 4))
        item = skin_sample_dtype(flags & 7 or 1) if magic == b"SU" else joint_sample_dtype(max(1, min(flags, 32)))
        size = n * item.itemsize + int(rng.integers(-2, 3)) * int(rng.random() < 0.2)
        t0 = int(rng.integers(2**62)) * int(rng.integers(1, 5))  # a quarter beyond int64
        header = HEADER.pack(magic, 1, flags, int(rng.integers(100, 110)), n, int(rng.integers(2**32)), t0)
        body = header + rng.bytes(max(size, 0))
        flood.append(body + struct.pack("<I", zlib.crc32(body)))
    expected: dict[str, int] = {}
    for d in flood:
        try:
            decode_packet(d)
        except PacketError as exc:
            expected[exc.reason] = expected.get(exc.reason, 0) + 1
    got: list[Delivery] = []

    async def main():
        async with SkinReceiver(on_packet=got.append, reorder_timeout_s=0.05) as rx:
            await _send_all(rx.port, flood, rx)
            await _send_all(rx.port, [_pkt(5, unit=2)], rx)
            await _until(lambda: any(d.packet.unit_id == 2 for d in got if d.key[0] == "skin"))
            return rx.stats()

    st = _run(main())
    assert st.malformed == expected and st.datagrams == len(flood) + 1
    assert {"bad_field", "bad_length", "bad_value"} <= set(expected) and expected["bad_checksum"] >= 500
    accepted = len(flood) - st.malformed_total
    counted = sum(s.received + s.duplicates + s.late + s.stale + s.held for s in st.streams.values()) + st.refused
    assert accepted > 0 and counted == accepted + 1  # the valid frames that decoded, and the real packet


def test_duplicates_and_reordering_put_back_in_order():
    order = [0, 1, 2, 2, 5, 3, 4, 6, 1, 7, 9, 8, 9]
    got: list[Delivery] = []

    async def main():
        async with SkinReceiver(on_packet=got.append, reorder_timeout_s=0.1) as rx:
            await _send_all(rx.port, [_pkt(s) for s in order], rx)
        return rx.stats()

    st = _run(main()).streams[("skin", 1)]
    assert [d.packet.seq for d in got] == list(range(10))
    assert [d.packet.accel[0, 2] for d in got] == list(range(10))
    assert (st.received, st.duplicates, st.out_of_order, st.lost, st.late) == (10, 3, 3, 0, 0)


def test_gaps_counted_exactly_with_small_window_and_wraparound():
    rng = np.random.default_rng(5)
    first = 2**32 - 300  # crosses the u32 wrap
    seqs = np.arange(first, first + 1000)
    missing = rng.choice(seqs[1:-1], 37, replace=False)
    sent = [int(s) for s in seqs if s not in set(missing.tolist())]
    got: list[Delivery] = []

    async def main():
        async with SkinReceiver(on_packet=got.append, reorder_window=4, reorder_timeout_s=0.05) as rx:
            await _send_all(rx.port, [_pkt(s) for s in sent], rx)
        return rx.stats()

    st = _run(main()).streams[("skin", 1)]
    assert st.lost == 37 and st.received == len(sent) and st.duplicates == 0 and st.late == 0
    assert [d.packet.seq for d in got] == [s % 2**32 for s in sent]


def test_late_packet_moves_from_lost_to_late():
    rx = SkinReceiver(reorder_window=2, reorder_timeout_s=10.0)
    for s in (0, 2, 3, 4):  # the window overflows at 4: seq 1 is given up
        rx.handle_datagram(_pkt(s), host_s=0.0)
    assert rx.stats().streams[("skin", 1)].lost == 1
    rx.handle_datagram(_pkt(1), host_s=0.0)
    st = rx.stats().streams[("skin", 1)]
    assert (st.lost, st.late, st.duplicates) == (0, 1, 0)
    rx.handle_datagram(_pkt(3), host_s=0.0)
    assert rx.stats().streams[("skin", 1)].duplicates == 1


def test_device_restart_is_not_a_flood_of_duplicates():
    """A reboot (sequence numbers and device clock start again, packets keep arriving in real time) is
    one restart once a consistent run of new packets has been seen: nothing lost, nothing duplicated."""
    got: list[Delivery] = []
    restarted: list = []
    rx = SkinReceiver(on_packet=got.append, reorder_timeout_s=0.05, on_restart=lambda k, f: restarted.append((k, f)))
    for s in range(100):  # 100 packets, device up for 10^3 s, one every 10 ms
        rx.handle_datagram(encode_packet(4, s, [10**9 + 10_000 * s], range=[1.0]), host_s=0.01 * s)
    rx.handle_datagram(encode_packet(4, 99, [10**9 + 990_000], range=[1.0]), host_s=1.0)  # a real duplicate
    for s in range(50):  # reboot: sequence numbers and device clock start again
        rx.handle_datagram(encode_packet(4, s, [10_000 * s], range=[2.0]), host_s=1.5 + 0.01 * s)
    rx.flush()
    st = rx.stats().streams[("skin", 4)]
    assert (st.restarts, st.duplicates, st.received, st.delivered, st.lost, st.stale) == (1, 1, 150, 150, 0, 0)
    assert [d.packet.range[0] for d in got] == [1.0] * 100 + [2.0] * 50
    assert rx.clock_fit(("skin", 4)).n_points == 5  # the fit restarted with the new clock
    assert len(restarted) == 1 and restarted[0][0] == ("skin", 4)
    assert restarted[0][1].offset_s == pytest.approx(-1000.0)  # the old epoch's fit, handed over before the reset


def test_clock_lower_envelope_synthetic():
    """Known offset and drift under one-sided exponential delays (mean 2 ms), 60 s at 100 Hz."""
    rng = np.random.default_rng(6)
    d = 5000.0 + np.arange(0, 60, 0.01)
    offset, drift = -4999.123456, -150e-6
    h = d + offset + drift * (d - d[0]) + rng.exponential(2e-3, d.size)
    est = ClockEstimator()
    for lo in range(0, d.size, 7):  # fed in small pieces like packets
        est.add(h[lo:lo + 7], d[lo:lo + 7])
    fit = est.fit()
    assert abs(fit.drift - drift) < 2e-6
    assert abs(fit.offset_s - offset) < 2e-4
    np.testing.assert_allclose(fit.to_host(d), d + offset + drift * (d - d[0]), atol=2e-4)
    # the bound on memory merges bins and keeps the estimate
    small = ClockEstimator(max_bins=64)
    small.add(h, d)
    assert len(small.envelope()[0]) <= 64 and abs(small.fit().drift - drift) < 5e-6
    # ordinary least squares is biased by the mean delay; the envelope is not
    ols = np.polyfit(d - d[0], h - d, 1)
    assert abs(ols[1] - offset) > 1.5e-3 > abs(fit.offset_s - offset)


def test_fit_lower_envelope_exact_line_and_short_span():
    x = np.linspace(0, 10, 50)
    y = 0.25 + 3e-4 * x + np.where(np.arange(50) % 5 == 0, 0.0, 0.01)
    fit = fit_lower_envelope(x, y)
    assert fit.offset_s == pytest.approx(0.25, abs=1e-12) and fit.drift == pytest.approx(3e-4, abs=1e-12)
    short = fit_lower_envelope(x, y, min_span_s=20.0)
    assert short.drift == 0.0 and short.offset_s == pytest.approx(0.25)


def test_emulated_clock_offset_and_drift_recovered():
    """A device clock 1000 s ahead running 2000 ppm fast, played in real time for 2.5 s."""
    ds = traffic_dataset(1, 2.5, np.random.default_rng(7), tof_hz=0)
    eps = 2000e-6
    emu = SkinEmulator(ds, 0, clocks={"su1": DeviceClock(1000.0, eps * 1e6)}, joints=False,
                       rng=np.random.default_rng(8))

    async def main():
        async with SkinReceiver(clock_estimator=lambda: ClockEstimator(min_span_s=1.0)) as rx:
            emu.addr = ("127.0.0.1", rx.port)
            report = await emu.run_async(max_wall_s=10)
            await _until(lambda: rx.stats().datagrams >= report.datagrams_sent)
            return report, rx.clock_fit(("skin", 1))

    report, fit = _run(main())
    assert abs(fit.drift - (1 / (1 + eps) - 1)) < 300e-6
    device_s = emu.device_stamps_us("su1") * 1e-6
    t_data = (device_s - 1000.0) / (1 + eps)
    err = fit.to_host(device_s) - (report.start_host_s + t_data)
    assert abs(np.median(err)) < 3e-3 and np.max(np.abs(err)) < 10e-3


def test_emulator_faults_match_receiver_counts():
    """Loss, duplication, reordering, corruption and jitter on 4 units + robot: every counter equals
    what the emulator says it did (sequence numbers start near the u32 wrap)."""
    ds = traffic_dataset(4, 2.0, np.random.default_rng(9))
    faults = Faults(loss=0.05, duplicate=0.05, reorder=0.05, reorder_depth=3, corrupt=0.03, jitter_s=5e-4)
    emu = SkinEmulator(ds, 0, faults=faults, rng=np.random.default_rng(10), speed=4.0, seq_start=2**32 - 40)

    async def main():
        async with SkinReceiver(reorder_timeout_s=0.2) as rx:
            emu.addr = ("127.0.0.1", rx.port)
            report = await emu.run_async(max_wall_s=10)
            await _until(lambda: rx.stats().datagrams >= report.datagrams_sent)
        return report, rx.stats()

    report, st = _run(main())
    assert report.completed and report.send_errors == 0
    assert st.datagrams == report.datagrams_planned
    assert st.malformed_total == sum(len(v) for v in report.corrupted.values()) > 0
    assert set(st.streams) == set(report.packets) and len(st.streams) == 5
    totals = np.zeros(3, dtype=int)
    for key, s in st.streams.items():
        e = report.expected(key)
        assert (s.received, s.duplicates, s.out_of_order, s.lost, s.late) == (
            e.received, e.duplicates, e.out_of_order, e.lost, 0), key
        totals += (s.duplicates, s.out_of_order, s.lost)
        dropped_inside = np.sum((report.dropped[key] > report.order[key].min())
                                & (report.dropped[key] < report.order[key].max()))
        assert s.lost >= dropped_inside
    assert np.all(totals > 0)
