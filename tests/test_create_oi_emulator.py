"""The emulated Create: OI mode machine, drive commands, every sensor packet, the stream, the pty."""
from __future__ import annotations

import math
import time

import pytest
import serial

from runtime.drivers import create_oi_protocol as P
from sitl.devices.create_oi import CreateOIDevice
from tests.fakes import FakeBody

MM_PER_COUNT = P.GEOMETRY["create2"].mm_per_count


class MemLink:
    """In-memory stand-in for the pty: the test writes host bytes, reads robot bytes."""
    path = "mem://create"

    def __init__(self):
        self.inbox = bytearray()
        self.outbox = bytearray()

    def read(self):
        data = bytes(self.inbox)
        self.inbox.clear()
        return data

    def write(self, data):
        self.outbox += data
        return len(data)

    def close(self):
        pass

    def take(self):
        data = bytes(self.outbox)
        self.outbox.clear()
        return data


def make(model="create2", **kw):
    body = FakeBody(**kw)
    link = MemLink()
    return CreateOIDevice(body, model=model, link=link), body, link


def send(dev, link, data, t=0.0):
    link.inbox += data
    dev.service(t)
    return link.take()


def run(dev, body, t0, t1, dt=0.005):
    t = t0
    while t < t1 - 1e-12:
        t = round(t + dt, 9)
        body.step(dt)
        dev.service(t)
    return t


# ----------------------------------------------------------------------------- modes
def test_off_mode_only_listens_for_start():
    dev, body, link = make()
    assert dev.mode_name == "off"
    assert send(dev, link, P.safe() + P.drive_direct(100, 100) + P.sensors(7)) == b""
    assert dev.stats.ignored == 3 and body.cmd == (0.0, 0.0)
    send(dev, link, P.start())
    assert dev.mode_name == "passive"


def test_drive_only_in_safe_or_full_and_stop_returns_to_off():
    dev, body, link = make()
    send(dev, link, P.start() + P.drive_direct(100, 100))
    assert body.cmd == (0.0, 0.0) and dev.stats.ignored == 1          # Passive: actuators ignored
    send(dev, link, P.safe() + P.drive_direct(100, -50))
    assert dev.mode_name == "safe" and body.cmd == (-0.05, 0.1)          # right first on the wire
    send(dev, link, P.full() + P.drive_direct(200, 200))
    assert dev.mode_name == "full" and body.cmd == (0.2, 0.2)
    send(dev, link, P.stream([7]) + P.stop())
    assert dev.mode_name == "off" and body.cmd == (0.0, 0.0) and not dev.streaming and dev.stream_ids == []
    assert send(dev, link, P.sensors(7)) == b""


def test_start_from_safe_goes_passive_and_stops_the_wheels():
    dev, body, link = make()
    send(dev, link, P.start() + P.safe() + P.drive_direct(100, 100))
    assert body.cmd == (0.1, 0.1)
    send(dev, link, P.start())
    assert dev.mode_name == "passive" and body.cmd == (0.0, 0.0)


def test_a_drive_command_persists_until_the_next():
    dev, body, link = make()
    send(dev, link, P.start() + P.safe() + P.drive_direct(150, 150))
    run(dev, body, 0.0, 2.0)
    assert body.cmd == (0.15, 0.15) and body.travel[0] == pytest.approx(0.3)


def test_wheel_drop_in_safe_mode_drops_to_passive_and_stops():
    dev, body, link = make()
    send(dev, link, P.start() + P.safe() + P.drive_direct(200, 200))
    body.drop = (True, False)
    dev.service(0.01)
    assert dev.mode_name == "passive" and body.cmd == (0.0, 0.0) and dev.stats.safety_stops == 1
    assert P.decode_packet(35, send(dev, link, P.sensors(35), 0.02))["oi_mode"] == P.MODE_PASSIVE


def test_wheel_drop_in_full_mode_keeps_driving():
    dev, body, link = make()
    send(dev, link, P.start() + P.full() + P.drive_direct(200, 200))
    body.drop = (True, True)
    dev.service(0.01)
    assert dev.mode_name == "full" and body.cmd == (0.2, 0.2) and dev.stats.safety_stops == 0


def test_cliff_in_safe_mode_when_the_body_reports_cliffs():
    dev, body, link = make()
    body.cliffs = lambda: (False, True, False, False)
    send(dev, link, P.start() + P.safe() + P.drive_direct(200, 200))
    assert dev.mode_name == "passive" and body.cmd == (0.0, 0.0)
    values = P.decode_packet(4, send(dev, link, P.sensors(4)))
    assert values["cliff_front_left_signal"] == 0 and values["cliff_left_signal"] > 0
    assert P.decode_packet(10, send(dev, link, P.sensors(10)))["cliff_front_left"] == 1


def test_reset_zeroes_the_encoders_and_stops_everything():
    dev, body, link = make(travel=(1.0, 1.0))
    send(dev, link, P.start() + P.stream([7]))
    assert P.decode_packet(43, send(dev, link, P.sensors(43)))["left_encoder_counts"] == round(1000 / MM_PER_COUNT)
    send(dev, link, P.reset())
    assert dev.mode_name == "off" and not dev.streaming
    send(dev, link, P.start())
    assert P.decode_packet(101, send(dev, link, P.sensors(101)))["right_encoder_counts"] == 0


def test_unknown_opcodes_are_counted():
    dev, body, link = make()
    send(dev, link, bytes([0, 1, 2, 200]) + P.start() + bytes([255]))
    assert dev.stats.unknown_opcodes == 5 and dev.mode_name == "passive"


# ----------------------------------------------------------------------------- drive commands
@pytest.mark.parametrize("velocity, radius, expected", [
    (-200, 500, (-200 * (500 - 117.5) / 500, -200 * (500 + 117.5) / 500)),    # the spec's Drive example
    (300, 0x8000, (300, 300)), (300, 0x7FFF, (300, 300)),
    (100, -1, (100, -100)),                     # clockwise in place
    (100, 1, (-100, 100)),                      # counter-clockwise in place
    (200, -1000, (200 * (-1000 - 117.5) / -1000, 200 * (-1000 + 117.5) / -1000)),   # right turn
])
def test_drive_radius_to_wheel_speeds(velocity, radius, expected):
    dev, body, link = make()
    send(dev, link, P.start() + P.safe() + P.drive(velocity, radius))
    assert body.cmd[0] * 1000 == pytest.approx(expected[0])
    assert body.cmd[1] * 1000 == pytest.approx(expected[1])
    values = P.decode_packet(5, send(dev, link, P.sensors(5)))
    assert values["requested_velocity"] == velocity
    assert values["requested_radius"] == (radius - 0x10000 if radius >= 0x8000 else radius)


def test_drive_direct_is_right_then_left_and_drive_pwm_is_approximated():
    dev, body, link = make()
    send(dev, link, P.start() + P.full() + bytes([145, 0, 100, 255, 156]))
    assert body.cmd == (-0.1, 0.1)
    values = P.decode_packet(5, send(dev, link, P.sensors(5)))
    assert (values["requested_right_velocity"], values["requested_left_velocity"]) == (100, -100)
    send(dev, link, P.drive_pwm(255, -128))
    assert body.cmd[1] == pytest.approx(0.5) and body.cmd[0] == pytest.approx(-0.5 * 128 / 255)
    send(dev, link, bytes([145, 0x7F, 0xFF, 0x80, 0x00]))          # out of range: clamped to +-500
    assert body.cmd == (-0.5, 0.5)


# ----------------------------------------------------------------------------- sensors
@pytest.mark.parametrize("model", P.MODELS)
def test_sensors_answers_every_packet_id_within_spec_ranges(model):
    dev, body, link = make(model, travel=(0.3, 0.2))
    body.bump = (True, False)
    send(dev, link, P.start() + P.safe() + P.drive_direct(100, 50))
    run(dev, body, 0.0, 0.5)
    specs = P.packet_specs(model)
    for pid in P.packet_ids(model):
        reply = send(dev, link, bytes([P.SENSORS, pid]), 0.5)
        assert len(reply) == P.packet_size(pid, model), pid
        values = P.decode_packet(pid, reply, model)
        for member in P.packet_members(pid, model):
            spec = specs[member]
            assert spec.lo <= values[spec.name] <= spec.hi, (pid, spec.name, values[spec.name])
        if 7 in P.packet_members(pid, model):
            assert values["bump_left"] and not values["bump_right"]
        if 35 in P.packet_members(pid, model):
            assert values["oi_mode"] == P.MODE_SAFE
    everything = send(dev, link, bytes([P.QUERY_LIST, len(P.packet_ids(model))]) + bytes(P.packet_ids(model)), 0.5)
    assert len(everything) == sum(P.packet_size(pid, model) for pid in P.packet_ids(model))
    assert dev.stats.bad_packet_ids == 0


def test_unknown_packet_ids_are_skipped_and_counted():
    dev, body, link = make("create1")
    send(dev, link, P.start())
    assert send(dev, link, bytes([142, 43])) == b""                    # no encoders on a Create 1
    reply = send(dev, link, bytes([149, 3, 7, 100, 35]))
    assert len(reply) == 2 and dev.stats.bad_packet_ids == 2
    assert P.decode_packet(6, send(dev, link, P.sensors(6, "create1")), "create1")["infrared_byte"] == 255


def test_encoder_counts_follow_wheel_travel_and_wrap_at_16_bits():
    dev, body, link = make(travel=(1.0, -0.5))
    send(dev, link, P.start())
    values = P.decode_packet(101, send(dev, link, P.sensors(101)))
    assert values["left_encoder_counts"] == round(1000.0 / MM_PER_COUNT) == 2249
    assert values["right_encoder_counts"] == round(-500.0 / MM_PER_COUNT)
    body.travel = [15.0, -15.0]                                       # 33741 counts: past 32767
    values = P.decode_packet(101, send(dev, link, P.sensors(101)))
    assert values["left_encoder_counts"] == round(15000.0 / MM_PER_COUNT) - 65536
    assert values["right_encoder_counts"] == 65536 - round(15000.0 / MM_PER_COUNT)


@pytest.mark.parametrize("model", P.MODELS)
def test_distance_and_angle_are_since_last_read(model):
    dev, body, link = make(model, track=P.GEOMETRY[model].track_mm / 1000)
    send(dev, link, P.start() + P.safe() + P.drive_direct(100, 100))
    t = run(dev, body, 0.0, 1.0)
    assert P.decode_packet(2, send(dev, link, P.sensors(2, model), t), model)["distance"] in (99, 100)
    assert P.decode_packet(19, send(dev, link, P.sensors(19, model), t), model)["distance"] == 0
    w = 100.0 / (body.track * 1000 / 2)                               # rad/s turning in place at 100 mm/s
    send(dev, link, P.drive(100, P.RADIUS_CCW), t)
    t2 = run(dev, body, t, t + math.pi / 2 / w)
    values = P.decode_packet(2, send(dev, link, P.sensors(2, model), t2), model)
    assert 89 <= values["angle"] <= 91 and abs(values["distance"]) <= 1


def test_battery_is_plausible_and_drains_faster_when_driving():
    drains = []
    for speed in (0, 400):
        dev, body, link = make()
        send(dev, link, P.start() + P.full() + P.drive_direct(speed, speed))
        before = P.decode_packet(3, send(dev, link, P.sensors(3)))
        t = run(dev, body, 0.0, 60.0, dt=0.05)
        after = P.decode_packet(3, send(dev, link, P.sensors(3), t))
        for v in (before, after):
            assert 13000 <= v["voltage"] <= 17000 and v["current"] < 0 and 15 <= v["temperature"] <= 40
            assert 0 < v["battery_charge"] <= v["battery_capacity"] == 2696
        assert (after["current"] < -300) == (speed > 0)             # motors draw on top of ~180 mA idle
        drains.append(before["battery_charge"] - after["battery_charge"])
    assert drains[1] > drains[0] > 0


def test_a_body_with_its_own_battery_is_reported_as_is():
    body, link = FakeBody(), MemLink()
    body.battery = lambda: {"charge_mah": 1234.4, "capacity_mah": 2696.0, "voltage_mv": 15012.6,
                            "current_ma": -512.2, "temperature_c": 31.2}
    body.motor_currents_ma = lambda: (210, 190)
    dev = CreateOIDevice(body, link=link)
    send(dev, link, P.start())
    v = P.decode_packet(100, send(dev, link, P.sensors(100)))
    assert (v["battery_charge"], v["voltage"], v["current"], v["temperature"]) == (1234, 15013, -512, 31)
    assert (v["left_motor_current"], v["right_motor_current"]) == (210, 190)


def test_song_and_play():
    dev, body, link = make()
    send(dev, link, P.start() + P.safe() + P.song(2, [(60, 32), (62, 32)]) + P.play(2))
    v = P.decode_packet(5, send(dev, link, P.sensors(5), 0.5))
    assert (v["song_number"], v["song_playing"]) == (2, 1)
    assert P.decode_packet(37, send(dev, link, P.sensors(37), 1.01))["song_playing"] == 0


def test_create1_scripts_are_stored_and_shown_but_not_played():
    dev, body, link = make("create1")
    script = bytes([137, 1, 44, 128, 0, 156, 1, 144, 137, 0, 0, 0, 0])
    send(dev, link, P.start() + bytes([152, len(script)]) + script)
    assert send(dev, link, bytes([154])) == bytes([len(script)]) + script
    send(dev, link, bytes([153]))
    assert dev.stats.not_emulated == 1 and body.cmd == (0.0, 0.0)


# ----------------------------------------------------------------------------- stream
def test_stream_sends_a_frame_every_15_ms_of_sim_time():
    dev, body, link = make()
    first = send(dev, link, P.start() + P.safe() + P.stream([7, 100, 44]) + P.drive_direct(100, 100))
    run(dev, body, 0.0, 0.15)
    parser = P.StreamParser()
    frames = parser.feed(first + link.take())
    assert len(frames) == 11 == dev.stats.frames                   # t = 0, 0.015, ..., 0.150
    assert parser.bad_checksum == parser.dropped_bytes == 0
    counts = [f["right_encoder_counts"] for f in frames]
    assert counts == sorted(counts) and counts[-1] == round(0.1 * 0.15 * 1000 / MM_PER_COUNT)
    assert frames[-1]["stream_packets"] == 3 and frames[-1]["oi_mode"] == P.MODE_SAFE


def test_stream_catches_up_at_most_one_frame_per_call():
    dev, body, link = make()
    send(dev, link, P.start() + P.stream([35]), 0.0)
    assert dev.stats.frames == 1
    dev.service(0.1)                                                 # six frames late: one frame
    dev.service(0.1001)                                              # one catch-up frame
    dev.service(0.1002)                                              # back on the grid: nothing due
    assert dev.stats.frames == 3
    dev.service(0.1151)
    assert dev.stats.frames == 4


def test_pause_resume_and_empty_stream():
    dev, body, link = make()
    send(dev, link, P.start() + P.stream([7]), 0.0)
    send(dev, link, P.pause_resume_stream(False), 0.01)
    dev.service(0.1)
    assert dev.stats.frames == 1
    send(dev, link, P.pause_resume_stream(True), 0.2)
    assert dev.stats.frames == 2
    send(dev, link, bytes([148, 0]), 0.3)                            # an empty list stops the stream
    dev.service(0.5)
    assert dev.stats.frames == 2 and not dev.streaming
    send(dev, link, bytes([150, 7]), 0.6)
    assert dev.stats.bad_arguments == 1


def test_stream_frames_stay_within_255_bytes():
    dev, body, link = make()
    out = send(dev, link, P.start() + P.stream([100, 100, 100, 100]))   # 4 x 81 bytes would not fit
    parser = P.StreamParser()
    assert len(parser.feed(out)) == 1 and parser.frame_bytes == len(out) == 3 + 3 * 81
    assert dev.stats.stream_overflow == 1


# ----------------------------------------------------------------------------- the pty
def _wait_read(port, n, dev, t, timeout=2.0):
    got = b""
    deadline = time.monotonic() + timeout
    while len(got) < n and time.monotonic() < deadline:
        dev.service(t)
        got += port.read(n - len(got))
    return got


def _pump(dev, t, rounds=20):
    for _ in range(rounds):
        dev.service(t)
        time.sleep(0.001)


def test_on_a_pty_a_client_can_close_and_reopen():
    body = FakeBody(travel=(0.5, 0.5))
    dev = CreateOIDevice(body)
    try:
        assert dev.path.startswith("/dev/")
        for attempt in range(2):
            t = 0.1 * attempt
            port = serial.serial_for_url(dev.path, 115200, timeout=0.01)
            port.write(P.start() + P.safe() + P.sensors(7) + P.query_list([43, 19]))
            reply = _wait_read(port, 1 + 4, dev, t)
            assert len(reply) == 5
            assert P.decode_packet(43, reply[1:3])["left_encoder_counts"] == round(500 / MM_PER_COUNT)
            port.write(bytes([P.STREAM, 1, 19]))                      # 19 is XOFF: raw mode must pass it
            frames = P.StreamParser().feed(_wait_read(port, 6, dev, t + 0.05))
            assert frames and "distance" in frames[0]
            port.write(P.pause_resume_stream(False))
            _pump(dev, t + 0.06)
            assert not dev.streaming
            port.close()
            _pump(dev, t + 0.07)                                      # no EIO on the master after close
        assert dev.mode_name == "safe" and dev.stats.unknown_opcodes == 0
    finally:
        dev.close()
