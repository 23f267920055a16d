"""A CAN base whose socketcand stream turns to garbage (or whose drives fall silent) for 10 s: python-can's per-frame complaints are counted, not
logged (no traceback anywhere), the driver says so once, the base is stopped by the drives' silence fault within
3 heartbeat periods of the last frame, no DeviceLost (the link is there, its bytes are bad), and once clean frames
return the drives are heard again and a fault reset brings the base back, in a measured time."""
from __future__ import annotations

import logging
import random

import pytest

from runtime.drivers import cia402_protocol as P
from tests.can_util import Rig


@pytest.mark.parametrize("mode", ["garbage", "silent"])
def test_garbage_or_silence_on_the_socketcand_stream_stops_the_base_and_the_link_recovers(mode, caplog):
    rng = random.Random(3)
    r = Rig("socketcand")
    try:
        with caplog.at_level(logging.INFO):
            r.open()
            r.v = 0.3
            r.step(1.0)
            assert r.left.motor != 0.0
            clients = r.dev.hub._channels[r.dev.channel].clients
            hub = r.dev.hub
            t0 = r.t
            stopped_at = None
            if mode == "silent":                # both drives off the bus for 10 s
                for d in r.dev.drives.values():
                    d.silence(True)
            while r.t - t0 < 10.0:              # or 10 s of garbage between the frames, every control period
                if mode == "garbage":
                    for c in clients:
                        hub._write(c, rng.randbytes(300), frame=False)
                r.step(r.period)
                if stopped_at is None and r.left.motor == r.right.motor == 0.0:
                    stopped_at = r.t - t0
            assert stopped_at is not None and stopped_at < 1.0, stopped_at
            assert r.base.sensors.faults and r.base.is_open
            if mode == "silent":
                for d in r.dev.drives.values():
                    d.silence(False)
            t1 = r.t
            heard = r.step(5.0, until=lambda rig: not any(k.endswith("_silent") for k in rig.base._current))
            assert heard is not None
            assert r.base.reset_faults(r.t)
            back = r.step(5.0, until=lambda rig: not rig.base.sensors.faults and rig.left.motor != 0.0)
            assert back is not None
            print(f"CAN {mode}: stopped {stopped_at:.2f} s after it began; drives heard {heard - t1:.2f} s and "
                  f"driving {back - t1:.2f} s after clean frames (reset at {heard - t1:.2f} s)")
            assert r.left.state == r.right.state == P.ENABLED
    finally:
        r.close()
    text = caplog.text
    assert "Traceback" not in text
    x = r.base.stats.extra
    if mode == "garbage":
        assert x["undecodable"] > 0 and x["bus_log_lines"] > 0
        assert text.count("undecodable input from") == 1 and text.count("decodes again") == 1, text
    driver = [rec for rec in caplog.records if rec.name == r.base.log.logger.name]
    assert len(driver) < 20, text


def test_an_error_in_python_cans_receive_thread_is_taken_by_the_frame_monitor():
    """While ``open`` and ``close`` run python-can's receive thread, what the bus raises there goes to the frame
    monitor (counted, its first line kept for one report) and the thread reads on, instead of ending with an
    uncaught exception's traceback."""
    import threading
    import time

    import can

    from runtime.drivers.cia402 import _FrameMonitor

    class Garbled(can.BusABC):
        def __init__(self):
            super().__init__(channel="garbled")
            self.reads = 0

        def _recv_internal(self, timeout):
            self.reads += 1
            time.sleep(0.002)
            raise can.CanError("Failed to receive: 'ascii' codec can't decode byte 0xfe\nTraceback (most recent ...")

        def send(self, msg, timeout=None):
            pass

    uncaught = []
    hook, threading.excepthook = threading.excepthook, uncaught.append
    bus, monitor = Garbled(), _FrameMonitor()
    try:
        notifier = can.Notifier(bus, [monitor], 0.01)
        deadline = time.monotonic() + 5.0
        while bus.reads < 5 and time.monotonic() < deadline:
            time.sleep(0.01)
        notifier.stop(1.0)
    finally:
        threading.excepthook = hook
        bus.shutdown()
    assert bus.reads >= 5 and not uncaught
    assert monitor.malformed >= 5
    assert monitor.thread_errors[0] == "CanError: Failed to receive: 'ascii' codec can't decode byte 0xfe"
