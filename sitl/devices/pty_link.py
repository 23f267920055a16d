"""A pseudo-terminal pair for device emulators: the emulator holds the master, a driver opens the slave.

The slave is put in raw mode (no echo, no line editing, no XON/XOFF: byte 19 is XOFF and also the
Create OI stream header) and its fd stays open for the link's lifetime, so the master never reads EIO
when a client closes and reopens the port.  The master is non-blocking.
"""
from __future__ import annotations

import errno
import os
import termios
import tty


class PtyLink:
    """Master side of one pty; ``path`` is the slave device a driver opens."""

    def __init__(self, master: int, slave: int, path: str):
        self.master = master
        self.slave = slave
        self.path = path
        self.closed = False

    def read(self, limit: int = 1 << 16) -> bytes:
        """Everything the client has written so far (up to ``limit`` bytes); b"" if nothing."""
        if self.closed:
            return b""
        chunks, n = [], 0
        while n < limit:
            try:
                chunk = os.read(self.master, min(4096, limit - n))
            except BlockingIOError:
                break
            except OSError as exc:
                if exc.errno == errno.EIO:      # no client and no slave fd: nothing to read
                    break
                raise
            if not chunk:
                break
            chunks.append(chunk)
            n += len(chunk)
        return b"".join(chunks)

    def write(self, data: bytes) -> int:
        """Write as much of ``data`` as the client's input queue takes; returns the bytes written."""
        if self.closed:
            return 0
        view, done = memoryview(data), 0
        while done < len(view):
            try:
                done += os.write(self.master, view[done:])
            except BlockingIOError:
                break
        return done

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self) -> "PtyLink":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self):
        self.close()


def open_pty() -> PtyLink:
    """Open a pty pair: slave raw and kept open, master non-blocking."""
    master, slave = os.openpty()
    try:
        tty.setraw(slave, termios.TCSANOW)
        attrs = termios.tcgetattr(slave)
        attrs[0] &= ~(termios.IXON | termios.IXOFF | termios.IXANY)   # iflag: no software flow control
        termios.tcsetattr(slave, termios.TCSANOW, attrs)
        os.set_blocking(master, False)
        path = os.ttyname(slave)
    except Exception:
        os.close(master)
        os.close(slave)
        raise
    return PtyLink(master, slave, path)
