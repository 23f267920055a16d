"""Stock RPLIDAR clients from PyPI read the emulator's pty: device info, health, and scans of a known arena.

The emulator is served from a thread on wall-clock time (the clients block on their reads).  ``pyrplidar`` runs
unmodified.  ``rplidar`` 0.9.2 toggles DTR to start an A1's motor in its constructor and scan loop; a pty has no
modem lines (pyserial's ioctl fails with ENOTTY), so its test subclass starts the motor by MOTOR_PWM only, as on an
A2, and everything else is the stock code."""
from __future__ import annotations

import math
import threading
import time

import pytest

from runtime import config as C

pytest.importorskip("pybullet")
from sitl.devices.rplidar import RplidarDevice  # noqa: E402
from sitl.world import World  # noqa: E402

HALF, X0 = 3.0, 1.0          # walls at +-3 m; the scanner at (1, 0) facing +x


def wall(angle_deg: float) -> float:
    a = -math.radians(angle_deg)
    c, s = math.cos(a), math.sin(a)
    return min((HALF - X0) / c if c > 1e-9 else math.inf, (-HALF - X0) / c if c < -1e-9 else math.inf,
               HALF / abs(s) if abs(s) > 1e-9 else math.inf)


@pytest.fixture()
def served():
    """An A1 emulator on a Pioneer in the arena, serviced every 2 ms of wall time until the test ends."""
    with World(C.WorldConfig(size=(2 * HALF, 2 * HALF)), wheel_radius_sigma=0.0) as w:
        body = w.add_body(1, (X0, 0.0, 0.0), "pioneer3dx")
        w.step(40)
        dev = RplidarDevice(body, "a1")
        stop = threading.Event()
        t0 = time.monotonic()

        def serve():
            while not stop.is_set():
                dev.service(time.monotonic() - t0)
                time.sleep(0.002)
        th = threading.Thread(target=serve, daemon=True)
        th.start()
        try:
            yield dev
        finally:
            stop.set()
            th.join(5)
            dev.close()


def check(points):
    """(angle deg, distance mm) of one revolution: the arena's walls within the A1's 1 %."""
    assert len(points) >= 300
    for angle, mm in points:
        d = wall(angle)
        assert abs(mm / 1000.0 - d) <= 0.01 * d + 0.001, (angle, mm, d)


def test_pyrplidar_reads_info_health_and_scans(served):
    pyrplidar = pytest.importorskip("pyrplidar")
    lidar = pyrplidar.PyRPlidar()
    lidar.connect(port=served.path, baudrate=115200, timeout=3)
    try:
        info = lidar.get_info()
        assert (info.model, info.firmware_major, info.firmware_minor, info.hardware) == (0x18, 1, 29, 7)
        assert info.serialnumber == served.info.serial.hex().upper()
        health = lidar.get_health()
        assert (health.status, health.error_code) == (0, 0)
        revs, cur = [], None
        for m in lidar.start_scan()():
            if m.start_flag:
                if cur is not None:
                    revs.append(cur)
                if len(revs) == 2:
                    break
                cur = []
            if cur is not None and m.distance > 0:
                cur.append((m.angle, m.distance))
        lidar.stop()
    finally:
        lidar.disconnect()
    for points in revs:
        check(points)


def test_rplidar_iterates_scans(served):
    rplidar = pytest.importorskip("rplidar")

    class PtyRPLidar(rplidar.RPLidar):
        def start_motor(self):          # no DTR on a pty: the A2 way only
            self.set_pwm(rplidar.DEFAULT_MOTOR_PWM)
            self.motor_running = True

        def stop_motor(self):
            self.set_pwm(0)
            self.motor_running = False

    lidar = PtyRPLidar(served.path, timeout=3)
    try:
        info = lidar.get_info()
        assert info["model"] == 0x18 and info["firmware"] == (1, 29) and info["hardware"] == 7
        assert lidar.get_health() == ("Good", 0)
        scans = []
        for scan in lidar.iter_scans():
            scans.append(scan)
            if len(scans) == 2:
                break
        lidar.stop()
        lidar.stop_motor()
    finally:
        lidar.disconnect()
    for scan in scans:
        assert all(q == 15 for q, _, _ in scan)
        check([(a, d) for _, a, d in scan])
