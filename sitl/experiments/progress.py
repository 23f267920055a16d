"""The progress line of every long command (the experiments' sweeps): one log line per finished run,

    [######------------------------] 2/10 cell A seed 3: 12 objects done (186 s wall; 420 s in all; ~1680 s left)

``what`` is the caller's, ``s wall`` the run's own wall time when it has one, ``s in all`` the time since the sweep
started, ``left`` the estimate at the mean rate so far.  With ``lines`` set, a long sweep logs at most that many
lines (the last run always)."""
from __future__ import annotations

import logging
import time
from typing import Callable


def bar(done: int, total: int, width: int = 30) -> str:
    """``[####------] done/total``: the share done in ``width`` characters."""
    k = min(width, int(width * done / total)) if total else width
    return "[" + "#" * k + "-" * (width - k) + f"] {done}/{total}"


class Progress:
    """Counts finished runs and logs the progress line (module docstring) for each, or for ``lines`` of them."""

    def __init__(self, total: int, log: logging.Logger, *, done: int = 0, lines: int | None = None, width: int = 30,
                 clock: Callable[[], float] = time.perf_counter):
        """``done``: runs finished before this sweep (resumed from a file); they count in the bar, not the rate."""
        self.total, self.log, self.lines, self.width, self.clock = total, log, lines, width, clock
        self.done = self.start = done
        self.t0 = clock()

    def step(self, what: str = "", wall: float | None = None) -> str:
        """One more run finished; returns its progress line (logged unless ``lines`` thins them out)."""
        before, self.done = self.done, self.done + 1
        took = self.clock() - self.t0
        left = took / (self.done - self.start) * max(self.total - self.done, 0)
        times = (f"{wall:.0f} s wall; " if wall is not None else "") + f"{took:.0f} s in all; ~{left:.0f} s left"
        line = f"{bar(self.done, self.total, self.width)}{' ' + what if what else ''} ({times})"
        if (not self.lines or self.done >= self.total
                or before * self.lines // max(self.total, 1) != self.done * self.lines // max(self.total, 1)):
            self.log.info("%s", line)
        return line
