"""The skin UDP packet format, version 1 (``docs/packet-format.md`` is the normative description).

Two packet types share one 20-byte little-endian header and end with a CRC-32 (``zlib.crc32``)
of every byte before it:

* skin packet, magic ``b"SU"``: ``n`` samples of one skin unit; ``flags`` say which of accel
  (3 x f32, m/s^2 specific force in the unit frame), gyro (3 x f32, rad/s) and range (f32, m, NaN =
  no target) each sample carries;
* joint-state packet, magic ``b"SJ"``: ``n`` samples of the robot's joint positions (rad) and
  velocities (rad/s), ``n_joints`` x f64 each.

``seq`` counts packets per source (unit id or robot id), wrapping at 2^32; ``t0_us`` is the device
timestamp of the first sample (u64, microseconds on the device's own clock) and each sample stores
its offset from it (u32, microseconds). Decoding is vectorised with NumPy structured dtypes.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from skincal.errors import ConfigError, SkincalError

VERSION = 1
"""Packet format version written by :func:`encode_packet` and the only one :func:`decode_packet` reads."""
MAGIC_SKIN = b"SU"
MAGIC_JOINTS = b"SJ"
HEADER = struct.Struct("<2sBBHHIQ")
"""magic, version, flags (skin) / n_joints (joints), source id, n samples, seq, t0_us."""
CRC = struct.Struct("<I")
MIN_SIZE = HEADER.size + CRC.size
MAX_DATAGRAM = 65507
"""Largest UDP payload over IPv4, bytes; keep packets <= 1472 bytes to avoid IP fragmentation."""

FLAG_ACCEL = 0x01
FLAG_GYRO = 0x02
FLAG_RANGE = 0x04
_FLAGS_ALL = FLAG_ACCEL | FLAG_GYRO | FLAG_RANGE
MAX_JOINTS = 32
MAX_T0_US = (1 << 63) - (1 << 32)
"""Largest ``t0_us`` accepted: every sample time ``t0_us + dt_us`` then fits in an int64 (~146,000 years)."""


class PacketError(SkincalError, ValueError):
    """A datagram is not a valid skincal packet; ``reason`` is a short machine-readable tag."""

    reason = "malformed"


class ShortPacketError(PacketError):
    """Fewer bytes than a header plus checksum."""

    reason = "short"


class BadMagicError(PacketError):
    """The first two bytes are neither ``SU`` nor ``SJ``."""

    reason = "bad_magic"


class BadChecksumError(PacketError):
    """The trailing CRC-32 does not match the bytes before it."""

    reason = "bad_checksum"


class UnknownVersionError(PacketError):
    """A version this reader does not know."""

    reason = "unknown_version"


class BadLengthError(PacketError):
    """The datagram length disagrees with the header (sample count, flags, joint count)."""

    reason = "bad_length"


class BadFieldError(PacketError):
    """A header field is out of range (no samples, reserved flag bits, zero joints, ``t0_us`` beyond int64)."""

    reason = "bad_field"


class BadValueError(PacketError):
    """A sample value no dataset can hold: a NaN or infinite accel, gyro, q or qd; an infinite or
    negative range (NaN is "no target" and allowed)."""

    reason = "bad_value"


@dataclass(frozen=True)
class SkinPacket:
    """Decoded skin packet.

    Attributes:
        unit_id: source unit id (u16).
        seq: packet sequence number of this unit (u32, wraps).
        t_us: ``(n,)`` int64 device timestamps of the samples, microseconds (device clock).
        accel: ``(n, 3)`` specific force in the unit frame, m/s^2, or ``None``.
        gyro: ``(n, 3)`` angular rate in the unit frame, rad/s, or ``None``.
        range: ``(n,)`` time-of-flight range along the unit's +z, m (NaN = no target), or ``None``.
    """

    unit_id: int
    seq: int
    t_us: np.ndarray
    accel: np.ndarray | None = None
    gyro: np.ndarray | None = None
    range: np.ndarray | None = None

    @property
    def n_samples(self) -> int:
        return int(self.t_us.shape[0])

    @property
    def flags(self) -> int:
        return (
            (FLAG_ACCEL if self.accel is not None else 0)
            | (FLAG_GYRO if self.gyro is not None else 0)
            | (FLAG_RANGE if self.range is not None else 0)
        )


@dataclass(frozen=True)
class JointPacket:
    """Decoded joint-state packet: ``t_us`` ``(n,)`` int64 µs (robot clock), ``q`` ``(n, J)`` rad,
    ``qd`` ``(n, J)`` rad/s, from robot ``source_id`` with packet sequence number ``seq``."""

    source_id: int
    seq: int
    t_us: np.ndarray
    q: np.ndarray
    qd: np.ndarray

    @property
    def n_samples(self) -> int:
        return int(self.t_us.shape[0])


def skin_sample_dtype(flags: int) -> np.dtype:
    """Structured little-endian dtype of one skin sample for ``flags`` (see module docstring)."""
    fields: list[tuple] = [("dt_us", "<u4")]
    if flags & FLAG_ACCEL:
        fields.append(("accel", "<f4", (3,)))
    if flags & FLAG_GYRO:
        fields.append(("gyro", "<f4", (3,)))
    if flags & FLAG_RANGE:
        fields.append(("range", "<f4"))
    return np.dtype(fields)


def joint_sample_dtype(n_joints: int) -> np.dtype:
    """Structured little-endian dtype of one joint-state sample with ``n_joints`` joints."""
    return np.dtype([("dt_us", "<u4"), ("q", "<f8", (n_joints,)), ("qd", "<f8", (n_joints,))])


def _timestamps(t_us: ArrayLike, what: str) -> tuple[int, np.ndarray]:
    t = np.asarray(t_us)
    if t.ndim != 1 or t.shape[0] == 0:
        raise ConfigError(f"{what}: t_us must be a non-empty 1-D array of device timestamps in µs, got {t.shape}")
    t = t.astype(np.int64)
    t0 = int(t[0])
    dt = t - t0
    if t0 < 0 or t0 > MAX_T0_US or np.any(dt < 0) or np.any(dt > 0xFFFFFFFF):
        raise ConfigError(f"{what}: t_us must be in 0..2^63-2^32 µs, non-decreasing and span < 2^32 µs within one "
                          "packet")
    return t0, dt


def _finish(header: bytes, body: bytes, what: str) -> bytes:
    data = header + body
    if len(data) + CRC.size > MAX_DATAGRAM:
        raise ConfigError(f"{what}: {len(data) + CRC.size} bytes exceed the UDP limit of {MAX_DATAGRAM}; send fewer")
    return data + CRC.pack(zlib.crc32(data))


def _check_id_seq(source: int, seq: int, n: int, what: str) -> None:
    if not 0 <= source <= 0xFFFF:
        raise ConfigError(f"{what}: id {source} out of range 0..65535")
    if not 0 <= seq <= 0xFFFFFFFF:
        raise ConfigError(f"{what}: seq {seq} out of range 0..2^32-1")
    if not 1 <= n <= 0xFFFF:
        raise ConfigError(f"{what}: {n} samples out of range 1..65535")


def encode_packet(
    unit_id: int,
    seq: int,
    t_us: ArrayLike,
    accel: ArrayLike | None = None,
    gyro: ArrayLike | None = None,
    range: ArrayLike | None = None,  # noqa: A002  (the field's name in the format)
) -> bytes:
    """Encode ``n`` samples of one skin unit as a version-1 skin packet.

    Args:
        unit_id: 0..65535. seq: packet sequence number, 0..2^32-1 (caller wraps).
        t_us: ``(n,)`` device timestamps, µs, non-decreasing. accel, gyro: ``(n, 3)`` m/s^2, rad/s.
        range: ``(n,)`` m, NaN = no target. At least one of accel, gyro, range must be given.
    """
    what = f"skin packet (unit {unit_id}, seq {seq})"
    t0, dt = _timestamps(t_us, what)
    n = dt.shape[0]
    _check_id_seq(unit_id, seq, n, what)
    flags = (FLAG_ACCEL if accel is not None else 0) | (FLAG_GYRO if gyro is not None else 0)
    flags |= FLAG_RANGE if range is not None else 0
    if flags == 0:
        raise ConfigError(f"{what}: nothing to send (give accel, gyro or range)")
    rec = np.empty(n, dtype=skin_sample_dtype(flags))
    rec["dt_us"] = dt
    for name, value, shape in (("accel", accel, (n, 3)), ("gyro", gyro, (n, 3)), ("range", range, (n,))):
        if value is None:
            continue
        arr = np.asarray(value, dtype=float)
        if arr.shape != shape:
            raise ConfigError(f"{what}: {name} must have shape {shape}, got {arr.shape}")
        rec[name] = arr
    return _finish(HEADER.pack(MAGIC_SKIN, VERSION, flags, unit_id, n, seq, t0), rec.tobytes(), what)


def encode_joint_packet(source_id: int, seq: int, t_us: ArrayLike, q: ArrayLike, qd: ArrayLike) -> bytes:
    """Encode ``n`` joint-state samples: ``t_us`` ``(n,)`` µs (robot clock), ``q`` ``(n, J)`` rad,
    ``qd`` ``(n, J)`` rad/s, ``1 <= J <= 32``."""
    what = f"joint packet (source {source_id}, seq {seq})"
    t0, dt = _timestamps(t_us, what)
    n = dt.shape[0]
    _check_id_seq(source_id, seq, n, what)
    q_arr, qd_arr = np.asarray(q, dtype=float), np.asarray(qd, dtype=float)
    if q_arr.ndim != 2 or q_arr.shape[0] != n or qd_arr.shape != q_arr.shape or not 1 <= q_arr.shape[1] <= MAX_JOINTS:
        raise ConfigError(f"{what}: q and qd must both have shape ({n}, J), 1 <= J <= {MAX_JOINTS}")
    n_joints = q_arr.shape[1]
    rec = np.empty(n, dtype=joint_sample_dtype(n_joints))
    rec["dt_us"], rec["q"], rec["qd"] = dt, q_arr, qd_arr
    return _finish(HEADER.pack(MAGIC_JOINTS, VERSION, n_joints, source_id, n, seq, t0), rec.tobytes(), what)


def decode_packet(data: bytes) -> SkinPacket | JointPacket:
    """Decode one datagram; raise a :class:`PacketError` subclass naming the problem.

    Checks, in order: length >= 24 bytes (short), magic (bad_magic), CRC-32 of all bytes but the
    last four (bad_checksum), version (unknown_version), header fields (bad_field, including
    ``t0_us`` > :data:`MAX_T0_US`), length equal to ``20 + n * sample_size + 4`` (bad_length), sample
    values (bad_value: non-finite accel, gyro, q, qd; infinite or negative range). A single
    corrupted byte outside the magic is always reported as a bad checksum (CRC-32 detects every
    burst of up to 32 bits). Any byte string either decodes or raises a :class:`PacketError`; nothing else.
    """
    size = len(data)
    if size < MIN_SIZE:
        raise ShortPacketError(f"packet: {size} bytes, shorter than the {MIN_SIZE}-byte header + checksum")
    magic, version, flags, source, n, seq, t0 = HEADER.unpack_from(data)
    if magic not in (MAGIC_SKIN, MAGIC_JOINTS):
        raise BadMagicError(f"packet: bad magic {magic!r} (expected {MAGIC_SKIN!r} or {MAGIC_JOINTS!r})")
    (crc,) = CRC.unpack_from(data, size - CRC.size)
    if zlib.crc32(memoryview(data)[: size - CRC.size]) != crc:
        raise BadChecksumError(f"packet: CRC-32 mismatch (stored 0x{crc:08x}) over {size - CRC.size} bytes")
    if version != VERSION:
        raise UnknownVersionError(f"packet: unknown version {version} (this reader knows {VERSION})")
    if n == 0:
        raise BadFieldError("packet: header says 0 samples")
    if magic == MAGIC_SKIN:
        if flags & ~_FLAGS_ALL or flags == 0:
            raise BadFieldError(f"skin packet (unit {source}): bad flags 0x{flags:02x}")
        dtype = skin_sample_dtype(flags)
    else:
        if not 1 <= flags <= MAX_JOINTS:
            raise BadFieldError(f"joint packet (source {source}): n_joints {flags} out of range 1..{MAX_JOINTS}")
        dtype = joint_sample_dtype(flags)
    if t0 > MAX_T0_US:
        raise BadFieldError(f"packet (source {source}, seq {seq}): t0_us {t0} beyond {MAX_T0_US} µs")
    expected = HEADER.size + n * dtype.itemsize + CRC.size
    if size != expected:
        raise BadLengthError(f"packet (source {source}, seq {seq}): {size} bytes, header implies {expected}")
    rec = np.frombuffer(data, dtype=dtype, count=n, offset=HEADER.size)
    t_us = rec["dt_us"].astype(np.int64) + np.int64(t0)
    if magic == MAGIC_JOINTS:
        q, qd = rec["q"].astype(float), rec["qd"].astype(float)  # f64 -> f64: no signalling-NaN trap
        if not (np.isfinite(q).all() and np.isfinite(qd).all()):
            raise BadValueError(f"joint packet (source {source}, seq {seq}): non-finite q or qd")
        return JointPacket(source, seq, t_us, q, qd)
    # every skin field after dt_us is f32: check them all at once, before any cast (a cast of a
    # signalling NaN from arbitrary bytes would raise the FP "invalid" flag)
    words = dtype.itemsize // 4
    values = np.frombuffer(data, dtype="<f4", count=n * words, offset=HEADER.size).reshape(n, words)[:, 1:]
    ok = np.isfinite(values)
    if flags & FLAG_RANGE:
        r = values[:, -1]
        ok[:, -1] = ~(np.isinf(r) | (r < 0))  # NaN: no target
    if not ok.all():
        raise BadValueError(f"skin packet (unit {source}, seq {seq}): non-finite accel or gyro, or an infinite or "
                            "negative range")
    range_m = None
    if flags & FLAG_RANGE:
        with np.errstate(invalid="ignore"):
            range_m = rec["range"].astype(float)
    return SkinPacket(
        unit_id=source,
        seq=seq,
        t_us=t_us,
        accel=rec["accel"].astype(float) if flags & FLAG_ACCEL else None,
        gyro=rec["gyro"].astype(float) if flags & FLAG_GYRO else None,
        range=range_m,
    )
