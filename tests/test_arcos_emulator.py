"""The ARCOS emulator on a pty (and TCP), driven by raw packets in the forms ARIA, p2os and Soar send: handshake,
SIPs every 100 ms with the whole tail, motion with accelerations, VEL2, SONAR and its FLAGS bits, POLLING, SETO,
STOP, E_STOP, CONFIG, the 2 s watchdog, stalls and bumpers, bad input."""
from __future__ import annotations

import socket
import time

import pytest
from hypothesis import given, settings, strategies as st

from runtime.drivers import arcos_protocol as P
from sitl.devices.arcos import ArcosDevice
from sitl.devices.tcp_link import open_tcp
from tests.arcos_util import FakePioneer, RawClient, run, sips, wheel_speed


@pytest.fixture
def rig():
    body = FakePioneer()
    dev = ArcosDevice(body)
    client = RawClient(dev.path)
    yield dev, body, client
    client.close()
    dev.close()


def handshake(dev, client, t=0.0):
    for n in range(3):
        client.send(P.sync(n))
        dev.service(t)
    return client.got()


def session(dev, client, open_arg: bool = True, t: float = 0.0):
    handshake(dev, client, t)
    client.send(P.open_() if open_arg else P.frame(b"\x01"), P.enable(True))
    dev.service(t)
    client.got()


# ----------------------------------------------------------------------------- handshake
def test_handshake_echoes_syncs_and_names_the_robot(rig):
    dev, _, client = rig
    got = handshake(dev, client)
    assert got[:2] == [b"\x00", b"\x01"]
    assert P.parse_sync2(got[2]) == ("mrta-sitl", "Pioneer", "p3dx-sh")
    assert dev.sync_seq == 3 and not dev.open and dev.stats.handshakes == 1


def test_only_sync0_starts_a_handshake(rig):
    """Soar sends CLOSE before it syncs: ignored while idle, as a stray SYNC1 is."""
    dev, _, client = rig
    client.send(P.frame(b"\x02"), P.sync(1))
    dev.service(0.0)
    assert client.got() == [] and dev.stats.ignored == 2 and dev.sync_seq == 0


def test_an_out_of_order_sync_is_answered_as_received(rig):
    dev, _, client = rig
    client.send(P.sync(0), P.sync(2))
    dev.service(0.0)
    got = client.got()
    assert got[0] == b"\x00" and got[1][0] == 2 and dev.sync_seq == 3


@pytest.mark.parametrize("open_arg", [True, False])
def test_open_with_or_without_an_argument_starts_sips_every_100_ms(rig, open_arg):
    dev, body, client = rig
    session(dev, client, open_arg)
    run(dev, body, 0.0, 1.0)
    got = sips(client.got())
    assert len(got) in (10, 11) and dev.stats.sessions == 1
    last = got[-1]
    assert last.flags3 is not None and last.state_of_charge is not None    # every tail field
    assert last.flags & P.FLAG_MOTORS and last.flags & P.FLAG_SONAR_ARRAYS[0] and last.flags & P.FLAG_SONAR_ARRAYS[1]
    assert len(P.frame(P.encode_sip(dev.sip()))) < 200


def test_close_ends_the_session_and_a_new_handshake_works(rig):
    dev, body, client = rig
    session(dev, client)
    client.send(P.vel(300))
    run(dev, body, 0.0, 0.5)
    client.send(P.frame(b"\x02"))                            # p2os: CLOSE bare
    run(dev, body, 0.5, 1.5)
    client.got()
    assert not dev.open and not dev.motors and body.cmd == (0.0, 0.0)
    run(dev, body, 1.5, 2.0)
    assert client.got() == []
    assert P.parse_sync2(handshake(dev, client, 2.0)[2])[1] == "Pioneer"


# ----------------------------------------------------------------------------- motion
def test_no_motion_before_enable(rig):
    dev, body, client = rig
    handshake(dev, client)
    client.send(P.open_(), P.vel(300))
    run(dev, body, 0.0, 1.0)
    assert body.cmd == (0.0, 0.0)
    client.send(P.enable(True))
    run(dev, body, 1.0, 2.5)
    assert wheel_speed(body.cmd)[0] == pytest.approx(0.3)


def test_vel_ramps_at_300_mm_s2_and_rvel_turns(rig):
    dev, body, client = rig
    session(dev, client)
    client.send(P.vel(300))
    run(dev, body, 0.0, 0.5)
    assert wheel_speed(body.cmd)[0] == pytest.approx(0.15, abs=0.002)
    run(dev, body, 0.5, 1.2)
    assert body.cmd == pytest.approx((0.3, 0.3))
    client.send(P.rvel(-30))
    run(dev, body, 1.2, 2.0)
    v, w = wheel_speed(body.cmd)
    assert v == pytest.approx(0.3) and w == pytest.approx(-0.5236, abs=1e-3)


def test_vel2_high_byte_left_low_byte_right(rig):
    dev, body, client = rig
    session(dev, client)
    client.send(P.vel2(-5, 10))                              # -100 mm/s left, 200 mm/s right
    run(dev, body, 0.0, 1.5)
    assert body.cmd == pytest.approx((-0.1, 0.2), abs=1e-6)


def test_stop_decelerates_and_e_stop_is_at_once(rig):
    dev, body, client = rig
    session(dev, client)
    client.send(P.vel(300))
    run(dev, body, 0.0, 1.5)
    client.send(P.stop())
    run(dev, body, 1.5, 1.6)
    assert wheel_speed(body.cmd)[0] == pytest.approx(0.27, abs=0.002)
    client.send(P.vel(300))
    run(dev, body, 1.6, 3.0)
    client.send(P.e_stop())
    run(dev, body, 3.0, 3.01)
    assert body.cmd == (0.0, 0.0)


def test_seto_zeroes_the_odometry(rig):
    dev, body, client = rig
    session(dev, client)
    client.send(P.vel(400))
    run(dev, body, 0.0, 2.0)
    assert sips(client.got())[-1].x > 300
    client.send(P.vel(0))
    run(dev, body, 2.0, 3.5)                                  # 1.33 s to stop at 300 mm/s^2
    client.send(P.seto())
    run(dev, body, 3.5, 3.8)
    last = sips(client.got())[-1]
    assert (last.x, last.y, last.th) == (0, 0, 0)


def test_config_packet(rig):
    dev, _, client = rig
    session(dev, client)
    client.send(P.config())
    dev.service(0.0)
    cfg = P.decode_config(next(b for b in client.got() if b[0] == P.CONFIG_PAC))
    assert (cfg["subclass"], cfg["watchdog_ms"], cfg["sip_cycle_ms"], cfg["trans_accel"]) == ("p3dx-sh", 2000, 100, 300)


# ----------------------------------------------------------------------------- watchdog
def test_watchdog_stops_the_robot_two_seconds_after_the_last_packet(rig):
    dev, body, client = rig
    session(dev, client)
    client.send(P.vel(300))
    run(dev, body, 0.0, 1.9)                                  # the VEL arrived at t = 0.005
    assert body.cmd != (0.0, 0.0) and dev.stats.watchdog_stops == 0
    run(dev, body, 1.9, 2.01)
    assert body.cmd == (0.0, 0.0) and dev.stats.watchdog_stops == 1 and dev.open
    client.send(P.pulse())
    run(dev, body, 2.01, 3.0)
    assert body.cmd == (0.0, 0.0)                             # a PULSE alone does not resume motion
    client.send(P.vel(200))
    run(dev, body, 3.0, 4.0)
    assert wheel_speed(body.cmd)[0] == pytest.approx(0.2)


def test_pulses_keep_the_watchdog_quiet(rig):
    dev, body, client = rig
    session(dev, client)
    client.send(P.vel(300))
    t = 0.0
    for _ in range(8):
        t = run(dev, body, t, t + 0.5)
        client.send(P.pulse())
    assert dev.stats.watchdog_stops == 0 and wheel_speed(body.cmd)[0] == pytest.approx(0.3)


# ----------------------------------------------------------------------------- sonar
def test_each_sip_carries_the_sonars_fired_since_the_last(rig):
    dev, body, client = rig
    body.ranges = {3: 1.234, 11: 0.5}
    session(dev, client)
    run(dev, body, 0.0, 1.0)
    got = sips(client.got())
    counts = [len(s.sonars) for s in got[1:]]
    assert all(4 <= c <= 6 for c in counts), counts          # 2 arrays x one per 40 ms x 100 ms
    seen = {n: r for s in got for n, r in s.sonars}
    assert set(seen) == set(range(16)) and seen[3] == 1234 and seen[11] == 500 and seen[0] == 5000


def test_sonar_off_and_on_with_the_flags_bits(rig):
    dev, body, client = rig
    session(dev, client)
    client.send(P.sonar(False))
    run(dev, body, 0.0, 0.5)
    client.got()
    run(dev, body, 0.5, 1.0)
    got = sips(client.got())
    assert all(not s.sonars and not s.flags & 0b110 for s in got)
    client.send(P.command(P.SONAR, (2 << 1) | 1))            # rear array (2) on only
    run(dev, body, 1.0, 1.2)
    client.got()
    run(dev, body, 1.2, 1.7)
    got = sips(client.got())
    assert all(s.flags & 0b110 == 0b100 for s in got)
    assert {n for s in got for n, _ in s.sonars} <= set(P.REAR_SONARS)
    client.send(P.sonar(True))
    run(dev, body, 1.7, 1.8)
    assert sips(client.got())[-1].flags & 0b110 == 0b110


@pytest.mark.parametrize("length_byte", [True, False])
def test_polling_sequence_in_aria_or_soar_string_form(rig, length_byte):
    dev, body, client = rig
    session(dev, client)
    client.body(P.POLLING, P.str_arg(bytes([4, 5]), length_byte=length_byte))     # sonars 3 and 4 (1-based)
    run(dev, body, 0.0, 0.05)
    body.fired.clear()
    run(dev, body, 0.05, 1.0)
    assert set(body.fired) == {3, 4}
    client.body(P.SAY, P.str_arg(b"\x01\x05\x3c", length_byte=length_byte))
    run(dev, body, 1.0, 1.01)
    assert dev.said == [b"\x01\x05\x3c"]


# ----------------------------------------------------------------------------- stall, bumpers, bad input
def test_stall_bits_after_a_quarter_second_and_bumper_bits(rig):
    dev, body, client = rig
    session(dev, client)
    client.send(P.vel(300))
    run(dev, body, 0.0, 1.0)
    body.stalled = [True, False]
    body.bumpers = (0b00100, 0b00001)
    run(dev, body, 1.0, 1.2)
    assert not sips(client.got())[-1].stall_bumpers & P.LEFT_STALL
    run(dev, body, 1.2, 1.5)
    bits = sips(client.got())[-1].stall_bumpers
    assert bits & P.LEFT_STALL and not bits & P.RIGHT_STALL
    assert (bits >> 9) & 0x7F == 0b00100 and (bits >> 1) & 0x7F == 0b00001


def test_bad_packets_and_arguments_are_counted(rig):
    dev, body, client = rig
    session(dev, client)
    bad = bytearray(P.vel(300))
    bad[-1] ^= 1
    client.send(bytes(bad), b"\x00\xfa\x13", P.frame(b"\x0b"), P.frame(b"\x63\x3b\x01\x00"), P.vel(100))
    run(dev, body, 0.0, 1.0)
    s = dev.stats
    assert s.bad_packets == 1 and s.bad_arguments == 1 and s.unsupported == 1 and dev.target == (100.0, 0.0)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.binary(max_size=40), max_size=6))
def test_random_bytes_never_crash_the_emulator(chunks):
    body = FakePioneer()
    dev = ArcosDevice(body)
    client = RawClient(dev.path)
    try:
        t, sent = 0.0, 0
        for c in chunks:
            client.send(P.sync(0) + c)
            sent += len(P.sync(0) + c)
            t = run(dev, body, t, t + 0.02)
        p = dev.parser
        assert dev.stats.bytes_in == p.fed == sent
        assert p.packet_bytes + p.dropped_bytes + p.pending == sent
    finally:
        client.close()
        dev.close()


# ----------------------------------------------------------------------------- TCP
def test_tcp_ports_from_8101_up_and_a_session_per_client():
    a, b = open_tcp(8101), open_tcp(8101)
    body = FakePioneer()
    dev = ArcosDevice(body, link=a)
    try:
        assert b.port > a.port >= 8101 and dev.endpoint() == {"port": f"socket://127.0.0.1:{a.port}", "baudrate": 9600}
        sock = socket.create_connection(("127.0.0.1", a.port))
        sock.sendall(P.sync(0) + P.sync(1) + P.sync(2) + P.open_() + P.enable(True) + P.vel(200))
        deadline = time.monotonic() + 2
        while dev.stats.sessions == 0 and time.monotonic() < deadline:
            dev.service(0.0)
        run(dev, body, 0.0, 1.0)
        assert dev.open and wheel_speed(body.cmd)[0] == pytest.approx(0.2)
        sock.close()
        deadline = time.monotonic() + 2
        while dev.open and time.monotonic() < deadline:
            dev.service(1.0)
        assert not dev.open and body.cmd == (0.0, 0.0) and a.disconnects == 1
    finally:
        dev.close()
        b.close()


def test_setv_and_setrv_limit_motion(rig):
    dev, body, client = rig
    session(dev, client)
    client.send(P.command(P.SETV, 150), P.command(P.SETRV, 20), P.vel(400), P.rvel(-90))
    run(dev, body, 0.0, 1.5)
    v, w = wheel_speed(body.cmd)
    assert v == pytest.approx(0.15) and w == pytest.approx(-0.349, abs=1e-3)
