"""Named protocols of the paper (Sec. IV; ``shared/reference/notes.md``, "Protocol").

* ``paper-sim``: A = 2 rad/s, f = 1 Hz, 3 s per joint, 2 s rest, P = 16. The paper sampled at
  100 Hz (its IMU rate); our robot stream defaults to 1 kHz (``rate_hz``).
* ``paper-real``: A = 2.0 rad/s, f = [0.75, 0.25, 0.35, 0.55, 0.75, 0.9, 0.9] Hz per joint (a
  7-joint robot), 3 s, 10 s rest, P = 12.

The static window (not given in the paper) is 1 s of the 2 s rest in ``paper-sim`` and 2 s of the
10 s rest in ``paper-real``.
"""

from __future__ import annotations

from skincal.errors import ConfigError
from skincal.protocol.config import ProtocolConfig

PROTOCOLS: dict[str, ProtocolConfig] = {
    "paper-sim": ProtocolConfig(
        name="paper-sim",
        n_poses=16,
        amplitude=2.0,
        frequency=1.0,
        excite_duration=3.0,
        rest_duration=2.0,
        static_duration=1.0,
    ),
    "paper-real": ProtocolConfig(
        name="paper-real",
        n_poses=12,
        amplitude=2.0,
        frequency=(0.75, 0.25, 0.35, 0.55, 0.75, 0.9, 0.9),
        excite_duration=3.0,
        rest_duration=10.0,
        static_duration=2.0,
    ),
}
"""Preset protocols by name (frozen configs; derive variants with ``dataclasses.replace``)."""


def get_protocol(name: str) -> ProtocolConfig:
    """The preset protocol ``name``; unknown names raise :class:`ConfigError` listing the presets."""
    try:
        return PROTOCOLS[name]
    except KeyError:
        raise ConfigError(f"unknown protocol '{name}' (presets: {', '.join(PROTOCOLS)})") from None
