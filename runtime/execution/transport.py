"""Carry an object to the delivery point, trip after trip: drive to the object, stand still while loading,
drive to the delivery point, stand still while unloading, and again, until the allocation agent ends the
commitment.  A trip's parameters (delivery point, load per trip, load time per wu, reach) come from the
commitment (see runtime/tasks/transport.py); a changed coalition reaches :meth:`recommit`, which keeps the
trip where it is, so a robot carrying a load never drops it because a partner joined or left.

Legs are driven in lanes (:func:`keep_lane`, ``lane`` m right of the straight line, default 1.2 robot radii):
robots going to an object and robots coming back from it do not meet head-on.

Progress: :data:`~runtime.tasks.transport.LOADED` after each load and
:data:`~runtime.tasks.transport.DELIVERED` after each unload, ``data={"wu": load}``.  A robot whose route is
blocked keeps trying (the avoidance behaviour and re-planning after a bump sort it out); the time lost is the
physical interference paper 000's model learns.
"""
from __future__ import annotations

import math

from runtime.control.arbiter import FollowPath
from runtime.control.pure_pursuit import PurePursuit
from runtime.tasks import Commitment, Progress
from runtime.tasks.transport import DELIVERED, LOADED

TO_OBJECT, LOADING, TO_DELIVERY, UNLOADING = "to_object", "loading", "to_delivery", "unloading"
DEFAULT_REACH = 0.3           # m
LANE_FACTOR = 1.2             # default lane offset: this many robot radii right of the straight line


def keep_lane(path: list, offset: float) -> list:
    """``path`` with each leg moved ``offset`` m to its right between its ends (it leaves and reaches the
    marks themselves along a taper of a quarter of the leg, at most 1 m): robots going and coming between the
    same two marks drive in two lanes and do not meet head-on.  Legs too short to taper stay as they are."""
    if offset <= 0 or len(path) < 2:
        return path
    out = [path[0]]
    for (x0, y0), (x1, y1) in zip(path, path[1:]):
        dx, dy = x1 - x0, y1 - y0
        length = math.hypot(dx, dy)
        taper = min(0.25 * length, 1.0)
        if taper >= offset:
            ux, uy = dx / length, dy / length
            rx, ry = uy * offset, -ux * offset                    # the right-hand normal
            out += [(x0 + ux * taper + rx, y0 + uy * taper + ry), (x1 - ux * taper + rx, y1 - uy * taper + ry)]
        out.append((x1, y1))
    return out


class TransportExecutor:
    def __init__(self, commitment: Commitment, ctx):
        self.ctx = ctx
        self.commitment = commitment
        self.task = commitment.task
        self.phase = TO_OBJECT
        self.follow = FollowPath(follower=self._pursuit())
        self.carrying = 0.0               # wu on board
        self.trips = 0                    # deliveries made
        self._dwell_until: float | None = None
        self._routed = False

    # ------------------------------------------------------------------ parameters
    @property
    def delivery(self) -> tuple[float, float]:
        d = self.commitment.param("delivery", (0.0, 0.0))
        return float(d[0]), float(d[1])

    @property
    def load(self) -> float:
        return float(self.commitment.param("load", 1.0))

    @property
    def load_time(self) -> float:
        return float(self.commitment.param("load_time", 0.0))

    @property
    def reach(self) -> float:
        return float(self.commitment.param("reach", DEFAULT_REACH))

    def _pursuit(self) -> PurePursuit:
        p = self.ctx.pursuit()
        p.goal_tolerance = max(p.goal_tolerance, float(self.commitment.param("reach", DEFAULT_REACH)))
        return p

    @property
    def lane(self) -> float:
        return float(self.commitment.param("lane", LANE_FACTOR * self.ctx.radius))

    def _route(self, pose) -> list:
        return keep_lane(self.ctx.planner.route(pose, self.goal), self.lane)

    @property
    def goal(self) -> tuple[float, float]:
        return self.task.position if self.phase in (TO_OBJECT, LOADING) else self.delivery

    @property
    def behaviours(self) -> list:
        return [self.follow]

    # ------------------------------------------------------------------ executive interface
    def recommit(self, commitment: Commitment, now: float) -> None:
        """Same task, new partners or parameters: carry on from where the trip is."""
        self.commitment = commitment
        self.follow.follower.goal_tolerance = max(self.ctx.goal_tolerance, self.reach)

    def begin(self, pose, now: float) -> None:
        if not self._routed and self.phase in (TO_OBJECT, TO_DELIVERY):
            self._routed = True
            self.follow.set_path(self._route(pose))

    def bump_ended(self, pose, now: float) -> None:
        if self.phase in (TO_OBJECT, TO_DELIVERY):
            self.follow.set_path(self._route(pose))

    def update(self, pose, now: float) -> list[Progress]:
        self.follow.update(pose, now)
        if self.phase in (TO_OBJECT, TO_DELIVERY):
            near = math.hypot(self.goal[0] - pose[0], self.goal[1] - pose[1]) <= self.reach
            if self.follow.done and near:
                self.phase = LOADING if self.phase == TO_OBJECT else UNLOADING
                self._dwell_until = now + self.load * self.load_time
                self.follow.set_path(None)        # stand still (the Stop behaviour votes for it)
            elif self.follow.done:                # stopped short (pushed, or the path ended off the mark)
                self.follow.set_path(self._route(pose))
            return []
        if now < self._dwell_until:
            return []
        if self.phase == LOADING:
            self.carrying = self.load
            self.phase = TO_DELIVERY
            out = [Progress(self.task.id, LOADED, now, data={"wu": self.load})]
        else:
            wu, self.carrying = self.carrying, 0.0
            self.trips += 1
            self.phase = TO_OBJECT
            out = [Progress(self.task.id, DELIVERED, now, data={"wu": wu})]
        self.follow.set_path(self._route(pose))
        return out

    def cancel(self, now: float) -> None:
        self.follow.set_path(None)
