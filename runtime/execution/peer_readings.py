"""Peers as range readings: where the fleet says the other robots stand, in the form a range sensor gives.

Every robot broadcasts its pose estimate in ``MRTA_ROBOT_STATE`` (at least once a second).  A robot with no
range sensor of its own (a Create, a CAN base) cannot see a peer parked in its way, and a parked robot
cannot see one that comes to it; from the peers' reports both can.  Each peer reported within ``max_age``
seconds and within ``max_range`` of the robot becomes readings on the near half of its body, a disc of the
robot's own radius (fleets here are of one size; the state message does not carry it): the point facing
the robot and two at 60 degrees either side, as ``(bearing, distance)`` in the robot frame like
:class:`runtime.drivers.base.BaseSensors` ``ranges``.  A report is a GPS-grade estimate up to a second old,
so the executive uses these only for the idle robot's making way (``Executive._make_way``), where a few tens
of centimetres do not matter, not to steer a moving robot.
"""
from __future__ import annotations

import math
from typing import Mapping

SIDES = (0.0, math.pi / 3, -math.pi / 3)     # rad around the direction from the peer's centre back to us


def readings(pose: tuple[float, float, float], peers: Mapping[int, tuple[float, float, float]], now: float,
             radius: float, max_age: float = 2.5, max_range: float = 2.0) -> tuple[tuple[float, float], ...]:
    """``peers``: robot id -> (x, y, time of the report) in the fleet frame.  Non-finite reports are skipped."""
    x, y, th = pose
    out = []
    for _, (px, py, at) in sorted(peers.items()):
        if not (math.isfinite(px) and math.isfinite(py)) or not 0.0 <= now - at <= max_age:
            continue
        dx, dy = px - x, py - y
        d = math.hypot(dx, dy)
        if d > max_range or d < 1e-9:
            continue
        back = math.atan2(-dy, -dx)
        for side in SIDES:
            sx, sy = px + radius * math.cos(back + side), py + radius * math.sin(back + side)
            rx, ry = sx - x, sy - y
            out.append((math.remainder(math.atan2(ry, rx) - th, math.tau), math.hypot(rx, ry)))
    return tuple(out)
