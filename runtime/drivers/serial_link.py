"""One non-blocking pyserial link for a base driver: open any URL, read everything waiting, write, close.

``serial.serial_for_url`` takes a device path, a pty, ``socket://host:port`` (a robot server on TCP, as
MobileSim offers) or ``loop://``.  Reads and writes never raise for a transient error: they are counted in
the driver's ``stats.extra`` (``bytes_in``, ``bytes_out``, ``writes``, ``read_errors``, ``write_errors``)
and logged sparingly; :data:`runtime.drivers.base.LOST_AFTER` reads in a row that fail raise
:class:`~runtime.drivers.base.DeviceLost` (the device vanished, the peer closed the socket).
"""
from __future__ import annotations

import socket

import serial

from runtime.drivers.base import LOST_AFTER, DeviceLost
from runtime.errors import InputError

MAX_READS_PER_POLL = 64
READ_CHUNK = 4096


def _sparse(n: int) -> bool:
    """Log the 1st, 10th, 100th and every 1000th occurrence."""
    return n in (1, 10, 100) or n % 1000 == 0


class SerialLink:
    """The link of one driver.  ``what`` names the base in messages ("Create OI", "ARCOS"); ``counters`` is
    the driver's ``stats.extra`` dict.  ``quiet=True`` logs failed reads and writes at DEBUG only (a driver that
    says once, itself, what a lost link means)."""

    def __init__(self, url: str, baudrate: int, what: str, log, counters: dict, quiet: bool = False):
        self.url = url
        self.baudrate = baudrate
        self.what = what
        self.log = log
        self.counters = counters
        for k in ("bytes_in", "bytes_out", "writes", "read_errors", "write_errors"):
            counters.setdefault(k, 0)
        self.ser = None
        self._failed_reads = 0
        self._warn = log.debug if quiet else log.warning

    def open(self) -> None:
        try:
            self.ser = serial.serial_for_url(self.url, self.baudrate, timeout=0)
        except (serial.SerialException, ValueError, OSError) as exc:
            raise InputError(f"{self.what} port {self.url!r}: cannot open ({exc}); "
                             "expected a serial device, pty or pyserial URL") from None
        self._failed_reads = 0

    def fileno(self) -> int | None:
        """The open port's file descriptor (a device, pty or ``socket://``); None for ``loop://`` or when closed."""
        from runtime.drivers.guard import port_fd
        return None if self.ser is None else port_fd(self.ser)

    def read_all(self) -> bytes:
        """Everything waiting (non-blocking); b"" if nothing.  DeviceLost after LOST_AFTER failed reads in a row."""
        chunks = []
        try:
            for _ in range(MAX_READS_PER_POLL):
                chunk = self.ser.read(max(READ_CHUNK, self.ser.in_waiting))
                if not chunk:
                    break
                chunks.append(chunk)
        except (serial.SerialException, OSError) as exc:
            c = self.counters
            c["read_errors"] += 1
            self._failed_reads += 1
            if self._failed_reads >= LOST_AFTER:
                raise DeviceLost(f"{self.what} port {self.url}: {self._failed_reads} reads in a row failed ({exc})")
            if _sparse(c["read_errors"]):
                self._warn("read %s: %s", self.url, exc)
        else:
            self._failed_reads = 0
        data = b"".join(chunks)
        self.counters["bytes_in"] += len(data)
        return data

    def write(self, data: bytes) -> bool:
        """Send ``data``; False (counted, logged sparingly) if the link refused it."""
        c = self.counters
        try:
            self.ser.write(data)
        except (serial.SerialException, OSError) as exc:
            c["write_errors"] += 1
            if _sparse(c["write_errors"]):
                self._warn("write %s: %s", self.url, exc)
            return False
        c["writes"] += 1
        c["bytes_out"] += len(data)
        return True

    def close(self) -> None:
        """Flush and close; a link that vanished meanwhile is logged, never raised."""
        if self.ser is None:
            return
        for step in (self.ser.flush, self.ser.close):
            try:
                step()
            except Exception as exc:       # SerialException, OSError, termios.error (a vanished tty)
                self._warn("close %s: %s", self.url, exc)
        self.ser = None
