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

from runtime.control.behaviours import FollowPath
from runtime.control.pure_pursuit import PurePursuit
from runtime.execution.executor import Executor
from runtime.tasks import Commitment, Progress
from runtime.tasks.transport import DELIVERED, LOADED, mark_reach

TO_OBJECT, LOADING, TO_DELIVERY, UNLOADING = "to_object", "loading", "to_delivery", "unloading"
TIP_POINTS = 6                # segments per quarter turn of a circuit (a leg goes on one quarter turn past its tip)
LANE_FACTOR = 1.6             # default lane offset: this many robot radii right of the straight line
TIP_FACTOR = 0.85             # a circuit's tip lies this share of reach short of its mark
LOOKAHEAD_FACTOR = 0.5        # pure pursuit looks ahead at most this share of the lane (the circuit's turn radius)
SPACING_FACTOR = 5.2          # a transport's circuit (about twice the marks' distance round) holds one robot per
                              # this many robot radii (1.3 m for a Pioneer); more partners wait their turn
CIRCUIT_MAX = 3               # ... and at most this many (the delivery point is shared with every other transport)
HOLD_FACTOR = 6.0             # a waiting robot stands this many radii beside the object's turn (off the circuit) ...
HOLD_BACK_FACTOR = 2.4        # ... this many radii short of the object, towards the delivery point (inside the
                              # arena, from an object near a wall) ...
HOLD_GAP_FACTOR = 2.6         # ... and this many nearer the delivery point per robot ahead of it in the queue (a
                              # queue parallel to the circuit, in its corridor), a new column this many further out
                              # once a column reaches HOLD_REACH of the way to the delivery point
HOLD_REACH = 0.6


def circuit_capacity(distance: float, spacing: float, most: int = CIRCUIT_MAX) -> int:
    """How many robots a transport between two marks ``distance`` m apart keeps driving: one per ``spacing`` m of
    its circuit (about ``2 * distance`` round), at least one and at most ``most``."""
    return max(1, min(most, int(2.0 * distance / spacing))) if spacing > 0 else most


def hold_spot(obj: tuple[float, float], delivery: tuple[float, float], turn: int, radius: float,
              side: float = 1.0) -> tuple[float, float]:
    """Where the ``turn``-th waiting robot (0, 1, ...) of a transport stands: beside the object's end of the
    circuit, a little short of the object, ``side`` 1 right of the line from the delivery point (-1 left), each
    nearer the delivery point than the one before it (a queue beside the circuit, within its own corridor: a queue
    standing further out stood on the next transport's way), in columns further out once a column reaches
    ``HOLD_REACH`` of the way: off the circuit's turn and off the way to and from the delivery point.
    Transports wait on the right (:class:`TransportExecutor`): the side of the lane towards the object, which the
    circuit's left turn round the object never sweeps.  A robot waiting on the left stood where every robot
    turning there points its sonar, and slowed them (one object 2.5 m out, three drivers and one waiting:
    46 wu in 300 s against 58 waiting on the right, and 66 with no one waiting)."""
    (x0, y0), (x1, y1) = delivery, obj
    d = math.hypot(x1 - x0, y1 - y0)
    ux, uy = ((x1 - x0) / d, (y1 - y0) / d) if d > 0 else (1.0, 0.0)
    gap, back0 = radius * HOLD_GAP_FACTOR, radius * HOLD_BACK_FACTOR
    column = max(1, 1 + int((HOLD_REACH * d - back0) / gap))          # robots per column
    col, row = divmod(turn, column)
    off = side * (radius * HOLD_FACTOR + gap * col)
    back = back0 + gap * row
    return x1 - ux * back + uy * off, y1 - uy * back - ux * off


def circuit_leg(start: tuple[float, float], goal: tuple[float, float], lane: float, reach: float,
                arc_points: int = TIP_POINTS, start_reach: float | None = None) -> list | None:
    """The leg from mark ``start`` to mark ``goal`` of a one-way circuit between them: robots leave ``start`` along a
    quarter circle of radius ``lane``, drive ``lane`` m right of the straight line, and turn left along a half
    circle round ``goal`` whose middle (the *tip*) lies ``TIP_FACTOR * reach`` short of ``goal`` on the line, so
    the turn passes within reach of the mark (``start``'s turn likewise with ``start_reach``, default ``reach``:
    the two marks may be worked from different distances); the leg ends on the way back's lane (``arc_points`` segments per
    quarter turn).  The way back is the same circuit seen from the other end: a robot that stops in the turn to
    load carries on forward, away from the robot behind it and onto the other lane, so arriving and departing
    robots never cross at a mark (driving on the right, the circuit turns left round each mark, as a roundabout
    does).  None when the marks are closer than the two turns need or ``lane`` is not positive."""
    (x0, y0), (x1, y1) = start, goal
    d = math.hypot(x1 - x0, y1 - y0)
    e = TIP_FACTOR * reach
    es = e if start_reach is None else TIP_FACTOR * start_reach
    if lane <= 0 or d < 2.0 * lane + e + es:
        return None
    ux, uy = (x1 - x0) / d, (y1 - y0) / d
    rx, ry = uy, -ux                                              # the right-hand normal
    cs = (x0 + ux * (es + lane), y0 + uy * (es + lane))           # centre of the turn leaving start
    cg = (x1 - ux * (e + lane), y1 - uy * (e + lane))             # ... and of the turn reaching goal
    out = []
    for k in range(arc_points + 1):                               # from start's tip to the right lane
        a = 0.5 * math.pi * k / arc_points
        out.append((cs[0] + lane * (-ux * math.cos(a) + rx * math.sin(a)),
                    cs[1] + lane * (-uy * math.cos(a) + ry * math.sin(a))))
    for k in range(2 * arc_points + 1):                           # from the right lane past goal's tip to the other
        a = 0.5 * math.pi * k / arc_points
        out.append((cg[0] + lane * (rx * math.cos(a) + ux * math.sin(a)),
                    cg[1] + lane * (ry * math.cos(a) + uy * math.sin(a))))
    return out


def join(pose, leg: list, lead: float, upto: int | None = None, since: int = 0, past=None) -> list:
    """``leg`` driven from ``pose``: straight to the point ``lead`` m past the leg's point nearest the robot (among
    its points ``since`` to ``upto``, default all), then on along the leg; straight to ``past`` (default the last
    point searched) when the nearest is the last point searched."""
    px, py = pose[0], pose[1]
    best, at = math.inf, (since, 0.0)
    for i, ((ax, ay), (bx, by)) in enumerate(zip(leg[since:upto], leg[since + 1:upto]), since):
        dx, dy = bx - ax, by - ay
        l2 = dx * dx + dy * dy
        t = 0.0 if l2 == 0 else min(max(((px - ax) * dx + (py - ay) * dy) / l2, 0.0), 1.0)
        d2 = (ax + t * dx - px) ** 2 + (ay + t * dy - py) ** 2
        if d2 < best:
            best, at = d2, (i, t * math.sqrt(l2))
    i, s = at
    last = len(leg[:upto]) - 2
    if i == last and s >= math.dist(leg[last], leg[last + 1]):
        return [(px, py), leg[last + 1] if past is None else past]
    s += lead
    while i < len(leg) - 1:
        (ax, ay), (bx, by) = leg[i], leg[i + 1]
        length = math.hypot(bx - ax, by - ay)
        if s <= length:
            f = s / length if length > 0 else 0.0
            return [(px, py), (ax + f * (bx - ax), ay + f * (by - ay))] + leg[i + 1:]
        s -= length
        i += 1
    return [(px, py), leg[-1]]


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


class TransportExecutor(Executor):
    def __init__(self, commitment: Commitment, ctx):
        super().__init__(commitment, ctx)
        self.phase = TO_OBJECT
        self.follow = FollowPath(follower=self._pursuit())
        self.carrying = 0.0               # wu on board
        self.trips = 0                    # deliveries made
        self._dwell_until: float | None = None
        self._routed = False
        self.turn = self._turn()          # None: drive the circuit; k: the k-th partner waiting beside the object

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
        return mark_reach(self.commitment, at_object=True)

    @property
    def delivery_reach(self) -> float:
        """How close to the delivery point it unloads: the radius of the delivery area (default: ``reach``)."""
        return mark_reach(self.commitment, at_object=False)

    def _pursuit(self) -> PurePursuit:
        p = self.ctx.pursuit()
        p.goal_tolerance = max(p.goal_tolerance, 0.5 * self.reach)
        p.lookahead = min(p.lookahead, LOOKAHEAD_FACTOR * self.lane)
        return p

    def retune(self) -> None:
        """After the executive applied changed tunables to the follower: look ahead no farther than the circuit's
        turns allow (a lookahead longer than about half the turn radius slows pure pursuit down in every turn)."""
        p = self.follow.follower
        p.lookahead = min(p.lookahead, LOOKAHEAD_FACTOR * self.lane)

    @property
    def spacing(self) -> float:
        return float(self.commitment.param("spacing", SPACING_FACTOR * self.ctx.radius))

    def _turn(self) -> int | None:
        """None when this robot drives the circuit: its id is among the lowest ``circuit_capacity`` of its
        coalition's; otherwise its place among those waiting (0 first).  Robots without an id always drive."""
        me = getattr(self.ctx, "robot_id", None)
        if me is None or not self.commitment.partners:
            return None
        d = math.hypot(self.task.position[0] - self.delivery[0], self.task.position[1] - self.delivery[1])
        most = int(self.commitment.param("circuit_max", CIRCUIT_MAX))
        rank = sorted({me, *self.commitment.partners}).index(me) - circuit_capacity(d, self.spacing, most)
        return None if rank < 0 else rank

    @property
    def lane(self) -> float:
        return float(self.commitment.param("lane", LANE_FACTOR * self.ctx.radius))

    def _route(self, pose) -> list:
        route = self.ctx.planner.route(pose, self.goal)
        if self.waiting:                                      # straight to its place beside the object
            return route
        going = self.phase in (TO_OBJECT, LOADING)
        other = self.delivery if going else self.task.position
        reach, other_reach = (self.reach, self.delivery_reach) if going else (self.delivery_reach, self.reach)
        at_start = math.hypot(pose[0] - other[0], pose[1] - other[1]) <= 2 * other_reach
        if len(route) == 2 and len(self.ctx.planner.route(other, self.goal)) == 2:     # the map leaves a straight way
            leg = circuit_leg(other, self.goal, self.lane, reach, start_reach=other_reach)
            if leg is not None:
                # from the mark it left, the circuit's turn; from elsewhere, the lane (not into the other mark's turn)
                return join(pose, leg, self.ctx.tunables.lookahead, upto=len(leg) - TIP_POINTS,
                            since=0 if at_start else TIP_POINTS, past=self.goal)
        return keep_lane(route, self.lane)

    @property
    def mark(self) -> tuple[float, float]:
        """Where the robot works next: the object, or the delivery point."""
        return self.task.position if self.phase in (TO_OBJECT, LOADING) else self.delivery

    @property
    def goal(self) -> tuple[float, float]:
        """Where the robot is going: its mark, or its place beside the object while it waits its turn."""
        if self.waiting:
            return hold_spot(self.task.position, self.delivery, self.turn, self.ctx.radius)
        return self.mark

    @property
    def waiting(self) -> bool:
        """Whether the robot, on its way to the object, waits for its turn beside it instead."""
        return self.phase == TO_OBJECT and self.turn is not None

    @property
    def behaviours(self) -> list:
        return [self.follow]

    # ------------------------------------------------------------------ executive interface
    def recommit(self, commitment: Commitment, now: float) -> bool:
        """Same task, new partners or parameters: carry on from where the trip is."""
        self.commitment = commitment
        self.follow.follower.goal_tolerance = max(self.ctx.goal_tolerance, 0.5 * self.reach)
        turn = self._turn()
        if turn != self.turn and self.phase == TO_OBJECT:     # its turn came, or its place changed: go there
            self.turn, self._routed = turn, False     # (one that carries finishes its trip first)
        return True

    def begin(self, pose, now: float) -> None:
        if not self._routed and self.phase in (TO_OBJECT, TO_DELIVERY):
            self._routed = True
            self.follow.set_path(self._route(pose))

    def bump_ended(self, pose, now: float) -> None:
        if self.phase in (TO_OBJECT, TO_DELIVERY):
            self.follow.set_path(self._route(pose))

    def update(self, pose, now: float) -> list[Progress]:
        self.follow.update(pose, now)
        if self.waiting:
            return []
        if self.phase in (TO_OBJECT, TO_DELIVERY):
            near = (math.hypot(self.mark[0] - pose[0], self.mark[1] - pose[1])
                    <= mark_reach(self.commitment, at_object=self.phase == TO_OBJECT))
            if near:                              # within reach of the mark: work from here
                self.phase = LOADING if self.phase == TO_OBJECT else UNLOADING
                self._dwell_until = now + self.load * self.load_time
                self.follow.set_path(None)        # stand still (the Stop behaviour votes for it)
            elif self.follow.done:                # the path ended off the mark (pushed, or odometry drifted so the
                # circuit's turn missed reach): straight for the mark, not round the circuit again and again
                self.follow.set_path(self.ctx.planner.route(pose, self.goal))
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
            self.phase, self.turn = TO_OBJECT, self._turn()
            out = [Progress(self.task.id, DELIVERED, now, data={"wu": wu})]
        self.follow.set_path(self._route(pose))
        return out

    def cancel(self, now: float) -> None:
        self.follow.set_path(None)
