"""Networks given as CIDR strings (``comms.unsigned_gcs``, ``mrta sitl run --unsigned-gcs``): parsing, and whether a
UDP source address lies in one of them.  IPv4 and IPv6; an IPv4 sender seen through an IPv6 socket
(``::ffff:10.0.0.5``) is matched as the IPv4 address it is."""
from __future__ import annotations

import ipaddress
from typing import Iterable

EXPECTED = "a network in CIDR form, e.g. 10.0.0.0/24 or fd00::/64"


def parse_network(text: str) -> ipaddress.IPv4Network | ipaddress.IPv6Network:
    """The network ``text`` names (a bare address is its /32 or /128); ValueError saying what is wrong, e.g. host
    bits set (``10.0.0.1/24``: did you mean 10.0.0.0/24?)."""
    if not isinstance(text, str) or not text.strip():
        raise ValueError("empty")
    try:
        return ipaddress.ip_network(text.strip(), strict=True)
    except ValueError as exc:
        if "host bits set" in str(exc):
            loose = ipaddress.ip_network(text.strip(), strict=False)
            raise ValueError(f"host bits set: the network is {loose}") from None
        raise ValueError("not an IPv4 or IPv6 network") from None


class Networks:
    """A list of networks; ``addr in nets`` for a socket address ``(host, port, ...)`` or a host string."""

    def __init__(self, texts: Iterable[str] = ()):
        self.nets = tuple(parse_network(t) for t in texts)

    def __bool__(self) -> bool:
        return bool(self.nets)

    def __str__(self) -> str:
        return ", ".join(map(str, self.nets))

    def __contains__(self, addr) -> bool:
        if not self.nets or addr is None:
            return False
        host = addr[0] if isinstance(addr, tuple) else addr
        try:
            ip = ipaddress.ip_address(str(host).split("%")[0])
        except ValueError:
            return False
        if ip.version == 6 and ip.ipv4_mapped is not None:
            ip = ip.ipv4_mapped
        return any(ip in n for n in self.nets)
