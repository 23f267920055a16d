"""SITL device emulators by ``base.type``: the same keys as :data:`runtime.drivers.registry.BASES`.

The launcher, for each robot, asks :func:`body_kind` which body to put in the world
(:meth:`sitl.world.World.add_body`), builds the device with :func:`make_device`, serves it with
``device.service(t)`` every physics step and merges ``device.endpoint()`` into the robot config it
writes (and the manifest); ``device.close()`` at the end.

A new base's emulator is one module plus one line in :data:`DEVICES`.  Its class provides:

* the classmethod ``from_config(body, cfg, robot_id)``: the device for ``base:`` config ``cfg`` (the
  driver's ``Config``) on ``body``, on a link of its own (a pty from :mod:`sitl.devices.pty_link`);
* the static or class method ``body_kind(cfg) -> str``: a key of :data:`sitl.bodies.registry.BODIES`;
* ``service(now)``: sample the body, act on the driver's bytes, send what is due at sim time ``now``;
* ``close()``: close the link;
* ``endpoint() -> dict``: the ``base:`` keys that point the driver at the device, e.g.
  ``{"port": "/dev/pts/5", "baudrate": 115200}``; they must load as that driver's ``Config``;
* optionally ``allow_clock_lag(seconds)``: a device that times its driver's silence in sim time (a CiA 402 drive's
  heartbeat consumer) adds ``seconds`` to the window.  The launcher calls it when each daemon runs in a process of
  its own, where the world may run that far ahead of a daemon's last read of the clock.
"""
from __future__ import annotations

from runtime.errors import InputError
from runtime.lazy import resolve

DEVICES: dict[str, str] = {
    "create_oi": "sitl.devices.create_oi:CreateOIDevice",   # Create 2 / Create 1 Open Interface on a pty
    "arcos": "sitl.devices.arcos:ArcosDevice",               # Pioneer 3-DX ARCOS server on a pty or TCP port
    "cia402": "sitl.devices.cia402:Cia402Device",           # two CiA 402 drives on the socketcand hub
}

# Sensor emulators by ``sensors[].type`` (the keys of runtime.drivers.registry.SENSORS): ``from_config(body, cfg,
# robot_id)`` on the robot's body, ``service(now)``, ``endpoint()`` and ``close()`` as a base's device.
SENSOR_DEVICES: dict[str, str] = {
    "nmea_gps": "sitl.devices.nmea_gps:NmeaGpsDevice",      # NMEA GPS on a pty, fixes from the body's true pose
    "rplidar": "sitl.devices.rplidar:RplidarDevice",        # RPLIDAR A1/A2 on a pty, beams from the world's ray casts
}


def make_sensor_device(cfg, body, robot_id: int):
    """The emulator of ``sensors:`` entry ``cfg`` on ``body``, ready to serve."""
    if cfg.type not in SENSOR_DEVICES:
        raise InputError(f"sensors type {cfg.type!r}: expected one with a SITL device, one of "
                         f"{', '.join(SENSOR_DEVICES)}")
    return resolve(SENSOR_DEVICES[cfg.type]).from_config(body, cfg, robot_id)


def device_class(type_name: str) -> type:
    """The emulator class of ``base.type`` ``type_name``."""
    if type_name not in DEVICES:
        raise InputError(f"base.type {type_name!r}: expected one with a SITL device, one of {', '.join(DEVICES)}")
    return resolve(DEVICES[type_name])


def body_kind(base_cfg) -> str:
    """Which body (:data:`sitl.bodies.registry.BODIES`) a robot with ``base:`` config ``base_cfg`` needs."""
    return device_class(base_cfg.type).body_kind(base_cfg)


def make_device(base_cfg, body, robot_id: int):
    """The emulator for ``base_cfg`` on ``body`` (built from ``body_kind(base_cfg)``), ready to serve."""
    return device_class(base_cfg.type).from_config(body, base_cfg, robot_id)
