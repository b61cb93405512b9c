"""Asyncio UDP receiver of skin and joint-state packets with per-source accounting and ordering.

Each source (``("skin", unit_id)`` or ``("joints", robot_id)``) is one stream of packet sequence
numbers. Per stream the receiver:

* drops and counts duplicates (a sequence number already delivered or buffered);
* counts packets arriving out of order (sequence number below the highest one seen) and puts them
  back in order in a reorder buffer of ``reorder_window`` packets / ``reorder_timeout_s`` seconds;
* when the buffer overflows or times out, skips the missing numbers: each counts as ``lost``; a
  skipped packet that arrives afterwards is dropped and moves from ``lost`` to ``late``. So ``lost``
  is exactly the number of sequence numbers never received between the first and last delivered;
* feeds (host receive time, device timestamp of the packet's last sample) to a
  :class:`~skincal.hw.clock.ClockEstimator`;
* tells a device *restart* from replayed or stale packets. A packet is *off the stream's epoch* when
  its device timestamp is more than ``restart_s`` older than the newest one of the stream, or more
  than ``restart_s`` ahead of it beyond the host time elapsed since, or newer while its sequence
  number is already passed, or when its sequence number jumps ahead by more than ``reorder_window``
  and more packets than one per 10 µs of device time (no phantom losses from one crafted number).
  The packet format has no boot id, so one such packet proves nothing (a
  replay looks the same): off-epoch packets are held as a candidate run, and only a consistent run
  (sequence numbers within ``reorder_window`` of each other and device times ordered like them) of
  ``restart_packets`` packets spanning ``restart_confirm_s`` of host time, with no new packet of the
  running epoch arriving meanwhile, is a restart: buffered packets are delivered,
  ``on_restart(key, last_fit)`` is called, sequence state and clock fit start afresh, the run is
  replayed into them, and ``restarts`` counts it. A run broken by a packet of the running epoch, or
  by an inconsistent one, or still unconfirmed when the receiver stops, counts as ``stale`` packets
  (never delivered, never in the clock fit);
* accepts at most ``max_units`` skin unit ids and ``max_robots`` joint-state sources (the first seen);
  datagrams of further sources are counted as ``refused`` and dropped, so a flood of ids cannot grow
  memory or the recording.

Invalid datagrams are counted by :attr:`PacketError.reason`; nothing a sender does stops the
receiver. In-order packets go to ``on_packet(Delivery)``. Sequence numbers are unwrapped (u32) into
Python ints, so streams run past 2^32 packets.
"""

from __future__ import annotations

import asyncio
import socket
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from skincal.errors import ConfigError
from skincal.hw.clock import ClockEstimator, ClockFit
from skincal.hw.packet import JointPacket, PacketError, SkinPacket, decode_packet

StreamKey = tuple[str, int]
"""``("skin", unit_id)`` or ``("joints", robot_id)``."""

_LATE_MEMORY = 1 << 16  # skipped sequence numbers remembered to tell "late" from "duplicate"
_MIN_PACKET_INTERVAL_US = 10  # no device sends packets faster: a longer sequence jump is off the epoch
_RUN_MEMORY = 4096  # off-epoch packets held per stream while a restart is unconfirmed (older ones: stale)


@dataclass(frozen=True)
class Delivery:
    """One packet released in sequence order, with its host receive time (s, ``host_clock``)."""

    key: StreamKey
    packet: SkinPacket | JointPacket
    host_receive_s: float


@dataclass(frozen=True)
class StreamStats:
    """Counters of one stream (packets unless named ``samples``). ``buffered``: waiting in the reorder
    buffer; ``held``: off-epoch packets held while a restart is unconfirmed (they end up delivered or
    ``stale``). Every decoded datagram of the stream is in exactly one of ``received``, ``duplicates``,
    ``late``, ``stale``, ``held``."""

    received: int = 0
    samples: int = 0
    delivered: int = 0
    duplicates: int = 0
    out_of_order: int = 0
    lost: int = 0
    late: int = 0
    restarts: int = 0
    buffered: int = 0
    stale: int = 0
    held: int = 0


@dataclass(frozen=True)
class ReceiverStats:
    """Snapshot of every stream's counters, malformed datagrams by reason, the datagram total and the
    datagrams refused because their source was beyond ``max_units`` / ``max_robots``."""

    streams: dict[StreamKey, StreamStats]
    malformed: dict[str, int]
    datagrams: int
    refused: int = 0

    @property
    def malformed_total(self) -> int:
        return sum(self.malformed.values())


@dataclass
class _Stream:
    clock: ClockEstimator
    next_seq: int | None = None  # next sequence number to deliver (unwrapped)
    first_seq: int | None = None  # first sequence number delivered
    highest: int | None = None
    buffer: dict[int, tuple[SkinPacket | JointPacket, float]] = field(default_factory=dict)
    oldest_s: float = 0.0
    skipped: set[int] = field(default_factory=set)
    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(
        ("received", "samples", "delivered", "duplicates", "out_of_order", "lost", "late", "restarts", "stale"), 0))
    max_device_us: int = -1  # newest device timestamp of the epoch, µs (-1: none yet)
    max_host_s: float = 0.0  # host time it arrived at
    run: deque[tuple[SkinPacket | JointPacket, float]] = field(default_factory=deque)  # restart candidates
    run_top: SkinPacket | JointPacket | None = None  # the run's packet with the newest device time

    def unwrap(self, seq: int) -> int:
        ref = self.highest if self.highest is not None else seq
        return ref + ((seq - ref + (1 << 31)) % (1 << 32)) - (1 << 31)


class _Protocol(asyncio.DatagramProtocol):
    def __init__(self, receiver: SkinReceiver) -> None:
        self.receiver = receiver

    def datagram_received(self, data: bytes, addr: tuple) -> None:
        self.receiver.handle_datagram(data)

    def error_received(self, exc: Exception) -> None:  # ICMP errors etc.: count, keep going
        self.receiver._count_malformed("socket_error")


class SkinReceiver:
    """UDP receiver (see module docstring).

    Args:
        host: address to bind, ``127.0.0.1`` by default. port: 0 picks a free port (see :attr:`port`).
        on_packet: called with each :class:`Delivery` in sequence order per stream.
        reorder_window: packets buffered per stream waiting for a missing one.
        reorder_timeout_s: longest a packet waits for a missing predecessor, s.
        host_clock: host time source, s (``time.monotonic``).
        rcvbuf_bytes: requested socket receive buffer (the kernel may cap it).
        clock_estimator: factory of the per-stream :class:`ClockEstimator` (e.g. to change ``min_span_s``).
        restart_s: device-time jump (s) that puts a packet off the stream's epoch (see module docstring).
        restart_packets, restart_confirm_s: a restart needs a consistent run of this many off-epoch
            packets spanning this many seconds of host time.
        max_units, max_robots: skin unit ids and joint-state sources accepted (first come); more are refused.
        on_restart: called with the stream key and its last clock fit (``None`` if none) when a restart
            is confirmed, after the buffered packets of the old epoch were delivered.
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 0,
        *,
        on_packet: Callable[[Delivery], None] | None = None,
        reorder_window: int = 64,
        reorder_timeout_s: float = 0.2,
        host_clock: Callable[[], float] = time.monotonic,
        rcvbuf_bytes: int = 4 << 20,
        clock_estimator: Callable[[], ClockEstimator] = ClockEstimator,
        restart_s: float = 5.0,
        restart_packets: int = 8,
        restart_confirm_s: float = 0.2,
        max_units: int = 64,
        max_robots: int = 4,
        on_restart: Callable[[StreamKey, ClockFit | None], None] | None = None,
    ) -> None:
        if reorder_window < 1 or reorder_timeout_s <= 0:
            raise ConfigError("receiver: reorder_window must be >= 1 packet and reorder_timeout_s > 0 s")
        if not restart_s > 0 or restart_packets < 1 or not restart_confirm_s >= 0:
            raise ConfigError("receiver: restart_s > 0 s, restart_packets >= 1 and restart_confirm_s >= 0 s required")
        if max_units < 0 or max_robots < 0:
            raise ConfigError(f"receiver: max_units {max_units} and max_robots {max_robots} must be >= 0")
        if not 0 <= port <= 65535:
            raise ConfigError(f"receiver: port {port} out of range 0..65535")
        self.host, self._requested_port = host, port
        self.on_packet = on_packet
        self.reorder_window = int(reorder_window)
        self.reorder_timeout_s = float(reorder_timeout_s)
        self.host_clock = host_clock
        self.rcvbuf_bytes = rcvbuf_bytes
        self.clock_estimator = clock_estimator
        self.restart_us = int(restart_s * 1e6)
        self.restart_packets, self.restart_confirm_s = int(restart_packets), float(restart_confirm_s)
        self.max_sources = {"skin": int(max_units), "joints": int(max_robots)}
        self.on_restart = on_restart
        self._streams: dict[StreamKey, _Stream] = {}
        self._n_sources = {"skin": 0, "joints": 0}
        self._malformed: dict[str, int] = {}
        self._datagrams = 0
        self._refused = 0
        self._transport: asyncio.DatagramTransport | None = None
        self._sweeper: asyncio.Task | None = None
        self.port: int | None = None

    # -- lifecycle -------------------------------------------------------------------------
    async def start(self) -> int:
        """Bind the socket and start receiving; returns the bound port."""
        loop = asyncio.get_running_loop()
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, self.rcvbuf_bytes)
            sock.bind((self.host, self._requested_port))
        except OSError as exc:
            sock.close()
            where = f"{self.host}:{self._requested_port}"
            raise ConfigError(f"receiver: cannot bind {where}: {exc.strerror or exc}") from exc
        sock.setblocking(False)
        self._transport, _ = await loop.create_datagram_endpoint(lambda: _Protocol(self), sock=sock)
        self.port = int(sock.getsockname()[1])
        self._sweeper = asyncio.create_task(self._sweep())
        return self.port

    @property
    def bound_address(self) -> tuple[str, int] | None:
        """``(host, port)`` the socket is bound to, as the operating system reports it; None when stopped."""
        if self._transport is None:
            return None
        host, port = self._transport.get_extra_info("sockname")[:2]
        return str(host), int(port)

    async def stop(self) -> None:
        """Stop receiving and deliver everything still buffered (missing ones count as lost)."""
        if self._sweeper is not None:
            self._sweeper.cancel()
            try:
                await self._sweeper
            except asyncio.CancelledError:
                pass
            self._sweeper = None
        if self._transport is not None:
            self._transport.close()
            self._transport = None
        self.flush()

    async def __aenter__(self) -> SkinReceiver:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    async def _sweep(self) -> None:
        while True:
            await asyncio.sleep(self.reorder_timeout_s / 4)
            self.release_stale()

    # -- input -----------------------------------------------------------------------------
    def _count_malformed(self, reason: str) -> None:
        self._malformed[reason] = self._malformed.get(reason, 0) + 1

    def handle_datagram(self, data: bytes, host_s: float | None = None) -> None:
        """Process one datagram (called by the protocol; public for replaying captures)."""
        host_s = self.host_clock() if host_s is None else host_s
        self._datagrams += 1
        try:
            packet = decode_packet(data)
        except PacketError as exc:
            self._count_malformed(exc.reason)
            return
        if isinstance(packet, SkinPacket):
            key: StreamKey = ("skin", packet.unit_id)
        else:
            key = ("joints", packet.source_id)
        stream = self._streams.get(key)
        if stream is None:
            if self._n_sources[key[0]] >= self.max_sources[key[0]]:
                self._refused += 1
                return
            self._n_sources[key[0]] += 1
            stream = self._streams[key] = _Stream(self.clock_estimator())
        self._accept(key, stream, packet, host_s)

    def _off_epoch(self, s: _Stream, seq: int, t_last: int, host_s: float) -> bool:
        if s.max_device_us < 0:
            return False
        behind = s.next_seq is not None and seq < s.next_seq
        ahead_us = t_last - s.max_device_us - max(host_s - s.max_host_s, 0.0) * 1e6
        jump = 0 if s.highest is None else seq - s.highest  # more packets than the device could have sent
        too_far = jump > self.reorder_window and jump > max(t_last - s.max_device_us, 0) // _MIN_PACKET_INTERVAL_US
        return t_last < s.max_device_us - self.restart_us or ahead_us > self.restart_us or too_far or (
            behind and t_last > s.max_device_us)

    def _accept(self, key: StreamKey, s: _Stream, packet: SkinPacket | JointPacket, host_s: float) -> None:
        seq = s.unwrap(packet.seq)
        c = s.counts
        t_last = int(packet.t_us[-1])
        if self._off_epoch(s, seq, t_last, host_s):
            self._candidate(key, s, packet, host_s)
            return
        if s.next_seq is not None and seq < s.next_seq:
            if s.first_seq is not None and seq < s.first_seq:  # before the stream's start: late
                c["late"] += 1
            elif seq in s.skipped:  # declared lost, arrived after all
                s.skipped.discard(seq)
                c["lost"] -= 1
                c["late"] += 1
            else:
                c["duplicates"] += 1
            return
        if seq in s.buffer:
            c["duplicates"] += 1
            return
        if s.run:  # the running epoch goes on: the candidate run was replayed or stale
            self._drop_run(s)
        if t_last > s.max_device_us:
            s.max_device_us, s.max_host_s = t_last, host_s
        c["received"] += 1
        c["samples"] += packet.n_samples
        if s.highest is not None and seq < s.highest:
            c["out_of_order"] += 1
        s.highest = seq if s.highest is None else max(s.highest, seq)
        s.clock.add(host_s, packet.t_us[-1] * 1e-6)
        if not s.buffer:
            s.oldest_s = host_s
        s.buffer[seq] = (packet, host_s)
        self._release(key, s, force=len(s.buffer) > self.reorder_window)

    def _candidate(self, key: StreamKey, s: _Stream, packet: SkinPacket | JointPacket, host_s: float) -> None:
        """Hold an off-epoch packet in the candidate run; confirm a restart when the run is long enough."""
        t_last = int(packet.t_us[-1])
        top = s.run_top
        if top is not None:
            step = (packet.seq - top.seq + (1 << 31)) % (1 << 32) - (1 << 31)
            dt = t_last - int(top.t_us[-1])
            if step == 0 and dt == 0:
                s.counts["duplicates"] += 1
                return
            if not (0 < abs(step) <= self.reorder_window and step * dt > 0 and abs(dt) <= self.restart_us):
                self._drop_run(s)  # not one device counting on: start over from this packet
        if s.run_top is None or t_last > int(s.run_top.t_us[-1]):
            s.run_top = packet
        s.run.append((packet, host_s))
        if len(s.run) > max(_RUN_MEMORY, self.restart_packets):
            s.run.popleft()
            s.counts["stale"] += 1
        if len(s.run) >= self.restart_packets and host_s - s.run[0][1] >= self.restart_confirm_s:
            run = sorted(s.run, key=lambda ph: int(ph[0].t_us[-1]))
            s.run.clear()
            s.run_top = None
            self._restart(key, s)
            for p, h in run:
                self._accept(key, s, p, h)

    def _drop_run(self, s: _Stream) -> None:
        s.counts["stale"] += len(s.run)
        s.run.clear()
        s.run_top = None

    # -- ordering --------------------------------------------------------------------------
    def _release(self, key: StreamKey, s: _Stream, force: bool) -> None:
        while s.buffer:
            if s.next_seq is None or s.next_seq not in s.buffer:
                if not force:  # wait: a stream starts (or skips a hole) only on overflow or timeout
                    break
                start = min(s.buffer)
                if s.next_seq is None:
                    s.first_seq = start
                else:
                    self._skip(s, s.next_seq, start)
                s.next_seq = start
            if s.next_seq not in s.buffer:
                break
            packet, host_s = s.buffer.pop(s.next_seq)
            s.next_seq += 1
            s.counts["delivered"] += 1
            if self.on_packet is not None:
                self.on_packet(Delivery(key, packet, host_s))
            force = len(s.buffer) > self.reorder_window
        if s.buffer:
            s.oldest_s = min(h for _, h in s.buffer.values())

    def _restart(self, key: StreamKey, s: _Stream) -> None:
        while s.buffer:
            self._release(key, s, force=True)
        if self.on_restart is not None:
            self.on_restart(key, s.clock.fit())
        s.next_seq = s.first_seq = s.highest = None
        s.skipped.clear()
        s.clock = self.clock_estimator()
        s.max_device_us = -1
        s.counts["restarts"] += 1

    def _skip(self, s: _Stream, first: int, stop: int) -> None:
        s.counts["lost"] += stop - first
        s.skipped.update(range(max(first, stop - _LATE_MEMORY), stop))
        if len(s.skipped) > _LATE_MEMORY:
            floor = stop - _LATE_MEMORY
            s.skipped = {q for q in s.skipped if q >= floor}

    def release_stale(self, now_s: float | None = None) -> None:
        """Give up waiting for missing packets older than ``reorder_timeout_s``."""
        now_s = self.host_clock() if now_s is None else now_s
        for key, s in self._streams.items():
            while s.buffer and now_s - s.oldest_s >= self.reorder_timeout_s:
                self._release(key, s, force=True)

    def flush(self) -> None:
        """Deliver everything buffered now, counting the holes as lost; an unconfirmed restart run is stale."""
        for key, s in self._streams.items():
            while s.buffer:
                self._release(key, s, force=True)
            self._drop_run(s)

    # -- output ----------------------------------------------------------------------------
    def stats(self) -> ReceiverStats:
        """A snapshot of all counters."""
        streams = {
            key: StreamStats(**s.counts, buffered=len(s.buffer), held=len(s.run))
            for key, s in sorted(self._streams.items())
        }
        return ReceiverStats(streams, dict(self._malformed), self._datagrams, self._refused)

    def clock_fit(self, key: StreamKey) -> ClockFit | None:
        """Current device-to-host clock fit of one stream (``None`` if unseen)."""
        s = self._streams.get(key)
        return None if s is None else s.clock.fit()

    def clock_fits(self) -> dict[StreamKey, ClockFit]:
        """Current clock fits of all streams."""
        fits = {key: s.clock.fit() for key, s in self._streams.items()}
        return {key: fit for key, fit in fits.items() if fit is not None}
