"""Faults of the CAN base: a silent drive, a drive in FAULT with an EMCY, a silent master, fault reset, and
garbage frames that never stop a loop and are counted."""
from __future__ import annotations

import time

import can
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from runtime.drivers import cia402_protocol as P
from runtime.drivers.cia402 import RESET_TIMEOUT, SILENT_PERIODS
from tests.can_util import TRANSPORTS, Rig


@pytest.fixture
def rig(request):
    r = Rig(getattr(request, "param", "virtual"))
    r.open()
    r.v = 0.8
    r.step(1.5)                                   # cruising at 0.8 m/s
    yield r
    r.close()


def faulted(r):
    return bool(r.base.sensors.faults)


def stopped(drive):
    return lambda r: drive.motor == 0.0


@pytest.mark.parametrize("rig", TRANSPORTS, indirect=True)
def test_a_silent_drive_stops_the_other_within_half_a_second_of_detection(rig):
    t_cut = rig.t
    rig.left.silence()
    t_detect = rig.step(2.0, until=faulted)
    hb = rig.cfg.heartbeat
    assert t_detect is not None and (SILENT_PERIODS - 1) * hb < t_detect - t_cut <= (SILENT_PERIODS + 1) * hb + 2 * rig.period
    assert rig.base.sensors.faults == ("left_drive_silent",)
    assert rig.base.stats.extra["fault_stops"] == 1
    t_stop = rig.step(0.5, until=stopped(rig.right))
    assert t_stop is not None and t_stop - t_detect <= 0.5                       # the other drive has stopped
    assert rig.right.state == P.QUICK_STOP
    rig.step(1.0)
    assert rig.left.motor == 0.0 and rig.left.state == P.FAULT                   # its own consumer stopped it
    assert rig.left.stats.consumer_timeouts == 1
    assert rig.right.motor == 0.0 and rig.base.sensors.faults == ("left_drive_silent",)     # latched
    assert rig.base.odometry.v == 0.0 and rig.base.odometry.w == 0.0        # no stale speed from the silent one


@pytest.mark.parametrize("code, name", [(P.EMCY_OVERCURRENT, "right_drive_emcy_2310"),
                                        (P.EMCY_ENCODER, "right_drive_emcy_7305")])
def test_a_drive_fault_with_emcy_stops_the_other(rig, code, name):
    rig.right.inject_fault(code)
    t_detect = rig.step(0.2, until=faulted)
    assert t_detect is not None and t_detect - rig.t <= 0.0 + 1e-9           # seen in the next cycle
    t_stop = rig.step(0.5, until=lambda r: r.left.motor == 0.0 and r.right.motor == 0.0)
    assert t_stop is not None and t_stop - t_detect <= 0.5
    rig.step(0.2)
    assert set(rig.base.sensors.faults) == {"right_drive_fault", name}
    assert rig.right.state == P.FAULT and rig.left.state == P.QUICK_STOP
    assert rig.base.drives[1].emcy == [code]


def test_fault_reset_brings_both_drives_back(rig):
    rig.right.inject_fault()
    rig.step(1.0)
    assert rig.base.sensors.faults and rig.left.motor == rig.right.motor == 0.0
    assert rig.base.reset_faults(rig.t)
    t_done = rig.step(1.0, until=lambda r: not r.base.sensors.faults)
    assert t_done is not None
    assert rig.left.state == rig.right.state == P.ENABLED and rig.right.error_code == 0
    assert rig.base.drives[1].node.emcy.log[-1].code == 0                      # the drive's EMCY error reset
    rig.step(1.5)
    assert rig.base.odometry.v == pytest.approx(0.8, abs=0.01)                 # driving again
    assert not rig.base.reset_faults(rig.t)                                    # nothing to reset


def test_a_reset_cannot_bring_back_a_silent_drive_until_it_is_back(rig):
    rig.left.silence()
    rig.step(1.0)
    assert rig.base.reset_faults(rig.t)
    rig.step(RESET_TIMEOUT + 0.5)
    assert rig.base.sensors.faults == ("left_drive_silent",) and rig.base._resetting is None   # gave up
    rig.left.silence(False)
    rig.step(0.5)
    # latched until a reset; back on the bus it shows FAULT (its consumer tripped while it was cut off)
    assert rig.base.sensors.faults == ("left_drive_fault", "left_drive_silent")
    assert rig.base.reset_faults(rig.t)
    assert rig.step(1.0, until=lambda r: not r.base.sensors.faults) is not None
    assert rig.left.state == P.ENABLED


def test_a_silent_master_stops_both_drives(rig):
    """The daemon dies: no heartbeat, no commands.  Each drive's consumer (0x1016, 3 periods) stops its motor."""
    rig.polling = False
    t0 = rig.t
    t_stop = rig.step(2.0, until=lambda r: r.left.motor == 0.0 and r.right.motor == 0.0)
    consumer = SILENT_PERIODS * rig.cfg.heartbeat
    assert t_stop is not None and t_stop - t0 <= consumer + 0.8 / rig.cfg.quick_stop_deceleration + 0.15
    assert rig.left.state == rig.right.state == P.FAULT
    assert rig.left.error_code == P.EMCY_HEARTBEAT


def test_a_drive_allowed_a_clock_lag_waits_that_much_longer_for_a_silent_master(rig):
    """Daemons in their own processes read the world's clock from a file; the world catching up on a lag runs
    ahead of them, so the launcher widens each drive's consumer window by that lag (sitl.launcher.MAX_LAG)."""
    lag = 0.25
    rig.dev.allow_clock_lag(lag)
    rig.polling = False
    t0 = rig.t
    t_silent = rig.step(2.0, until=lambda r: r.left.stats.consumer_timeouts > 0)
    consumer = SILENT_PERIODS * rig.cfg.heartbeat
    assert t_silent is not None
    assert consumer + lag - rig.cfg.heartbeat < t_silent - t0 <= consumer + lag + rig.period
    assert rig.right.stats.consumer_timeouts == 1
    assert rig.step(2.0, until=lambda r: r.left.state == r.right.state == P.FAULT) is not None


def test_a_drive_that_leaves_operational_is_a_fault(rig):
    with rig.base._receiving():
        rig.base.drives[0].node.nmt.state = "PRE-OPERATIONAL"       # as a second master might
    rig.step(0.5, until=faulted)
    assert "left_drive_pre-operational" in rig.base.sensors.faults
    rig.step(0.5)
    assert rig.left.motor == 0.0 and rig.right.motor == 0.0


# ----------------------------------------------------------------------------- garbage
frames = st.builds(lambda ext, ident, data, rtr: can.Message(arbitration_id=ident & (0x1FFFFFFF if ext else 0x7FF),
                                                              is_extended_id=ext, data=data, is_remote_frame=rtr),
                   st.booleans(), st.integers(0, 0x1FFFFFFF), st.binary(max_size=8), st.booleans())


def inject_and_count(rig, msgs: list) -> None:
    """Put ``msgs`` on the bus, run 0.1 s (no exception may come out of poll(), set_velocity() or service()),
    and check the driver and both drives counted every one of them (as a frame of some kind, or malformed)."""
    def counted():
        return (rig.base.stats.frames + rig.base.stats.extra["malformed"],
                *(sum(d.stats.frames_in.values()) + d.stats.malformed for d in (rig.left, rig.right)))
    before = counted()
    noise = can.Bus(interface="virtual", channel=rig.driver_cfg.channel)
    try:
        for msg in msgs:
            noise.send(msg)
        rig.step(0.1)
    finally:
        noise.shutdown()
    assert all(after >= b + len(msgs) for after, b in zip(counted(), before))


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(frames, min_size=1, max_size=30))
def test_garbage_frames_never_stop_a_loop_and_are_counted(rig, junk):
    inject_and_count(rig, junk)


TRAFFIC = [(0x000, bytes([0x01, 0x01])), (0x701, bytes([0x05])), (0x77F, bytes([0x05])),
           (0x181, bytes([0x37, 0x06, 0x03])), (0x281, bytes.fromhex("00100000c0090000")),
           (0x201, bytes.fromhex("0f00c0090000" "03")), (0x601, bytes.fromhex("4041600000000000")),
           (0x581, bytes.fromhex("4b41600037060000")), (0x081, bytes.fromhex("1023030000000000"))]


def flipped(k: int, bit: int) -> can.Message:
    """TRAFFIC[k] with bit ``bit`` flipped: 0-10 in the identifier, then the data bits."""
    can_id, data = TRAFFIC[k]
    data = bytearray(data)
    if bit < 11:
        can_id ^= 1 << bit
    elif (bit - 11) // 8 < len(data):
        data[(bit - 11) // 8] ^= 1 << ((bit - 11) % 8)
    return can.Message(arbitration_id=can_id, data=bytes(data), is_extended_id=False)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.tuples(st.integers(0, len(TRAFFIC) - 1), st.integers(0, 74)), min_size=1, max_size=20))
def test_bit_flipped_frames_never_stop_a_loop_and_are_counted(rig, flips):
    """Frames of this base's own traffic with one bit flipped in the 11-bit id or the data."""
    inject_and_count(rig, [flipped(k, bit) for k, bit in flips])


@pytest.mark.parametrize("can_id, data", [
    (0x281, b"\x01\x02\x03"),                  # TPDO2 shorter than its map
    (0x181, b""),                              # TPDO1 empty
    (0x701, b""),                              # heartbeat without a state
    (0x081, b"\x10\x23"),                      # EMCY cut short
    (0x601, b"\x40"),                          # SDO request cut short
    (0x201, b"\x0f"),                          # RPDO cut short
])
def test_truncated_frames_are_counted_as_malformed(rig, can_id, data):
    noise = can.Bus(interface="virtual", channel=rig.driver_cfg.channel)
    try:
        before = rig.base.stats.extra["malformed"], rig.left.stats.malformed
        noise.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))
        rig.step(0.1)
    finally:
        noise.shutdown()
    assert rig.base.stats.extra["malformed"] + rig.left.stats.malformed > sum(before)
    assert rig.base.sensors.faults == () and rig.left.state == P.ENABLED


# ----------------------------------------------------------------------------- what the ground station sees
def test_sys_status_motor_outputs_unhealthy_while_the_base_reports_faults():
    from runtime.comms.link import MavlinkLink
    from runtime.comms.telemetry import GcsTelemetry
    from runtime.drivers.base import BaseSensors
    from tests.test_comms_telemetry import DATUM, Gcs

    gcs = Gcs()
    link = MavlinkLink(3, "127.0.0.1:0", [], gcs.address)
    try:
        tel = GcsTelemetry(link, 3, DATUM)
        motor = link.module.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
        health = []
        for t, faults in enumerate([(), ("left_drive_silent",), ()]):
            tel.tick(float(t), (0.0, 0.0, 0.0), (0.0, 0.0), BaseSensors(faults=faults), None)
            s = next(m for m in gcs.receive(6) if m.get_type() == "SYS_STATUS")   # a tick sends 6 now
            assert s.onboard_control_sensors_present & s.onboard_control_sensors_enabled & motor
            health.append(bool(s.onboard_control_sensors_health & motor))
        assert health == [True, False, True]
    finally:
        link.close()
        gcs.sock.close()


def test_a_vanished_hub_is_a_lost_device():
    """The SITL (or a remote socketcand) goes away: the drives fall silent, then sends fail; after LOST_AFTER
    failed sends in a row the driver raises DeviceLost, on which the daemon stops (exit code 3)."""
    from runtime.drivers.base import LOST_AFTER, DeviceLost

    r = Rig("socketcand")
    try:
        r.open()
        r.v = 0.3
        r.step(0.5)
        r.dev.hub.remove_channel(r.dev.channel)
        deadline = time.monotonic() + 5.0       # the hub's thread closes the connection when it gets to it
        with pytest.raises(DeviceLost, match="sends on socketcand") as info:
            while time.monotonic() < deadline:
                r.t += r.period
                r.base.poll(r.t)
                r.base.set_velocity(r.v, r.w, r.t)
                time.sleep(0.01)
        assert "\n" not in str(info.value)
        assert "left_drive_silent" in r.base.sensors.faults
        assert r.base.stats.extra["send_errors"] >= LOST_AFTER
    finally:
        r.base.close()
        r.dev.close()
