"""RPLIDAR driver against the emulator on a pty, in one pybullet world: scans of a known arena, garbage and
truncation on the line, a scanner that stops, an unhealthy one, a port that closes."""
from __future__ import annotations

import logging
import math

import pytest
import serial

from runtime import config as C
from runtime.drivers import rplidar_protocol as P
from runtime.drivers.rplidar import Rplidar, robot_ranges
from runtime.errors import InputError

pytest.importorskip("pybullet")
from sitl.devices.rplidar import MODELS, RplidarDevice  # noqa: E402
from sitl.world import World  # noqa: E402

HALF = 3.0          # the arena's walls' inner faces at +-3 m
X0 = 1.0            # the robot stands at (1, 0) facing +x: walls 2 m ahead, 3 m left and right, 4 m behind


@pytest.fixture(scope="module")
def body():
    with World(C.WorldConfig(size=(2 * HALF, 2 * HALF)), wheel_radius_sigma=0.0) as w:
        b = w.add_body(1, (X0, 0.0, 0.0), "pioneer3dx")
        w.step(40)
        yield b


def expected(angle_deg: float, pose) -> float:
    """Distance from the scanner at ``pose`` to the arena wall along device angle ``angle_deg`` (clockwise)."""
    x, y, yaw = pose
    a = yaw - math.radians(angle_deg)
    c, s = math.cos(a), math.sin(a)
    return min((HALF - x) / c if c > 1e-9 else math.inf, (-HALF - x) / c if c < -1e-9 else math.inf,
               (HALF - y) / s if s > 1e-9 else math.inf, (-HALF - y) / s if s < -1e-9 else math.inf)


def run(dev, drv, t0: float, seconds: float, poll_every: int = 10, dt: float = 0.005, between=None):
    """Serve ``dev`` every ``dt`` of sim time and poll ``drv`` every ``poll_every`` steps; the scans and end time."""
    scans, t = [], t0
    for i in range(int(round(seconds / dt))):
        t += dt
        dev.service(t)
        if between is not None:
            between(i, t)
        if i % poll_every == 0:
            scans += drv.poll(t)
    return scans, t


@pytest.mark.parametrize("model", ["a1", "a2"])
def test_scans_match_the_arena_within_the_datasheet(body, model):
    dev = RplidarDevice(body, model)
    drv = Rplidar(dev.path, model=model)
    try:
        drv.open(0.0)
        scans, _ = run(dev, drv, 0.0, 1.0)
        m = MODELS[model]
        assert drv.usable and drv.info.name == ("A1M8" if model == "a1" else "A2M8") and drv.health.status == 0
        assert len(scans) >= int(m.scan_hz) - 2 and all(s.nodes == m.samples for s in scans[1:])
        assert dev.pwm == (P.DEFAULT_PWM if model == "a2" else 0)
        pose = body.pose()
        for scan in scans[1:]:
            assert len(scan.points) == m.samples                 # every beam meets a wall inside 12 m
            for angle, r, q in scan.points:
                assert q == 15 and abs(r - expected(angle, pose)) <= 0.01 * r + 0.001
        bearings = dict(robot_ranges(scans[-1], (0.0, 0.0, 0.0)))
        ahead = min(bearings, key=abs)
        assert abs(bearings[ahead] - (HALF - X0)) < 0.03
        left = dict(drv.ranges())                              # the same, as BaseSensors.ranges
        assert abs(left[min(left, key=lambda b: abs(b - math.pi / 2))] - HALF) < 0.05
        assert drv.parser.stats.dropped_bytes == 0
    finally:
        drv.close()
        dev.close()


def test_garbage_and_truncation_on_the_line_are_dropped_and_scans_go_on(body):
    dev = RplidarDevice(body, "a1", seed=3)
    drv = Rplidar(dev.path)
    try:
        drv.open(0.0)

        def noise(i, t):
            if i % 37 == 5:
                dev.link.write(b"\x00\xa5\x5a\x13" * (1 + i % 3))      # garbage, a descriptor's start cut short
            if i % 53 == 7:
                dev.link.write(P.encode_node(False, 15, 64, 4000)[:3])   # a node cut short
        scans, _ = run(dev, drv, 0.0, 1.5, between=noise)
        st = drv.parser.stats
        assert st.dropped_bytes > 0 and st.bad_nodes > 0 and st.resyncs > 1
        assert st.bytes == st.good_bytes + st.dropped_bytes + drv.parser.pending_bytes
        assert len(scans) >= 5 and drv.usable
        pose = body.pose()
        good = [abs(r - expected(a, pose)) <= 0.01 * r + 0.001 for s in scans for a, r, _ in s.points]
        assert sum(good) / len(good) > 0.99          # a node straddling the garbage may decode oddly, rarely
    finally:
        drv.close()
        dev.close()


def test_a_scanner_that_stops_is_reported_once_and_not_used_until_it_scans(body, caplog):
    dev = RplidarDevice(body, "a1")
    drv = Rplidar(dev.path, stall_timeout=0.3, robot_id=7)
    try:
        drv.open(0.0)
        _, t = run(dev, drv, 0.0, 0.6)
        assert drv.usable
        dev.jammed = True
        with caplog.at_level(logging.WARNING, logger="mrta.rplidar"):
            _, t = run(dev, drv, t, 2.0)
        lines = [r for r in caplog.records if "no measurement" in r.getMessage()]
        assert len(lines) == 1 and lines[0].robot == 7 and dev.path in lines[0].getMessage()
        assert not drv.usable and drv.stalled and drv.stats.stalls == 1 and drv.ranges() == ()
        dev.jammed = False
        scans, _ = run(dev, drv, t, 1.5)
        assert drv.usable and scans and not drv.stalled
    finally:
        drv.close()
        dev.close()


def test_an_a2_whose_motor_is_off_sends_no_nodes(body):
    dev = RplidarDevice(body, "a2")
    drv = Rplidar(dev.path, model="a2", motor_pwm=0, stall_timeout=0.3)
    try:
        drv.open(0.0)
        scans, _ = run(dev, drv, 0.0, 1.0)
        assert scans == [] and dev.stats.nodes == 0 and dev.scanning and drv.stalled and not drv.usable
    finally:
        drv.close()
        dev.close()


def test_a_protection_stop_is_reset_once_and_then_scans(body, caplog):
    dev = RplidarDevice(body, "a1")
    dev.health = P.Health(P.HEALTH_ERROR, 0x2A)
    drv = Rplidar(dev.path)
    try:
        drv.open(0.0)
        with caplog.at_level(logging.WARNING, logger="mrta.rplidar"):
            scans, _ = run(dev, drv, 0.0, 0.8)
        assert scans and drv.usable and drv.resets == 1 and drv.health.status == P.HEALTH_GOOD
        assert not [r for r in caplog.records if r.levelno >= logging.WARNING]
    finally:
        drv.close()
        dev.close()


def test_an_unhealthy_scanner_is_not_started(body, caplog):
    dev = RplidarDevice(body, "a1")
    dev.health = P.Health(P.HEALTH_ERROR, 0x2A)
    dev.persistent_fault = True
    drv = Rplidar(dev.path)
    try:
        drv.open(0.0)
        with caplog.at_level(logging.WARNING, logger="mrta.rplidar"):
            scans, _ = run(dev, drv, 0.0, 0.8)
        assert scans == [] and drv.state == "failed" and not dev.scanning and drv.resets == 1
        assert [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING] == [
            f"rplidar on {dev.path}: health error (code 42) after a reset: not used"]
    finally:
        drv.close()
        dev.close()


def test_stop_and_reset_end_the_stream(body):
    dev = RplidarDevice(body, "a1")
    drv = Rplidar(dev.path)
    try:
        drv.open(0.0)
        _, t = run(dev, drv, 0.0, 0.5)
        assert dev.scanning
        for cmd in (P.CMD_STOP, P.CMD_RESET):
            drv.link.write(P.request(cmd))
            dev.service(t + 0.005)
            assert not dev.scanning
            n = dev.stats.nodes
            dev.service(t + 0.5)
            assert dev.stats.nodes == n
            drv.link.write(P.request(P.CMD_SCAN))
            t += 0.6
            dev.service(t)
            assert dev.scanning
    finally:
        drv.close()
        dev.close()


def test_a_closed_port_is_one_log_line_and_the_owner_lives(body, caplog):
    dev = RplidarDevice(body, "a1")
    drv = Rplidar(dev.path, stall_timeout=0.3, robot_id=4)
    drv.open(0.0)
    _, t = run(dev, drv, 0.0, 0.6)
    assert drv.usable
    dev.close()                                     # the scanner's end of the line goes away
    with caplog.at_level(logging.DEBUG, logger="mrta.rplidar"):
        for _ in range(60):
            t += 0.05
            assert drv.poll(t) == []
    warnings = [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(warnings) == 1 and "port lost" in warnings[0].getMessage() and warnings[0].robot == 4
    assert drv.state == "lost" and not drv.usable
    drv.close()                                     # never raises


def test_a_port_that_does_not_open_names_it():
    with pytest.raises(InputError, match="rplidar port '/nonexistent/tty'"):
        Rplidar("/nonexistent/tty").open(0.0)


def _read(port, host, enough, limit: float = 2.0) -> list:
    """What the host parser makes of the port's bytes, read until ``enough(got)`` or ``limit`` s: bytes written to a
    pty master reach the slave through the kernel's tty work queue, not always by the next read (a clean-clone
    make test read nothing once)."""
    import time
    got, end = [], time.monotonic() + limit
    while True:
        got += host.feed(port.read(65536))
        if enough(got) or time.monotonic() > end:
            return got
        time.sleep(0.005)


def test_info_asked_during_a_scan_is_answered_when_it_stops(body):
    dev = RplidarDevice(body, "a1")
    host = P.ResponseParser()
    try:
        port = serial.serial_for_url(dev.path, 115200, timeout=0)
        port.write(P.request(P.CMD_SCAN))
        dev.service(0.005)
        dev.service(0.1)
        port.write(P.request(P.CMD_GET_INFO))
        dev.service(0.2)
        got = _read(port, host, lambda g: g)
        assert got and all(isinstance(x, P.Node) for x in got)        # no info inside the node stream
        port.write(P.request(P.CMD_STOP))
        dev.service(0.205)
        host.reset()
        got = _read(port, host, lambda g: any(not isinstance(x, P.Node) for x in g))
        assert [x for x in got if not isinstance(x, P.Node)] == [dev.info]
        port.close()
    finally:
        dev.close()
