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
