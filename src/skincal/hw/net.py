"""Which addresses a skincal server or receiver may bind without asking: loopback only, unless ``--public``.

One check for every command that listens (``skincal view``, ``skincal record``): the viewer has no
login and the recorder takes any datagram, so listening beyond this machine is an explicit choice.
"""

from __future__ import annotations

import ipaddress

from skincal.errors import ConfigError

LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1")
"""Names of the loopback interface accepted as such (besides any address in 127.0.0.0/8 or ::1)."""


def is_loopback(host: str) -> bool:
    """Whether ``host`` names the loopback interface (``localhost``, 127.0.0.0/8, ``::1``)."""
    if host in LOOPBACK_HOSTS:
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:  # a host name other than localhost (or garbage): not known to be loopback
        return False


def check_bind(host: str, public: bool, option: str = "--host", purpose: str = "serve beyond this machine") -> None:
    """Refuse binding ``host`` (given as ``option``) beyond loopback unless ``public`` (``--public``)."""
    if not public and not is_loopback(host):
        raise ConfigError(f"{option} {host} is not a loopback address; add --public to {purpose}")
