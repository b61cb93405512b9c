"""Received ROS 2 messages decoded one at a time: a malformed or oversized sample is counted and
dropped, never fatal.

``cyclonedds``' ``DataReader.take`` decodes a whole batch and raises on the first bad sample (the
batch is lost with it), so :class:`RawReader` takes the serialised samples (``ddspy_take``, the
call ``take`` itself makes) and :func:`decode` turns each into its struct or ``None``:

* more than ``max_bytes`` (:data:`MAX_BYTES` per type): oversized;
* bytes that are not exactly one serialised struct: malformed. ``cyclonedds`` reads leniently (an
  empty sample decodes as zeros, a string length beyond the data gives a short string), so the
  sample must have its 4-byte plain-CDR encapsulation header and the read must end within the data,
  at most :data:`MAX_PADDING` bytes before its end (ROS 2 writers pad to a multiple of 4); bad UTF-8
  or a sequence beyond the data fails while reading;
* read, but not what the message says it is (:func:`check`): a JointState whose arrays disagree with
  its names, a non-string frame id, more than :data:`MAX_JOINTS` joints: malformed.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Any

from cyclonedds.idl._support import Buffer

from skincal.data.ros2 import messages as m

MAX_JOINTS = 256
"""A JointState with more names is refused (oversized)."""
MAX_BYTES: dict[Any, int] = {
    m.Imu: 4096,
    m.JointState: 64 * 1024,
    m.String: 16 * 1024 * 1024,  # a URDF with inline meshes is large
    m.TFMessage: 1024 * 1024,
    m.DiagnosticArray: 1024 * 1024,
}
"""Largest accepted serialised sample per type, bytes (default :data:`DEFAULT_MAX_BYTES`)."""
DEFAULT_MAX_BYTES = 64 * 1024
MAX_PADDING = 3
"""Trailing bytes allowed after the serialised struct (CDR padding to a multiple of 4)."""
ENCAPSULATION = (b"\x00\x00", b"\x00\x01")
"""XCDR1 plain CDR encapsulation ids: ``CDR_BE``, ``CDR_LE``."""


@dataclass
class DropCounts:
    """Samples dropped per ROS topic and reason (``oversized``, ``malformed``)."""

    counts: Counter = field(default_factory=Counter)

    def add(self, topic: str, reason: str, n: int = 1) -> None:
        if n > 0:
            self.counts[(topic, reason)] += n

    def total(self, reason: str | None = None) -> int:
        return sum(n for (_, r), n in self.counts.items() if reason is None or r == reason)

    def as_dict(self) -> dict[str, dict[str, int]]:
        out: dict[str, dict[str, int]] = {}
        for (topic, reason), n in sorted(self.counts.items()):
            out.setdefault(topic, {})[reason] = n
        return out


def check(msg: Any) -> bool:
    """The decoded ``msg`` is consistent (module docstring)."""
    if isinstance(msg, m.JointState):
        names: Any = msg.name
        n = len(names)
        if n > MAX_JOINTS or len(msg.position) != n or len(msg.velocity) not in (0, n):
            return False
        return all(isinstance(x, str) for x in names)
    return True


def decode(kind: Any, data: bytes, drops: DropCounts | None = None, topic: str = "") -> Any | None:
    """The ``kind`` struct serialised in ``data`` (with its 4-byte encapsulation header), or ``None``
    (counted in ``drops`` under ``topic``) when it is oversized or malformed."""
    if len(data) > MAX_BYTES.get(kind, DEFAULT_MAX_BYTES):
        if drops is not None:
            drops.add(topic, "oversized")
        return None
    data = bytes(data)
    try:
        if len(data) < 4 or data[:2] not in ENCAPSULATION:
            raise ValueError("not plain CDR")
        buffer = Buffer(data, align_offset=4)
        msg = kind.__idl__.deserialize(buffer)
        ok = 0 <= len(data) - buffer.tell() <= MAX_PADDING and check(msg)
    except Exception:  # noqa: BLE001 - any decoding failure of foreign bytes is a dropped sample
        ok, msg = False, None
    if not ok:
        if drops is not None:
            drops.add(topic, "malformed")
        return None
    return msg


class RawReader:
    """A ``cyclonedds`` ``DataReader`` whose samples are decoded by :func:`decode`, each on its own."""

    def __init__(self, reader: Any, kind: Any, topic: str, drops: DropCounts) -> None:
        self.reader, self.kind, self.topic, self.drops = reader, kind, topic, drops

    def take(self, n: int = 4096) -> list[tuple[Any, bytes]]:
        """Up to ``n`` ``(message, serialised bytes)`` pairs (bad ones dropped and counted; disposals
        skipped)."""
        from cyclonedds._clayer import ddspy_take
        from cyclonedds.core import InstanceState, SampleState, ViewState

        got = ddspy_take(self.reader._ref, SampleState.Any | ViewState.Any | InstanceState.Any, n)
        if isinstance(got, int):  # a DDS return code: nothing taken
            return []
        out = []
        for data, info in got:
            if not info.valid_data:
                continue
            msg = decode(self.kind, data, self.drops, self.topic)
            if msg is not None:
                out.append((msg, data))
        return out
