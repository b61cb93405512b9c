"""Host side of the skin hardware: UDP packet format, receiver, clock sync, recorder, emulator.

``docs/packet-format.md`` documents the wire format. The receiver binds 127.0.0.1 by default.
"""

from skincal.hw.clock import ClockEstimator, ClockFit, fit_lower_envelope
from skincal.hw.emulator import DeviceClock, EmulatorReport, Faults, SkinEmulator, StreamExpectation, unit_ids_for
from skincal.hw.packet import (
    BadChecksumError,
    BadFieldError,
    BadLengthError,
    BadMagicError,
    BadValueError,
    JointPacket,
    PacketError,
    ShortPacketError,
    SkinPacket,
    UnknownVersionError,
    decode_packet,
    encode_joint_packet,
    encode_packet,
)
from skincal.hw.receiver import Delivery, ReceiverStats, SkinReceiver, StreamKey, StreamStats
from skincal.hw.recorder import Recorder, RecordingSummary, default_unit_name
from skincal.hw.session import record

__all__ = [
    "BadChecksumError", "BadFieldError", "BadLengthError", "BadMagicError", "BadValueError", "ClockEstimator",
    "ClockFit",
    "Delivery", "DeviceClock", "EmulatorReport", "Faults", "JointPacket", "PacketError", "ReceiverStats",
    "Recorder", "RecordingSummary", "ShortPacketError", "SkinEmulator", "SkinPacket", "SkinReceiver",
    "StreamExpectation", "StreamKey", "StreamStats", "UnknownVersionError", "decode_packet", "default_unit_name",
    "encode_joint_packet", "encode_packet", "fit_lower_envelope", "record", "unit_ids_for",
]
