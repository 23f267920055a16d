"""Devices that babble or go silent: a base whose device sends garbage or nothing for 10 s stands still within one
watchdog period of its last valid input, logs one line per episode (no traceback, nothing per frame), counts what it
dropped, and drives again by itself once clean bytes return, in a measured time."""
from __future__ import annotations

import logging

import pytest

from runtime.drivers.arcos import ArcosBase
from runtime.drivers.create_oi import CreateOI
from sitl.devices.arcos import ArcosDevice
from sitl.devices.create_oi import CreateOIDevice
from sitl.devices.pty_link import open_pty
from tests.arcos_util import FakePioneer
from tests.babble_util import Babbler, Episode
from tests.fakes import FakeBody

WATCHDOG = 0.5


def _arcos(seed):
    body = FakePioneer()
    link = Babbler(open_pty(), seed)
    dev = ArcosDevice(body, link=link)
    drv = ArcosBase(dev.path, watchdog=WATCHDOG)
    return drv, dev, body, link, lambda: body.wheel_rates() != (0.0, 0.0)


def _create(seed):
    body = FakeBody()
    link = Babbler(open_pty(), seed)
    dev = CreateOIDevice(body, link=link)
    drv = CreateOI(dev.path, watchdog=WATCHDOG)
    return drv, dev, body, link, lambda: body.cmd != (0.0, 0.0)


# (TCP is left to the kill tests: these run the simulated clock some 250 times faster than the wall clock, where
# loopback TCP's own scheduling shows as seconds)
CASES = [(_arcos, "garbage"), (_arcos, "silent"), (_arcos, "both"), (_create, "garbage"), (_create, "silent")]


@pytest.mark.parametrize("make, mode", CASES, ids=[f"{m.__name__[1:]}-{mode}" for m, mode in CASES])
def test_a_base_that_babbles_or_goes_silent_stops_and_recovers_by_itself(make, mode, caplog):
    drv, dev, body, link, moving = make(seed=7)
    try:
        drv.open(0.0)
        with caplog.at_level(logging.INFO):
            ep = Episode(drv, dev, body, link, moving, mode)
    finally:
        drv.close()
        dev.close()
    text = caplog.text
    print(f"{make.__name__[1:]} {mode}: stood still after {ep.stopped_after} s, drove again {ep.recovered_after} s "
          f"after clean bytes returned")
    assert ep.stopped_after is not None and not ep.moved_during
    # one watchdog period of no valid input, plus the base's own deceleration and a control period; a robot that
    # hears garbage instead of the stop stops by its own watchdog (ARCOS: 2 s)
    assert ep.stopped_after <= (2.0 if mode == "both" else WATCHDOG) + 1.0, ep.stopped_after
    assert ep.recovered_after is not None, "did not drive again within 10 s of clean bytes"
    assert "Traceback" not in text
    assert text.count("no valid input from the base") == 1, text
    assert text.count("valid input from the base again") == 1, text
    if mode != "silent":
        assert drv.stats.dropped_bytes > 0 or drv.stats.bad_checksum > 0
    driver = [r for r in caplog.records if r.name == drv.log.logger.name]
    assert len(driver) < 20, text                                # nothing per frame


def test_a_stray_header_with_a_long_count_does_not_hold_back_the_good_packets_after_it():
    from runtime.drivers import arcos_protocol as P
    p = P.PacketParser()
    good = P.sync(0)
    assert p.feed(b"\x12\xfa\xfb\xfa" + good) == [good[3:-2]]          # count 0xFA: 253 bytes it would wait for
    assert p.stale_headers == 1 and p.pending == 0 and p.dropped_bytes == 4
    assert p.feed(b"\xfa\xfb\xfa\x00\x01") == [] and p.pending == 5      # nothing after it yet: it may be real
