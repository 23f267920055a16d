"""``avoid_obstacles`` (paper 003 Section 3, Figs. 6-7): keep robot ``robot`` clear of obstacles, with range
data from any robot.  A separate task, allocated beside the robot's other tasks: its coalition is the
obstacle avoider on ``robot`` (Alg. 4) fed by an obstacle detector fed by a range-data reader, on that robot
or on another one (whose reader then keeps the region around ``robot`` in view, Alg. 3).

A task kind module, allocated by CoMutaR (:mod:`runtime.allocation.comutar`).  Mission item:
MAV_CMD_USER_1 (31010), param1 = the robot to protect, param2 = duration (s after the award; 0: until the
operator withdraws it).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from runtime.config.build import rng
from runtime.tasks.model import Estimate, Profile, Travel

KIND = "avoid_obstacles"
EXECUTOR = "runtime.execution.avoidance:AvoidanceExecutor"
MAV_CMD_USER_1 = 31010
COMMANDS = (MAV_CMD_USER_1,)
MAX_DURATION = 1e6


@dataclass(frozen=True)
class AvoidObstacles:
    robot: int = field(default=1, metadata=rng(1, 250))                    # the robot kept clear
    duration: float = field(default=0.0, metadata=rng(0.0, MAX_DURATION))  # s after the award; 0: until withdrawn


Spec = AvoidObstacles


def estimate(spec: AvoidObstacles, profile: Profile, travel: Travel) -> Estimate:
    return Estimate(0.0, spec.duration if spec.duration > 0 else math.inf)


def from_item(command: int, params: tuple[float, float, float, float], x: float, y: float) -> AvoidObstacles:
    robot, duration = params[0], params[1]
    if not (math.isfinite(robot) and float(robot).is_integer() and 1 <= robot <= 250):
        raise ValueError(f"param1 (robot): expected a robot id 1..250, got {robot}")
    if not (math.isfinite(duration) and 0 <= duration <= MAX_DURATION):
        raise ValueError(f"param2 (duration, s): expected a number 0..{MAX_DURATION:g}, got {duration}")
    return AvoidObstacles(int(robot), float(duration))


def to_item(spec: AvoidObstacles) -> tuple[int, tuple[float, float, float, float]]:
    return MAV_CMD_USER_1, (float(spec.robot), float(spec.duration), 0.0, 0.0)


@dataclass(frozen=True)
class Guidance:
    """What the allocation family tells an ``avoid_obstacles`` commitment's executor each cycle (data it writes;
    the executor never calls the agent)."""
    window: object                                 # runtime.control.cspace.Window: the robot's c-space
    avoider: float | None                          # the avoider's weight when this robot runs it, else None
    obstacles: object                              # the avoider's (M, 3) input discs; None: nothing fresh (stop)
    region: tuple | None                           # (robot, x, y, radius) a reader keeps in view, or None
    reader: float | None                           # that reader's weight ...
    sensor: object                                 # ... and its runtime.control.cspace.Sensor
    obstacles_any: object                          # (M, 3) discs: every obstacle the robot knows (for detours)
