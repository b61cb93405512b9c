"""Receiver throughput on loopback: U units x R Hz for N seconds (run by hand, not in the tests).

    python benchmarks/bench_receiver.py --seconds 60 --units 100 --rate 100 --loss 0.01

The emulator runs in a child process (its own core), the receiver in this one. Reports the packet
rate, the receiver's CPU time per packet, per-stream losses counted by the receiver against what
the emulator says it dropped (any excess is loss on the host: socket buffer overflow), the receiver's
stale/refused counters, and the latency of the mapped times: host receive time minus the device
time of the packet's last sample mapped by the stream's final clock fit (the lower envelope puts the
fastest deliveries at 0; this figure used to be asserted, < 5 ms median, in a unit test that failed
under load).
"""

from __future__ import annotations

import argparse
import asyncio
import multiprocessing as mp
import time

import numpy as np

from skincal.hw.emulator import DeviceClock, Faults, SkinEmulator
from skincal.hw.receiver import SkinReceiver
from skincal.hw.synthetic import traffic_dataset


def _emulate(port: int, args: argparse.Namespace, out: mp.Queue) -> None:
    ds = traffic_dataset(args.units, args.seconds, np.random.default_rng(1), imu_hz=args.rate, tof_hz=0)
    clocks = dict.fromkeys(ds.imu, DeviceClock(100.0, args.drift_ppm))
    emu = SkinEmulator(ds, port, faults=Faults(loss=args.loss), rng=np.random.default_rng(2), joints=False,
                       batch=args.batch, clocks=clocks)
    out.put(("planned", emu.plan.datagrams_planned))
    report = emu.run(max_wall_s=args.seconds * 2 + 10)
    expected = {key: report.expected(key) for key in report.packets}
    dropped = sum(len(v) for v in report.dropped.values())
    out.put(("done", report.datagrams_sent, report.wall_s, dropped, expected, report.start_host_s))


async def _receive(args: argparse.Namespace) -> None:
    delivered = 0
    arrivals: dict = {}  # stream -> [(host receive s, device s of the last sample)]

    def count(delivery) -> None:
        nonlocal delivered
        delivered += 1
        arrivals.setdefault(delivery.key, []).append((delivery.host_receive_s, delivery.packet.t_us[-1] * 1e-6))

    async with SkinReceiver(on_packet=count) as rx:
        queue: mp.Queue = mp.get_context("spawn").Queue()
        child = mp.get_context("spawn").Process(target=_emulate, args=(rx.port, args, queue))
        cpu0, wall0 = time.process_time(), time.monotonic()
        child.start()
        while queue.empty():
            await asyncio.sleep(0.05)
        planned = queue.get()[1]
        cpu0, wall0 = time.process_time(), time.monotonic()  # exclude the child's start-up
        while queue.empty():
            await asyncio.sleep(0.1)
        _, sent, emu_wall, dropped, expected, start_host = queue.get()
        t_wait = time.monotonic() + 5
        while rx.stats().datagrams < sent and time.monotonic() < t_wait:
            await asyncio.sleep(0.05)
        cpu, wall = time.process_time() - cpu0, time.monotonic() - wall0
        child.join(10)
    st = rx.stats()
    lost = sum(s.lost for s in st.streams.values())
    lost_expected = sum(e.lost for e in expected.values())
    mismatched = sum(st.streams[k].lost != e.lost for k, e in expected.items() if k in st.streams)
    print(f"units {args.units} x {args.rate:g} Hz x {args.seconds:g} s, batch {args.batch}, loss {args.loss:g}")
    print(f"planned {planned} datagrams, sent {sent} in {emu_wall:.2f} s ({sent / emu_wall:.0f} /s)")
    print(f"received {st.datagrams} datagrams ({st.datagrams / wall:.0f} /s over {wall:.2f} s), "
          f"delivered {delivered} packets, malformed {st.malformed_total}")
    print(f"receiver CPU {cpu:.2f} s = {1e6 * cpu / max(st.datagrams, 1):.1f} us per datagram "
          f"({100 * cpu / wall:.0f} % of one core)")
    print(f"lost (receiver) {lost}; dropped by emulator {dropped}, of which visible to a receiver "
          f"{lost_expected}; host-side loss {lost - lost_expected}; streams with lost != expected: {mismatched}")
    # clock: device = 100 s + (1 + e) t; the host sent data time t at start_host + t (CLOCK_MONOTONIC)
    eps = args.drift_ppm * 1e-6
    t_mid = np.array([0.0, args.seconds / 2, args.seconds])
    errs, drifts = [], []
    for fit in rx.clock_fits().values():
        errs.append(fit.to_host(100.0 + (1 + eps) * t_mid) - (start_host + t_mid))
        drifts.append(fit.drift - (1 / (1 + eps) - 1))
    errs_ms, drifts_ppm = 1e3 * np.abs(errs), 1e6 * np.abs(drifts)
    fits = rx.clock_fits()
    lat_ms = 1e3 * np.concatenate([np.array(v)[:, 0] - fits[k].to_host(np.array(v)[:, 1])
                                   for k, v in arrivals.items() if k in fits])
    print(f"latency of mapped times (host receive - fit(device)): median {np.median(lat_ms):.3f} ms, "
          f"p99 {np.percentile(lat_ms, 99):.3f} ms, max {lat_ms.max():.3f} ms; min {lat_ms.min():.3f} ms; "
          f"stale {sum(s.stale for s in st.streams.values())}, refused {st.refused}")
    print(f"clock ({args.drift_ppm:g} ppm device drift): |drift error| median {np.median(drifts_ppm):.2f} ppm, "
          f"max {drifts_ppm.max():.2f} ppm; |host time error| at start/middle/end median "
          f"{', '.join(f'{v:.3f}' for v in np.median(errs_ms, axis=0))} ms, max {errs_ms.max():.3f} ms")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--units", type=int, default=100)
    parser.add_argument("--rate", type=float, default=100.0, help="IMU samples per second per unit")
    parser.add_argument("--loss", type=float, default=0.01, help="emulator packet loss probability")
    parser.add_argument("--batch", type=int, default=1, help="samples per packet")
    parser.add_argument("--drift-ppm", type=float, default=50.0, help="device clock drift of every unit")
    asyncio.run(_receive(parser.parse_args()))


if __name__ == "__main__":
    main()
