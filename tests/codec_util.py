"""Frames of the fleet dialect for message tests: encode as a robot would, decode as the link does."""
from __future__ import annotations

from runtime.comms import codec


def frame(mod, msg) -> bytes:
    """One MAVLink 2 frame for ``msg`` from its sender."""
    return codec.encode(msg, mod.MAVLink(None, srcSystem=msg.sender, srcComponent=1))


def decode(mod, data: bytes) -> tuple[list, int]:
    """Parse like the link does: (our messages, frames refused: invalid values or fields that do not convert)."""
    rx = mod.MAVLink(None, srcSystem=200, srcComponent=1)
    rx.robust_parsing = True
    out, refused = [], 0
    for m in rx.parse_buffer(data) or []:
        try:
            msg = codec.from_mavlink(m)
        except Exception:
            refused += 1
            continue
        if msg is not None:
            out.append(msg)
    return out, refused


def damage(data: bytes, rnd, flips: int) -> bytes:
    """``data`` with ``flips`` random bits flipped, cut at a random length."""
    out = bytearray(data)
    for _ in range(flips):
        i = rnd.randrange(len(out))
        out[i] ^= 1 << rnd.randrange(8)
    return bytes(out[:rnd.randrange(len(out) + 1)])
