"""A robot server's TCP port for device emulators: one client at a time, as MobileSim serves each robot.

:func:`open_tcp` listens on the first free port from ``port`` up (MobileSim gives its first robot 8101 and
each further one the next port; two fleets or tests side by side move up the same way).  The link is
non-blocking and has the pty link's ``read``/``write``/``close``; a client that connects while another is
connected waits in the backlog until the first leaves.  ``connects`` and ``disconnects`` count sessions,
so the emulator can start a new one when its client goes.
"""
from __future__ import annotations

import errno
import socket

from runtime.errors import InputError

PORT_RANGE = 200            # ports tried above the requested one


class TcpLink:
    """Listening socket plus the connected client, if any; ``path`` is the pyserial URL a driver opens."""

    def __init__(self, server: socket.socket, host: str, port: int):
        self.server = server
        self.host = host
        self.port = port
        self.client: socket.socket | None = None
        self.connects = 0
        self.disconnects = 0
        self.closed = False

    @property
    def path(self) -> str:
        return f"socket://{self.host}:{self.port}"

    @property
    def connected(self) -> bool:
        return self.client is not None

    def _accept(self) -> None:
        if self.client is not None or self.closed:
            return
        try:
            client, _ = self.server.accept()
        except (BlockingIOError, InterruptedError):
            return
        client.setblocking(False)
        client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.client = client
        self.connects += 1

    def _drop(self) -> None:
        if self.client is not None:
            try:
                self.client.close()
            except OSError:
                pass
            self.client = None
            self.disconnects += 1

    def read(self, limit: int = 1 << 16) -> bytes:
        """What the client sent (up to ``limit`` bytes); b"" if nothing or no client.  A client that closed
        its end is dropped (see ``disconnects``)."""
        self._accept()
        if self.client is None:
            return b""
        chunks, n = [], 0
        while n < limit:
            try:
                chunk = self.client.recv(min(4096, limit - n))
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                self._drop()
                break
            if not chunk:
                self._drop()
                break
            chunks.append(chunk)
            n += len(chunk)
        return b"".join(chunks)

    def write(self, data: bytes) -> int:
        """Send as much of ``data`` as the socket takes now; returns the bytes sent (0 without a client)."""
        if self.client is None:
            return 0
        try:
            return self.client.send(data)
        except (BlockingIOError, InterruptedError):
            return 0
        except OSError:
            self._drop()
            return 0

    def hang_up(self) -> None:
        """Drop the current client (the robot server closes the connection)."""
        self._drop()

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self._drop()
        try:
            self.server.close()
        except OSError:
            pass

    def __del__(self):
        self.close()


def open_tcp(port: int, host: str = "127.0.0.1") -> TcpLink:
    """Listen on ``host`` at the first free port from ``port`` on (non-blocking)."""
    for p in range(port, min(port + PORT_RANGE, 65536)):
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)   # a port whose last client is in TIME_WAIT
        try:
            s.bind((host, p))
        except OSError as exc:
            s.close()
            if exc.errno in (errno.EADDRINUSE, errno.EACCES):
                continue
            raise InputError(f"TCP robot port {host}:{p}: cannot listen ({exc.strerror})") from None
        s.listen(4)
        s.setblocking(False)
        return TcpLink(s, host, p)
    raise InputError(f"TCP robot port: expected a free port in {host}:{port}..{port + PORT_RANGE - 1}, all busy")
