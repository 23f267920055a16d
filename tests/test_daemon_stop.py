"""`mrta daemon`'s loop ends on SIGTERM wherever the signal lands: also inside code that catches ``Exception``
(every parser loop does, to count what it drops), where a stop request raised as an ``Exception`` was swallowed
and the daemon ran on until its clock stalled (the launcher-killed test failed that way under load)."""
from __future__ import annotations

import os
import signal
from types import SimpleNamespace

from runtime.daemon import run
from runtime.log import get_logger


class InstantClock:
    def __init__(self):
        self.t = 0.0

    def now(self) -> float:
        return self.t

    def sleep_until(self, t: float) -> None:
        self.t = max(self.t, t)


class SignalledInsideAParser:
    """A daemon whose first cycle gets SIGTERM while a parser's ``except Exception`` is around it."""
    period = 0.1
    guard = None

    def __init__(self):
        self.stats = SimpleNamespace(cycles=0, missed_deadlines=0, worst_lateness=0.0, cpu_seconds=0.0,
                                     wall_seconds=0.0)
        self.log = get_logger("test.daemon_stop")
        self.swallowed = 0
        self.closed = False

    def open(self, now: float) -> None:
        pass

    def start_guard(self) -> None:
        pass

    def step(self, now: float) -> None:
        self.stats.cycles += 1
        if self.stats.cycles == 1:
            try:                                     # as a parser loop guards one frame
                os.kill(os.getpid(), signal.SIGTERM)
                for _ in range(10_000):              # the handler runs here, inside the try
                    pass
            except Exception:
                self.swallowed += 1

    def close(self) -> None:
        self.closed = True

    def snapshot(self) -> dict:
        return {}


def test_sigterm_inside_a_catch_all_still_ends_the_loop():
    handlers = signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)
    d = SignalledInsideAParser()
    try:
        assert run(d, InstantClock(), duration=10.0) == 0
    finally:
        signal.signal(signal.SIGTERM, handlers[0])
        signal.signal(signal.SIGINT, handlers[1])
    assert d.swallowed == 0
    assert d.stats.cycles == 1                       # not the 100 cycles of the whole duration
    assert d.closed                                  # and the base was still told to stop
