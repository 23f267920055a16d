"""Frames of the fleet dialect for message tests: encode as a robot would, decode as the link does."""
from __future__ import annotations

import contextlib

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


@contextlib.contextmanager
def codec_registry_kept():
    """The codec's class <-> message registry as it was, once the block ends: a test that registers classes of its
    own (or unregisters the fleet's) must not leave the rest of the suite without them (under pytest-xdist any test
    may run after it in the same process)."""
    from runtime.comms import codec
    codec.register_fleet()                 # kept with the fleet's classes in, as any other test finds it
    names = ("_by_class", "_by_name", "_classes")
    saved = {n: dict(getattr(codec, n)) for n in names}, codec._fleet_registered
    try:
        yield
    finally:
        for n, d in saved[0].items():
            getattr(codec, n).clear()
            getattr(codec, n).update(d)
        codec._fleet_registered = saved[1]
