"""Ground-station telemetry: what a stock pymavlink client sees, rates, frames and units."""
from __future__ import annotations

import math
import socket

import pymap3d
import pytest

from runtime.comms import codec, dialect
from runtime.comms.link import MavlinkLink
from runtime.comms.telemetry import (CUSTOM_MODE_AUTO, CUSTOM_MODE_HOLD, CUSTOM_MODE_INITIALISING,
                                     GcsTelemetry)
from runtime.config import Datum
from runtime.drivers.base import BaseSensors

DATUM = Datum(lat=33.7756, lon=-84.3963, alt=300.0)
BATTERY = BaseSensors(voltage=14.2, current=-0.8, battery_charge=2.0, battery_capacity=2.7)


class Gcs:
    """A UDP socket that decodes everything sent to it with the dialect's own parser."""

    def __init__(self):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.2)
        mod = dialect.load()
        self.mav = mod.MAVLink(None, srcSystem=255, srcComponent=190)

    @property
    def address(self) -> str:
        return "127.0.0.1:%d" % self.sock.getsockname()[1]

    def receive(self, count: int) -> list:
        out = []
        while len(out) < count:
            try:
                data, _ = self.sock.recvfrom(65535)
            except socket.timeout:
                break
            out += self.mav.parse_buffer(data) or []
        return out


@pytest.fixture
def gcs():
    g = Gcs()
    yield g
    g.sock.close()


@pytest.fixture
def make(gcs):
    made = []

    def _make(robot_id=3, key=None):
        link = MavlinkLink(robot_id, "127.0.0.1:0", [], gcs.address, signing_key=key)
        made.append(link)
        return link, GcsTelemetry(link, robot_id, DATUM)

    yield _make
    for link in made:
        link.close()


def _free_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


@pytest.mark.parametrize("key", [None, bytes(range(32))], ids=["unsigned", "signed"])
def test_stock_pymavlink_client_sees_a_ground_rover_that_moves(key):
    from pymavlink import mavutil

    port = _free_udp_port()
    conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}")
    link = MavlinkLink(7, "127.0.0.1:0", [], f"127.0.0.1:{port}", signing_key=key)
    try:
        tel = GcsTelemetry(link, 7, DATUM)
        tel.tick(0.0, (0.0, 0.0, 0.0), (0.0, 0.0), BATTERY, None)
        hb = conn.recv_match(type="HEARTBEAT", blocking=True, timeout=5)
        assert hb is not None
        assert hb.type == mavutil.mavlink.MAV_TYPE_GROUND_ROVER
        assert hb.autopilot == mavutil.mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
        assert hb.get_srcSystem() == 7 and hb.get_srcComponent() == 1
        p1 = conn.recv_match(type="GLOBAL_POSITION_INT", blocking=True, timeout=5)
        tel.tick(0.2, (25.0, -40.0, 0.0), (0.0, 0.0), BATTERY, None)
        p2 = conn.recv_match(type="GLOBAL_POSITION_INT", blocking=True, timeout=5)
        assert p1 is not None and p2 is not None and p2.get_srcSystem() == 7
        assert (p1.lat, p1.lon) == (round(DATUM.lat * 1e7), round(DATUM.lon * 1e7))
        assert p2.lat < p1.lat and p2.lon > p1.lon              # moved south-east
        assert p2.time_boot_ms == 200
    finally:
        link.close()
        conn.close()


def test_rates_over_ten_seconds_of_injected_time(make, gcs):
    link, tel = make()
    for i in range(200):                                          # 20 Hz for 10 s
        tel.tick(i * 0.05, (1.0, 2.0, 0.5), (0.1, 0.0), BATTERY, 4)
    got = gcs.receive(10 * 3 + 50 * 3)
    counts: dict[str, int] = {}
    for m in got:
        counts[m.get_type()] = counts.get(m.get_type(), 0) + 1
    assert counts == {"HEARTBEAT": 10, "SYS_STATUS": 10, "GPS_RAW_INT": 10, "GLOBAL_POSITION_INT": 50,
                      "LOCAL_POSITION_NED": 50, "ATTITUDE": 50}


def test_positions_are_geodetic_and_ned(make, gcs):
    link, tel = make()
    pose, vel = (12.5, -7.25, math.radians(30)), (0.3, -0.4)        # ENU
    tel.tick(12.345, pose, vel, BATTERY, None)
    msgs = {m.get_type(): m for m in gcs.receive(5)}
    g, n = msgs["GLOBAL_POSITION_INT"], msgs["LOCAL_POSITION_NED"]
    e, nn, u = pymap3d.geodetic2enu(g.lat / 1e7, g.lon / 1e7, g.alt / 1000, DATUM.lat, DATUM.lon, DATUM.alt)
    assert (e, nn) == (pytest.approx(12.5, abs=0.02), pytest.approx(-7.25, abs=0.02))
    assert abs(u) < 0.01 and abs(g.relative_alt) <= 10
    assert (g.vx, g.vy, g.vz) == (-40, 30, 0)                     # cm/s north, east, down
    assert g.hdg == 6000                                          # 30 deg CCW from east = 060 true
    assert (n.x, n.y, n.z) == (pytest.approx(-7.25), pytest.approx(12.5), 0.0)
    assert (n.vx, n.vy) == (pytest.approx(-0.4), pytest.approx(0.3))
    assert g.time_boot_ms == n.time_boot_ms == 12345


@pytest.mark.parametrize("theta, hdg", [(0.0, 9000), (math.pi / 2, 0), (math.pi, 27000),
                                        (-math.pi / 2, 18000), (math.radians(135), 31500),
                                        (float("nan"), 65535)])
def test_heading_from_enu_yaw(make, gcs, theta, hdg):
    link, tel = make()
    tel.tick(0.0, (0.0, 0.0, theta), (0.0, 0.0), BATTERY, None)
    g = next(m for m in gcs.receive(5) if m.get_type() == "GLOBAL_POSITION_INT")
    assert g.hdg == hdg


def test_mode_and_state_follow_the_robot(make, gcs):
    link, tel = make()
    mod = link.module
    tel.tick(0.0, None, (0.0, 0.0), BATTERY, None)        # no pose yet
    first = gcs.receive(2)
    assert {m.get_type() for m in first} == {"HEARTBEAT", "SYS_STATUS"}
    hb = next(m for m in first if m.get_type() == "HEARTBEAT")
    assert hb.system_status == mod.MAV_STATE_CALIBRATING and hb.custom_mode == CUSTOM_MODE_INITIALISING
    assert hb.base_mode & mod.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED

    tel.tick(1.0, (0.0, 0.0, 0.0), (0.0, 0.0), BATTERY, None)
    hb = next(m for m in gcs.receive(5) if m.get_type() == "HEARTBEAT")
    assert hb.system_status == mod.MAV_STATE_STANDBY and hb.custom_mode == CUSTOM_MODE_HOLD

    tel.tick(2.0, (0.0, 0.0, 0.0), (0.0, 0.0), BATTERY, 6)            # working on a task
    got = gcs.receive(5)
    hb = next(m for m in got if m.get_type() == "HEARTBEAT")
    assert hb.system_status == mod.MAV_STATE_ACTIVE and hb.custom_mode == CUSTOM_MODE_AUTO
    assert hb.base_mode & mod.MAV_MODE_FLAG_SAFETY_ARMED and hb.base_mode & mod.MAV_MODE_FLAG_AUTO_ENABLED
    # the peer HEARTBEAT the link sends carries the same mode
    assert (link.base_mode, link.custom_mode, link.system_status) == (hb.base_mode, hb.custom_mode,
                                                                      hb.system_status)

    low = BaseSensors(voltage=12.0, current=-0.5, battery_charge=0.2, battery_capacity=2.7)
    tel.tick(3.0, (0.0, 0.0, 0.0), (0.0, 0.0), low, 6)
    got = {m.get_type(): m for m in gcs.receive(5)}
    assert got["HEARTBEAT"].system_status == mod.MAV_STATE_CRITICAL
    assert not got["SYS_STATUS"].onboard_control_sensors_health & mod.MAV_SYS_STATUS_SENSOR_BATTERY
    tel.tick(4.0, None, (0.0, 0.0), low, None)              # critical outranks localizing
    got = {m.get_type(): m for m in gcs.receive(5)}
    assert got["HEARTBEAT"].system_status == mod.MAV_STATE_CRITICAL
    assert got["HEARTBEAT"].custom_mode == CUSTOM_MODE_INITIALISING


def test_the_link_heartbeat_is_right_before_the_first_tick(make):
    link, tel = make()
    mod = link.module
    assert link.custom_mode == CUSTOM_MODE_INITIALISING and link.system_status == mod.MAV_STATE_CALIBRATING
    assert link.base_mode & mod.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED


def _heartbeat(gcs, tel, now, pose, status, battery=BATTERY):
    tel.tick(now, pose, (0.0, 0.0), battery, status)
    got = {m.get_type(): m for m in gcs.receive(6 if pose is not None else 3)}     # + GPS_RAW_INT, ATTITUDE
    return got["HEARTBEAT"], got["SYS_STATUS"]


POSE = (1.0, 2.0, 0.0)


@pytest.mark.parametrize("armed, pose, task, mode, state", [
    (True, None, None, "INITIALISING", "CALIBRATING"),        # localizing
    (True, POSE, None, "HOLD", "STANDBY"),                    # idle: may drive, nothing to do
    (True, POSE, 4, "AUTO", "ACTIVE"),                        # executing (allocating or converged)
    (False, POSE, 4, "HOLD", "STANDBY"),                      # stopped by the operator, task kept
    (False, POSE, None, "HOLD", "STANDBY"),
    (False, None, None, "INITIALISING", "CALIBRATING"),
])
def test_what_mavproxy_prints_for_each_robot_state(make, gcs, armed, pose, task, mode, state):
    """pymavlink's mode_string_v10 and motors_armed logic are what MAVProxy prints and announces."""
    from pymavlink import mavutil

    link, tel = make()
    tel.armed = armed
    hb, sys_status = _heartbeat(gcs, tel, 0.0, pose, task)
    assert mavutil.mode_string_v10(hb) == mode
    assert bool(hb.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED) == armed
    assert hb.system_status == getattr(link.module, "MAV_STATE_" + state)
    motors = link.module.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    assert bool(sys_status.onboard_control_sensors_enabled & motors) == armed      # MAVProxy "safety off"
    assert sys_status.onboard_control_sensors_present & motors


def test_disarm_takes_effect_on_the_next_tick(make, gcs):
    from pymavlink import mavutil

    link, tel = make()
    hb, _ = _heartbeat(gcs, tel, 0.0, POSE, 4)
    assert mavutil.mode_string_v10(hb) == "AUTO" and hb.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    tel.armed = False
    hb, _ = _heartbeat(gcs, tel, 1.0, POSE, 4)
    assert mavutil.mode_string_v10(hb) == "HOLD" and not hb.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    assert (link.base_mode, link.custom_mode) == (hb.base_mode, hb.custom_mode)


def _mavproxy_fence_says(sys_statuses) -> list[str]:
    """MAVProxy's fence module (mavproxy_fence.handle_sys_status): what it announces for a sequence of
    SYS_STATUS messages, starting from its initial present=False, enabled=False, healthy=True."""
    from pymavlink import mavutil

    bits = mavutil.mavlink.MAV_SYS_STATUS_GEOFENCE
    present, enabled, healthy, said = False, False, True, []
    for m in sys_statuses:
        now = (m.onboard_control_sensors_present & bits) == bits
        said += ["fence present"] if now and not present else ["fence removed"] if present and not now else []
        present = now
        now = (m.onboard_control_sensors_enabled & bits) == bits
        said += ["fence enabled"] if now and not enabled else ["fence disabled"] if enabled and not now else []
        enabled = now
        now = (m.onboard_control_sensors_health & bits) == bits
        said += ["fence OK"] if now and not healthy else ["fence breach"] if healthy and not now else []
        healthy = now
    return said


def _mavproxy_warning_status(m) -> list[str]:
    """MAVProxy's warning module check_status: the SYS_STATUS health groups it flags."""
    from pymavlink import mavutil

    L = mavutil.mavlink
    groups = {"AS": L.MAV_SYS_STATUS_SENSOR_DIFFERENTIAL_PRESSURE, "MAG": L.MAV_SYS_STATUS_SENSOR_3D_MAG,
              "INS": L.MAV_SYS_STATUS_SENSOR_3D_ACCEL | L.MAV_SYS_STATUS_SENSOR_3D_GYRO,
              "AHRS": L.MAV_SYS_STATUS_AHRS, "TERR": L.MAV_SYS_STATUS_TERRAIN, "LOG": L.MAV_SYS_STATUS_LOGGING,
              "FEN": L.MAV_SYS_STATUS_GEOFENCE}
    return [name for name, bits in groups.items() if m.onboard_control_sensors_health & bits != bits]


def test_sys_status_raises_no_false_alarm_in_mavproxy(make, gcs):
    link, tel = make()
    low = BaseSensors(voltage=12.0, current=-0.5, battery_charge=0.2, battery_capacity=2.7)
    seen = []
    for i, (pose, task, battery, armed) in enumerate([(None, None, BATTERY, True), (POSE, None, BATTERY, True),
                                                      (POSE, 3, BATTERY, True), (POSE, 3, BATTERY, False),
                                                      (POSE, 3, low, True), (POSE, None, BaseSensors(), True)]):
        tel.armed = armed
        seen.append(_heartbeat(gcs, tel, float(i), pose, task, battery)[1])
    assert _mavproxy_fence_says(seen) == []                      # was: "fence breach" on the first one
    assert _mavproxy_warning_status(seen[0]) == ["AHRS"]         # true: no pose estimate yet
    assert [_mavproxy_warning_status(s) for s in seen[1:]] == [[]] * 5
    mod = link.module
    for s in seen:
        assert not s.onboard_control_sensors_present & mod.MAV_SYS_STATUS_GEOFENCE     # no fence claimed
        assert s.onboard_control_sensors_enabled & ~s.onboard_control_sensors_present == 0
        assert 0 <= s.onboard_control_sensors_health < 2 ** 32


def test_a_stock_console_sees_unhealthy_only_what_fails(make, gcs):
    """QGC and MAVProxy's console colour a sensor red when present, enabled and unhealthy."""
    link, tel = make()
    mod = link.module
    low = BaseSensors(voltage=12.0, current=-0.5, battery_charge=0.2, battery_capacity=2.7)

    def red(s):
        return s.onboard_control_sensors_present & s.onboard_control_sensors_enabled & ~s.onboard_control_sensors_health

    assert red(_heartbeat(gcs, tel, 0.0, None, None)[1]) == mod.MAV_SYS_STATUS_AHRS
    assert red(_heartbeat(gcs, tel, 1.0, POSE, 2)[1]) == 0
    assert red(_heartbeat(gcs, tel, 2.0, POSE, 2, low)[1]) == mod.MAV_SYS_STATUS_SENSOR_BATTERY


def test_sys_status_battery_units(make, gcs):
    link, tel = make()
    mod = link.module
    tel.tick(0.0, None, None, BATTERY, None)
    s = next(m for m in gcs.receive(3) if m.get_type() == "SYS_STATUS")
    assert (s.voltage_battery, s.current_battery, s.battery_remaining) == (14200, 80, 74)
    assert s.onboard_control_sensors_present & mod.MAV_SYS_STATUS_SENSOR_BATTERY
    tel.tick(1.0, None, None, BaseSensors(), None)         # a base that reports nothing
    s = next(m for m in gcs.receive(3) if m.get_type() == "SYS_STATUS")
    assert (s.voltage_battery, s.current_battery, s.battery_remaining) == (65535, -1, -1)


def test_sys_status_reports_comm_errors(make, gcs):
    link, tel = make()
    link.feed(b"\x01\x02garbage", 0.0)
    link.feed(b"\x03more", 0.0)
    tel.tick(0.0, None, None, BATTERY, None)
    s = next(m for m in gcs.receive(3) if m.get_type() == "SYS_STATUS")
    assert s.errors_comm == 2 and s.drop_rate_comm == 10000


def test_no_gcs_means_nothing_sent():
    link = MavlinkLink(2, "127.0.0.1:0", [], None)
    try:
        tel = GcsTelemetry(link, 2, (33.0, -84.0, 10.0))
        tel.tick(0.0, (0.0, 0.0, 0.0), (0.0, 0.0), BATTERY, None)
        assert tel.sent == {} and link.counters.sent == 0
    finally:
        link.close()


# ---------------------------------------------------------------------- what MAVSDK reads

def _mavsdk_health(s) -> dict:
    """MAVSDK telemetry_impl.cpp process_sys_status: a calibration is set only from a present bit (false until
    then); global position = GPS present and healthy; local position = that, optical flow or vision."""
    m = dialect.load()
    health = {"gyro": False, "accel": False, "mag": False}
    for key, bit in (("gyro", m.MAV_SYS_STATUS_SENSOR_3D_GYRO), ("accel", m.MAV_SYS_STATUS_SENSOR_3D_ACCEL),
                     ("mag", m.MAV_SYS_STATUS_SENSOR_3D_MAG)):
        if s.onboard_control_sensors_present & bit:
            health[key] = bool(s.onboard_control_sensors_health & bit)
    gps = m.MAV_SYS_STATUS_SENSOR_GPS
    health["global"] = bool(s.onboard_control_sensors_present & gps and s.onboard_control_sensors_health & gps)
    return health


class _Fix:
    def __init__(self, t, valid=True, quality=1, sats=9):
        self.t, self.valid, self.fix_quality, self.num_sats = t, valid, quality, sats
        self.lat, self.lon, self.alt = DATUM.lat + 1e-5, DATUM.lon, 301.5
        self.hdop, self.speed, self.course = 0.9, 0.25, math.radians(90)


def test_attitude_gps_and_health_as_mavsdk_reads_them(gcs):
    link = MavlinkLink(3, "127.0.0.1:0", [], gcs.address)
    try:
        mod = link.module
        tel = GcsTelemetry(link, 3, DATUM, gps=True)
        got = {m.get_type(): m for m in _tick(gcs, tel, 0.0, (1.0, 2.0, math.radians(30)), ())}
        a = got["ATTITUDE"]
        assert (a.roll, a.pitch) == (0.0, 0.0) and a.yaw == pytest.approx(math.radians(60))     # NED: 060
        g = got["GPS_RAW_INT"]
        assert (g.fix_type, g.satellites_visible) == (mod.GPS_FIX_TYPE_NO_FIX, 0)              # no fix yet
        assert _mavsdk_health(got["SYS_STATUS"]) == {"gyro": True, "accel": True, "mag": True, "global": False}
        got = {m.get_type(): m for m in _tick(gcs, tel, 1.0, (1.0, 2.0, math.radians(20)), [_Fix(0.9)])}
        g = got["GPS_RAW_INT"]
        assert (g.fix_type, g.satellites_visible, g.eph, g.vel, g.cog) == (mod.GPS_FIX_TYPE_3D_FIX, 9, 90, 25, 9000)
        assert (g.lat, g.alt) == (round((DATUM.lat + 1e-5) * 1e7), 301500)
        assert _mavsdk_health(got["SYS_STATUS"])["global"] is True
        assert got["ATTITUDE"].yawspeed == pytest.approx(math.radians(10), rel=1e-3)       # turning clockwise
        got = {m.get_type(): m for m in _tick(gcs, tel, 4.0, (1.0, 2.0, 0.0), ())}            # the fix is stale
        assert got["GPS_RAW_INT"].fix_type == mod.GPS_FIX_TYPE_NO_FIX
        assert _mavsdk_health(got["SYS_STATUS"])["global"] is False
    finally:
        link.close()


def _tick(gcs, tel, now, pose, fixes):
    tel._slow.next = None
    for every in tel.streams.values():
        every.next = None                        # every stream due: one of each
    tel.tick(now, pose, (0.0, 0.0), BATTERY, None, fixes)
    return gcs.receive(6)


def test_a_robot_without_gps_says_so(make, gcs):
    link, tel = make()
    tel.tick(0.0, (0.0, 0.0, 0.0), (0.0, 0.0), BATTERY, None)
    got = {m.get_type(): m for m in gcs.receive(6)}
    assert got["GPS_RAW_INT"].fix_type == link.module.GPS_FIX_TYPE_NO_GPS
    assert not got["SYS_STATUS"].onboard_control_sensors_present & link.module.MAV_SYS_STATUS_SENSOR_GPS


def test_set_message_interval_changes_a_stream_and_get_reads_it(make, gcs):
    link, tel = make()
    m = link.module
    assert tel.interval(m.MAVLINK_MSG_ID_ATTITUDE) == 200000
    assert tel.set_interval(m.MAVLINK_MSG_ID_ATTITUDE, 500000)                  # 2 Hz
    assert tel.set_interval(m.MAVLINK_MSG_ID_GPS_RAW_INT, -1)                   # off
    assert tel.set_interval(m.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 1000)          # 1 kHz asked: 50 Hz given
    assert tel.interval(m.MAVLINK_MSG_ID_LOCAL_POSITION_NED) == 20000
    assert not tel.set_interval(m.MAVLINK_MSG_ID_HEARTBEAT, 100000)             # not a stream here
    assert not tel.set_interval(m.MAVLINK_MSG_ID_ATTITUDE, -5)
    assert tel.interval(m.MAVLINK_MSG_ID_HEARTBEAT) is None and tel.interval(99999) is None
    for i in range(100):                                                        # 100 Hz for 1 s
        tel.tick(i * 0.01, (1.0, 2.0, 0.5), (0.1, 0.0), BATTERY, 4)
    counts: dict[str, int] = {}
    for msg in gcs.receive(1 + 1 + 2 + 5 + 50):
        counts[msg.get_type()] = counts.get(msg.get_type(), 0) + 1
    assert counts == {"HEARTBEAT": 1, "SYS_STATUS": 1, "ATTITUDE": 2, "GLOBAL_POSITION_INT": 5,
                      "LOCAL_POSITION_NED": 50}
    assert tel.set_interval(m.MAVLINK_MSG_ID_GPS_RAW_INT, 0)                    # 0: back to the default
    assert tel.interval(m.MAVLINK_MSG_ID_GPS_RAW_INT) == 1000000


@pytest.mark.parametrize("mode, armed, task, busy, want, mavsdk", [
    ("auto", True, None, True, "AUTO", "Mission"),            # the fleet's mission runs: this robot bids for it
    ("auto", True, None, False, "HOLD", "Hold"),              # nothing to do
    ("hold", True, None, True, "HOLD", "Hold"),               # paused by the operator
    ("rtl", True, None, True, "RTL", "ReturnToLaunch"),
    ("rtl", False, None, False, "RTL", "ReturnToLaunch"),
])
def test_operator_modes_read_the_same_in_mavproxy_and_mavsdk(make, gcs, mode, armed, task, busy, want, mavsdk):
    from pymavlink import mavutil

    link, tel = make()
    tel.mode, tel.armed, tel.busy = mode, armed, busy
    hb, _ = _heartbeat(gcs, tel, 0.0, POSE, task)
    assert hb.autopilot == link.module.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert mavutil.mode_string_v10(hb) == want
    # MAVSDK flight_mode.cpp to_flight_mode_from_ardupilot_rover_mode
    assert {10: "Mission", 4: "Hold", 11: "ReturnToLaunch", 0: "Manual", 15: "Offboard"}[hb.custom_mode] == mavsdk
