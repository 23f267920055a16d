"""A device link that babbles or goes silent on demand, and a loop that runs a base driver against an emulator
through it on a simulated clock, for the garbage and silence tests (``tests/test_device_babble.py``)."""
from __future__ import annotations

import random
import time


class Babbler:
    """Wraps an emulator's link (pty or TCP): in ``"garbage"`` mode what the device writes is replaced by random
    bytes of the same length and ``flood`` more per write; in ``"both"`` mode so is what it reads (the robot hears
    garbage instead of the daemon's commands); in ``"silent"`` mode what it writes is dropped; ``"clean"`` passes
    it on.  Everything else is the wrapped link's."""

    def __init__(self, link, seed: int = 0, flood: int = 64):
        self.link = link
        self.mode = "clean"
        self.rng = random.Random(seed)
        self.flood = flood

    def __getattr__(self, name):
        return getattr(self.link, name)

    def write(self, data: bytes) -> int:
        if self.mode == "silent":
            return len(data)
        if self.mode in ("garbage", "both"):
            self.link.write(self.rng.randbytes(len(data) + self.flood))
            return len(data)
        return self.link.write(data)

    def read(self, *args) -> bytes:
        data = self.link.read(*args)
        return self.rng.randbytes(len(data) + self.flood) if self.mode == "both" else data


class Episode:
    """Drives ``drv`` at (0.2 m/s, 0.2 rad/s) against ``dev`` on ``body`` (5 ms device steps, 50 ms control
    cycles, simulated time): clean for ``before`` s, then ``mode`` for ``spell`` s, then clean for ``after`` s.

    ``stopped_after``: seconds from the spell's start until the body's wheels stood still (None: never);
    ``recovered_after``: seconds from the spell's end until the driver decoded fresh odometry and the wheels turned
    again (None: not within ``after``).  ``wall``: run no faster than the wall clock."""

    def __init__(self, drv, dev, body, link: Babbler, moving, mode: str, before=2.0, spell=10.0, after=10.0,
                 dt=0.005, period=0.05, wall=False):
        self.stopped_after = self.recovered_after = None
        self.moved_during = False
        t, k, fresh_since_clean = 0.0, 0, False
        end = before + spell + after
        every = round(period / dt)
        w0 = time.monotonic()
        while t < end - 1e-9:
            k += 1
            t = k * dt
            if wall:                                   # the simulated clock kept to the wall clock (TCP links)
                time.sleep(max(0.0, w0 + t - time.monotonic()))
            link.mode = mode if before <= t < before + spell else "clean"
            body.step(dt)
            dev.service(t)
            if k % every == 0:
                fresh = drv.poll(t)
                drv.set_velocity(0.2, 0.2, t)
                if t >= before + spell and fresh:
                    fresh_since_clean = True
            if before <= t < before + spell:
                if self.stopped_after is None and not moving():
                    self.stopped_after = t - before
                elif self.stopped_after is not None and moving():
                    self.moved_during = True
            elif t >= before + spell and self.recovered_after is None and fresh_since_clean and moving():
                self.recovered_after = t - before - spell
            if t < before and k == round(before / dt) - 1:
                assert moving(), "the body never moved before the spell"
