"""Transport trips on the in-memory bus without physics: for tests and fast sweeps of the dr family.

:class:`TransportRobot` is a :class:`~runtime.fleet.simulate.SimRobot` whose execution of a ``transport``
commitment is what :class:`~runtime.execution.transport.TransportExecutor` does, kinematically: straight to the
object at the robot's speed, a dwell of ``load * load_time`` once within ``reach``, ``loaded`` (``wu`` = load),
straight to the delivery point, a dwell, ``delivered``, and again, until the agent ends the commitment.  A
changed commitment of the same task carries on where the trip is (a load on board survives a change of group).
Bodies do not collide, so there is no physical interference: I measured here is the model's, not the world's.
Other kinds are driven as SimRobot drives them.

:class:`TransportFleet` is a :class:`~runtime.fleet.simulate.SimFleet` of such robots running ``dr`` by default;
:meth:`TransportFleet.delivered` sums what each robot unloaded per task (the weight it was granted), and
:meth:`TransportFleet.put` hands objects in as an operator's mission item 31001 would.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from runtime.fleet.simulate import MAV_FRAME_LOCAL_ENU, SimFleet, SimRobot
from runtime.tasks import Commitment, Progress
from runtime.tasks.transport import DELIVERED, LOADED, MAV_CMD_WAYPOINT_USER_2, mark_reach

TO_OBJECT, LOADING, TO_DELIVERY, UNLOADING = "to_object", "loading", "to_delivery", "unloading"


@dataclass
class Trip:
    commitment: Commitment
    phase: str = TO_OBJECT
    until: float = math.inf
    carrying: float = 0.0

    def goal(self) -> tuple[float, float]:
        if self.phase in (TO_OBJECT, LOADING):
            return self.commitment.task.position
        d = self.commitment.param("delivery", (0.0, 0.0))
        return float(d[0]), float(d[1])


class TransportRobot(SimRobot):
    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.trip: Trip | None = None
        self.loads = 0                                # loads made (execution's count)

    def _drive(self, dt: float, now: float) -> list:
        commitments = self.agent.commitments if self.node.armed else ()
        c = commitments[0] if commitments else None
        if c is None or c.task.kind != "transport":
            self.trip = None
            return super()._drive(dt, now)
        if self.trip is None or self.trip.commitment.task_id != c.task_id:
            self.trip = Trip(c)
        self.trip.commitment = c
        trip = self.trip
        if trip.phase in (TO_OBJECT, TO_DELIVERY):
            gx, gy = trip.goal()
            d = math.hypot(gx - self.pos[0], gy - self.pos[1])
            reach = mark_reach(c, at_object=trip.phase == TO_OBJECT)
            step = min(max(0.0, d - reach * 0.5), self.speed * dt)
            if d > 0:
                self.pos = (self.pos[0] + (gx - self.pos[0]) * step / d, self.pos[1] + (gy - self.pos[1]) * step / d)
                self.driven += step
            if d - step <= reach:
                trip.phase = LOADING if trip.phase == TO_OBJECT else UNLOADING
                trip.until = now + float(c.param("load", 1.0)) * float(c.param("load_time", 0.0))
            return []
        if now < trip.until:
            return []
        if trip.phase == LOADING:
            trip.carrying, trip.phase = float(c.param("load", 1.0)), TO_DELIVERY
            self.loads += 1
            return self.node.on_progress(Progress(c.task_id, LOADED, now, data={"wu": trip.carrying}), now)
        wu, trip.carrying, trip.phase = trip.carrying, 0.0, TO_OBJECT
        return self.node.on_progress(Progress(c.task_id, DELIVERED, now, data={"wu": wu}), now)


@dataclass
class TransportFleet(SimFleet):
    method: str = "dr"
    robot_class: type = TransportRobot

    def put(self, to: int, objects, now: float | None = None) -> list[int]:
        """Objects ``(x, y, weight wu, deadline s, u_max)`` handed to robot ``to``; returns their task ids."""
        now = self.bus.now if now is None else now
        node = self.robots[to].node
        before = set(node.table.entries)
        items = [(MAV_CMD_WAYPOINT_USER_2, MAV_FRAME_LOCAL_ENU, (w, dl, u, 0.0), x, y) for x, y, w, dl, u in objects]
        self.bus.send(node.add_items(items, now), now)
        return sorted(set(node.table.entries) - before)

    def delivered(self) -> dict[int, float]:
        """task -> wu delivered, summed over every robot's own account (the loads it was granted and unloaded)."""
        out: dict[int, float] = {}
        for r in self.robots.values():
            for task, e in r.agent.accounts.items():
                out[task] = out.get(task, 0.0) + e.delivered
        return out
