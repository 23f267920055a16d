"""CreateOI driver: exact bytes over loop://, and odometry, rollover and watchdog against the emulator on a pty."""
from __future__ import annotations

import math
import time

import pytest
from hypothesis import example, given, settings, strategies as st

from runtime.drivers import create_oi_protocol as P
from runtime.drivers.create_oi import CreateOI
from runtime.errors import InputError
from sitl.devices.create_oi import CreateOIDevice
from tests.fakes import FakeBody

MM_PER_COUNT = P.GEOMETRY["create2"].mm_per_count


def loop_driver(model="create2", mode="safe", **kw):
    drv = CreateOI("loop://", model=model, mode=mode, **kw)
    drv.open(0.0)
    return drv


def drain(drv):
    """What the driver wrote (loop:// echoes it back) since the last drain."""
    return drv.ser.read(4096)


# ----------------------------------------------------------------------------- arguments and bytes
@pytest.mark.parametrize("kw", [
    {"model": "roomba"}, {"mode": "passive"}, {"baudrate": 12345}, {"max_speed": 0.6}, {"max_speed": 0},
    {"watchdog": 0},
])
def test_bad_settings_are_one_line_input_errors(kw):
    with pytest.raises(InputError) as exc:
        CreateOI("loop://", **kw)
    assert "\n" not in str(exc.value) and "expected" in str(exc.value)


def test_a_port_that_cannot_open_names_the_port():
    drv = CreateOI("/dev/does-not-exist-create")
    with pytest.raises(InputError, match="/dev/does-not-exist-create"):
        drv.open(0.0)


@pytest.mark.parametrize("model, mode, expected", [
    ("create2", "safe", [128, 131, 148, 5, 7, 35, 3, 43, 44]),
    ("create2", "full", [128, 132, 148, 5, 7, 35, 3, 43, 44]),
    ("create1", "safe", [128, 131, 148, 5, 7, 35, 3, 19, 20]),
])
def test_open_bytes(model, mode, expected):
    drv = loop_driver(model, mode)
    assert drain(drv) == bytes(expected)
    assert drv.baudrate == P.GEOMETRY[model].default_baud == drv.ser.baudrate


@pytest.mark.parametrize("v, w, right, left", [
    (0.2, 0.0, 200, 200),
    (0.0, 1.0, 118, -118),                   # 1 rad/s in place: 117.5 mm/s each wheel, rounded
    (0.1, 0.5, 159, 41),
    (-0.3, 0.0, -300, -300),
    (0.5, 2.0, 500, 180),                    # the faster wheel clipped to 0.5 m/s, the other scaled alike
    (0.0, -10.0, -500, 500),
])
def test_set_velocity_sends_drive_direct_right_wheel_first(v, w, right, left):
    drv = loop_driver()
    drain(drv)
    drv.set_velocity(v, w, 0.1)
    assert drain(drv) == bytes([145]) + right.to_bytes(2, "big", signed=True) + left.to_bytes(2, "big", signed=True)


def _reference_wheels(v, w, max_speed, track_mm=235.0):
    """The Drive Direct wheel speeds (right, left) in mm/s as the driver computed them before the policy
    moved into MobileBase: each wheel v -+ w*track/2, both scaled alike to the fastest at max_speed."""
    half = track_mm / 2000.0
    left, right = v - w * half, v + w * half
    peak = max(abs(left), abs(right))
    if peak > max_speed:
        left, right = left * max_speed / peak, right * max_speed / peak
    return right * 1000.0, left * 1000.0


def _rounds_to(got: int, exact: float) -> bool:
    """``got`` is ``exact`` rounded; at a tie (within float noise of .5: v=0.094, w=1.12, max_speed=0.123 gives
    -20.5 mm/s, which the two ways of scaling land either side of) either neighbour is."""
    return got == round(exact) or (abs(abs(exact - math.floor(exact)) - 0.5) < 1e-9 and abs(got - exact) <= 0.5 + 1e-9)


@settings(max_examples=300, deadline=None)
@example(v=0.094, w=1.12, max_speed=0.123, model="create2")       # a tie at -20.5 mm/s
@given(v=st.floats(-3.0, 3.0) | st.integers(-3000, 3000).map(lambda n: n / 1000.0),
       w=st.floats(-30.0, 30.0) | st.integers(-30000, 30000).map(lambda n: n / 1000.0),
       max_speed=st.sampled_from([0.5, 0.3, 0.123, 0.01]), model=st.sampled_from(P.MODELS))
def test_drive_direct_bytes_are_unchanged_by_the_shared_policy(v, w, max_speed, model):
    drv = loop_driver(model=model, max_speed=max_speed)
    drain(drv)
    drv.set_velocity(v, w, 0.0)
    right, left = _reference_wheels(v, w, max_speed, P.GEOMETRY[model].track_mm)
    data = drain(drv)
    assert len(data) == 5 and data[0] == 145, data
    got = int.from_bytes(data[1:3], "big", signed=True), int.from_bytes(data[3:5], "big", signed=True)
    assert _rounds_to(got[0], right) and _rounds_to(got[1], left), (got, right, left)


@pytest.mark.parametrize("model, track", [("create2", 0.235), ("create1", 0.258)])
def test_footprint_from_the_geometry_table(model, track):
    fp = CreateOI("loop://", model=model, max_speed=0.4).footprint
    assert (fp.radius, fp.track, fp.max_speed) == (0.17, track, 0.4)
    assert fp.max_turn_rate == pytest.approx(2 * 0.4 / track)


def test_clipping_keeps_the_curvature():
    drv = loop_driver(max_speed=0.3)
    drain(drv)
    drv.set_velocity(0.5, 2.0, 0.0)
    data = drain(drv)
    right, left = int.from_bytes(data[1:3], "big", signed=True), int.from_bytes(data[3:5], "big", signed=True)
    assert right == 300
    half = 117.5
    assert (right - left) / (right + left) == pytest.approx((2.0 * half) / 500.0, abs=0.01)


def test_non_finite_commands_stop_the_wheels():
    drv = loop_driver()
    drain(drv)
    drv.set_velocity(float("nan"), 0.0, 0.0)
    assert drain(drv) == bytes([145, 0, 0, 0, 0]) and drv.stats.nonfinite_commands == 1


def test_close_bytes():
    for model, last in (("create2", 173), ("create1", 128)):     # no Stop on a Create 1: Start = Passive
        drv = loop_driver(model)
        ser = drv.ser
        ser.close = lambda: None                                    # keep the loop open to read it back
        drain(drv)
        drv.close()
        assert ser.read(100) == bytes([145, 0, 0, 0, 0, 150, 0, last]) and drv.ser is None


# ----------------------------------------------------------------------------- watchdog (injected time)
def test_watchdog_sends_zero_once_after_half_a_second_without_commands():
    drv = loop_driver(watchdog=0.5)
    drain(drv)
    drv.set_velocity(0.2, 0.0, 1.0)
    drain(drv)
    drv.poll(1.3)
    drv.poll(1.499)
    assert drain(drv) == b"" and drv.stats.watchdog_stops == 0
    drv.poll(1.5)
    assert drain(drv) == bytes([145, 0, 0, 0, 0]) and drv.stats.watchdog_stops == 1
    drv.poll(2.5)
    assert drain(drv) == b"" and drv.stats.watchdog_stops == 1
    drv.set_velocity(0.0, 0.0, 3.0)                  # a zero command needs no watchdog
    drain(drv)
    drv.poll(9.0)
    assert drain(drv) == b"" and drv.stats.watchdog_stops == 1
    drv.set_velocity(0.1, 0.0, 10.0)                 # fresh commands keep it quiet
    for k in range(1, 10):
        drv.poll(10.0 + 0.1 * k)
        drv.set_velocity(0.1, 0.0, 10.0 + 0.1 * k)
    assert drv.stats.watchdog_stops == 1


# ----------------------------------------------------------------------------- frames over loop://
def _frame(left, right, mode=P.MODE_SAFE, bumps=0):
    return P.build_stream_frame([
        (7, bytes([bumps])), (35, bytes([mode])),
        (3, P.encode_packet(3, {"charging_state": 0, "voltage": 14800, "current": -420, "temperature": 27,
                                "battery_charge": 2100, "battery_capacity": 2696})),
        (43, left.to_bytes(2, "big", signed=True)), (44, right.to_bytes(2, "big", signed=True))])


@pytest.mark.parametrize("start, delta", [(32700, 136), (-32700, -136), (32767, 1), (-32768, -1), (100, -300)])
def test_encoder_rollover_both_ways(start, delta):
    drv = loop_driver()
    drain(drv)
    drv.ser.write(_frame(start, start))
    assert drv.poll(0.0) is False                    # the first frame only sets the reference
    wrapped = (start + delta + 0x8000) % 0x10000 - 0x8000
    drv.ser.write(_frame(wrapped, wrapped))
    assert drv.poll(0.015) is True
    assert drv.odometry.x == pytest.approx(delta * MM_PER_COUNT / 1000.0)
    assert drv.odometry.v == pytest.approx(delta * MM_PER_COUNT / 1000.0 / 0.015)
    assert drv.odometry.theta == 0.0


def test_frames_update_sensors_and_garbage_is_counted():
    drv = loop_driver()
    drain(drv)
    drv.ser.write(b"\x01\x02\x03" + _frame(0, 0, bumps=0b1010) + b"\x13\x05\x00\x00")
    drv.poll(0.0)
    s = drv.sensors
    assert s.bump_left and not s.bump_right and s.wheel_drop            # bits 1 and 3: bump left, drop left
    assert (s.voltage, s.current, s.battery_charge, s.battery_capacity) == (14.8, -0.42, 2.1, 2.696)
    assert s.mode == "safe"
    drv.ser.write(_frame(10, -10, P.MODE_PASSIVE, bumps=0b0001))
    drv.poll(0.015)
    assert s.bump_right and not s.bump_left and not s.wheel_drop and s.mode == "passive"
    assert drv.stats.frames == 2
    assert drv.stats.dropped_bytes == 3 + 4 and drv.stats.bad_checksum >= 1
    assert drv.odometry.theta == pytest.approx(-20 * MM_PER_COUNT / 235.0)


# ----------------------------------------------------------------------------- against the emulator on a pty
class Rig:
    """Driver and emulator on one pty, stepped in lock-step sim time."""

    def __init__(self, model="create2", travel=(0.0, 0.0), **kw):
        self.body = FakeBody(travel, track=P.GEOMETRY[model].track_mm / 1000.0)
        self.dev = CreateOIDevice(self.body, model=model)
        self.drv = CreateOI(self.dev.path, model=model, **kw)
        self.t = 0.0
        self.drv.open(self.t)
        self.settle()

    def settle(self, timeout=2.0):
        """Service both ends at the current sim time until every byte written has been read."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.dev.service(self.t)
            self.drv.poll(self.t)
            if (self.dev.stats.bytes_in == self.drv.stats.extra["bytes_out"]
                    and self.drv.stats.extra["bytes_in"] == self.dev.stats.bytes_out):
                return
            time.sleep(0.0002)
        raise AssertionError("pty did not settle")

    def drive(self, v, w, seconds, dt=0.005):
        end = self.t + seconds
        while self.t < end - 1e-9:
            self.drv.set_velocity(v, w, self.t)
            self.settle()
            self.t = round(self.t + dt, 9)
            self.body.step(dt)
            self.settle()
        self.drv.set_velocity(0.0, 0.0, self.t)
        for _ in range(4):                                   # let the last frames through
            self.settle()
            self.t = round(self.t + dt, 9)
            self.body.step(dt)
        self.settle()

    def close(self):
        self.drv.close()
        self.dev.close()


@pytest.fixture
def rig():
    made = []

    def make(**kw):
        r = Rig(**kw)
        made.append(r)
        return r
    yield make
    for r in made:
        r.close()


def test_open_puts_the_emulator_in_safe_mode_streaming(rig):
    r = rig()
    assert r.dev.mode_name == "safe" and r.dev.stream_ids == [7, 35, 3, 43, 44]
    assert r.drv.sensors.mode == "safe" and 13.0 < r.drv.sensors.voltage < 17.0
    assert r.drv.sensors.battery_capacity == pytest.approx(2.696)


@pytest.mark.parametrize("model", P.MODELS)
def test_odometry_straight_line_within_1_percent(rig, model):
    r = rig(model=model)
    r.drive(0.25, 0.0, 4.0)
    assert r.body.x == pytest.approx(1.0, rel=0.01)
    assert r.drv.odometry.x == pytest.approx(r.body.x, rel=0.01)
    assert abs(r.drv.odometry.y) < 0.01 and abs(r.drv.odometry.theta) < 0.01
    assert r.drv.stats.bad_checksum == 0 and r.drv.stats.dropped_bytes == 0


@pytest.mark.parametrize("model", P.MODELS)
def test_odometry_in_place_turn_within_1_percent(rig, model):
    # 2.5 rad: the Create 1 reports whole degrees, so up to 1 degree is still unreported at the end
    r = rig(model=model)
    r.drive(0.0, 0.8, 2.5 / 0.8)
    assert r.body.theta == pytest.approx(2.5, rel=0.01)
    assert r.drv.odometry.theta == pytest.approx(r.body.theta, rel=0.01)
    assert math.hypot(r.drv.odometry.x, r.drv.odometry.y) < 0.005


@pytest.mark.parametrize("travel, v", [(14.55, 0.3), (-14.55, -0.3)])
def test_encoder_rollover_through_the_emulator(rig, travel, v):
    r = rig(travel=(travel, travel))
    start = r.dev.values()["left_encoder_counts"]
    assert abs(start) > 32600
    r.drive(v, 0.0, 1.0)
    assert abs(r.dev.values()["left_encoder_counts"]) > 32000 and \
        (r.dev.values()["left_encoder_counts"] > 0) != (start > 0)         # the counter wrapped
    assert r.drv.odometry.x == pytest.approx(v * 1.0, rel=0.01)


def test_watchdog_stops_the_emulated_robot(rig):
    r = rig()
    r.drv.set_velocity(0.2, 0.0, r.t)
    r.settle()
    assert r.body.cmd == (0.2, 0.2)
    for _ in range(120):                                  # 0.6 s of sim time with no command
        r.t = round(r.t + 0.005, 9)
        r.body.step(0.005)
        r.settle()
    assert r.body.cmd == (0.0, 0.0) and r.drv.stats.watchdog_stops == 1


def test_wheel_drop_reaches_the_driver(rig):
    r = rig()
    r.drv.set_velocity(0.2, 0.0, r.t)
    r.settle()
    r.body.drop = (False, True)
    r.t += 0.02
    r.settle()
    r.t += 0.02
    r.settle()
    assert r.drv.sensors.wheel_drop and r.drv.sensors.mode == "passive" and r.body.cmd == (0.0, 0.0)


def _run_for(r, seconds, dt=0.02, v=0.2):
    """Command v every step (as the daemon does) and advance sim time."""
    end = r.t + seconds
    while r.t < end - 1e-9:
        r.drv.set_velocity(v, 0.0, r.t)
        r.settle()
        r.t = round(r.t + dt, 9)
        r.body.step(dt)
        r.settle()


def test_back_to_safe_mode_once_the_wheels_are_down_again(rig):
    r = rig()
    _run_for(r, 0.2)
    r.body.drop = (True, True)                       # picked up: Safe -> Passive, wheels stopped
    _run_for(r, 3.0)
    assert r.dev.mode_name == "passive" and r.body.cmd == (0.0, 0.0)
    assert r.drv.stats.extra["mode_recoveries"] == 0  # not while the wheels hang
    r.body.drop = (False, False)                     # put down again
    _run_for(r, 0.5)
    assert r.dev.mode_name == "passive"              # waits a moment first
    _run_for(r, 1.0)
    assert r.dev.mode_name == "safe" and r.drv.sensors.mode == "safe"
    assert r.drv.stats.extra["mode_recoveries"] == 1
    assert r.body.cmd == pytest.approx((0.2, 0.2))   # the daemon's commands drive it again


def test_mode_recovery_backs_off_while_a_cliff_persists(rig):
    r = rig()
    _run_for(r, 0.2)
    r.body.cliffs = lambda: (False, True, False, False)   # a cliff the driver cannot see in its stream
    times = []
    end = r.t + 40.0
    while r.t < end:
        before = r.drv.stats.extra["mode_recoveries"]
        _run_for(r, 0.1)
        if r.drv.stats.extra["mode_recoveries"] > before:
            times.append(r.t)
    gaps = [b - a for a, b in zip(times, times[1:])]
    assert 4 <= len(times) <= 6
    assert all(b > a for a, b in zip(gaps, gaps[1:]))      # each wait longer than the last
    assert r.dev.mode_name == "passive" and r.dev.stats.safety_stops == len(times) + 1
    assert r.body.cmd == (0.0, 0.0)


def test_no_recovery_when_the_base_was_never_in_safe_mode(rig):
    r = rig()
    r.drv.sensors.mode = "unknown"
    r.drv._reached_mode = False
    r.dev.mode = P.MODE_PASSIVE                        # e.g. someone sent Start from another program
    _run_for(r, 5.0)
    assert r.drv.stats.extra["mode_recoveries"] == 0 and r.dev.mode_name == "passive"


def test_a_vanished_device_is_reported_lost_after_a_run_of_failed_reads():
    """The pty's far end closes (a USB serial adapter pulled, the SITL gone): reads fail with EIO; after
    LOST_AFTER of them in a row the driver raises DeviceLost, one line naming the port."""
    import os

    from runtime.drivers.base import LOST_AFTER, DeviceLost
    master, slave = os.openpty()
    name = os.ttyname(slave)
    base = CreateOI(name)
    base.open(0.0)
    os.close(master)
    for k in range(LOST_AFTER - 1):
        base.poll(k * 0.05)
    with pytest.raises(DeviceLost, match=f"Create OI port {name}: {LOST_AFTER} reads in a row failed"):
        base.poll(LOST_AFTER * 0.05)
    base.close()                                   # closing a lost base does not raise
    os.close(slave)


def test_the_daemon_stops_on_a_lost_device_and_writes_its_final_snapshot(tmp_path):
    """`mrta daemon` whose serial device vanishes exits with code 3, no traceback, its snapshot written."""
    import json
    import os
    import threading

    import yaml

    from runtime import config as C
    from runtime.clock import ScaledClock
    from runtime.daemon import Daemon, run
    master, slave = os.openpty()
    cfg = C.from_dict(C.RobotConfig, {"base": {"port": os.ttyname(slave)}, "gps": {"enabled": False},
                                      "comms": {"listen": "127.0.0.1:0", "gcs": None},
                                      "localization": {"initial_pose": [0, 0, 0]}})
    d = Daemon(cfg)
    threading.Timer(0.3, os.close, (master,)).start()
    stats = tmp_path / "stats.json"
    code = run(d, ScaledClock(4.0), duration=30.0, stats_path=str(stats))
    os.close(slave)
    assert code == 3
    assert json.loads(stats.read_text())["cycles"] > 0


@pytest.mark.parametrize("ending", ["SIGTERM", "exception"])
def test_the_daemon_stops_a_moving_create_on_a_signal_and_on_an_exception(tmp_path, ending):
    """A Create has no watchdog of its own: whatever ends `mrta daemon`'s loop, the base is told to stop.  The
    daemon drives the emulated Create at 0.2 m/s; a SIGTERM (or an exception in a cycle) ends the run, and the
    emulator's wheels are at rest and the OI is out of Safe mode (Stop) afterwards."""
    import os
    import signal
    import threading

    from runtime import config as C
    from runtime.clock import ScaledClock
    from runtime.daemon import Daemon, run
    body = FakeBody(track=P.GEOMETRY["create2"].track_mm / 1000.0)
    dev = CreateOIDevice(body)
    done = threading.Event()

    def emulate():
        t0 = time.monotonic()
        while not done.is_set():
            dev.service(time.monotonic() - t0)
            time.sleep(0.005)

    cfg = C.from_dict(C.RobotConfig, {"base": {"port": dev.path}, "gps": {"enabled": False},
                                      "comms": {"listen": "127.0.0.1:0", "gcs": None},
                                      "localization": {"initial_pose": [0, 0, 0]}})
    d = Daemon(cfg)
    step, moving = d.step, []

    def step_and_drive(now):
        step(now)
        d.base.set_velocity(0.2, 0.0, now)
        moving.append(body.cmd != (0.0, 0.0))
        if ending == "exception" and len(moving) > 20:
            raise RuntimeError("a bug in a cycle")

    d.step = step_and_drive
    emulator = threading.Thread(target=emulate, daemon=True)
    emulator.start()
    handlers = signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)
    timer = threading.Timer(1.0, os.kill, (os.getpid(), signal.SIGTERM))
    try:
        if ending == "SIGTERM":
            timer.start()
            assert run(d, ScaledClock(1.0), duration=30.0) == 0
        else:
            with pytest.raises(RuntimeError, match="a bug in a cycle"):
                run(d, ScaledClock(1.0), duration=30.0)
        assert any(moving), "the emulated Create never moved"
        deadline = time.monotonic() + 2.0
        while (body.cmd != (0.0, 0.0) or dev.mode_name == "safe") and time.monotonic() < deadline:
            time.sleep(0.01)
        assert body.cmd == (0.0, 0.0) and dev.mode_name != "safe", (body.cmd, dev.mode_name)
    finally:
        timer.cancel()
        done.set()
        emulator.join(2.0)
        dev.close()
        signal.signal(signal.SIGTERM, handlers[0])
        signal.signal(signal.SIGINT, handlers[1])
