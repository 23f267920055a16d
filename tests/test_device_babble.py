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
from sitl.devices.tcp_link import open_tcp
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


@pytest.mark.slow
def test_a_pioneer_over_tcp_that_babbles_stops_and_recovers_on_the_wall_clock(caplog):
    """The same over TCP (MobileSim's and the emulator's port), on the wall clock: 3.5 s of garbage (longer than the
    driver's 3 s SIP timeout, so it hands-shakes again through it), then 3 s clean."""
    mode = "garbage"
    body = FakePioneer()
    link = Babbler(open_tcp(18301), seed=7)
    dev = ArcosDevice(body, link=link)
    drv = ArcosBase(dev.path, watchdog=WATCHDOG)
    try:
        drv.open(0.0)
        with caplog.at_level(logging.INFO):
            ep = Episode(drv, dev, body, link, lambda: body.wheel_rates() != (0.0, 0.0), mode, before=1.0, spell=3.5,
                         after=3.0, wall=True)
    finally:
        drv.close()
        dev.close()
    print(f"arcos tcp {mode}: stood still after {ep.stopped_after} s, drove again {ep.recovered_after} s after "
          f"clean bytes returned")
    assert ep.stopped_after is not None and not ep.moved_during
    assert ep.stopped_after <= WATCHDOG + 1.0 + 1.0, ep.stopped_after            # + 1 s for a loaded machine
    assert ep.recovered_after is not None, "did not drive again within 3 s of clean bytes"
    text = caplog.text
    assert "Traceback" not in text
    assert text.count("no valid input from the base") == 1 and text.count("valid input from the base again") == 1
    assert len([r for r in caplog.records if r.name == drv.log.logger.name]) < 20, text


def test_a_stray_header_with_a_long_count_does_not_hold_back_the_good_packets_after_it():
    from runtime.drivers import arcos_protocol as P
    p = P.PacketParser()
    good = P.sync(0)
    assert p.feed(b"\x12\xfa\xfb\xfa" + good) == [good[3:-2]]          # count 0xFA: 253 bytes it would wait for
    assert p.stale_headers == 1 and p.pending == 0 and p.dropped_bytes == 4
    assert p.feed(b"\xfa\xfb\xfa\x00\x01") == [] and p.pending == 5      # nothing after it yet: it may be real


class _StillBody:
    def pose(self):
        return (3.0, -2.0, 0.0)

    def velocity(self):
        return (0.0, 0.0)


@pytest.mark.parametrize("mode", ["garbage", "silent"])
def test_a_gps_that_babbles_or_goes_silent_is_one_outage_and_its_fixes_return(mode, caplog):
    """10 s of garbage or silence from the receiver: no fix comes from it, what it sent is counted, one line opens
    the outage and one closes it, and the first fix after clean bytes comes within one epoch (0.2 s)."""
    from runtime.config import Datum
    from runtime.drivers.nmea_gps import NmeaGps
    from sitl.devices.nmea_gps import NmeaGpsDevice

    link = Babbler(open_pty(), seed=5, flood=200)
    dev = NmeaGpsDevice(_StillBody(), Datum(), link=link)
    gps = NmeaGps(dev.path)
    during = first_after = None
    usable = {}
    try:
        with caplog.at_level(logging.INFO):
            for k in range(1, 22 * 20 + 1):            # 22 s: 2 clean, 10 babbling or silent, 10 clean
                t = k * 0.05
                link.mode = mode if 2.0 <= t < 12.0 else "clean"
                dev.service(t)
                fixes = gps.poll(t)
                usable[round(t, 2)] = gps.usable
                if 2.3 <= t < 12.0 and fixes:
                    during = t
                if t >= 12.0 and fixes and first_after is None:
                    first_after = t - 12.0
    finally:
        gps.close()
        dev.close()
    print(f"gps {mode}: first fix {first_after} s after clean bytes")
    assert during is None and first_after is not None and first_after <= 0.25
    assert gps.stats.outages == 1
    assert usable[1.9] and not usable[11.9] and usable[21.9]        # a sensors: entry unusable during the outage
    if mode == "garbage":
        assert gps.stats.dropped_bytes > 10_000
    text = caplog.text
    assert "Traceback" not in text
    assert text.count("no gps fix") == 1 and text.count("gps fixes again") == 1, text
    assert len([r for r in caplog.records if r.name == gps.log.logger.name]) == 2, text
