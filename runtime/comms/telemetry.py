"""Ground-station telemetry of one robot over its :class:`~runtime.comms.link.MavlinkLink`.

Sent by :meth:`GcsTelemetry.tick` (system id = robot id, component 1):

* 1 Hz: HEARTBEAT (MAV_TYPE_GROUND_ROVER, MAV_AUTOPILOT_GENERIC) and SYS_STATUS (battery, comm errors);
  (the robot's tasks go to the ground station as MRTA_ROBOT_STATE, from :mod:`runtime.comms.ground`);
* 5 Hz, once a pose exists: GLOBAL_POSITION_INT (pymap3d ENU -> geodetic around the datum) and
  LOCAL_POSITION_NED (ENU -> NED: x north, y east, z down).

HEARTBEAT, chosen so a stock MAVProxy and QGroundControl show something true:

* custom_mode uses ArduPilot Rover's mode numbers, because that is how they are read: pymavlink's
  ``mode_string_v10`` (MAVProxy's prompt and "Mode X" announcements) looks custom_mode up in
  ``mode_mapping_rover`` for *any* non-PX4 autopilot whose type is GROUND_ROVER, whenever base_mode has
  CUSTOM_MODE_ENABLED.  (The custom modes 0/1/2 sent before read as MANUAL/ACRO/LEARNING.)  Three of
  its names say what our robot does: INITIALISING (16) while localizing (no pose yet), AUTO (10) while
  it is armed and holds a task (it drives to it), HOLD (4) otherwise (no task, or disarmed: it stands).
  Rover has no name for an auction phase: allocating vs executing is in MRTA_ROBOT_STATE.state.
  QGroundControl's generic firmware plugin shows "Custom:0xa"-style names for these until it learns
  names from AVAILABLE_MODES, which the project dialect (common.xml only) cannot send.
* base_mode: CUSTOM_MODE_ENABLED (so the above is read), AUTO_ENABLED always (the robot finds its own
  goals: tasks come from auctions, there is no manual mode), SAFETY_ARMED iff :attr:`GcsTelemetry.armed`
  (the operator allows it to drive; independent of holding a task).  MAVProxy prints ARMED/DISARMED
  from that bit alone (mavutil ``motors_armed``).
* system_status: CRITICAL below 15 % battery (whatever else holds), CALIBRATING without a pose
  estimate, ACTIVE while armed with a task (motors engaged), STANDBY otherwise.

SYS_STATUS sensor bits: present = MOTOR_OUTPUTS, AHRS (the pose estimate) and BATTERY (when the base
reports a voltage); enabled = AHRS, BATTERY, and MOTOR_OUTPUTS only while armed (MAVProxy's console
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
CUSTOM_MODE_INITIALISING = 16   # localizing: no pose estimate yet
NO_TASK = 0xFFFF
LOW_BATTERY = 15.0              # % remaining below which the state is MAV_STATE_CRITICAL
SLOW_PERIOD = 1.0               # s: HEARTBEAT, SYS_STATUS
FAST_PERIOD = 0.2               # s: GLOBAL_POSITION_INT, LOCAL_POSITION_NED


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
    """Due once per ``period`` of the injected clock, without bursts after a pause."""

    def __init__(self, period: float):
        self.period = period
        self.next: float | None = None

    def due(self, now: float) -> bool:
        if self.next is not None and now < self.next:
            return False
        nxt = (now if self.next is None else self.next) + self.period
        self.next = nxt if nxt > now else now + self.period
        return True


class GcsTelemetry:
    def __init__(self, link, robot_id: int, datum, *, armed: bool = True):
        self.link = link
        self.robot_id = int(robot_id)
        self.lat0, self.lon0, self.alt0 = _datum(datum)
        self.m = link.module
        self.mav = link.mav
        self._slow = _Every(SLOW_PERIOD)
        self._fast = _Every(FAST_PERIOD)
        self.sent: dict[str, int] = {}
        # allowed to drive (HEARTBEAT SAFETY_ARMED); the daemon sets it, e.g. False on an operator stop.
        # True by default: nothing but holding a task gates driving in this runtime today.
        self.armed = bool(armed)
        self._update_mode(None, NO_TASK, math.nan)

    # ------------------------------------------------------------------ public
    def tick(self, now: float, pose, velocity, battery, task: int | None) -> None:
        """Send whatever is due at ``now``.

        ``pose``: (x east, y north, heading rad CCW from east) in the fleet frame, or None.
        ``velocity``: (v east, v north) m/s.  ``battery``: an object with ``voltage`` (V),
        ``current`` (A, negative = discharging), ``battery_charge`` and ``battery_capacity``
        (e.g. :class:`~runtime.drivers.base.BaseSensors`), or None.  ``task``: the task the robot works
        on (None: none).
        """
        task = NO_TASK if task is None else int(task)
        remaining = self._remaining(battery)
        self._update_mode(pose, task, remaining)
        if self._slow.due(now):
            self._send(self.link.heartbeat())
            self._send(self._sys_status(battery, remaining, pose is not None))
        if pose is not None and self._fast.due(now):
            self._send_position(now, pose, velocity)

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
        driving = armed and task != NO_TASK
        base = m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | m.MAV_MODE_FLAG_AUTO_ENABLED
        if armed:
            base |= m.MAV_MODE_FLAG_SAFETY_ARMED
        link.base_mode = base
        if pose is None:
            link.custom_mode, status = CUSTOM_MODE_INITIALISING, m.MAV_STATE_CALIBRATING
        elif driving:
            link.custom_mode, status = CUSTOM_MODE_AUTO, m.MAV_STATE_ACTIVE
        else:
            link.custom_mode, status = CUSTOM_MODE_HOLD, m.MAV_STATE_STANDBY
        link.system_status = m.MAV_STATE_CRITICAL if _critical(remaining) else status

    def _sys_status(self, battery, remaining: float, localized: bool):
        m, c = self.m, self.link.counters
        voltage = getattr(battery, "voltage", math.nan)
        current = getattr(battery, "current", math.nan)
        present = m.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS | m.MAV_SYS_STATUS_AHRS
        enabled = m.MAV_SYS_STATUS_AHRS
        failing = 0 if localized else m.MAV_SYS_STATUS_AHRS
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

    def _send_position(self, now: float, pose, velocity) -> None:
        x, y = float(pose[0]), float(pose[1])
        theta = pose[2] if len(pose) > 2 else None
        ve, vn = (float(velocity[0]), float(velocity[1])) if velocity is not None else (0.0, 0.0)
        if not (math.isfinite(x) and math.isfinite(y)):
            return
        if not (math.isfinite(ve) and math.isfinite(vn)):
            ve = vn = 0.0
        t_ms = int(max(now, 0.0) * 1000) & 0xFFFFFFFF
        lat, lon, alt = pymap3d.enu2geodetic(x, y, 0.0, self.lat0, self.lon0, self.alt0)
        hdg = 65535
        if _finite(theta):
            hdg = _clip(math.degrees(math.pi / 2 - theta) % 360.0 * 100, 0, 35999)
        self._send(self.mav.global_position_int_encode(
            t_ms, _clip(lat * 1e7, -900000000, 900000000), _clip(lon * 1e7, -1800000000, 1800000000),
            _clip(alt * 1000, -2**31, 2**31 - 1), _clip((alt - self.alt0) * 1000, -2**31, 2**31 - 1),
            _clip(vn * 100, -32768, 32767), _clip(ve * 100, -32768, 32767), 0, hdg))
        self._send(self.mav.local_position_ned_encode(t_ms, y, x, 0.0, vn, ve, 0.0))

    def _send(self, mavmsg) -> None:
        if self.link.send_gcs(mavmsg):
            name = mavmsg.get_type()
            self.sent[name] = self.sent.get(name, 0) + 1
