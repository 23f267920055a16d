"""The CiA 402 base driver against the emulated drives: the frames on the wire (NMT, SDO, PDO, heartbeats), the
402 start-up, odometry and commands, on python-can ``virtual``, through the socketcand hub, and on ``vcan0``
where it exists."""
from __future__ import annotations

import math
import struct

import pytest

from runtime.drivers import cia402_protocol as P
from runtime.drivers.cia402 import Cia402Base, Cia402Config, bus_kwargs
from runtime.errors import InputError
from tests.can_util import TRANSPORTS, Rig, Sniffer


@pytest.fixture
def rig(request):
    r = Rig(getattr(request, "param", "virtual"))
    yield r
    r.close()


def sdo_download(index, sub, value, size):
    """Expedited SDO download request (CiA 301): 0x23/0x27/0x2B/0x2F for 4/3/2/1 bytes."""
    cmd = {4: 0x23, 3: 0x27, 2: 0x2B, 1: 0x2F}[size]
    return bytes([cmd]) + struct.pack("<HB", index, sub) + value.to_bytes(size, "little", signed=value < 0).ljust(4, b"\0")


# ----------------------------------------------------------------------------- start-up on the wire
def test_open_puts_the_cia402_start_up_on_the_wire():
    rig = Rig("virtual")
    sniff = Sniffer(rig.driver_cfg.channel)
    try:
        rig.open()
        frames = sniff.take()
        ids = [f[0] for f in frames]
        assert (0x000, bytes([P.NMT_PRE_OPERATIONAL, 1])) in frames and (0x000, bytes([P.NMT_PRE_OPERATIONAL, 2])) in frames
        assert (0x601, sdo_download(0x1017, 0, 100, 2)) in frames                     # heartbeat 100 ms
        assert (0x601, sdo_download(0x1016, 1, 0x007F012C, 4)) in frames              # consume 127 every 300 ms
        assert (0x601, sdo_download(0x6060, 0, 3, 1)) in frames                       # profile velocity
        assert (0x601, sdo_download(0x1A01, 1, 0x60640020, 4)) in frames              # TPDO2: position actual
        assert (0x601, sdo_download(0x1A01, 2, 0x606C0020, 4)) in frames              # ... and velocity actual
        assert (0x601, sdo_download(0x1600, 2, 0x60FF0020, 4)) in frames              # RPDO1: target velocity
        assert (0x601, bytes([0x40, 0x02, 0x65, 0x00, 0, 0, 0, 0])) in frames         # 0x6502 read by the library
        start = frames.index((0x000, bytes([P.NMT_START, 1])))
        after = frames[start:]
        cws = [struct.unpack_from("<H", d)[0] for i, d in after if i == 0x201]
        assert cws[:3] == [0x06, 0x07, 0x0F]                                          # Shutdown, Switch on, Enable
        assert all(len(d) == 7 and d[6] == 3 for i, d in after if i == 0x201)         # cw, target, mode 3
        sws = [struct.unpack_from("<H", d)[0] for i, d in after if i == 0x181]
        answers = [P.state_of(sw) for sw in sws]
        for state in ("READY TO SWITCH ON", "SWITCHED ON", "OPERATION ENABLED"):
            assert state in answers
        assert answers.index("READY TO SWITCH ON") < answers.index("SWITCHED ON") < answers.index("OPERATION ENABLED")
        assert ids.index(0x581) > ids.index(0x601)                                    # answers follow requests
    finally:
        sniff.close()
        rig.close()


def test_cyclic_traffic_heartbeats_both_ways_and_pdos():
    rig = Rig("virtual")
    sniff = Sniffer(rig.driver_cfg.channel)
    try:
        rig.open()
        sniff.take()
        sniff.frames.clear()
        rig.v = 0.5
        rig.step(1.0)
        frames = sniff.take()
        by_id = {}
        for i, d in frames:
            by_id.setdefault(i, []).append(d)
        assert by_id[0x77F][0] == bytes([0x05])                          # this master's heartbeat, operational
        assert 9 <= len(by_id[0x77F]) <= 11                               # every 0.1 s
        assert set(by_id[0x701]) == {bytes([0x05])} and 9 <= len(by_id[0x701]) <= 11
        assert set(by_id[0x702]) == {bytes([0x05])}
        assert 45 <= len(by_id[0x281]) <= 51 and all(len(d) == 8 for d in by_id[0x281])   # TPDO2 every 20 ms
        assert {struct.unpack_from("<H", d)[0] for d in by_id[0x201] + by_id[0x202]} == {0x0F}
        left_target = struct.unpack_from("<i", by_id[0x201][-1], 2)[0]
        right_target = struct.unpack_from("<i", by_id[0x202][-1], 2)[0]
        assert left_target == rig.base.units.velocity(0.5) > 0
        assert right_target == -left_target                                # the right motor is mirrored
    finally:
        sniff.close()
        rig.close()


# ----------------------------------------------------------------------------- motion
@pytest.mark.parametrize("rig", TRANSPORTS, indirect=True)
def test_odometry_follows_the_wheels(rig):
    rig.open()
    rig.v, rig.w = 0.5, 0.0
    rig.step(2.0)
    rig.v, rig.w = 0.3, 0.8
    rig.step(2.0)
    o, b = rig.base.odometry, rig.body
    assert o.v == pytest.approx(0.3, abs=0.01) and o.w == pytest.approx(0.8, abs=0.02)
    rig.v = rig.w = 0.0
    rig.step(1.0)                                                           # stopped: the last TPDOs are in
    assert b.x > 1.0                                                        # it moved
    assert math.hypot(o.x - b.x, o.y - b.y) < 0.002 and abs(math.remainder(o.theta - b.theta, math.tau)) < 0.002
    assert rig.left.state == rig.right.state == P.ENABLED
    assert rig.base.sensors.faults == () and rig.base.stats.extra["malformed"] == 0
    assert rig.base.stats.frames > 0 and rig.left.stats.malformed == 0


def test_ramps_follow_the_profile_acceleration(rig):
    rig.open()
    rig.v = 1.0
    rig.step(0.2)
    v1 = rig.base.odometry.v
    rig.step(0.4)
    assert (rig.base.odometry.v - v1) / 0.4 == pytest.approx(1.0, abs=0.05)         # 1 m/s^2 (0x6083)
    rig.step(1.0)
    assert rig.base.odometry.v == pytest.approx(1.0, abs=0.01)


def test_the_watchdog_stops_the_drives_when_commands_stop(rig):
    rig.open()
    rig.v = 0.4
    rig.step(1.0)
    rig.base.set_velocity(0.4, 0.0, rig.t)
    t0 = rig.t
    while rig.t < t0 + 1.5:                          # polls go on, commands do not
        rig.polling = False
        rig.step(0.05)
        rig.base.poll(rig.t)
    assert rig.base.stats.watchdog_stops == 1
    assert rig.left.motor == 0 and rig.right.motor == 0 and rig.base.sensors.faults == ()


def test_close_disables_the_drives_and_their_consumer(rig):
    rig.open()
    rig.v = 0.3
    rig.step(0.5)
    rig.base.close()
    rig.polling = False
    rig.step(1.0)                                    # no master heartbeat any more: no consumer fault either
    assert rig.left.state == rig.right.state == P.READY
    assert rig.left.nmt_state == "PRE-OPERATIONAL" and rig.left.stats.consumer_timeouts == 0
    assert rig.left.motor == 0


# ----------------------------------------------------------------------------- errors
@pytest.mark.parametrize("kw, what", [
    ({"left_node": 1, "right_node": 1}, "three different node ids"),
    ({"master_node": 2}, "three different node ids"),
    ({"options": ("tcp_tune",)}, "name=value"),
    ({"options": ("x=[",)}, "YAML scalar"),
])
def test_bad_settings_are_one_line_input_errors(kw, what):
    with pytest.raises(InputError, match=what) as info:
        Cia402Base(Cia402Config(**kw))
    assert "\n" not in str(info.value)


def test_bus_kwargs_pass_options_through():
    cfg = Cia402Config(interface="socketcand", channel="can3", host="10.0.0.2", port=29536,
                       options=("tcp_tune=true", "receive_own_messages=false"))
    assert bus_kwargs(cfg) == {"interface": "socketcand", "channel": "can3", "host": "10.0.0.2", "port": 29536,
                               "tcp_tune": True, "receive_own_messages": False}


def test_a_bus_that_cannot_open_names_the_interface():
    base = Cia402Base(Cia402Config(interface="no-such-interface", channel="x"))
    with pytest.raises(InputError, match="no-such-interface") as info:
        base.open(0.0)
    assert "\n" not in str(info.value)


def test_no_drive_on_the_bus_names_the_node():
    base = Cia402Base(Cia402Config(interface="virtual", channel="cia402-test-empty"))
    with pytest.raises(InputError, match=r"left drive \(node 1\)") as info:
        base.open(0.0)
    assert "\n" not in str(info.value) and not base.is_open


def test_a_drive_without_profile_velocity_is_refused(rig):
    rig.left.node.data_store[0x6502] = {0: (0x0001).to_bytes(4, "little")}     # profile position only
    with pytest.raises(InputError, match=r"0x6502.*profile velocity"):
        rig.open()


def test_a_node_that_is_not_a_402_device_is_refused(rig):
    rig.right.node.data_store[0x1000] = {0: (0x00000191).to_bytes(4, "little")}  # CiA 401 I/O module
    with pytest.raises(InputError, match=r"right drive \(node 2\).*profile 402"):
        rig.open()


def test_the_emulator_refuses_other_modes_by_sdo_abort(rig):
    from canopen.sdo import SdoAbortedError
    rig.open()
    node = rig.base.drives[0].node
    with rig.base._receiving():
        with pytest.raises(SdoAbortedError) as info:
            node.sdo[0x6060].raw = 1
        assert info.value.code == 0x06090030
        assert node.sdo[0x6061].raw == 3
