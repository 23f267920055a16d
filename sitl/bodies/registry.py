"""Simulated bodies by kind: the only list of them.

A kind names ``module:Class``; the module (and pybullet) is imported when a world adds a body of that
kind.  :meth:`sitl.world.World.add_body` builds ``Class(client, robot_id, start, rng, gui=...,
wheel_radius_sigma=...)`` (pybullet client id, robot id, (x, y, yaw) in the world, a seeded
``numpy.random.Generator`` of its own, GUI shapes or not, the relative spread of its tyres' rolling radius)
and calls ``stepped()`` after every physics step and ``after_step(dt)`` every motor-sample period.

A new body is one module plus one line here.  Its class provides: that constructor; a ``radius``
class attribute (m, the circle holding the body; the world keeps starts that far inside its walls);
``pose() -> (x, y, yaw)`` ground truth; ``stepped()``; ``after_step(dt)``; and whatever its device
emulator reads (the Create OI device: ``set_wheel_speeds``, ``wheel_travel``, ``bumps``, ``wheel_drop``,
optionally ``battery``, ``motor_currents_ma``, ``cliffs``; the GPS device: ``pose``, ``velocity``).
Which kind a base type drives is its device's ``body_kind`` (:mod:`sitl.devices.registry`).
"""
from __future__ import annotations

from runtime.errors import InputError
from runtime.lazy import resolve

BODIES: dict[str, str] = {
    "create2": "sitl.bodies.create2:SimCreate2",     # iRobot Create 2 (also stands in for a Create 1)
    "pioneer3dx": "sitl.bodies.pioneer3dx:SimPioneer3DX",   # Pioneer 3-DX with its 16-sonar ring
    "candiff": "sitl.bodies.candiff:SimCanDiff",     # small industrial AMR, two CAN wheel drives
}


def body_class(kind: str) -> type:
    """The class of body ``kind`` (a key of :data:`BODIES`)."""
    if kind not in BODIES:
        raise InputError(f"body kind {kind!r}: expected one of {', '.join(BODIES)}")
    return resolve(BODIES[kind])
