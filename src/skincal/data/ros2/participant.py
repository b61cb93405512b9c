"""The one factory of DDS participants: loopback with multicast off unless told otherwise.

A ROS 2 graph is a DDS domain (``ROS_DOMAIN_ID``, 0-232 with the default port mapping). skincal joins
it through Cyclone DDS with an explicit configuration (never the user's ``CYCLONEDDS_URI``, so that
what is joined is what is printed):

* default: the loopback interface ``127.0.0.1`` only, multicast off, discovery by unicast to the
  participants on ``127.0.0.1`` (``Peers``; participant indices ``auto`` up to
  :data:`MAX_PARTICIPANTS`): no packet leaves the machine. A ROS 2 node on the same machine joins
  with the same settings (``CYCLONEDDS_URI`` set to :func:`config_xml`'s text).
* ``interface="eth0"``: that interface, with multicast discovery (ROS 2's default), to reach a robot
  on the network; :attr:`Ros2Participant.joined` names the interface and its addresses.
"""

from __future__ import annotations

import os
import socket
from dataclasses import dataclass
from typing import Any
from xml.sax.saxutils import quoteattr

from skincal.errors import ConfigError
from skincal.names import printable

LOOPBACK = "127.0.0.1"
MAX_PARTICIPANTS = 32
"""Participants per domain on one machine that find each other without multicast (Cyclone's
``MaxAutoParticipantIndex``; its default is 9)."""
MAX_DOMAIN_ID = 232
"""The largest domain id the default RTPS port mapping allows (ROS 2 documents 0-101 and 215-232 as safe)."""
DOMAIN_ENV = "ROS_DOMAIN_ID"


def domain_id(given: int | None = None, env: dict[str, str] | None = None) -> int:
    """``given``, else ``ROS_DOMAIN_ID``, else 0; a one-line :class:`ConfigError` outside 0..232."""
    env = dict(os.environ) if env is None else env
    if given is None:
        text = env.get(DOMAIN_ENV, "").strip()
        if not text:
            return 0
        try:
            given = int(text)
        except ValueError:
            shown = printable(repr(text))
            raise ConfigError(f"{DOMAIN_ENV}={shown} is not a domain id (an integer 0-{MAX_DOMAIN_ID})") from None
    if not 0 <= int(given) <= MAX_DOMAIN_ID:
        raise ConfigError(f"domain id {given}: must be 0-{MAX_DOMAIN_ID}")
    return int(given)


def interface_addresses(name: str) -> list[str]:
    """IPv4/IPv6 addresses of the interface ``name`` (``psutil`` when installed, else none known)."""
    try:
        import psutil
    except ImportError:
        return []
    addrs = psutil.net_if_addrs().get(name, [])
    return [a.address for a in addrs if a.family in (socket.AF_INET, socket.AF_INET6)]


def check_interface(name: str) -> str:
    """``name`` if the machine has such a network interface, else a one-line :class:`ConfigError`."""
    names = [n for _, n in socket.if_nameindex()]
    if name not in names:
        raise ConfigError(f"--interface {printable(name)!r}: no such network interface (have: {', '.join(names)})")
    return name


def config_xml(interface: str | None = None) -> str:
    """The Cyclone DDS configuration (XML text, for ``Domain(config=...)`` or ``CYCLONEDDS_URI``):
    loopback without multicast (``interface`` None), else ``interface`` with multicast discovery."""
    if interface is None:
        general = (
            f"<Interfaces><NetworkInterface address={quoteattr(LOOPBACK)}/></Interfaces>"
            "<AllowMulticast>false</AllowMulticast>"
        )
        discovery = (
            f"<ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>{MAX_PARTICIPANTS - 1}"
            f"</MaxAutoParticipantIndex><Peers><Peer address={quoteattr(LOOPBACK)}/></Peers>"
        )
    else:
        general = f"<Interfaces><NetworkInterface name={quoteattr(interface)}/></Interfaces>"
        discovery = ""
    return (
        '<CycloneDDS><Domain id="any"><General>' + general + "</General><Discovery>" + discovery
        + "</Discovery></Domain></CycloneDDS>"
    )  # fmt: skip


@dataclass
class Ros2Participant:
    """A joined domain: ``participant`` (a ``cyclonedds.domain.DomainParticipant``), the ``domain``
    object that holds its configuration (kept alive with it), and what was joined."""

    participant: Any
    domain: Any
    domain_id: int
    interface: str | None

    @property
    def joined(self) -> str:
        """One line: the domain and the interface (with its addresses) and whether multicast is on."""
        if self.interface is None:
            return f"ROS 2 domain {self.domain_id} on the loopback interface ({LOOPBACK}), multicast off"
        addrs = interface_addresses(self.interface)
        shown = f" ({', '.join(addrs)})" if addrs else ""
        return (f"ROS 2 domain {self.domain_id} on interface {printable(self.interface)}{shown}, Cyclone DDS's default "
                "discovery (multicast where the interface supports it)")

    def close(self) -> None:
        """Delete the participant (its readers and writers with it)."""
        try:
            self.participant._delete()  # cyclonedds entities are deleted when collected; do it now
        except Exception:  # noqa: BLE001 - already gone
            pass


def join(domain: int | None = None, interface: str | None = None) -> Ros2Participant:
    """Join ROS 2 domain ``domain`` (else ``ROS_DOMAIN_ID``, else 0) on the loopback interface with
    multicast off, or on ``interface`` (module docstring). Needs the ``ros2`` extra."""
    did = domain_id(domain)
    if interface is not None:
        check_interface(interface)
    try:
        from cyclonedds.domain import Domain, DomainParticipant
    except ImportError:
        raise ConfigError("ROS 2 needs the cyclonedds package: pip install 'skincal[ros2]'") from None
    try:
        dom = Domain(did, config_xml(interface))
        participant = DomainParticipant(did)
    except Exception as exc:  # DDSException: a bad configuration, no such interface, ports taken
        from skincal.errors import first_line

        raise ConfigError(f"cannot join ROS 2 domain {did}: {first_line(exc)}") from None
    return Ros2Participant(participant, dom, did, interface)
