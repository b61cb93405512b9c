"""Play a :class:`~skincal.data.Dataset` over UDP as skin units (and the robot) with controlled faults.

Each unit becomes one skin source (its IMU and ToF samples share the unit's packet sequence
numbers); the joint stream becomes robot source 0. Packets carry ``batch`` samples and are sent at
the data time of their last sample divided by ``speed``. Device timestamps follow a
:class:`DeviceClock` per unit: ``device_s = offset_s + (1 + drift_ppm * 1e-6) * (t - t_first)``.

Faults (:class:`Faults`, drawn from the ``rng`` given, all up front and vectorised):

1. each packet is dropped with probability ``loss``;
2. a kept packet is sent twice (back to back) with probability ``duplicate``;
3. each datagram is corrupted with probability ``corrupt`` (one byte XORed with a non-zero value);
4. each datagram is moved ``1..reorder_depth`` places later with probability ``reorder``;
5. each send is delayed by an exponential jitter of mean ``jitter_s`` (wall-clock seconds; it never
   reorders by itself).

The :class:`EmulatorReport` lists exactly what happened per stream, and what a receiver on a lossless
link should therefore count (:meth:`EmulatorReport.expected`).
"""

from __future__ import annotations

import asyncio
import re
import socket
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from skincal.data.dataset import Dataset
from skincal.errors import ConfigError
from skincal.hw.packet import encode_joint_packet, encode_packet

StreamKey = tuple[str, int]
_IMU, _TOF, _JOINTS = 0, 1, 2


MAX_JITTER_S = 60.0
"""Largest mean extra send delay accepted (s): a datagram a minute late is already lost to any receiver."""


@dataclass(frozen=True)
class Faults:
    """Fault probabilities per packet/datagram, reorder depth (datagrams) and mean jitter (s)."""

    loss: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    reorder_depth: int = 3
    jitter_s: float = 0.0
    corrupt: float = 0.0

    def __post_init__(self) -> None:
        for name in ("loss", "duplicate", "reorder", "corrupt"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ConfigError(f"emulator: --{name} {getattr(self, name)} must be a probability in [0, 1]")
        if self.reorder_depth < 1:
            raise ConfigError(f"emulator: --reorder-depth {self.reorder_depth} must be >= 1 datagram")
        if not 0.0 <= self.jitter_s <= MAX_JITTER_S:  # NaN, inf and 1e308 too (no send time beyond time_t)
            raise ConfigError(f"emulator: --jitter {self.jitter_s} s must be a mean delay in [0, {MAX_JITTER_S:g}] s")


@dataclass(frozen=True)
class DeviceClock:
    """A device clock: ``device_s = offset_s + (1 + drift_ppm * 1e-6) * t`` for data time ``t`` (s)."""

    offset_s: float = 0.0
    drift_ppm: float = 0.0

    def device_us(self, t_s: np.ndarray) -> np.ndarray:
        """Device timestamps in µs (int64) of data times ``t_s`` ``(N,)`` s (>= 0 after the offset)."""
        d = np.round((self.offset_s + (1.0 + self.drift_ppm * 1e-6) * np.asarray(t_s, dtype=float)) * 1e6)
        if d.size and d.min() < 0:
            raise ConfigError(f"emulator: device clock offset {self.offset_s} s gives negative timestamps")
        return d.astype(np.int64)


@dataclass(frozen=True)
class StreamExpectation:
    """What a receiver should count for one stream on a lossless, order-keeping link."""

    received: int
    duplicates: int
    out_of_order: int
    lost: int


@dataclass(frozen=True)
class EmulatorReport:
    """What the emulator did. Sequence numbers are unwrapped ints (sent modulo 2^32).

    ``order`` holds, per stream, the sequence numbers of the *valid* (uncorrupted) datagrams in send
    order; ``dropped``/``duplicated``/``corrupted`` the sequence numbers affected (``corrupted`` once
    per corrupted datagram). ``start_host_s`` is the ``time.monotonic()`` instant of data time
    ``t_first`` (the dataset's first sample).
    """

    unit_ids: dict[str, int]
    packets: dict[StreamKey, int]
    samples: dict[StreamKey, int]
    dropped: dict[StreamKey, np.ndarray]
    duplicated: dict[StreamKey, np.ndarray]
    corrupted: dict[StreamKey, np.ndarray]
    reordered: int
    order: dict[StreamKey, np.ndarray]
    datagrams_planned: int
    datagrams_sent: int = 0
    send_errors: int = 0
    start_host_s: float = 0.0
    wall_s: float = 0.0
    completed: bool = False
    t_first: float = 0.0
    extra: dict[str, float] = field(default_factory=dict)

    def expected(self, key: StreamKey) -> StreamExpectation:
        """Receiver counts implied by the valid datagrams of ``key`` in send order (trailing losses
        are invisible to a receiver, so ``lost`` counts holes between the lowest and highest valid)."""
        s = self.order.get(key, np.empty(0, dtype=np.int64))
        if s.size == 0:
            return StreamExpectation(0, 0, 0, 0)
        unique, first_idx = np.unique(s, return_index=True)
        first = np.zeros(s.size, dtype=bool)
        first[first_idx] = True
        prev_max = np.maximum.accumulate(np.r_[s[0], s[:-1]])
        ooo = int(np.sum(first[1:] & (s[1:] < prev_max[1:])))
        lost = int(unique[-1] - unique[0] + 1 - unique.size)
        return StreamExpectation(int(unique.size), int(s.size - unique.size), ooo, lost)


def unit_ids_for(names: list[str]) -> dict[str, int]:
    """Unit id per unit name: ``k`` for names ``su<k>`` when all names have that form and the ``k``
    are distinct and < 65536; otherwise 1, 2, ... in order."""
    nums = [re.fullmatch(r"su(\d+)", n) for n in names]
    if all(nums):
        ids = [int(m.group(1)) for m in nums]  # type: ignore[union-attr]
        if len(set(ids)) == len(ids) and max(ids, default=0) < 65536:
            return dict(zip(names, ids, strict=True))
    return {n: i + 1 for i, n in enumerate(names)}


class SkinEmulator:
    """UDP emulator of skin units and the robot (see module docstring).

    Args:
        dataset: what to play. host, port: destination (loopback by default).
        faults: fault configuration. rng: the only source of randomness.
        speed: data seconds per wall second (> 0). batch: samples per packet.
        clocks: device clock per unit name (default: offset 0, no drift); ``robot_clock`` for joints.
        duration_s: play only samples with ``t - t_first < duration_s``.
        max_datagrams: stop after this many datagrams. joints: send the joint stream too.
        seq_start: first packet sequence number of every stream (test wrap-around with ~2^32).
        max_burst: datagrams sent back to back before yielding the CPU for ``burst_pause_s``.
    """

    def __init__(
        self,
        dataset: Dataset,
        port: int,
        *,
        host: str = "127.0.0.1",
        faults: Faults | None = None,
        rng: np.random.Generator | None = None,
        speed: float = 1.0,
        batch: int = 1,
        clocks: dict[str, DeviceClock] | None = None,
        robot_clock: DeviceClock | None = None,
        duration_s: float | None = None,
        max_datagrams: int | None = None,
        joints: bool = True,
        seq_start: int = 0,
        max_burst: int = 32,
        burst_pause_s: float = 2e-4,
    ) -> None:
        if not speed > 0 or not np.isfinite(speed):
            raise ConfigError(f"emulator: --speed {speed} must be a finite number > 0")
        if batch < 1 or not 0 <= port <= 65535 or max_burst < 1:
            raise ConfigError("emulator: batch >= 1 sample, port in 0..65535 and max_burst >= 1 required")
        self.dataset, self.addr = dataset, (host, int(port))
        self.faults = faults or Faults()
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.speed, self.batch = float(speed), int(batch)
        self.clocks = clocks or {}
        self.robot_clock = robot_clock or DeviceClock()
        self.duration_s, self.max_datagrams = duration_s, max_datagrams
        self.joints, self.seq_start = joints and dataset.joints is not None, int(seq_start)  # IMU-only: none
        self.max_burst, self.burst_pause_s = int(max_burst), float(burst_pause_s)
        self._stop = threading.Event()
        self._plan()

    # -- schedule --------------------------------------------------------------------------
    def _plan(self) -> None:
        ds = self.dataset
        times = [s.t for s in ds.imu.values()] + [s.t for s in ds.tof.values()]
        times += [ds.joints.t] if self.joints else []
        times = [np.asarray(t, dtype=float) for t in times if len(t)]
        if not times:
            raise ConfigError("emulator: the dataset has no samples to send")
        self.t_first = min(float(t[0]) for t in times)
        self.unit_ids = unit_ids_for(list(dict.fromkeys([*ds.imu, *ds.tof])))
        # sources: (key, kind, arrays, device_us); packets: (source, start, stop, send time)
        self._sources: list[tuple[StreamKey, int, dict[str, np.ndarray], np.ndarray]] = []
        rows = []
        for kind, streams in ((_IMU, ds.imu), (_TOF, ds.tof)):
            for name, st in streams.items():
                if kind == _IMU:
                    arrays = {"t": st.t, "accel": st.accel, "gyro": st.gyro}
                else:
                    arrays = {"t": st.t, "range": st.range}
                clock = self.clocks.get(name, DeviceClock())
                rows.append(self._add_source(("skin", self.unit_ids[name]), kind, arrays, clock))
        if self.joints:
            arrays = {"t": ds.joints.t, "q": ds.joints.q, "qd": ds.joints.qd}
            rows.append(self._add_source(("joints", 0), _JOINTS, arrays, self.robot_clock))
        plan = np.concatenate([r for r in rows if r.size]) if any(r.size for r in rows) else np.empty((0, 4))
        plan = plan[np.argsort(plan[:, 3], kind="stable")]
        src, start, stop, send_t = plan[:, 0].astype(int), plan[:, 1].astype(int), plan[:, 2].astype(int), plan[:, 3]
        keys = [self._sources[i][0] for i in range(len(self._sources))]
        key_idx = np.array([sorted(set(keys)).index(k) for k in keys], dtype=int)
        stream_of = key_idx[src] if src.size else np.empty(0, dtype=int)
        seq = np.zeros(src.size, dtype=np.int64)
        for k in np.unique(stream_of):  # per stream, sequence numbers in send order
            sel = stream_of == k
            seq[sel] = self.seq_start + np.arange(int(sel.sum()))
        self._apply_faults(src, start, stop, send_t, seq, sorted(set(keys)), stream_of)

    def _add_source(self, key: StreamKey, kind: int, arrays: dict, clock: DeviceClock) -> np.ndarray:
        t = np.asarray(arrays["t"], dtype=float)
        n = t.size if self.duration_s is None else int(np.searchsorted(t - self.t_first, self.duration_s))
        arrays = {k: (None if v is None else np.asarray(v, dtype=float)[:n]) for k, v in arrays.items()}
        device_us = clock.device_us(arrays["t"] - self.t_first)
        self._sources.append((key, kind, arrays, device_us))
        starts = np.arange(0, n, self.batch)
        stops = np.minimum(starts + self.batch, n)
        send_t = arrays["t"][stops - 1] - self.t_first if n else np.empty(0)
        return np.column_stack([np.full(starts.size, len(self._sources) - 1), starts, stops, send_t])

    def device_stamps_us(self, unit: str) -> np.ndarray:
        """``(N,)`` the device clock stamps (us) the emulator sends with the IMU samples of ``unit`` (the
        dataset's instants through that unit's :class:`DeviceClock`), to compare a receiver's clock fit with."""
        key = ("skin", self.unit_ids[unit])
        return next(us for k, kind, _, us in self._sources if k == key and kind == _IMU)

    def _apply_faults(self, src, start, stop, send_t, seq, keys, stream_of) -> None:
        f, rng, n = self.faults, self.rng, src.size
        dropped = rng.random(n) < f.loss
        dup = (rng.random(n) < f.duplicate) & ~dropped
        kept = np.flatnonzero(~dropped)
        d_idx = np.repeat(kept, 1 + dup[kept].astype(int))  # datagram -> packet
        m = d_idx.size
        corrupt = rng.random(m) < f.corrupt
        corrupt_pos, corrupt_xor = rng.random(m), rng.integers(1, 256, m)
        moved = rng.random(m) < f.reorder
        shift = np.where(moved, rng.integers(1, f.reorder_depth + 1, m) + 0.5, 0.0)
        order = np.argsort(np.arange(m) + shift, kind="stable")
        jitter = rng.exponential(f.jitter_s, m) if f.jitter_s > 0 else np.zeros(m)
        # wall-clock send instants, s after the start, non-decreasing in the final order
        d_send = np.maximum.accumulate((send_t[d_idx] / self.speed + jitter)[order]) if m else np.empty(0)
        d_idx, corrupt, corrupt_pos, corrupt_xor = d_idx[order], corrupt[order], corrupt_pos[order], corrupt_xor[order]
        self._datagrams = (d_idx, d_send, corrupt, corrupt_pos, corrupt_xor)
        self._packets = (src, start, stop, seq)
        per = {k: stream_of == i for i, k in enumerate(keys)}
        d_stream = stream_of[d_idx]
        self._report = EmulatorReport(
            unit_ids=dict(self.unit_ids),
            packets={k: int(sel.sum()) for k, sel in per.items()},
            samples={k: int((stop - start)[sel].sum()) for k, sel in per.items()},
            dropped={k: seq[sel & dropped] for k, sel in per.items()},
            duplicated={k: seq[sel & dup] for k, sel in per.items()},
            corrupted={k: seq[d_idx[(d_stream == i) & corrupt]] for i, k in enumerate(keys)},
            reordered=int(moved.sum()),
            order={k: seq[d_idx[(d_stream == i) & ~corrupt]] for i, k in enumerate(keys)},
            datagrams_planned=m,
            t_first=self.t_first,
        )

    @property
    def plan(self) -> EmulatorReport:
        """The planned faults (before sending; counts of what was sent are filled in by :meth:`run`)."""
        return self._report

    # -- sending ---------------------------------------------------------------------------
    def _encode(self, i: int) -> bytes:
        d_idx, _, corrupt, pos, xor = self._datagrams
        src, start, stop, seq = self._packets
        p = int(d_idx[i])
        key, kind, arrays, device_us = self._sources[int(src[p])]
        a, b, s = int(start[p]), int(stop[p]), int(seq[p]) % (1 << 32)
        if kind == _JOINTS:
            data = encode_joint_packet(key[1], s, device_us[a:b], arrays["q"][a:b], arrays["qd"][a:b])
        elif kind == _IMU:
            gyro = arrays["gyro"]
            data = encode_packet(key[1], s, device_us[a:b], accel=arrays["accel"][a:b],
                                 gyro=None if gyro is None else gyro[a:b])
        else:
            data = encode_packet(key[1], s, device_us[a:b], range=arrays["range"][a:b])
        if corrupt[i]:
            buf = bytearray(data)
            buf[int(pos[i] * len(buf))] ^= int(xor[i])
            data = bytes(buf)
        return data

    def stop(self) -> None:
        """Ask a running :meth:`run` to stop after the current datagram (thread-safe)."""
        self._stop.set()

    def run(self, max_wall_s: float | None = None) -> EmulatorReport:
        """Send everything (blocking), paced at ``speed``; stop early on :meth:`stop`, ``max_datagrams``
        or ``max_wall_s`` seconds. Returns the report with the counts of what was sent."""
        _, d_send, _, _, _ = self._datagrams
        limit = d_send.size if self.max_datagrams is None else min(d_send.size, self.max_datagrams)
        sent = errors = burst = 0
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            start = time.monotonic() + 0.01
            deadline = None if max_wall_s is None else start + max_wall_s
            for i in range(limit):
                target = start + d_send[i]
                now = time.monotonic()
                if self._stop.is_set() or (deadline is not None and now > deadline):
                    break
                if target - now > 5e-4:
                    time.sleep(target - now)
                    burst = 0
                elif burst >= self.max_burst:
                    time.sleep(self.burst_pause_s)
                    burst = 0
                try:
                    sock.sendto(self._encode(i), self.addr)
                    sent += 1
                except OSError:
                    errors += 1
                burst += 1
        r = self._report
        return EmulatorReport(**{**r.__dict__, "datagrams_sent": sent, "send_errors": errors, "start_host_s": start,
                                 "wall_s": time.monotonic() - start, "completed": sent + errors == d_send.size})

    async def run_async(self, max_wall_s: float | None = None) -> EmulatorReport:
        """:meth:`run` in a worker thread, so a receiver can share the event loop."""
        return await asyncio.to_thread(self.run, max_wall_s)
