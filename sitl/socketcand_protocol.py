"""The socketcand ASCII protocol, server side: framing, parsing and formatting.  Pure code, no I/O.

socketcand (linux-can/socketcand) serves SocketCAN buses over TCP; python-can's stock ``socketcand`` interface
is its client.  Every message is ``< ... >``.  The exchange the stock client makes (python-can
``can/interfaces/socketcand/socketcand.py``, lines 126-188 in 4.x, and socketcand's README):

* server on accept: ``< hi >``; client ``< open can0 >``, server ``< ok >`` (BCM mode);
  client ``< rawmode >``, server ``< ok >`` (raw mode: every frame on the bus goes to the client);
* server -> client: ``< frame ID SEC.USEC HEXDATA >`` (``frame 701 1712345678.000123 05``);
* client -> server: ``< send ID DLC B0 B1 ... >`` with the bytes in hex (``send 601 8 2f 60 60 0 3 0 0 0``).

An ID of three hex digits is a standard (11-bit) frame, eight digits an extended (29-bit) one, as socketcand
reads them.  :class:`Splitter` frames a byte stream into commands and counts what it drops;
:func:`parse_send` and :func:`format_frame` convert between ``can.Message`` and the ASCII.
"""
from __future__ import annotations

from dataclasses import dataclass

import can

MAX_COMMAND = 256           # characters between '<' and '>' (a send of 8 bytes is < 40)
WHITESPACE = b" \t\r\n"


@dataclass
class SplitterStats:
    """Every byte fed is in a command returned, dropped, whitespace between commands, or still buffered."""
    bytes: int = 0
    commands: int = 0
    command_bytes: int = 0      # bytes of the commands returned, '<' and '>' included
    dropped_bytes: int = 0      # bytes outside '< >' that are not whitespace, and bytes of dropped commands
    between_bytes: int = 0      # whitespace between commands
    truncated: int = 0          # commands cut short by a new '<'
    too_long: int = 0           # commands longer than MAX_COMMAND
    non_ascii: int = 0          # commands with a byte outside printable ASCII


class Splitter:
    """Bytes from a socketcand peer -> the text of each ``< ... >`` command, in order."""

    def __init__(self, max_len: int = MAX_COMMAND):
        self.max_len = max_len
        self.stats = SplitterStats()
        self._buf = bytearray()     # from '<' while inside a command
        self._skip = False          # inside a command too long to keep: dropping until '>' or '<'

    @property
    def buffered(self) -> int:
        return len(self._buf)

    def feed(self, data: bytes) -> list[str]:
        s = self.stats
        s.bytes += len(data)
        out: list[str] = []
        for b in data:
            if b == 0x3C:                              # '<' starts a command, cutting short one still open
                if self._buf:
                    self._drop(len(self._buf), "truncated")
                self._skip = False
                self._buf = bytearray(b"<")
            elif self._skip:
                s.dropped_bytes += 1
                if b == 0x3E:
                    self._skip = False
            elif not self._buf:
                if b in WHITESPACE:
                    s.between_bytes += 1
                else:
                    s.dropped_bytes += 1
            elif b == 0x3E:                            # '>' ends it
                self._buf.append(b)
                raw, self._buf = bytes(self._buf), bytearray()
                if all(0x20 <= c < 0x7F for c in raw):
                    s.commands += 1
                    s.command_bytes += len(raw)
                    out.append(raw[1:-1].decode("ascii").strip())
                else:
                    self._drop(len(raw), "non_ascii")
            else:
                self._buf.append(b)
                if len(self._buf) > self.max_len + 1:
                    self._drop(len(self._buf), "too_long")
                    self._buf = bytearray()
                    self._skip = True
        return out

    def _drop(self, n: int, why: str) -> None:
        self.stats.dropped_bytes += n
        setattr(self.stats, why, getattr(self.stats, why) + 1)
        self._buf = bytearray()


def _hex(token: str, max_digits: int) -> int | None:
    if not 1 <= len(token) <= max_digits or any(c not in "0123456789abcdefABCDEF" for c in token):
        return None
    return int(token, 16)


def parse_send(args: list[str]) -> can.Message | None:
    """The frame of ``send ID DLC B0 ... >``'s arguments (after ``send``), or None if they are not one:
    ID of 1-3 hex digits (standard, <= 0x7FF) or 8 (extended, <= 0x1FFFFFFF), DLC 0-8, then exactly DLC
    bytes of 1-2 hex digits."""
    if len(args) < 2:
        return None
    ident = _hex(args[0], 8)
    extended = len(args[0]) == 8
    dlc = _hex(args[1], 1)
    if ident is None or dlc is None or dlc > 8 or len(args) != 2 + dlc:
        return None
    if extended and ident > 0x1FFFFFFF or not extended and (len(args[0]) > 3 or ident > 0x7FF):
        return None
    data = [_hex(t, 2) for t in args[2:]]
    if any(b is None for b in data):
        return None
    return can.Message(arbitration_id=ident, is_extended_id=extended, data=bytes(data), dlc=dlc)


def format_frame(msg: can.Message, timestamp: float) -> str:
    """``< frame ID SEC.USEC HEXDATA >`` for ``msg`` received at ``timestamp`` (s since the epoch)."""
    ident = f"{msg.arbitration_id & 0x1FFFFFFF:08X}" if msg.is_extended_id else f"{msg.arbitration_id & 0x7FF:03X}"
    sec = int(timestamp)
    usec = min(999999, max(0, round((timestamp - sec) * 1e6)))
    return f"< frame {ident} {sec}.{usec:06d} {bytes(msg.data).hex().upper()} >"


def command(text: str) -> tuple[str, list[str]]:
    """A command's verb and arguments (``"send 601 2 1 2"`` -> ``("send", ["601", "2", "1", "2"])``)."""
    parts = text.split()
    return (parts[0], parts[1:]) if parts else ("", [])
