"""Hostile input to the hardware path (issue 19): crafted and fuzzed packets, replays, floods of unit ids,
NaN samples and ``--bind`` beyond loopback. Receivers run on real UDP sockets on 127.0.0.1 and every
recording is read back with :func:`skincal.data.hdf5.read_dataset`."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

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
    flags = draw(st.integers(0, 255))
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
