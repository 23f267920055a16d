"""Acceptance: unmodified third-party Create 2 libraries drive the emulator over its pty.

The emulator is serviced in a background thread on the monotonic clock, because these libraries
block (sleeps, reads with timeouts).  Findings about the libraries themselves are asserted where they
show on the wire, so a fixed release will flag here:

* pycreate2 0.8.0 ``SensorPacketDecoder`` names bit 0 of packet 7 ``bump_left``; the spec's bit 0 is
  Bump Right (and bit 2 Wheel Drop Right), so its left/right bumps and wheel drops are swapped.
* pyroombaadapter 0.3.0 ``move(v, 0)`` clamps the special straight radius 32768 to 2000 mm before
  sending, so "straight" is a 2 m left arc.
"""
from __future__ import annotations

import gc
import threading
import time

import pytest

from runtime.drivers import create_oi_protocol as P
from sitl.devices.create_oi import CreateOIDevice
from tests.fakes import FakeBody


class Emulated:
    """Emulator + body serviced every millisecond of wall time in a thread."""

    def __init__(self):
        self.body = FakeBody()
        self.dev = CreateOIDevice(self.body)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        t0 = last = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            self.body.step(now - last)
            last = now
            self.dev.service(now - t0)
            time.sleep(0.001)

    def wait_for(self, condition, timeout=3.0):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if condition():
                return True
            time.sleep(0.005)
        return condition()

    def close(self):
        self._stop.set()
        self._thread.join(timeout=2)
        self.dev.close()


@pytest.fixture
def emulated():
    em = Emulated()
    yield em
    em.close()


def test_pycreate2_starts_drives_and_reads_sensors(emulated):
    from pycreate2 import Create2

    em, body, dev = emulated, emulated.body, emulated.dev
    body.bump = (False, True)                          # only the right bumper pressed
    bot = Create2(dev.path, 115200)
    bot.start()
    assert em.wait_for(lambda: dev.mode_name == "passive")
    bot.safe()
    assert em.wait_for(lambda: dev.mode_name == "safe")
    bot.drive_direct(200, 100)                         # pycreate2 takes (right, left)
    assert em.wait_for(lambda: body.cmd == (0.1, 0.2))
    time.sleep(0.3)
    s = bot.get_sensors()                              # Sensors (142) packet 100: 80 bytes
    assert s.open_interface_mode == P.MODE_SAFE
    assert (s.velocity_right, s.velocity_left) == (200, 100)
    assert 13000 < s.voltage < 17000 and s.current < 0 and 15 <= s.temperature <= 40
    assert s.battery_capacity == 2696 and 0 < s.battery_charge <= 2696
    assert 0 < s.encoder_counts_left < s.encoder_counts_right
    assert s.distance > 0 and s.angle > 0              # forward, turning left (right wheel faster)
    assert s.cliff_left_signal > 0 and not s.cliff_left
    assert s.bumps_wheeldrops.bump_left and not s.bumps_wheeldrops.bump_right   # pycreate2's swap, see above
    assert body.travel[1] > body.travel[0] > 0.02       # the body moved
    bot.full()
    assert em.wait_for(lambda: dev.mode_name == "full")
    del bot                                            # its destructor stops the wheels and sends Stop (173)
    gc.collect()
    assert em.wait_for(lambda: dev.mode_name == "off")
    assert body.cmd == (0.0, 0.0)
    assert dev.stats.unknown_opcodes == 0 and dev.stats.bad_packet_ids == 0 and dev.stats.ignored == 0


def test_pyroombaadapter_drives_reads_and_streams(emulated):
    pra = pytest.importorskip("pyroombaadapter", reason="pyroombaadapter is not installed")
    em, body, dev = emulated, emulated.body, emulated.dev
    adapter = pra.PyRoombaAdapter(dev.path)            # Start + Safe, then it sleeps 1 s
    assert em.wait_for(lambda: dev.mode_name == "safe")
    adapter.send_drive_direct(150, 120)                # (right, left) mm/s
    assert em.wait_for(lambda: body.cmd == (0.12, 0.15))
    time.sleep(0.2)
    assert adapter.request_oi_mode() == P.MODE_SAFE
    assert 13000 < adapter.request_voltage() < 17000
    left, right = adapter.request_encoder_counts()
    assert 0 < left < right
    adapter.move(0.0, 0.5)                             # turn in place: Drive with radius 1
    assert em.wait_for(lambda: body.cmd == (-0.058, 0.058))
    adapter.move(0.2, 0.0)                             # "straight": sent as radius 2000 (their clamp)
    assert em.wait_for(lambda: dev.requested["requested_radius"] == 2000)
    assert body.cmd[1] > body.cmd[0] > 0
    adapter.send_drive_direct(0, 0)
    adapter.data_stream_start(["OI Mode", "Voltage"])
    mode, volts = adapter.data_stream_read()
    assert mode == P.MODE_SAFE and 13000 < volts < 17000
    adapter.data_stream_stop()                          # [148][0]
    assert em.wait_for(lambda: not dev.streaming)
    del adapter                                         # its destructor sends Start: back to Passive
    gc.collect()
    assert em.wait_for(lambda: dev.mode_name == "passive")
    assert dev.stats.unknown_opcodes == 0 and dev.stats.bad_packet_ids == 0
