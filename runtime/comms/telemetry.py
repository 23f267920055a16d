"""Ground-station telemetry of one robot over its :class:`~runtime.comms.link.MavlinkLink`.

Sent by :meth:`GcsTelemetry.tick` (system id = robot id, component 1):

* 1 Hz: HEARTBEAT (MAV_TYPE_GROUND_ROVER, MAV_AUTOPILOT_GENERIC), SYS_STATUS (battery, comm errors)
  and the robot's allocation state as MRTA_STATUS (so a ground station sees the assignment);
* 5 Hz, once a pose exists: GLOBAL_POSITION_INT (pymap3d ENU -> geodetic around the datum) and
  LOCAL_POSITION_NED (ENU -> NED: x north, y east, z down).

HEARTBEAT meaning: base_mode always has AUTO (tasks come from auctions) and CUSTOM_MODE; SAFETY_ARMED
while the robot holds a task (it may drive).  custom_mode is the allocation phase (CUSTOM_MODE_*).
system_status: CALIBRATING without a pose estimate, CRITICAL below 15 % battery, ACTIVE while holding a
task, STANDBY otherwise.  time_boot_ms is ``now`` in milliseconds (clock seconds: monotonic time since
boot on a robot, simulated seconds in SITL).
"""
from __future__ import annotations

import math

import pymap3d

from runtime.allocation.formation.messages import BROADCAST, Status
from runtime.comms import codec

CUSTOM_MODE_LOCALIZING = 0      # no pose estimate yet
CUSTOM_MODE_ALLOCATING = 1      # taking part in auctions, allocation not converged
CUSTOM_MODE_CONVERGED = 2       # the robot believes the allocation has converged
NO_TASK = 0xFFFF
LOW_BATTERY = 15.0              # % remaining below which the state is MAV_STATE_CRITICAL
SLOW_PERIOD = 1.0               # s: HEARTBEAT, SYS_STATUS, MRTA_STATUS
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
    def __init__(self, link, robot_id: int, datum):
        self.link = link
        self.robot_id = int(robot_id)
        self.lat0, self.lon0, self.alt0 = _datum(datum)
        self.m = link.module
        self.mav = link.mav
        self._slow = _Every(SLOW_PERIOD)
        self._fast = _Every(FAST_PERIOD)
        self.sent: dict[str, int] = {}

    # ------------------------------------------------------------------ public
    def tick(self, now: float, pose, velocity, battery, status, converged: bool | None = None) -> None:
        """Send whatever is due at ``now``.

        ``pose``: (x east, y north, heading rad CCW from east) in the fleet frame, or None.
        ``velocity``: (v east, v north) m/s.  ``battery``: an object with ``voltage`` (V),
        ``current`` (A, negative = discharging), ``battery_charge`` and ``battery_capacity``
        (e.g. :class:`~runtime.drivers.base.BaseSensors`), or None.  ``status``: a
        :class:`~runtime.allocation.formation.messages.Status`, or the task held (None = none) with
        ``converged`` beside it.
        """
        task, conv = self._allocation(status, converged)
        remaining = self._remaining(battery)
        self._update_mode(pose, task, conv, remaining)
        if self._slow.due(now):
            self._send(self.link.heartbeat())
            self._send(self._sys_status(battery, remaining))
            self._send(codec.to_mavlink(Status(self.robot_id, BROADCAST, 0, task, conv), self.m))
        if pose is not None and self._fast.due(now):
            self._send_position(now, pose, velocity)

    # ------------------------------------------------------------------ pieces
    @staticmethod
    def _allocation(status, converged) -> tuple[int, bool]:
        if isinstance(status, Status):
            return int(status.task), bool(status.converged)
        task = NO_TASK if status is None else int(status)
        return task, bool(converged)

    @staticmethod
    def _remaining(battery) -> float:
        charge = getattr(battery, "battery_charge", math.nan)
        cap = getattr(battery, "battery_capacity", math.nan)
        if _finite(charge) and _finite(cap) and cap > 0:
            return min(max(100.0 * charge / cap, 0.0), 100.0)
        return math.nan

    def _update_mode(self, pose, task: int, conv: bool, remaining: float) -> None:
        m, link = self.m, self.link
        holding = task != NO_TASK
        base = m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | m.MAV_MODE_FLAG_AUTO_ENABLED
        if holding:
            base |= m.MAV_MODE_FLAG_SAFETY_ARMED
        link.base_mode = base
        if pose is None:
            link.custom_mode, link.system_status = CUSTOM_MODE_LOCALIZING, m.MAV_STATE_CALIBRATING
            return
        link.custom_mode = CUSTOM_MODE_CONVERGED if conv else CUSTOM_MODE_ALLOCATING
        if _finite(remaining) and remaining < LOW_BATTERY:
            link.system_status = m.MAV_STATE_CRITICAL
        else:
            link.system_status = m.MAV_STATE_ACTIVE if holding else m.MAV_STATE_STANDBY

    def _sys_status(self, battery, remaining: float):
        m, c = self.m, self.link.counters
        voltage = getattr(battery, "voltage", math.nan)
        current = getattr(battery, "current", math.nan)
        sensors = m.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
        health = sensors
        if _finite(voltage):
            sensors |= m.MAV_SYS_STATUS_SENSOR_BATTERY
            if not (_finite(remaining) and remaining < LOW_BATTERY):
                health |= m.MAV_SYS_STATUS_SENSOR_BATTERY
        dropped = c.bad_crc + c.parse_errors + c.unsigned_dropped + c.bad_signature_dropped
        total = dropped + c.received
        return self.mav.sys_status_encode(
            sensors, sensors, health,
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
