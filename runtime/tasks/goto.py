"""``goto``: drive to a point; done on arrival, after holding there ``hold`` seconds, or never (station
keeping: a formation position) when ``hold`` is None.

Mission items: MAV_CMD_NAV_WAYPOINT (param1 = hold time, s) and MAV_CMD_NAV_LOITER_UNLIM (hold for ever).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

from runtime.config.build import rng
from runtime.tasks.model import Estimate, Profile, Travel

KIND = "goto"
EXECUTOR = "runtime.execution.goto:GotoExecutor"
MAV_CMD_NAV_WAYPOINT = 16
MAV_CMD_NAV_LOITER_UNLIM = 17
COMMANDS = (MAV_CMD_NAV_WAYPOINT, MAV_CMD_NAV_LOITER_UNLIM)


@dataclass(frozen=True)
class Goto:
    x: float                      # m, east in the fleet frame
    y: float                      # m, north
    hold: Optional[float] = field(default=0.0, metadata=rng(0.0, None))   # s to stay there; None: for ever


Spec = Goto


def estimate(spec: Goto, profile: Profile, travel: Travel) -> Estimate:
    d = travel(spec.x, spec.y)
    if not math.isfinite(d):
        return Estimate(math.inf, math.inf)
    return Estimate(d, d / profile.speed + (spec.hold or 0.0))


def from_item(command: int, params: tuple[float, float, float, float], x: float, y: float) -> Goto:
    """The spec of a mission item (position already in the fleet frame, metres)."""
    if command == MAV_CMD_NAV_LOITER_UNLIM:
        return Goto(x, y, None)
    hold = params[0]
    return Goto(x, y, float(hold) if math.isfinite(hold) and hold > 0 else 0.0)


def to_item(spec: Goto) -> tuple[int, tuple[float, float, float, float]]:
    if spec.hold is None:
        return MAV_CMD_NAV_LOITER_UNLIM, (0.0, 0.0, 0.0, 0.0)
    return MAV_CMD_NAV_WAYPOINT, (float(spec.hold), 0.0, 0.0, 0.0)
