"""A third-party ARCOS client against the emulator: Soar's (PyPI "Soar", soar.robot.arcos.ARCOSClient), which
sends CLOSE before it syncs, strings without a length byte, and decodes the standard SIP through ROTVEL."""
from __future__ import annotations

import threading
import time

import pytest

from runtime.drivers import arcos_protocol as P
from sitl.devices.arcos import ArcosDevice
from tests.arcos_util import FakePioneer, wheel_speed

arcos = pytest.importorskip("soar.robot.arcos", reason="the Soar package (pip install Soar) is not installed")


class RealTime:
    """The emulator served in wall-clock time on a thread, as a real robot runs."""

    def __init__(self, dev, body):
        self.dev, self.body = dev, body
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._loop, daemon=True)
        self.thread.start()

    def _loop(self):
        t0 = last = time.monotonic()
        while not self.stop.is_set():
            now = time.monotonic()
            self.body.step(now - last)
            last = now
            self.dev.service(now - t0)
            time.sleep(0.002)

    def close(self):
        self.stop.set()
        self.thread.join(2)


def test_soar_connects_reads_sips_and_sonar_and_drives():
    body = FakePioneer()
    body.ranges = {3: 1.2}
    dev = ArcosDevice(body)
    served = RealTime(dev, body)
    client = arcos.ARCOSClient(timeout=1.0)
    try:
        client.connect(forced_ports=[dev.path])               # CLOSE, SYNC0-2, OPEN, SONAR 1, waits for sonar
        # Its CLOSE before syncing may or may not reach us (Soar reopens the port and flushes its output buffer,
        # which on a pty can discard the unread CLOSE); test_arcos_emulator covers a CLOSE while idle.
        assert dev.stats.handshakes == 1 and dev.stats.bad_packets == 0
        sip = client.standard
        assert sip["TYPE"] == "STANDARD" and sip["FLAGS"] & 0x2 and "ROTVEL" in sip
        assert client.sonars[3] == 1200
        client.send_command(arcos.ENABLE, 1)
        client.send_command(arcos.VEL, 250)
        deadline = time.monotonic() + 5
        while wheel_speed(body.cmd)[0] < 0.249 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert wheel_speed(body.cmd)[0] == pytest.approx(0.25)
        client.send_command(arcos.SAY, b"\x01\x05\x3c")      # Soar's string form: NUL, no length byte
        time.sleep(1.2)
        assert client.standard["XPOS"] > 100 and dev.said == [b"\x01\x05\x3c"]
    finally:
        client.disconnect()                                   # STOP, CLOSE
        time.sleep(0.2)
        served.close()
    assert not dev.open and body.cmd == (0.0, 0.0)
    assert dev.commands[-2:] == [P.STOP, P.CLOSE]
    dev.close()
