"""Skin packet format: byte layout against the documented offsets, round trips, every error reason."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest

from skincal.errors import ConfigError, SkincalError
from skincal.hw.packet import (
    FLAG_ACCEL,
    FLAG_GYRO,
    FLAG_RANGE,
    BadChecksumError,
    BadFieldError,
    BadLengthError,
    BadMagicError,
    JointPacket,
    PacketError,
    ShortPacketError,
    SkinPacket,
    UnknownVersionError,
    decode_packet,
    encode_joint_packet,
    encode_packet,
)


def _reseal(body: bytes) -> bytes:
    """Append a correct CRC-32 to hand-made bytes."""
    return body + struct.pack("<I", zlib.crc32(body))


def _sample(rng: np.random.Generator, n: int = 3):
    t_us = 1_000_000_000_000 + np.cumsum(rng.integers(9000, 11000, n))
    return t_us, rng.normal(0, 5, (n, 3)), rng.normal(0, 1, (n, 3)), rng.uniform(0.01, 4.0, n)


def test_layout_matches_documented_offsets():
    """Parse by hand with struct at the offsets of docs/packet-format.md (independent of numpy dtypes)."""
    t_us = np.array([5_000_000_123, 5_000_010_123])
    accel = np.array([[0.5, -1.25, 9.81], [1.0, 2.0, 3.0]])
    gyro = np.array([[0.1, 0.2, 0.3], [-0.1, -0.2, -0.3]])
    rng_m = np.array([0.75, np.nan])
    data = encode_packet(513, 0xDEADBEEF, t_us, accel=accel, gyro=gyro, range=rng_m)
    assert data[0:2] == b"SU"
    assert data[2] == 1
    assert data[3] == FLAG_ACCEL | FLAG_GYRO | FLAG_RANGE
    assert struct.unpack_from("<H", data, 4)[0] == 513
    assert struct.unpack_from("<H", data, 6)[0] == 2
    assert struct.unpack_from("<I", data, 8)[0] == 0xDEADBEEF
    assert struct.unpack_from("<Q", data, 12)[0] == 5_000_000_123
    size = 4 + 12 + 12 + 4
    assert len(data) == 20 + 2 * size + 4
    for i in range(2):
        off = 20 + i * size
        assert struct.unpack_from("<I", data, off)[0] == t_us[i] - t_us[0]
        np.testing.assert_array_equal(struct.unpack_from("<3f", data, off + 4), accel[i].astype(np.float32))
        np.testing.assert_array_equal(struct.unpack_from("<3f", data, off + 16), gyro[i].astype(np.float32))
        np.testing.assert_array_equal(struct.unpack_from("<f", data, off + 28), rng_m[i:i + 1].astype(np.float32))
    assert struct.unpack_from("<I", data, len(data) - 4)[0] == zlib.crc32(data[:-4])


@pytest.mark.parametrize(
    "fields", [("accel",), ("accel", "gyro"), ("range",), ("gyro", "range"), ("accel", "gyro", "range")]
)
def test_skin_round_trip(fields):
    rng = np.random.default_rng(1)
    t_us, accel, gyro, range_m = _sample(rng, 5)
    given = {"accel": accel, "gyro": gyro, "range": range_m}
    kwargs = {k: given[k] for k in fields}
    p = decode_packet(encode_packet(7, 42, t_us, **kwargs))
    assert isinstance(p, SkinPacket)
    assert (p.unit_id, p.seq, p.n_samples) == (7, 42, 5)
    np.testing.assert_array_equal(p.t_us, t_us)
    for name in ("accel", "gyro", "range"):
        got = getattr(p, name)
        if name in fields:
            np.testing.assert_array_equal(got, given[name].astype(np.float32).astype(float))
            np.testing.assert_allclose(got, given[name], rtol=1e-6)  # f32: ~6e-8 relative
        else:
            assert got is None


def test_nan_range_survives():
    p = decode_packet(encode_packet(1, 0, [10, 20], range=[np.nan, 1.5]))
    assert np.isnan(p.range[0]) and p.range[1] == 1.5


def test_joint_round_trip():
    rng = np.random.default_rng(2)
    q, qd = rng.uniform(-2, 2, (4, 7)), rng.uniform(-1, 1, (4, 7))
    t_us = np.array([0, 1000, 2000, 3000]) + 77
    data = encode_joint_packet(3, 2**32 - 1, t_us, q, qd)
    assert data[:2] == b"SJ" and data[3] == 7 and len(data) == 20 + 4 * (4 + 2 * 7 * 8) + 4
    p = decode_packet(data)
    assert isinstance(p, JointPacket)
    assert (p.source_id, p.seq) == (3, 2**32 - 1)
    np.testing.assert_array_equal(p.t_us, t_us)
    np.testing.assert_array_equal(p.q, q)  # f64: exact
    np.testing.assert_array_equal(p.qd, qd)


def test_short_packets():
    good = encode_packet(1, 0, [0], accel=[[0, 0, 9.81]])
    for n in (0, 1, 19, 23):
        with pytest.raises(ShortPacketError) as e:
            decode_packet(good[:n])
        assert e.value.reason == "short"


def test_bad_magic():
    good = encode_packet(1, 0, [0], accel=[[0, 0, 9.81]])
    with pytest.raises(BadMagicError):
        decode_packet(_reseal(b"XX" + good[2:-4]))


def test_every_single_byte_corruption_is_caught():
    """CRC-32 catches any one corrupted byte: outside the magic it is always a bad checksum."""
    good = encode_packet(9, 1234, [0, 10_000], accel=np.ones((2, 3)), gyro=np.zeros((2, 3)))
    rng = np.random.default_rng(3)
    for pos in range(len(good)):
        buf = bytearray(good)
        buf[pos] ^= int(rng.integers(1, 256))
        with pytest.raises(PacketError) as e:
            decode_packet(bytes(buf))
        assert isinstance(e.value, BadMagicError if pos < 2 else BadChecksumError), pos
        assert e.value.reason == ("bad_magic" if pos < 2 else "bad_checksum")


def test_unknown_version_with_valid_checksum():
    good = encode_packet(1, 0, [0], accel=[[0, 0, 9.81]])
    body = bytearray(good[:-4])
    body[2] = 2
    with pytest.raises(UnknownVersionError, match="version 2"):
        decode_packet(_reseal(bytes(body)))


def test_bad_length_and_fields():
    good = encode_packet(1, 0, [0, 1], accel=np.zeros((2, 3)))
    with pytest.raises(BadLengthError):  # one sample cut off, checksum recomputed
        decode_packet(_reseal(good[:-4 - 16]))
    with pytest.raises(BadLengthError):  # trailing garbage
        decode_packet(_reseal(good[:-4] + b"\x00"))
    body = bytearray(good[:-4])
    body[3] = 0x08  # reserved flag bit
    with pytest.raises(BadFieldError):
        decode_packet(_reseal(bytes(body)))
    body = bytearray(good[:-4])
    body[6:8] = b"\x00\x00"  # zero samples
    with pytest.raises(BadFieldError):
        decode_packet(_reseal(bytes(body)))


def test_packet_errors_are_skincal_errors():
    with pytest.raises(SkincalError):
        decode_packet(b"")


def test_encode_rejects_bad_input():
    with pytest.raises(ConfigError):
        encode_packet(1, 0, [0])  # nothing to send
    with pytest.raises(ConfigError):
        encode_packet(70000, 0, [0], range=[1.0])
    with pytest.raises(ConfigError):
        encode_packet(1, 2**32, [0], range=[1.0])
    with pytest.raises(ConfigError):
        encode_packet(1, 0, [10, 5], range=[1.0, 1.0])  # time going backwards
    with pytest.raises(ConfigError):
        encode_packet(1, 0, [0, 1], accel=np.zeros((3, 3)))
    with pytest.raises(ConfigError):
        encode_packet(1, 0, np.arange(5000), accel=np.zeros((5000, 3)))  # > 65507 bytes
