"""Ground-station telemetry of one robot over its :class:`~runtime.comms.link.MavlinkLink`.

Sent by :meth:`GcsTelemetry.tick` (system id = robot id, component 1):

* 1 Hz: HEARTBEAT (MAV_TYPE_GROUND_ROVER, MAV_AUTOPILOT_ARDUPILOTMEGA), SYS_STATUS (battery, comm errors),
  HOME_POSITION (where the robot started: its first pose, where RTL drives it, once it has a pose), GPS_RAW_INT
  (the robot's last GPS fix: fix type, satellites; GPS_FIX_TYPE_NO_GPS for a robot without a GPS, NO_FIX while
  it has no valid fix of the last 2 s); (the robot's tasks go to the ground station as
  MRTA_ROBOT_STATE, from :mod:`runtime.comms.ground`);
* 5 Hz, once a pose exists: GLOBAL_POSITION_INT (pymap3d ENU -> geodetic around the datum), LOCAL_POSITION_NED
  (ENU -> NED: x north, y east, z down) and ATTITUDE (roll and pitch 0, yaw from the pose's heading, NED: 0 north,
  clockwise; yawspeed from the heading's change).

Every stream but HEARTBEAT takes MAV_CMD_SET_MESSAGE_INTERVAL (:meth:`GcsTelemetry.set_interval`: an interval in
us, 0 the default, -1 off; at most :data:`MAX_RATE` Hz) and MAV_CMD_GET_MESSAGE_INTERVAL; the rates hold for every
ground station of the robot (ArduPilot keeps them per link; a robot has one ground link).

MAV_AUTOPILOT_ARDUPILOTMEGA, because the three stock ground stations then decode the same: MAVSDK reads ArduPilot
Rover's modes only for that autopilot (src/mavsdk/core/flight_mode.cpp ``to_flight_mode_from_custom_mode``; any
other autopilot is read as PX4), sends mode changes as MAV_CMD_DO_SET_MODE with the Rover number in param2
(system_impl.cpp ``make_command_ardupilot_mode``) and parameters C-cast; pymavlink/MAVProxy read the same Rover
numbers for it (``mode_mapping_rover``), and QGroundControl's APM plugin names them.

HEARTBEAT, chosen so a stock MAVProxy and QGroundControl show something true:

* custom_mode uses ArduPilot Rover's mode numbers: pymavlink's ``mode_string_v10`` (MAVProxy's prompt and
  "Mode X" announcements) looks custom_mode up in ``mode_mapping_rover`` for a non-PX4 autopilot whose type is
  GROUND_ROVER, whenever base_mode has CUSTOM_MODE_ENABLED, and MAVSDK maps AUTO to Mission, HOLD to Hold,
  RTL to ReturnToLaunch.  INITIALISING (16) while localizing (no pose yet; MAVSDK: Unknown), RTL (11) after a
  return to launch (the robot drives to its home), HOLD (4) when paused by the operator (:attr:`mode` "hold"),
  and in the robot's normal mode ("auto": it takes tasks) AUTO (10) while it is armed and holds a task or the
  fleet has open tasks (:attr:`busy`: the fleet's mission is running), HOLD otherwise (nothing to do, or
  disarmed: it stands).  Rover has no name for an auction phase: allocating vs executing is in
  MRTA_ROBOT_STATE.state.
* base_mode: CUSTOM_MODE_ENABLED (so the above is read), AUTO_ENABLED always (the robot finds its own
  goals: tasks come from auctions, there is no manual mode), SAFETY_ARMED iff :attr:`GcsTelemetry.armed`
  (the operator allows it to drive; independent of holding a task).  MAVProxy prints ARMED/DISARMED
  from that bit alone (mavutil ``motors_armed``).
* system_status: CRITICAL below 15 % battery (whatever else holds), CALIBRATING without a pose
  estimate, ACTIVE while armed with a task or returning to launch (motors engaged), STANDBY otherwise.

SYS_STATUS sensor bits: present = MOTOR_OUTPUTS, AHRS (the pose estimate), GPS (a robot with a GPS; failing
while it has no valid fix, so MAVSDK's ``is_global_position_ok`` is true only with one), 3D_GYRO, 3D_ACCEL
and 3D_MAG (the robot has no such sensors to calibrate; MAVSDK reads a calibration as failed unless the bit
is present and healthy, telemetry_impl.cpp ``process_sys_status``) and BATTERY (when the base
reports a voltage); enabled = the same but MOTOR_OUTPUTS only while armed (MAVProxy's console
and ``arm safetystatus`` read enabled motor outputs as "safety off, vehicle dangerous").  health = every
bit of MAV_SYS_STATUS_SENSOR except what is actually failing -- AHRS without a pose, BATTERY when
critical, MOTOR_OUTPUTS while the base reports faults (``sensors.faults``) -- since MAVLink's health bit means "no error" and MAVProxy alarms on missing health bits
of sensors that are not even present: its fence module starts ``healthy=True`` and says "fence breach"
on the first SYS_STATUS without the GEOFENCE health bit (the false breach seen before), and its
warning module flags any of AS/MAG/INS/AHRS/TERR/LOG/FEN unhealthy.  ArduPilot sets GEOFENCE health
the same way whenever its fence has not failed, present or not.

time_boot_ms is ``now`` in milliseconds (clock seconds: monotonic time since boot on a robot,
simulated seconds in SITL).
"""
from __future__ import annotations

import math

import pymap3d

# custom_mode: ArduPilot Rover numbers (pymavlink mavutil.mode_mapping_rover), see the module docstring
CUSTOM_MODE_HOLD = 4            # standing: no task, or disarmed
CUSTOM_MODE_AUTO = 10           # armed and holding a task: driving to it / at it
CUSTOM_MODE_RTL = 11            # returning to launch: driving to its home
CUSTOM_MODE_INITIALISING = 16   # localizing: no pose estimate yet
NO_TASK = 0xFFFF
LOW_BATTERY = 15.0              # % remaining below which the state is MAV_STATE_CRITICAL
SLOW_PERIOD = 1.0               # s: HEARTBEAT
GPS_STALE = 2.0                 # s: a fix older than this is no fix
MAX_RATE = 50.0                 # Hz: the fastest SET_MESSAGE_INTERVAL honoured
# the streams and their default periods (s); SET_MESSAGE_INTERVAL changes them
STREAMS = {"SYS_STATUS": 1.0, "GPS_RAW_INT": 1.0, "HOME_POSITION": 1.0, "GLOBAL_POSITION_INT": 0.2,
           "LOCAL_POSITION_NED": 0.2, "ATTITUDE": 0.2}
POSE_STREAMS = ("GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "ATTITUDE")      # once a pose exists
MODES = ("auto", "hold", "rtl")     # the operator's: take tasks / paused / return to launch


def _clip(v: float, lo: int, hi: int) -> int:
    return int(min(max(round(v), lo), hi))


def _finite(v) -> bool:
    try:
        return v is not None and math.isfinite(float(v))
    except (TypeError, ValueError):
        return False


def _datum(d) -> tuple[float, float, float]:
    if isinstance(d, dict):
        return float(d["lat"]), float(d["lon"]), float(d.get("alt", 0.0))
    if isinstance(d, (tuple, list)):
        return float(d[0]), float(d[1]), float(d[2]) if len(d) > 2 else 0.0
    return float(d.lat), float(d.lon), float(getattr(d, "alt", 0.0))


def _critical(remaining: float) -> bool:
    return _finite(remaining) and remaining < LOW_BATTERY


def _all_sensor_bits(m) -> int:
    """Every MAV_SYS_STATUS_SENSOR bit the dialect defines (the 32-bit fields' enum)."""
    bits = 0
    for value, entry in m.enums["MAV_SYS_STATUS_SENSOR"].items():
        if not entry.name.endswith("ENUM_END") and 0 < value < 2 ** 32:
            bits |= value
    return bits


class _Every:
    """Due once per ``period`` of the injected clock, without bursts after a pause (``period`` None: never)."""

    def __init__(self, period: float | None):
        self.period = period
        self.next: float | None = None

    def due(self, now: float) -> bool:
        if self.period is None:
            return False
        if self.next is not None and now < self.next:
            return False
        nxt = (now if self.next is None else self.next) + self.period
        self.next = nxt if nxt > now else now + self.period
        return True


class GcsTelemetry:
    def __init__(self, link, robot_id: int, datum, *, armed: bool = True, gps: bool = False):
        self.link = link
        self.robot_id = int(robot_id)
        self.lat0, self.lon0, self.alt0 = _datum(datum)
        self.m = link.module
        self.mav = link.mav
        self.gps = bool(gps)                     # the robot has a GPS receiver
        self._slow = _Every(SLOW_PERIOD)
        self.streams = {name: _Every(period) for name, period in STREAMS.items()}
        self.sent: dict[str, int] = {}
        # allowed to drive (HEARTBEAT SAFETY_ARMED); the daemon sets it, e.g. False on an operator stop.
        # True by default: nothing but holding a task gates driving in this runtime today.
        self.armed = bool(armed)
        self.mode = "auto"                       # the operator's mode (MODES)
        self.busy = False                        # the fleet has open tasks (its mission is running)
        self.home: tuple[float, float] | None = None     # where the robot started (fleet frame; HOME_POSITION)
        self._fix = None                         # the last GPS fix
        self._yaw: tuple[float, float] | None = None     # (time, yaw) of the last ATTITUDE
        self._update_mode(None, NO_TASK, math.nan)

    # ------------------------------------------------------------------ public
    def tick(self, now: float, pose, velocity, battery, task: int | None, fixes=()) -> None:
        """Send whatever is due at ``now``.

        ``pose``: (x east, y north, heading rad CCW from east) in the fleet frame, or None.
        ``velocity``: (v east, v north) m/s.  ``battery``: an object with ``voltage`` (V),
        ``current`` (A, negative = discharging), ``battery_charge`` and ``battery_capacity``
        (e.g. :class:`~runtime.drivers.base.BaseSensors`), or None.  ``task``: the task the robot works
        on (None: none).  ``fixes``: the GPS fixes of this cycle (``valid``, ``lat``, ``lon``, ``alt``, ``t``,
        ``fix_quality``, ``num_sats``, ``hdop``, ``speed``, ``course``).
        """
        task = NO_TASK if task is None else int(task)
        for fix in fixes:
            self._fix = fix
        remaining = self._remaining(battery)
        self._update_mode(pose, task, remaining)
        if self._slow.due(now):
            self._send(self.heartbeat())
        for name, every in self.streams.items():
            if (pose is not None or name not in POSE_STREAMS) and every.due(now):
                msg = self.message(name, now, pose, velocity, battery)
                if msg is not None:
                    self._send(msg)

    def heartbeat(self):
        m = self.m
        return self.mav.heartbeat_encode(m.MAV_TYPE_GROUND_ROVER, m.MAV_AUTOPILOT_ARDUPILOTMEGA, self.link.base_mode,
                                         self.link.custom_mode, self.link.system_status)

    def message(self, name: str, now: float, pose, velocity, battery):
        """Stream ``name`` as it stands at ``now`` (None: nothing to say, e.g. no pose yet)."""
        if name == "SYS_STATUS":
            return self._sys_status(battery, self._remaining(battery), pose is not None, now)
        if name == "GPS_RAW_INT":
            return self._gps_raw(now)
        if name == "HOME_POSITION":
            return self._home()
        if pose is None or not all(_finite(v) for v in pose[:2]):
            return None
        if name == "ATTITUDE":
            return self._attitude(now, pose)
        return self._position(name, now, pose, velocity)

    def interval(self, msg_id: int) -> int | None:
        """The interval (us) of stream ``msg_id``: -1 off; None: not a stream of this robot."""
        every = self.streams.get(self.stream_name(msg_id))
        if every is None:
            return None
        return -1 if every.period is None else int(round(every.period * 1e6))

    def set_interval(self, msg_id: int, interval_us: float) -> bool:
        """SET_MESSAGE_INTERVAL: ``interval_us`` > 0 the interval (at most MAX_RATE Hz), 0 the default, -1 off.
        False: not a stream of this robot, or a value the command does not define."""
        name = self.stream_name(msg_id)
        if name not in self.streams or not _finite(interval_us) or interval_us < -1 or -1 < interval_us < 0:
            return False
        every = self.streams[name]
        every.period = (STREAMS[name] if interval_us == 0 else None if interval_us == -1
                        else max(float(interval_us) / 1e6, 1.0 / MAX_RATE))
        every.next = None                        # the new rate starts now
        return True

    def stream_name(self, msg_id: int) -> str | None:
        try:
            return self.m.mavlink_map[int(msg_id)].msgname
        except (KeyError, TypeError, ValueError, AttributeError):
            return None

    # ------------------------------------------------------------------ pieces
    @staticmethod
    def _remaining(battery) -> float:
        charge = getattr(battery, "battery_charge", math.nan)
        cap = getattr(battery, "battery_capacity", math.nan)
        if _finite(charge) and _finite(cap) and cap > 0:
            return min(max(100.0 * charge / cap, 0.0), 100.0)
        return math.nan

    def _update_mode(self, pose, task: int, remaining: float) -> None:
        """HEARTBEAT base_mode, custom_mode and system_status for the state now (kept on the link, which
        also heartbeats the peers with them)."""
        m, link = self.m, self.link
        armed = bool(self.armed)
        base = m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | m.MAV_MODE_FLAG_AUTO_ENABLED
        if armed:
            base |= m.MAV_MODE_FLAG_SAFETY_ARMED
        link.base_mode = base
        if pose is None:
            link.custom_mode, status = CUSTOM_MODE_INITIALISING, m.MAV_STATE_CALIBRATING
        elif self.mode == "rtl":
            link.custom_mode, status = CUSTOM_MODE_RTL, m.MAV_STATE_ACTIVE if armed else m.MAV_STATE_STANDBY
        elif self.mode == "auto" and armed and (task != NO_TASK or self.busy):
            link.custom_mode = CUSTOM_MODE_AUTO
            status = m.MAV_STATE_ACTIVE if task != NO_TASK else m.MAV_STATE_STANDBY
        else:
            link.custom_mode, status = CUSTOM_MODE_HOLD, m.MAV_STATE_STANDBY
        link.system_status = m.MAV_STATE_CRITICAL if _critical(remaining) else status

    def _gps_state(self, now: float) -> tuple[int, object]:
        """(GPS_FIX_TYPE, the fix or None) at ``now``."""
        m, fix = self.m, self._fix
        if not self.gps:
            return m.GPS_FIX_TYPE_NO_GPS, None
        t = getattr(fix, "t", now)
        if fix is None or not getattr(fix, "valid", False) or not (_finite(t) and now - t <= GPS_STALE):
            return m.GPS_FIX_TYPE_NO_FIX, None
        quality = getattr(fix, "fix_quality", 1)
        kind = {2: m.GPS_FIX_TYPE_DGPS, 4: m.GPS_FIX_TYPE_RTK_FIXED, 5: m.GPS_FIX_TYPE_RTK_FLOAT}.get(quality)
        if kind is None:
            kind = m.GPS_FIX_TYPE_3D_FIX if _finite(getattr(fix, "alt", math.nan)) else m.GPS_FIX_TYPE_2D_FIX
        return kind, fix

    def _gps_raw(self, now: float):
        kind, fix = self._gps_state(now)
        t_us = int(max(now, 0.0) * 1e6)
        if fix is None:
            return self.mav.gps_raw_int_encode(t_us, kind, 0, 0, 0, 65535, 65535, 65535, 65535, 0)
        sats = int(getattr(fix, "num_sats", 0) or 0)
        hdop, speed, course = (getattr(fix, k, math.nan) for k in ("hdop", "speed", "course"))
        alt = fix.alt if _finite(fix.alt) else 0.0
        return self.mav.gps_raw_int_encode(
            t_us, kind, _clip(fix.lat * 1e7, -900000000, 900000000), _clip(fix.lon * 1e7, -1800000000, 1800000000),
            _clip(alt * 1000, -2**31, 2**31 - 1), _clip(hdop * 100, 0, 65534) if _finite(hdop) else 65535, 65535,
            _clip(speed * 100, 0, 65534) if _finite(speed) else 65535,
            _clip(math.degrees(course) % 360.0 * 100, 0, 35999) if _finite(course) else 65535,
            min(sats, 254) if sats > 0 else 255)

    def _home(self):
        """HOME_POSITION: where the robot started (its first pose), where RTL drives it; None before a pose."""
        if self.home is None:
            return None
        x, y = self.home
        lat, lon, alt = pymap3d.enu2geodetic(x, y, 0.0, self.lat0, self.lon0, self.alt0)
        return self.mav.home_position_encode(_clip(lat * 1e7, -900000000, 900000000),
                                             _clip(lon * 1e7, -1800000000, 1800000000),
                                             _clip(alt * 1000, -2**31, 2**31 - 1), y, x, 0.0, [1.0, 0.0, 0.0, 0.0],
                                             0.0, 0.0, 0.0)

    def _attitude(self, now: float, pose):
        theta = pose[2] if len(pose) > 2 else math.nan
        if not _finite(theta):
            return None
        yaw = math.remainder(math.pi / 2 - float(theta), 2 * math.pi)        # NED: 0 north, clockwise
        rate = 0.0
        if self._yaw is not None and now > self._yaw[0]:
            rate = math.remainder(yaw - self._yaw[1], 2 * math.pi) / (now - self._yaw[0])
        self._yaw = (now, yaw)
        return self.mav.attitude_encode(int(max(now, 0.0) * 1000) & 0xFFFFFFFF, 0.0, 0.0, yaw, 0.0, 0.0, rate)

    def _sys_status(self, battery, remaining: float, localized: bool, now: float):
        m, c = self.m, self.link.counters
        voltage = getattr(battery, "voltage", math.nan)
        current = getattr(battery, "current", math.nan)
        none_to_calibrate = m.MAV_SYS_STATUS_SENSOR_3D_GYRO | m.MAV_SYS_STATUS_SENSOR_3D_ACCEL | \
            m.MAV_SYS_STATUS_SENSOR_3D_MAG
        present = m.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS | m.MAV_SYS_STATUS_AHRS | none_to_calibrate
        enabled = m.MAV_SYS_STATUS_AHRS | none_to_calibrate
        failing = 0 if localized else m.MAV_SYS_STATUS_AHRS
        if self.gps:
            present |= m.MAV_SYS_STATUS_SENSOR_GPS
            enabled |= m.MAV_SYS_STATUS_SENSOR_GPS
            if self._gps_state(now)[1] is None:
                failing |= m.MAV_SYS_STATUS_SENSOR_GPS
        if self.armed:
            enabled |= m.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
        if getattr(battery, "faults", ()):              # the base reports a fault (a drive silent, in FAULT ...)
            failing |= m.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
        if _finite(voltage):
            present |= m.MAV_SYS_STATUS_SENSOR_BATTERY
            enabled |= m.MAV_SYS_STATUS_SENSOR_BATTERY
            if _critical(remaining):
                failing |= m.MAV_SYS_STATUS_SENSOR_BATTERY
        health = _all_sensor_bits(m) & ~failing
        dropped = c.bad_crc + c.parse_errors + c.unsigned_dropped + c.bad_signature_dropped + c.replayed_dropped
        total = dropped + c.received
        return self.mav.sys_status_encode(
            present, enabled, health,
            0,                                                        # load: not measured
            _clip(voltage * 1000, 0, 65534) if _finite(voltage) else 65535,            # mV
            _clip(-current * 100, -32768, 32767) if _finite(current) else -1,          # cA, + = drawn
            _clip(remaining, 0, 100) if _finite(remaining) else -1,                    # %
            _clip(10000 * dropped / total, 0, 10000) if total else 0,                   # c%
            min(dropped, 65535), 0, 0, 0, 0)

    def _position(self, name: str, now: float, pose, velocity):
        x, y = float(pose[0]), float(pose[1])
        theta = pose[2] if len(pose) > 2 else None
        ve, vn = (float(velocity[0]), float(velocity[1])) if velocity is not None else (0.0, 0.0)
        if not (math.isfinite(ve) and math.isfinite(vn)):
            ve = vn = 0.0
        t_ms = int(max(now, 0.0) * 1000) & 0xFFFFFFFF
        if name == "LOCAL_POSITION_NED":
            return self.mav.local_position_ned_encode(t_ms, y, x, 0.0, vn, ve, 0.0)
        lat, lon, alt = pymap3d.enu2geodetic(x, y, 0.0, self.lat0, self.lon0, self.alt0)
        hdg = 65535
        if _finite(theta):
            hdg = _clip(math.degrees(math.pi / 2 - theta) % 360.0 * 100, 0, 35999)
        return self.mav.global_position_int_encode(
            t_ms, _clip(lat * 1e7, -900000000, 900000000), _clip(lon * 1e7, -1800000000, 1800000000),
            _clip(alt * 1000, -2**31, 2**31 - 1), _clip((alt - self.alt0) * 1000, -2**31, 2**31 - 1),
            _clip(vn * 100, -32768, 32767), _clip(ve * 100, -32768, 32767), 0, hdg)

    def _send(self, mavmsg) -> None:
        if self.link.send_gcs(mavmsg):
            name = mavmsg.get_type()
            self.sent[name] = self.sent.get(name, 0) + 1
