"""``rendezvous``: ``robots`` robots meet at a point; the task is done once all of them have arrived.
It carries a ``value`` (what the fleet gains by doing it), which coalition auctions trade off against
the members' travel.

Mission item: MAV_CMD_WAYPOINT_USER_1 (31000, "user defined waypoint": a ground station shows it as a
waypoint), param1 = robots needed, param2 = value.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from runtime.config.build import rng
from runtime.tasks.model import Estimate, Profile, Travel

KIND = "rendezvous"
EXECUTOR = "runtime.execution.rendezvous:RendezvousExecutor"
MAV_CMD_WAYPOINT_USER_1 = 31000
COMMANDS = (MAV_CMD_WAYPOINT_USER_1,)
MAX_ROBOTS = 8


@dataclass(frozen=True)
class Rendezvous:
    x: float
    y: float
    robots: int = field(default=2, metadata=rng(1, MAX_ROBOTS))   # coalition size the task needs
    value: float = field(default=100.0, metadata=rng(0.0, None))   # worth (same unit as costs: metres)


Spec = Rendezvous


def estimate(spec: Rendezvous, profile: Profile, travel: Travel) -> Estimate:
    """This robot's share: its own travel to the point.  The coalition's time is its slowest member's."""
    d = travel(spec.x, spec.y)
    if not math.isfinite(d):
        return Estimate(math.inf, math.inf)
    return Estimate(d, d / profile.speed)


def from_item(command: int, params: tuple[float, float, float, float], x: float, y: float) -> Rendezvous:
    k, value = params[0], params[1]
    if not (math.isfinite(k) and float(k).is_integer() and 1 <= k <= MAX_ROBOTS):
        raise ValueError(f"param1 (robots needed): expected an integer 1..{MAX_ROBOTS}, got {k}")
    if not (math.isfinite(value) and value >= 0):
        raise ValueError(f"param2 (value): expected a finite number >= 0, got {value}")
    return Rendezvous(x, y, int(k), float(value))


def to_item(spec: Rendezvous) -> tuple[int, tuple[float, float, float, float]]:
    return MAV_CMD_WAYPOINT_USER_1, (float(spec.robots), float(spec.value), 0.0, 0.0)
