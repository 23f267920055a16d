"""One Clock interface: the wall clock on robots, a scaled or lock-step clock in SITL.

Agents never read a clock; the daemon reads one and passes ``now`` in.  Three implementations:

* :class:`WallClock` - monotonic seconds, real sleeping (robots).
* :class:`ScaledClock` - sim seconds = (monotonic - epoch) * speedup; separate SITL processes that
  share ``epoch`` and ``speedup`` agree on the time without talking to each other.
* :class:`SimClock` - lock-step: time only moves when the owner calls :meth:`advance`.
"""
from __future__ import annotations

import time
from typing import Protocol


class Clock(Protocol):
    def now(self) -> float: ...
    def sleep_until(self, t: float) -> None: ...


class WallClock:
    def now(self) -> float:
        return time.monotonic()

    def sleep_until(self, t: float) -> None:
        dt = t - time.monotonic()
        if dt > 0:
            time.sleep(dt)


class ScaledClock:
    """Sim time running ``speedup`` times faster than the monotonic clock from ``epoch``."""

    def __init__(self, speedup: float = 1.0, epoch: float | None = None):
        if speedup <= 0:
            raise ValueError("speedup must be > 0")
        self.speedup = speedup
        self.epoch = time.monotonic() if epoch is None else epoch

    def now(self) -> float:
        return (time.monotonic() - self.epoch) * self.speedup

    def sleep_until(self, t: float) -> None:
        dt = (t - self.now()) / self.speedup
        if dt > 0:
            time.sleep(dt)


class SimClock:
    """Lock-step clock: ``sleep_until`` never blocks, the stepping loop calls ``advance``."""

    def __init__(self, start: float = 0.0):
        self._t = start

    def now(self) -> float:
        return self._t

    def advance(self, dt: float) -> float:
        self._t += dt
        return self._t

    def sleep_until(self, t: float) -> None:
        if t > self._t:
            self._t = t


class ClockStalled(RuntimeError):
    """The simulator stopped publishing time: it has exited or hung."""


class SharedClock:
    """Sim time published by the simulator process in a small memory-mapped file.

    The simulator is the time master: if it falls behind (a loaded machine), every daemon's time
    slows with it, so no daemon ever acts on sensor data from a future the world has not reached.
    Layout: three little-endian doubles (seq, t, seq); a reader retries until both seq agree.
    ``speedup`` is only a hint for how long to sleep between looks at the clock.
    """

    _FMT = "<3d"

    def __init__(self, path: str, speedup: float = 1.0, stall_timeout: float = 30.0):
        import mmap
        self.stall_timeout = stall_timeout     # wall seconds without the time moving: the simulator is gone
        self.on_wait = None                    # called at each look while sleep_until waits (the stop guard's beat)
        self._fh = open(path, "rb")
        self._mm = mmap.mmap(self._fh.fileno(), 24, access=mmap.ACCESS_READ)
        self.speedup = max(speedup, 1e-3)

    def now(self) -> float:
        import struct
        while True:
            a, t, b = struct.unpack_from(self._FMT, self._mm, 0)
            if a == b:
                return t

    def sleep_until(self, t: float) -> None:
        last, since = self.now(), time.monotonic()
        while True:
            now = self.now()
            remaining = t - now
            if remaining <= 0:
                return
            if now != last:
                last, since = now, time.monotonic()
            elif time.monotonic() - since > self.stall_timeout:
                raise ClockStalled(f"simulator clock stopped at {now:.3f} s for {self.stall_timeout:.0f} s")
            if self.on_wait is not None:
                self.on_wait()
            time.sleep(min(0.005, max(0.0002, remaining / self.speedup)))

    def close(self) -> None:
        self._mm.close()
        self._fh.close()


class ClockPublisher:
    """The simulator's side of :class:`SharedClock`: ``publish(t)`` after every step."""

    def __init__(self, path: str, t: float = 0.0):
        import mmap
        import os
        tmp = f"{path}.tmp"
        with open(tmp, "wb") as fh:
            fh.write(b"\0" * 24)
        self._fh = open(tmp, "r+b")
        self._mm = mmap.mmap(self._fh.fileno(), 24)
        self._seq = 0.0
        self.publish(t)
        os.replace(tmp, path)      # readers only ever see a file that holds a time

    def publish(self, t: float) -> None:
        import struct
        self._seq += 1.0
        struct.pack_into("<d", self._mm, 0, self._seq)
        struct.pack_into("<d", self._mm, 8, t)
        struct.pack_into("<d", self._mm, 16, self._seq)

    def close(self) -> None:
        self._mm.close()
        self._fh.close()
