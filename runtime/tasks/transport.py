"""``transport``: move an object of ``weight`` weight units (wu) from its place to the fleet's delivery point
before its ``deadline`` (seconds after the task appeared), for a utility of up to ``u_max`` (paper 000's
foraging task).  Robots carry at most their load capacity per trip and load and unload for a set time per wu;
several robots may share one object.  Objects are virtual (marks on the floor): the coalition's leader keeps
the weight left, not the world.

Where the weight goes, how much one robot carries and how long loading takes are the robot's and the fleet's,
not the task's: the allocation agent hands them to the executor in the commitment's ``params``:

* ``delivery`` - ``(x, y)`` of the delivery point, fleet frame, m
* ``load`` - wu this robot carries per trip
* ``load_time`` - s per wu to load, and again to unload
* ``reach`` - m: the robot loads once its centre is this close to the object
* ``delivery_reach`` - m: ... and unloads once this close to the delivery point (the delivery area's radius;
  default ``reach``)

The executor reports :data:`LOADED` after each load and :data:`DELIVERED` after each unload, with the wu in
``Progress.data["wu"]``; it never reports ``done``: the agent ends the commitment.

Mission item: MAV_CMD_WAYPOINT_USER_2 (31001) at the object, param1 = weight (wu), param2 = deadline (s),
param3 = maximum utility.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from runtime.config.build import rng
from runtime.tasks.model import Estimate, Profile, Travel

KIND = "transport"
EXECUTOR = "runtime.execution.transport:TransportExecutor"
MAV_CMD_WAYPOINT_USER_2 = 31001
COMMANDS = (MAV_CMD_WAYPOINT_USER_2,)
LOADED, DELIVERED = "loaded", "delivered"          # Progress events of a transport
MAX_WEIGHT = 1e6
MAX_DEADLINE = 1e6                                  # s (11.6 days)
MAX_UTILITY = 1e9
DEFAULT_REACH = 0.3                                 # m, a commitment's ``reach`` when it gives none


def mark_reach(commitment, at_object: bool) -> float:
    """How close to its mark a robot works under ``commitment``: ``reach`` at the object; ``delivery_reach``
    (default ``reach``) at the delivery point."""
    reach = float(commitment.param("reach", DEFAULT_REACH))
    return reach if at_object else float(commitment.param("delivery_reach", reach))


@dataclass(frozen=True)
class Transport:
    x: float                                                           # m, the object, fleet frame
    y: float
    weight: float = field(default=40.0, metadata=rng(0.0, MAX_WEIGHT, lo_open=True))     # wu
    deadline: float = field(default=108.0, metadata=rng(0.0, MAX_DEADLINE, lo_open=True))  # s after it appeared
    u_max: float = field(default=100.0, metadata=rng(0.0, MAX_UTILITY))   # utility if delivered in time


Spec = Transport


def estimate(spec: Transport, profile: Profile, travel: Travel) -> Estimate:
    """This robot's way to the object; what the whole transport takes depends on the coalition and is the
    allocation method's to predict (paper 000, eqs. 2-5)."""
    d = travel(spec.x, spec.y)
    if not math.isfinite(d):
        return Estimate(math.inf, math.inf)
    return Estimate(d, d / profile.speed)


def _number(value: float, name: str, lo: float, hi: float, lo_open: bool = False) -> float:
    ok = math.isfinite(value) and (value > lo if lo_open else value >= lo) and value <= hi
    if not ok:
        bound = f"> {lo:g}" if lo_open else f">= {lo:g}"
        raise ValueError(f"{name}: expected a number {bound} and <= {hi:g}, got {value}")
    return float(value)


def from_item(command: int, params: tuple[float, float, float, float], x: float, y: float) -> Transport:
    weight = _number(params[0], "param1 (weight, wu)", 0.0, MAX_WEIGHT, lo_open=True)
    deadline = _number(params[1], "param2 (deadline, s)", 0.0, MAX_DEADLINE, lo_open=True)
    u_max = _number(params[2], "param3 (maximum utility)", 0.0, MAX_UTILITY)
    return Transport(x, y, weight, deadline, u_max)


def to_item(spec: Transport) -> tuple[int, tuple[float, float, float, float]]:
    return MAV_CMD_WAYPOINT_USER_2, (float(spec.weight), float(spec.deadline), float(spec.u_max), 0.0)
