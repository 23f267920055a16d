"""Reading a UDP socket so that nothing goes missing unseen: datagrams the kernel dropped because the socket's
receive buffer was full (a flood, or a reader that fell behind) are counted by the kernel per socket; this module
reads that count.

Linux keeps it in ``sk_drops``.  With the ``SO_RXQ_OVFL`` socket option every datagram read carries the count at
the time it was queued as ancillary data, so a reader learns of drops as soon as the next datagram arrives; the
``drops`` column of ``/proc/net/udp`` (and ``udp6``) for the socket's inode gives the current count at any time.
Elsewhere both are unavailable and the count stays 0.
"""
from __future__ import annotations

import os
import socket
import struct
import sys

SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40 if sys.platform.startswith("linux") else None)
_ANCILLARY = socket.CMSG_SPACE(4) if hasattr(socket, "CMSG_SPACE") else 0
MAX_DATAGRAM = 65535


def count_overflows(sock: socket.socket) -> bool:
    """Ask the kernel to attach its drop count to every datagram read from ``sock``; False if it cannot."""
    if SO_RXQ_OVFL is None or not hasattr(sock, "recvmsg"):
        return False
    try:
        sock.setsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL, 1)
    except OSError:
        return False
    return True


def receive(sock: socket.socket, counting: bool) -> tuple[bytes, tuple, int | None]:
    """One datagram: ``(data, source address, the kernel's drop count or None)``.  Raises what ``recvfrom``
    raises (BlockingIOError when there is nothing to read)."""
    if not counting:
        data, addr = sock.recvfrom(MAX_DATAGRAM)
        return data, addr, None
    data, ancillary, _flags, addr = sock.recvmsg(MAX_DATAGRAM, _ANCILLARY)
    drops = None
    for level, kind, payload in ancillary:
        if level == socket.SOL_SOCKET and kind == SO_RXQ_OVFL and len(payload) >= 4:
            drops = struct.unpack("=I", payload[:4])[0]
    return data, addr, drops


def datagrams(sock: socket.socket, counting: bool, counters, limit: int):
    """Yield ``(data, source address)`` for up to ``limit`` datagrams waiting on the non-blocking ``sock``,
    raising ``counters.kernel_dropped`` to the kernel's drop count whenever a datagram carries it.  Errors the
    socket reports (an ICMP error for an earlier send) are skipped, at most ``limit`` of them."""
    for _ in range(limit):
        try:
            data, addr, drops = receive(sock, counting)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            continue
        if drops is not None:
            counters.kernel_dropped = max(counters.kernel_dropped, drops)
        yield data, addr


def proc_drops(sock: socket.socket) -> int | None:
    """The kernel's drop count for ``sock`` from /proc/net/udp(6), or None where there is no such file."""
    try:
        inode = str(os.fstat(sock.fileno()).st_ino)
    except OSError:
        return None
    for name in ("/proc/net/udp", "/proc/net/udp6"):
        try:
            with open(name) as fh:
                next(fh, None)                     # the header line
                for line in fh:
                    fields = line.split()
                    if len(fields) > 12 and fields[9] == inode:
                        return int(fields[12])
        except (OSError, ValueError):
            continue
    return None


def bound(sock: socket.socket | None, family: int, addr: tuple, listen: str, what: str = "comms.listen") -> socket.socket:
    """A UDP socket bound to ``addr``: ``sock`` if it is one (an InputError naming ``what`` if it is bound
    elsewhere or is no UDP socket), else a new one bound here."""
    from runtime.errors import InputError

    if sock is not None:
        try:
            ok = sock.type == socket.SOCK_DGRAM and sock.getsockname()[:2] == addr[:2]
            where = sock.getsockname()
        except OSError as e:
            raise InputError(f"{what}: the socket handed in is not usable ({e.strerror})") from None
        if not ok:
            raise InputError(f"{what}: expected the socket handed in to be UDP bound to {listen!r}, got "
                             f"{where!r}")
        return sock
    sock = socket.socket(family, socket.SOCK_DGRAM)
    try:
        sock.bind(addr)
    except OSError as e:
        sock.close()
        raise InputError(f"{what}: cannot bind {listen!r} ({e.strerror})") from None
    return sock


class UdpTransport:
    """The default transport: one non-blocking UDP socket bound to ``listen``; a peer frame goes to every peer
    address (one copy each, so the link draws its loss model per copy, as a radio loses a broadcast for one
    receiver and not another).  Needs nothing beyond the standard library.

    The transport interface (:mod:`runtime.comms.transport`): ``copies``, :meth:`destinations`, :meth:`send`,
    :meth:`receive`, :meth:`membership`, :meth:`check_drops`, :meth:`close`.  The link keeps everything else."""

    copies = True            # destinations() are receivers: the link's loss model draws once per copy when sending
    peer_addresses = True    # a frame goes to each comms.peers address: they must resolve
    joins = False            # a robot not in comms.peers has no address here: the roster is the config's

    @classmethod
    def check_config(cls, comms, file: str) -> None:
        """Nothing beyond the peer addresses (``peer_addresses``) and ``comms.listen``, checked by the loader."""

    def __init__(self, family: int, listen_addr, peers, what: str = "comms.listen", sock: socket.socket | None = None,
                 listen: str | None = None):
        """``sock``: a UDP socket already bound to ``listen_addr`` (held since the port was checked, or inherited)
        instead of binding one here; ``listen``: the address as the config writes it, for errors."""
        self.peers = list(peers)
        self.sock = bound(sock, family, listen_addr, listen_addr if listen is None else listen, what)
        self.sock.setblocking(False)
        self._overflows = count_overflows(self.sock)

    @property
    def address(self) -> tuple:
        return self.sock.getsockname()[:2]

    def destinations(self, dest: int) -> list:
        """Where a peer frame for robot ``dest`` (0: every robot) goes: every peer, as today (the receivers keep
        what is addressed to them)."""
        return self.peers

    def send(self, frame: bytes, where) -> None:
        """One datagram to ``where`` (an address); raises OSError."""
        self.sock.sendto(frame, where)

    def receive(self, counters, limit: int):
        """``(data, source address, origin)`` for up to ``limit`` datagrams waiting; origin is None (loss was
        drawn when sending)."""
        for data, addr in datagrams(self.sock, self._overflows, counters, limit):
            yield data, addr, None

    def membership(self) -> list:
        """Robots that joined (id, True) or left (id, False) since the last call: UDP cannot tell."""
        return []

    def check_drops(self, counters) -> None:
        counters.kernel_dropped = max(counters.kernel_dropped, proc_drops(self.sock) or 0)

    def close(self) -> None:
        self.sock.close()
