"""ArcosBase driver against a robot played by the test on a pty: the handshake as ARIA runs it, the exact bytes
of motion, keep-alive and close, odometry across the 15-bit wrap, sonar ranges, bumpers, stall, battery, faults."""
from __future__ import annotations

import math
import os

import pytest
from hypothesis import given, settings, strategies as st

from runtime.drivers import arcos_protocol as P
from runtime.drivers.arcos import ArcosBase, arcos_footprint
from runtime.drivers.base import DeviceLost
from runtime.errors import InputError
from sitl.devices.pty_link import open_pty


class Robot:
    """The robot end of a pty, played by hand."""

    def __init__(self):
        self.link = open_pty()
        self.parser = P.PacketParser()

    def got(self) -> list[bytes]:
        """Packets (wire form) the driver sent since the last call."""
        return [P.frame(b) for b in self.parser.feed(self.link.read())]

    def send(self, *bodies: bytes) -> None:
        self.link.write(b"".join(P.frame(b) for b in bodies))

    def close(self):
        self.link.close()


@pytest.fixture
def rig():
    robot = Robot()
    drv = ArcosBase(robot.link.path)
    yield robot, drv
    drv.close()
    robot.close()


def connect(robot: Robot, drv: ArcosBase, now: float = 0.0) -> list[bytes]:
    """Run the handshake; the packets the driver sent after SYNC2's reply."""
    drv.open(now)
    for n in range(3):
        assert robot.got() == [P.sync(n)]
        robot.send(bytes([n]) if n < 2 else P.sync2_reply("Robot7", "Pioneer", "p3dx-sh"))
        drv.poll(now)
    return robot.got()


def sip_body(**kw) -> bytes:
    kw.setdefault("flags", P.FLAG_MOTORS | P.FLAG_SONAR_ARRAYS[0] | P.FLAG_SONAR_ARRAYS[1])
    return P.encode_sip(P.Sip(**kw))


# ----------------------------------------------------------------------------- settings
@pytest.mark.parametrize("kw", [{"max_speed": 3.0}, {"max_speed": 0}, {"subclass": "p2dx"}, {"watchdog": 0}])
def test_bad_settings_are_one_line_input_errors(kw):
    with pytest.raises(InputError) as exc:
        ArcosBase("loop://", **kw)
    assert "\n" not in str(exc.value) and "expected" in str(exc.value)


def test_a_port_that_cannot_open_names_it():
    drv = ArcosBase("socket://127.0.0.1:1")
    with pytest.raises(InputError, match="socket://127.0.0.1:1"):
        drv.open(0.0)


def test_footprint_from_p3dx_sh():
    fp = arcos_footprint(P.P3DX_SH, 0.75)
    assert fp.radius == 0.25 and fp.track == pytest.approx(0.35714, abs=1e-5) and fp.max_speed == 0.75
    assert fp.max_turn_rate == pytest.approx(2 * 0.75 / 0.35714, rel=1e-4)
    assert arcos_footprint().max_turn_rate == pytest.approx(math.radians(500))       # MaxRVelocity caps it


# ----------------------------------------------------------------------------- handshake
def test_handshake_then_open_enable_sonar_config(rig):
    robot, drv = rig
    after = connect(robot, drv)
    assert after == [P.open_(), P.enable(True), P.sonar(True), P.config()]
    assert drv.state == "connected" and drv.identity == ("Robot7", "Pioneer", "p3dx-sh")
    assert drv.stats.extra["handshakes"] == 1


def test_a_wrong_reply_starts_again_at_sync0(rig):
    robot, drv = rig
    drv.open(0.0)
    robot.got()
    robot.send(b"\x00")
    drv.poll(0.0)
    assert robot.got() == [P.sync(1)]
    robot.send(b"\x02")                               # expected 1
    drv.poll(0.01)
    assert robot.got() == [P.sync(0)] and drv.stats.extra["sync_restarts"] == 1


def test_a_late_answer_to_a_resent_sync_is_ignored_not_a_restart(rig):
    """A round trip longer than SYNC_RETRY: SYNC0 went out twice; the first answer moves on to SYNC1 and the second,
    late, answer to SYNC0 must not send the handshake back to SYNC0 (before, a steady delay livelocked it)."""
    robot, drv = rig
    drv.open(0.0)
    drv.poll(0.3)                                     # no answer within SYNC_RETRY: SYNC0 again
    assert robot.got() == [P.sync(0), P.sync(0)]
    robot.send(b"\x00")
    drv.poll(0.35)
    assert robot.got() == [P.sync(1)]
    robot.send(b"\x00")                              # the answer to the second SYNC0, late
    drv.poll(0.36)
    assert robot.got() == [] and drv.stats.extra["late_sync_replies"] == 1
    assert drv.stats.extra["sync_restarts"] == 0
    robot.send(b"\x01")
    drv.poll(0.37)
    assert robot.got() == [P.sync(2)]


def test_sips_still_flowing_close_the_old_session_first(rig):
    robot, drv = rig
    drv.open(0.0)
    robot.got()
    robot.send(sip_body(), sip_body())
    drv.poll(0.0)
    assert robot.got() == [P.close(), P.sync(0)]      # once, not once per SIP
    assert drv.stats.extra["stale_sessions"] == 1 and drv.state == "sync"


def test_silence_resends_the_sync_and_every_third_miss_closes(rig):
    robot, drv = rig
    drv.open(0.0)
    robot.got()
    drv.poll(0.1)
    assert robot.got() == []
    sent = []
    for k in range(1, 4):
        drv.poll(0.26 * k)
        sent.append(robot.got())
    assert sent == [[P.sync(0)], [P.sync(0)], [P.close(), P.sync(0)]]


def test_handshake_answers_in_odd_chunks(rig):
    robot, drv = rig
    drv.open(0.0)
    robot.got()
    wire = P.frame(b"\x00")
    robot.link.write(b"garbage" + wire[:2])
    drv.poll(0.0)
    robot.link.write(wire[2:])
    drv.poll(0.0)
    assert robot.got() == [P.sync(1)] and drv.stats.dropped_bytes == len(b"garbage")


# ----------------------------------------------------------------------------- motion and keep-alive
def test_velocity_is_vel_then_rvel(rig):
    robot, drv = rig
    connect(robot, drv)
    drv.set_velocity(0.2, 0.0, 0.0)
    assert robot.got() == [P.vel(200), P.rvel(0)]
    drv.set_velocity(-0.1, 0.5, 0.2)
    assert robot.got() == [P.vel(-100), P.rvel(29)]            # 0.5 rad/s = 28.6 deg/s


def test_changes_wait_for_the_next_sip_cycle_but_stops_go_at_once(rig):
    robot, drv = rig
    connect(robot, drv)
    drv.set_velocity(0.2, 0.0, 1.0)
    robot.got()
    drv.set_velocity(0.25, 0.0, 1.05)
    assert robot.got() == []
    drv.poll(1.08)
    assert robot.got() == []
    drv.poll(1.1)
    assert robot.got() == [P.vel(250), P.rvel(0)]
    drv.set_velocity(0.0, 0.0, 1.12)
    assert robot.got() == [P.vel(0), P.rvel(0)]


def test_moving_resends_every_half_second_and_silence_sends_pulse(rig):
    robot, drv = rig
    connect(robot, drv, 0.0)
    drv.set_velocity(0.3, 0.0, 0.0)
    robot.got()
    drv.set_velocity(0.3, 0.0, 0.3)
    assert robot.got() == []                                 # unchanged: not sent again yet
    drv.set_velocity(0.3, 0.0, 0.5)
    assert robot.got() == [P.vel(300), P.rvel(0)]
    drv.set_velocity(0.0, 0.0, 0.6)
    robot.got()
    drv.poll(1.0)
    assert robot.got() == []
    drv.poll(1.1)
    assert robot.got() == [P.pulse()]                        # 0.5 s with nothing sent
    drv.poll(1.3)
    assert robot.got() == []


def test_watchdog_stop_after_silence_from_the_daemon(rig):
    robot, drv = rig
    connect(robot, drv)
    drv.set_velocity(0.3, 0.0, 0.0)
    robot.got()
    drv.poll(0.49)
    drv.poll(0.5)
    assert robot.got() == [P.pulse(), P.vel(0), P.rvel(0)] and drv.stats.watchdog_stops == 1    # no refresh first


def test_close_sends_stop_and_close(rig):
    robot, drv = rig
    connect(robot, drv)
    drv.close()
    assert robot.got() == [P.stop(), P.close()]
    assert drv.state == "closed"


# ----------------------------------------------------------------------------- SIPs
def test_odometry_in_the_frame_of_the_first_sip_across_the_wrap(rig):
    robot, drv = rig
    connect(robot, drv)
    th0 = 1024                                                # the robot starts facing +y in its own frame
    robot.send(sip_body(x=0x7F00, y=100, th=th0))
    assert drv.poll(0.1)
    assert (drv.odometry.x, drv.odometry.y, drv.odometry.theta) == (0.0, 0.0, 0.0)
    robot.send(sip_body(x=0x7F00, y=100 + 500, th=th0))       # 0.5 m ahead (robot +y)
    drv.poll(0.2)
    assert drv.odometry.x == pytest.approx(0.5) and drv.odometry.y == pytest.approx(0.0, abs=1e-9)
    robot.send(sip_body(x=0x7F00 + 0x200 - 0x8000, y=600, th=th0 + 1024))   # x wrapped: 0.512 m to robot +x
    drv.poll(0.3)
    o = drv.odometry
    assert o.x == pytest.approx(0.5) and o.y == pytest.approx(-0.512) and o.theta == pytest.approx(math.pi / 2)
    assert o.distance == pytest.approx(1.012)


def test_velocities_from_the_wheels_and_rotvel(rig):
    robot, drv = rig
    connect(robot, drv)
    robot.send(sip_body(left_vel=100, right_vel=300))                  # no tail: ARIA's DiffConv fallback
    drv.poll(0.1)
    assert drv.odometry.v == pytest.approx(0.2) and drv.odometry.w == pytest.approx(100 * 0.0056)
    tail = dict(grip_anport=0, analog=0, digin=0, digout=0, battery_x10=125, charge_state=0, rot_vel_x10=320)
    robot.send(sip_body(left_vel=100, right_vel=300, **tail))
    drv.poll(0.2)
    assert drv.odometry.w == pytest.approx(math.radians(32.0))


def test_sonar_readings_become_ranges_from_the_centre(rig):
    robot, drv = rig
    connect(robot, drv)
    robot.send(sip_body(sonars=((3, 1000), (4, 5000), (12, 700), (20, 300))))
    drv.poll(0.1)
    got = dict(zip((3, 12), drv.sensors.ranges))
    assert len(drv.sensors.ranges) == 2                      # 5000 mm is no echo; sonar 20 does not exist
    assert got[3] == pytest.approx(P.P3DX_SH.sonar_point(3, 1000))
    assert got[12] == pytest.approx(P.P3DX_SH.sonar_point(12, 700))
    assert drv.stats.extra["bad_sonar"] == 1
    robot.send(sip_body(sonars=()))
    drv.poll(0.6)
    assert len(drv.sensors.ranges) == 2                      # kept while fresh ...
    robot.send(sip_body(sonars=()))
    drv.poll(1.2)
    assert drv.sensors.ranges == ()                          # ... and aged out after a second
    robot.send(sip_body(sonars=((3, 900), (12, 900)), flags=P.FLAG_MOTORS | P.FLAG_SONAR_ARRAYS[1]))
    drv.poll(1.3)
    assert drv.sensors.ranges == (P.P3DX_SH.sonar_point(12, 900),)       # the front array reports off


@pytest.mark.parametrize("bits, v, left, right", [
    (P.LEFT_STALL, 0.2, True, False),
    (P.RIGHT_STALL, 0.2, False, True),
    (P.LEFT_STALL | P.RIGHT_STALL, -0.2, False, False),      # stalled while reversing: not a bump ahead
    (0b00001 << 9, 0.0, True, False),                        # front bumper 1 (leftmost)
    (0b00100 << 9, 0.0, True, True),                         # the centre one
    (0b10000 << 9, 0.0, False, True),
    (0b11111 << 1, 0.2, False, False),                       # rear bumpers are not bumps ahead
])
def test_stall_and_bumper_bits(rig, bits, v, left, right):
    robot, drv = rig
    connect(robot, drv)
    drv.set_velocity(v, 0.0, 0.0)
    robot.send(sip_body(stall_bumpers=bits))
    drv.poll(0.05)
    assert (drv.sensors.bump_left, drv.sensors.bump_right) == (left, right)


def test_battery_mode_and_faults(rig):
    robot, drv = rig
    connect(robot, drv)
    robot.send(sip_body(battery_dv=121))
    drv.poll(0.1)
    assert drv.sensors.voltage == pytest.approx(12.1) and drv.sensors.mode == "enabled" and drv.sensors.faults == ()
    tail = dict(grip_anport=0, analog=0, digin=0, digout=0, battery_x10=128, charge_state=0, rot_vel_x10=0,
                fault_flags=0b10010, lat_vel=0, temperature=30, state_of_charge=76)
    robot.send(sip_body(battery_dv=121, flags=P.FLAG_ESTOP, **tail))
    drv.poll(0.2)
    s = drv.sensors
    assert s.voltage == pytest.approx(12.8) and (s.battery_charge, s.battery_capacity) == (76.0, 100.0)
    assert s.mode == "estop" and s.faults == ("estop", "high_temperature", "gyro_fault")


def test_disabled_motors_are_enabled_again_and_reported(rig):
    robot, drv = rig
    connect(robot, drv, 0.0)
    robot.send(sip_body(flags=0))
    drv.poll(0.5)
    assert robot.got() == [P.pulse()]                        # ENABLE went out at connect, 0.5 s ago
    robot.send(sip_body(flags=0))
    drv.poll(1.0)
    assert P.enable(True) in robot.got() and drv.stats.extra["enable_requests"] == 1
    robot.send(sip_body(flags=0))
    drv.poll(2.1)
    assert "motors_disabled" in drv.sensors.faults and drv.sensors.mode == "disabled"


def test_no_sips_for_three_seconds_handshakes_again(rig):
    robot, drv = rig
    connect(robot, drv, 0.0)
    robot.send(sip_body())
    drv.poll(0.1)
    robot.got()
    drv.poll(3.2)
    assert drv.state == "sync" and robot.got() == [P.sync(0)] and drv.stats.extra["reconnects"] == 1


def test_garbage_and_bad_sips_are_counted_not_raised(rig):
    robot, drv = rig
    connect(robot, drv)
    bad = bytearray(P.frame(sip_body(x=5)))
    bad[6] ^= 0xFF
    robot.link.write(os.urandom(64) + bytes(bad))
    robot.send(b"\x32\x01\x02", b"\x99\x01", sip_body(x=7))         # a short SIP, a foreign packet, a good one
    drv.poll(0.1)
    x = drv.stats.extra
    assert x["bad_sip"] == 1 and x["other_packets"] >= 1 and drv.last_sip.x == 7
    assert drv.stats.bad_checksum >= 1 and drv.stats.dropped_bytes >= 64


def test_a_vanished_pty_is_reported_lost():
    robot = Robot()
    drv = ArcosBase(robot.link.path)
    connect(robot, drv)
    robot.close()
    with pytest.raises(DeviceLost, match="ARCOS port"):
        for k in range(100):
            drv.poll(0.01 * k)
    drv.close()


# ----------------------------------------------------------------------------- any input
def _noise():
    good = st.sampled_from([P.frame(sip_body(x=3, sonars=((1, 800),))), P.frame(b"\x20abc\x00"), P.frame(b"\x00"),
                            P.frame(P.sync2_reply("a", "b", "c"))])
    return st.lists(st.one_of(st.binary(max_size=40), good), max_size=8)


@settings(max_examples=60, deadline=None)
@given(_noise(), st.booleans())
def test_any_bytes_in_sync_or_connected_never_raise_and_are_counted(chunks, connected):
    robot = Robot()
    drv = ArcosBase(robot.link.path)
    try:
        if connected:
            connect(robot, drv)
        else:
            drv.open(0.0)
        t = 0.0
        for c in chunks:
            robot.link.write(c)
            t += 0.03
            drv.poll(t)
        p = drv.parser
        assert p.packet_bytes + p.dropped_bytes + p.pending == p.fed == drv.stats.extra["bytes_in"]
        assert drv.state in ("sync", "connected")
    finally:
        drv.close()
        robot.close()
