"""Base drivers by ``base.type``: the only list of them.

Each entry names ``module:Class``; the module is imported only when that type is used (as python-can's
``BACKENDS`` does), so a robot that drives a Create never imports the CAN stack.  The robot config's
``base:`` section is a union chosen by ``base.type`` over :func:`config_classes`; a wrong type names
these keys.

A new base is one driver module plus one line in :data:`BASES` (and, for the SITL, one device module
plus one line in :mod:`sitl.devices.registry`).  The driver module provides one class that

* subclasses :class:`runtime.drivers.base.MobileBase` and calls
  ``super().__init__(footprint, watchdog, log)`` with its :class:`~runtime.drivers.base.Footprint`
  (radius, track, max_speed, max_turn_rate), the command watchdog in seconds and
  ``runtime.log.get_logger(<name>, robot_id)``;
* has ``Config``: a frozen dataclass, the schema of the ``base:`` section, whose first field is
  ``type: Literal["<its key here>"] = "<its key here>"`` and whose other fields all have defaults
  (ranges in ``field(metadata=rng(lo, hi))``), e.g. ``port``, ``watchdog``, ``max_speed``;
* has the classmethod ``from_config(cfg, robot_id)`` returning an unopened driver;
* implements ``_open(now)``, ``_close()``, ``_read(now) -> bool`` and ``_command(v, w, now) -> bool``
  (see :mod:`runtime.drivers.base`), filling ``odometry``, ``sensors`` (``ranges`` and ``faults`` if it
  has them) and the link counters of ``stats`` (``frames``, ``bad_checksum``, ``dropped_bytes``; its
  own in ``stats.extra``).
"""
from __future__ import annotations

from runtime.lazy import resolve

BASES: dict[str, str] = {
    "create_oi": "runtime.drivers.create_oi:CreateOI",      # iRobot Create 2 / Create 1, Open Interface
    "arcos": "runtime.drivers.arcos:ArcosBase",              # Pioneer 3-DX (ARCOS), serial or socket://
    "cia402": "runtime.drivers.cia402:Cia402Base",          # two CiA 402 wheel drives on CAN (canopen)
}


# Sensors by ``sensors[].type``: a driver class with ``Config`` (first field ``type: Literal[<key>]``),
# ``from_config(cfg, robot_id)``, ``open(now)``, ``poll(now)``, ``close()``, ``usable``, ``kind`` (what the
# allocation is told the robot carries: "gps", "laser") and ``reports``: "fixes" (poll() returns position fixes for
# the pose estimate) or "ranges" (``ranges()``: BaseSensors.ranges pairs, merged with the base's).  The Pioneer's
# sonar ring is part of its base (``MobileBase.sensor_kinds``), not an entry.
SENSORS: dict[str, str] = {
    "nmea_gps": "runtime.drivers.nmea_gps:NmeaGps",          # NMEA 0183 GPS receiver, serial
    "rplidar": "runtime.drivers.rplidar:Rplidar",            # Slamtec RPLIDAR A1/A2 laser scanner, serial
}


def sensor_class(type_name: str) -> type:
    """The driver class of ``sensors[].type`` ``type_name`` (a key of :data:`SENSORS`)."""
    return resolve(SENSORS[type_name])


def sensor_config_classes() -> dict[str, type]:
    """``{sensors[].type: its config dataclass}`` (the robot config's ``sensors:`` entries)."""
    return {name: sensor_class(name).Config for name in SENSORS}


def open_sensor(cfg, robot_id: int):
    """The driver for ``sensors:`` entry ``cfg``, not yet opened (an NMEA GPS opens its port when built)."""
    return sensor_class(cfg.type).from_config(cfg, robot_id)


def driver_class(type_name: str) -> type:
    """The driver class of ``base.type`` ``type_name`` (a key of :data:`BASES`)."""
    return resolve(BASES[type_name])


def config_classes() -> dict[str, type]:
    """``{base.type: its config dataclass}`` (the robot config's ``base:`` union)."""
    return {name: driver_class(name).Config for name in BASES}


def open_base(cfg, robot_id: int):
    """The driver for ``cfg`` (a ``base:`` config of any registered type), not yet opened."""
    return driver_class(cfg.type).from_config(cfg, robot_id)
