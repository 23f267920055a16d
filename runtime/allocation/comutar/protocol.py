"""Paper 003 (CoMutaR) as a sans-IO allocation agent: one robot's actions bidding in Contract Net auctions
under constraint functions (Alg. 1), and the auctioneer role for the tasks it took in.

:class:`ComutarAgent` implements :class:`runtime.allocation.agent.Agent`.  It holds

* this robot's :class:`~runtime.allocation.comutar.actions.Catalogue` (from its sensors) and the
  :class:`~runtime.allocation.comutar.resources.Ledger` of its share-restricted resources: ``processor``
  (share of a core), ``link`` (Mb/s given to data streams between robots) and ``cspace`` (its allowed
  next-frame configurations);
* the :class:`~runtime.allocation.comutar.bidder.Bidder` (its actions: announcements, queries, bids,
  awards, holdings) and the :class:`~runtime.allocation.comutar.auctioneer.Auctioneer` (tasks it took in);
* per surveillance task a :class:`~runtime.tasks.surveillance.Board` (visits and claims,
  spread by ``CmSurvey``), and the regions consumers asked it to watch (``CmRegion``).

It may hold several commitments at once (e.g. a surveillance task and an obstacle-avoidance task); each
carries its actions and connections in ``params`` (see :meth:`ComutarAgent.commitments`).  What it needs from
outside beyond the Agent protocol: :meth:`ComutarAgent.sense` each cycle (pose, and the obstacles the robot
knows), and execution reading :meth:`survey_target`, :meth:`region` and reporting visits as
``Progress(task, "visited", data={"waypoint": i})``.

Messages it sends to itself (a bid to itself as the auctioneer, a query its own actions answer) are handled
here without the wire; broadcasts go to the wire and to itself.  Messages from outside are checked once
more (``invalid()``) and must come from a configured peer; what cannot be acted on is counted in
:attr:`ComutarAgent.dropped` by reason, and never raises.
"""
from __future__ import annotations

import itertools
import math
from collections import Counter
from pathlib import Path
from typing import Sequence

import numpy as np

from runtime.allocation.agent import AgentContext, Method, TaskEvent, route
from runtime.allocation.comutar import actions as A
from runtime.control import cspace as C
from runtime.allocation.comutar.auctioneer import Auctioneer
from runtime.allocation.comutar.bidder import Bidder, Slot
from runtime.allocation.comutar.messages import (WIRE_MESSAGES, CmAck, CmAnnounce, CmAward, CmBid, CmCancel, CmCost,
                                                 CmDone, CmHold, CmQuery, CmRegion, CmResign, CmStream, CmSurvey,
                                                 MAX_DISCS, pack_disc)
from runtime.allocation.comutar.options import ComutarOptions
from runtime.allocation.comutar.resources import CSPACE, Ledger, Resource
from runtime.tasks import avoid_obstacles as AV, surveillance as SV
from runtime.tasks.surveillance import VISITED, Board
from runtime.log import get_logger
from runtime.messages import BROADCAST, why_invalid
from runtime.tasks import FAILED as P_FAILED, Commitment, Progress, Task

KINDS = ("surveillance", "avoid_obstacles")
CHOOSE_PERIOD = 0.25                      # s between re-evaluations of the nearest waypoint (at once on news)
CLAIM_STALE = 5                           # status periods without a surveyor's CmSurvey before its claim is dropped
STREAM_PERIOD = {A.RANGE_DATA: 0.1, A.OBSTACLE_LIST: 0.2}   # s: the 10 Hz and 5 Hz of ActionSpec.rates
SENSE_FRESH = 0.5                         # s: a provider streams only readings newer than this
SELF_ECHO = 0.12                          # m past a consumer's body: a streamed disc this close is the consumer itself
OWN_SENSOR = object()                     # ComutarAgent._feed: the avoider reads this robot's own sensor


class ComutarAgent:
    """One robot's CoMutaR agent (see the module docstring)."""

    def __init__(self, ctx: AgentContext, sensors: Sequence[str] | None = None):
        self.robot_id = int(ctx.robot_id)
        self.options: ComutarOptions = ctx.options if ctx.options is not None else ComutarOptions()
        self.estimator = ctx.estimator
        self.log = get_logger("alloc.comutar", self.robot_id)
        self.peers = frozenset(int(p) for p in ctx.peers) - {self.robot_id}
        self.lost: set[int] = set()
        self.catalogue = A.catalogue(sensors or ())
        self.window = C.Window(v_max=self.options.speed, w_max=self.options.turn_rate)
        self.ledger = Ledger()
        me = self.robot_id
        self.ledger.add(Resource(me, "processor", capacity=self.options.processor, unit=" cores"))
        self.ledger.add(Resource(me, "link", capacity=self.options.link_capacity, unit=" Mb/s"))
        self.ledger.add(Resource(me, "cspace", CSPACE))
        self.tasks: dict[int, Task] = {}
        self.fleet_version = 0               # bumped when the tasks or the live robots change
        self.pose: tuple[float, float, float] | None = None
        self.obstacles = np.zeros((0, 3))
        self.sensed_at = -math.inf
        # (task, info) -> (last heard, from, [(heard, discs and their shadows)] of the last feed_memory s)
        self.feeds: dict[tuple[int, str], tuple[float, int, list[tuple[float, np.ndarray]]]] = {}
        self._stream_at: dict[tuple[int, str, int], float] = {}
        self.boards: dict[int, Board] = {}
        self.regions: dict[int, tuple[float, float, float]] = {}
        self.available = True
        self.events: list[TaskEvent] = []
        self.dropped: Counter = Counter()
        self.bidder = Bidder(self)
        self.auction = Auctioneer(self)
        self._status_at: dict[int, float] = {}
        self._survey_heard: dict[tuple[int, int], float] = {}     # (task, surveyor) -> its last CmSurvey
        self._choose_at: dict[int, float] = {}
        self._region_at: dict[int, float] = {}
        self._refused: set[int] = set()

    # ------------------------------------------------------------------ what the daemon reads
    @property
    def commitments(self) -> tuple[Commitment, ...]:
        """One per task held.  ``role``: the actions, joined by "+"; ``params``: ``auction``, ``actions``
        (names), ``inputs`` ((info, provider robot), ...), ``outputs`` ((info, consumer robot), ...), ``region``
        ((robot, x, y, radius) a reader keeps in view, for readers serving another robot)."""
        out = []
        for tid, h in sorted(self.bidder.holdings.items()):
            task = self.tasks.get(tid)
            if task is None:
                continue
            slots = self.bidder.held_slots(tid)
            ins, outs = self.bidder.links(tid)
            robots = {r >> 16 for r in h.award} - {self.robot_id}
            params = [("auction", h.auction), ("actions", tuple(s.spec.name for s in slots)),
                      ("inputs", tuple(sorted(ins.items()))), ("outputs", tuple(sorted(outs.items())))]
            region = self.region(tid)
            if region is not None and any(s.spec.motion == A.SENSOR for s in slots):
                params.append(("region", region))
            out.append(Commitment(task, tuple(sorted(robots)), "+".join(s.spec.name for s in slots), tuple(params)))
        return tuple(out)

    @property
    def converged(self) -> bool:
        return not self.auction.busy and not self.bidder.pending

    @property
    def allocating(self) -> bool:
        return self.bidder.pending

    def pop_events(self) -> list[TaskEvent]:
        out, self.events = self.events, []
        return out

    # ------------------------------------------------------------------ the robot's situation
    def sense(self, pose, obstacles=None, now: float | None = None) -> None:
        """This cycle's pose (x, y, heading; None: not localized) and what its own range sensor sees ((M, 3)
        discs: x, y, radius, fleet frame; one per echo on a robot, see :func:`echo_discs`).  The obstacle
        detector's output is these discs; the obstacle avoider's constraint function reads them at bid time, and
        they are what this robot streams to the consumers of its readers and detectors."""
        self.pose = None if pose is None else (float(pose[0]), float(pose[1]), float(pose[2]) if len(pose) > 2 else 0.0)
        if obstacles is not None:
            self.obstacles = np.asarray(obstacles, dtype=float).reshape(-1, 3)
            if now is not None:
                self.sensed_at = float(now)

    def perceive(self, pose, ranges, now: float) -> None:
        """The daemon's each cycle: the pose estimate and the base's range readings ((bearing, distance) pairs,
        robot frame; the driver leaves out readings with no echo), one disc per echo (:func:`echo_discs`)."""
        self.sense(pose, echo_discs(pose, ranges), now)

    # ------------------------------------------------------------------ what execution reads
    def guidance(self, now: float) -> dict:
        """What each commitment's executor is to do now, as data (task id -> the task kind's ``Guidance``): the
        host hands it to the executive each cycle; executors never call the agent."""
        held = self.commitments
        known = self.obstacle_input_any(now) if held else None
        return {c.task_id: self._GUIDES[c.task.kind](self, c, now, known) for c in held}

    def _survey_guide(self, c: Commitment, now: float, known: np.ndarray) -> SV.Guidance:
        board = self.boards.get(c.task_id)
        return SV.Guidance(self.window, self.survey_target(c.task_id),
                           None if board is None else frozenset(board.visited), self.options.visit_radius,
                           self.protected(now), known)

    def _avoid_guide(self, c: Commitment, now: float, known: np.ndarray) -> AV.Guidance:
        actions = tuple(c.param("actions", ()))
        reader = next((spec for spec in A.READERS.values() if spec.name in actions), None)
        avoider = A.AVOIDER.weight if A.AVOIDER.name in actions else None
        return AV.Guidance(self.window, avoider, self.obstacle_input(c.task_id, now) if avoider is not None else None,
                           self.region(c.task_id), None if reader is None else reader.weight,
                           None if reader is None else A.SENSORS[reader.sensor], known)

    _GUIDES = {SV.KIND: _survey_guide, AV.KIND: _avoid_guide}     # the task kinds this family allocates

    def obstacle_input(self, task_id: int, now: float) -> np.ndarray | None:
        """The obstacle list this robot's avoider in ``task_id`` works from now ((M, 3) discs, fleet frame), or
        None when it has none fresh: its provider's stream (obstacle list, or range data its own detector turns
        into one) is overdue (``options.feed_periods`` of its period: 0.25 s for 10 Hz range data), or this robot
        does not hold the task.  A robot's own
        sensor counts as fresh.  The streamed discs are those of the last ``options.feed_memory`` s (a disc that
        one echo frame misses is still there), each followed by its shadow (:func:`shadowed`: the provider heard
        only the side facing it); streamed discs on the robot's own body are dropped; the robots this one serves
        (regions it keeps in view) are added."""
        feed = self._feed(task_id, now)
        if feed is None:
            return None
        if feed is OWN_SENSOR:
            return self._with_consumers(self.obstacles)
        discs = np.vstack([d for t, d in feed[2] if now - t < self.options.feed_memory] or [feed[2][-1][1]])
        if len(discs) and self.pose is not None:
            gap = np.hypot(discs[:, 0] - self.pose[0], discs[:, 1] - self.pose[1])
            discs = discs[gap > self.estimator.profile.radius + SELF_ECHO]
        return self._with_consumers(discs)

    def _feed(self, task_id: int, now: float):
        """What this robot's avoider in ``task_id`` reads now: :data:`OWN_SENSOR`, its provider's feed while it is
        fresh, or None (the task not held, or the feed overdue)."""
        if task_id not in self.bidder.holdings:
            return None
        ins, _ = self.bidder.links(task_id)
        src = ins.get(A.OBSTACLE_LIST)
        info = A.OBSTACLE_LIST
        if src == self.robot_id:
            src, info = ins.get(A.RANGE_DATA, self.robot_id), A.RANGE_DATA
        if src is None or src == self.robot_id:
            return OWN_SENSOR
        feed = self.feeds.get((task_id, info))
        if feed is None or feed[1] != src or now - feed[0] > self.feed_timeout(info):
            return None
        return feed

    def feed_timeout(self, info: str) -> float:
        """Seconds after which a stream of ``info`` is overdue: ``feed_periods`` of its period."""
        return self.options.feed_periods * STREAM_PERIOD.get(info, 0.2)

    def obstacle_input_any(self, now: float) -> np.ndarray:
        """Every obstacle this robot knows now: its avoiders' inputs (empty when none is fresh)."""
        lists = [d for tid in self.bidder.holdings for d in [self.obstacle_input(tid, now)] if d is not None]
        return np.vstack(lists) if lists else np.zeros((0, 3))

    def _with_consumers(self, discs: np.ndarray) -> np.ndarray:
        """``discs`` and the robots I keep in view for others (a low robot may pass under my sonar)."""
        mine = [(x, y, self.estimator.profile.radius) for tid in self.bidder.holdings
                for r in [self.region(tid)] if r is not None for x, y in [r[1:3]]]
        return np.vstack([discs.reshape(-1, 3), np.asarray(mine, float)]) if mine else discs.reshape(-1, 3)

    def protected(self, now: float) -> bool:
        """False while an ``avoid_obstacles`` task for this robot exists and its avoider is not running on fresh
        data (not allocated yet, its provider lost or silent): a robot that must avoid obstacles and cannot does
        not move (the surveillance executor stops)."""
        for tid, t in self.tasks.items():
            if t.kind == "avoid_obstacles" and getattr(t.spec, "robot", None) == self.robot_id:
                if self._feed(tid, now) is None:
                    return False
        return True

    @property
    def position(self) -> tuple[float, float]:
        return (self.pose[0], self.pose[1]) if self.pose is not None else (math.nan, math.nan)

    @property
    def can_bid(self) -> bool:
        return self.available and self.pose is not None

    def survey_target(self, task_id: int) -> tuple[float, float] | None:
        """Where this robot heads in surveillance task ``task_id``: its claimed waypoint; while it waits (every
        open waypoint claimed by others), a point clear of the open waypoints if it stands too near one for
        another robot to reach it (:meth:`Board.clear_of`); None: stay (nothing to do, or not held)."""
        board = self.boards.get(task_id)
        if board is None or task_id not in self.bidder.holdings:
            return None
        point = board.point()
        if point is None and self.pose is not None:
            radius = self.estimator.profile.radius
            point = board.clear_of(self.position, 2 * radius + self.options.visit_radius)
        return point

    def region(self, task_id: int) -> tuple[int, float, float, float] | None:
        """(robot, x, y, radius): the region a reader of mine keeps in view for ``task_id``'s consumer."""
        for slot in self.bidder.held_slots(task_id):
            if slot.spec.motion == A.SENSOR and slot.region[0] != self.robot_id:
                x, y, r = self.regions.get(task_id, (slot.region[1], slot.region[2], self.options.region_radius))
                return slot.region[0], x, y, r
        return None

    def cspace_mask(self, slot: Slot, now: float):
        """phi(now) of ``slot`` on this robot's c-space: its allowed candidates (None: forbids nothing)."""
        if self.pose is None:
            return None
        pose = np.asarray(self.pose)[None, :]
        if slot.spec.motion == A.AVOID and len(self.obstacles):
            return C.avoid(self.window, pose, self.obstacles, self.estimator.profile.radius).allowed[0]
        if slot.spec.motion == A.SENSOR and slot.region[0] != self.robot_id:
            x, y, r = self.regions.get(slot.task, (slot.region[1], slot.region[2], self.options.region_radius))
            return C.sensor_view(self.window, pose, [(x, y)], r, A.SENSORS[slot.spec.sensor]).allowed[0]
        return None

    # ------------------------------------------------------------------ pricing
    def own_cost(self, slot: Slot) -> float:
        """A slot's own share of a bid (s): its action's cost, its processor share, and its travel."""
        spec = slot.spec
        cost = spec.cost + spec.processor / max(self.options.processor, 1e-9)
        if spec.motion == A.SURVEY:
            board = self.boards.get(slot.task)
            task = self.tasks.get(slot.task)
            if board is None and task is not None:
                board = Board(task.spec.waypoints(), self.robot_id)
            if board is not None and self.pose is not None:
                d = board.nearest_open(self.position)
                cost += (d if math.isfinite(d) else 0.0) / self.options.speed
        elif spec.motion == A.SENSOR and slot.region[0] != self.robot_id and self.pose is not None:
            sensor = A.SENSORS[spec.sensor]
            d = math.dist(self.position, slot.region[1:])
            cost += max(0.0, d - sensor.far * sensor.range) / self.options.speed
        return cost

    def link_cost(self, rate: float, robot: int) -> float:
        """A stream received from another robot: its share of this robot's link."""
        return 0.0 if robot == self.robot_id else rate / max(self.options.link_capacity, 1e-9)

    def in_range(self, spec: A.ActionSpec, x: float, y: float) -> bool:
        """Is (x, y) within the range of ``spec``'s sensor from here, or within ``options.reader_reach`` m more
        (the robot drives over: its reader's cost counts the way; it streams once the region is in view)?"""
        return self.pose is not None and \
            math.dist(self.position, (x, y)) <= A.SENSORS[spec.sensor].range + self.options.reader_reach

    def _sees(self, task_id: int) -> bool:
        """Does my reader in ``task_id`` take in the whole region it keeps in view for the consumer (its sensor's
        full range and angle, :meth:`~runtime.control.cspace.Sensor.covers`)?  A reader that does not
        (still on its way, or left behind) does not stream: its consumer would take the silence of an unwatched
        place for a clear one, and drive into what the sensor cannot reach.  (Alg. 3 keeps the region within
        ``far`` of the range and off the angle's borders; this looser test keeps a stream from flickering at
        that margin.)"""
        region = self.region(task_id)
        if region is None:
            return True
        if self.pose is None:
            return False
        return any(A.SENSORS[slot.spec.sensor].covers(self.pose, region[1:3], region[3])
                   for slot in self.bidder.held_slots(task_id) if slot.spec.motion == A.SENSOR and slot.spec.sensor)

    def serves(self, spec: A.ActionSpec, task: Task) -> bool:
        """Can ``spec`` accomplish ``task`` on this robot (an avoider protects only its own robot)."""
        return task.kind != "avoid_obstacles" or getattr(task.spec, "robot", None) == self.robot_id

    # ------------------------------------------------------------------ fleet
    def is_live(self, rid: int) -> bool:
        return rid == self.robot_id or (rid in self.peers and rid not in self.lost)

    def auctioneer_of(self, task_id: int) -> int:
        """The robot that took the task in, or, if it is lost, the lowest-id live robot."""
        origin = task_id >> 16
        if self.is_live(origin):
            return origin
        return min([self.robot_id] + [p for p in self.peers if p not in self.lost])

    # ------------------------------------------------------------------ inputs
    def add_tasks(self, tasks: Sequence[Task], now: float) -> list:
        for t in tasks:
            if t.kind in KINDS:
                self.tasks[t.id] = t
                self.fleet_version += 1
                if t.kind == "surveillance" and t.id not in self.boards:
                    self.boards[t.id] = Board(t.spec.waypoints(), self.robot_id)
            elif t.id not in self._refused:
                self._refused.add(t.id)
                self.log.warning("task %d is a %s: CoMutaR allocates %s tasks only", t.id, t.kind, "|".join(KINDS))
                if t.id >> 16 == self.robot_id:
                    self.events.append(TaskEvent(t.id, "failed", (self.robot_id,),
                                                 f"{t.kind} tasks are not allocated by CoMutaR"))
        return []

    def withdraw_tasks(self, task_ids: Sequence[int], now: float) -> list:
        self.fleet_version += 1
        for t in task_ids:
            self.tasks.pop(t, None)
            self.boards.pop(t, None)
            self.regions.pop(t, None)
            self.feeds = {k: v for k, v in self.feeds.items() if k[0] != t}
            self.bidder.drop(t)
        self.auction.withdraw(task_ids)
        return []

    def set_available(self, available: bool, now: float) -> list:
        self.available = bool(available)
        if available:
            return []
        out = []
        for t in list(self.bidder.holdings):
            out += self.bidder.resign(t, "disarmed")
        self.bidder.release([r for r, s in self.bidder.slots.items() if not s.held])
        return self._route(out, now)

    def on_peer_joined(self, robot_id: int, now: float) -> list:
        """A robot joined the fleet: its messages count from now (it bids on the next ``CmAnnounce``, which goes to
        every robot; an auction open now counts its bid if it comes before the auction closes) and, the live robots
        having changed, the auctioneers' tasks are looked at again (``fleet_version``)."""
        if robot_id == self.robot_id or (robot_id in self.peers and robot_id not in self.lost):
            return []
        self.peers |= {int(robot_id)}
        self.lost.discard(robot_id)
        self.fleet_version += 1
        return []

    def on_peer_lost(self, robot_id: int, now: float) -> list:
        if robot_id not in self.peers:
            return []
        self.lost.add(robot_id)
        self.fleet_version += 1
        for board in self.boards.values():
            board.forget(robot_id)
        out = []
        for tid in list(self.bidder.holdings):
            ins, outs = self.bidder.links(tid)
            if robot_id in ins.values():
                out += self.bidder.resign(tid, f"robot {robot_id}, a provider of its inputs, is lost")
            elif robot_id in outs.values():
                self.log.info("task %d: the consumer robot %d is lost: releasing", tid, robot_id)
                self.bidder.drop(tid)
        out += self.auction.on_peer_lost(robot_id, now)
        return self._route(out, now)

    def on_progress(self, p: Progress, now: float) -> list:
        if p.task not in self.bidder.holdings:
            return []
        if p.event == VISITED:
            board = self.boards.get(p.task)
            i = p.data.get("waypoint")
            if board is not None and isinstance(i, int) and board.visit(i):
                self._status_at[p.task] = self._choose_at[p.task] = -math.inf
            return []
        if p.event == P_FAILED:
            return self._route(self.bidder.resign(p.task, f"execution failed: {p.detail}"), now)
        return []

    def on_message(self, msg, now: float) -> list:
        sender = getattr(msg, "sender", None)
        if not isinstance(msg, WIRE_MESSAGES):
            if type(msg).__name__ != "RobotState":          # the fleet's states pass every agent: not ours
                self.dropped["not a CoMutaR message"] += 1
            return []
        if not (isinstance(sender, int) and sender in self.peers):
            self.dropped["not a robot of the fleet"] += 1
            return []
        if getattr(msg, "dest", None) not in (BROADCAST, self.robot_id):
            self.dropped["addressed to another robot"] += 1
            return []
        why = why_invalid(msg)
        if why is not None:
            self.dropped["invalid"] += 1
            self.log.debug("dropped %s from robot %d: %s", type(msg).__name__, sender, why)
            return []
        if sender in self.lost:
            self.lost.discard(sender)
            self.fleet_version += 1
        return self._route(self._dispatch(msg, now), now)

    def on_tick(self, now: float) -> list:
        out = self.bidder.tick(now)
        out += self.auction.tick(now)
        out += self._surveys(now)
        out += self._region_updates(now)
        out += self._streams(now)
        return self._route(out, now)

    def _streams(self, now: float) -> list:
        """What my readers and detectors serving other robots send them: my sensor's discs (range data: one per
        echo; the obstacle list: the same discs, and my own body), at 10 Hz and 5 Hz, from a fresh reading, nearest
        me first; when they are more than one stream carries (a laser's), nearest the region I keep in view."""
        if self.pose is None or now - self.sensed_at > SENSE_FRESH:
            return []
        out = []
        for tid in self.bidder.holdings:
            _, outs = self.bidder.links(tid)
            if not self._sees(tid):
                continue
            for info, consumer in outs.items():
                if consumer == self.robot_id or now - self._stream_at.get((tid, info, consumer), -math.inf) \
                        < STREAM_PERIOD.get(info, 0.2) - 1e-9:
                    continue
                self._stream_at[(tid, info, consumer)] = now
                discs = self.obstacles
                if info == A.OBSTACLE_LIST:
                    discs = np.vstack([discs, [[self.pose[0], self.pose[1], self.estimator.profile.radius]]])
                ox, oy = self.position
                region = self.region(tid) if len(discs) > MAX_DISCS else None
                order = stream_order(discs, (ox, oy), None if region is None else region[1:3])
                packed = [v for v in (pack_disc(*discs[i], ox, oy) for i in order) if v is not None]
                out.append(CmStream(self.robot_id, consumer, tid, A.INFO[info], float(now), ox, oy,
                                    tuple(packed[:MAX_DISCS])))
        return out

    # ------------------------------------------------------------------ surveillance and regions
    def _surveys(self, now: float) -> list:
        out = []
        for tid, board in self.boards.items():
            for r in [r for r in board.claims if r != self.robot_id
                      and now - self._survey_heard.get((tid, r), now) > CLAIM_STALE * self.options.status_period]:
                board.forget(r)          # a surveyor that left the task (resigned, cancelled) no longer holds a claim
            held = tid in self.bidder.holdings
            if held and self.pose is not None and now >= self._choose_at.get(tid, -math.inf):
                self._choose_at[tid] = now + CHOOSE_PERIOD
                if board.choose(self.position, now, self.options.switch):
                    self._status_at[tid] = -math.inf
            if board.complete and tid in self.auction.jobs:
                out += self.auction.complete(tid, now)
            if held and now - self._status_at.get(tid, -math.inf) >= self.options.status_period:
                self._status_at[tid] = now
                target = 0 if board.target is None else board.target + 1
                visited = tuple(sorted(i + 1 for i in board.visited))[:200]
                out.append(CmSurvey(self.robot_id, BROADCAST, tid, target, float(board.claimed_at), visited))
        return out

    def _region_updates(self, now: float) -> list:
        out = []
        for tid in self.bidder.holdings:
            ins, _ = self.bidder.links(tid)
            remote = sorted({r for r in ins.values() if r != self.robot_id})
            if not remote or self.pose is None or now - self._region_at.get(tid, -math.inf) < self.options.region_period:
                continue
            self._region_at[tid] = now
            h = self.bidder.holdings[tid]
            providers = sorted({r >> 16 for r in h.award} - {self.robot_id})
            x, y = self.position
            out += [CmRegion(self.robot_id, r, tid, x, y, self.options.region_radius) for r in providers]
        return out

    # ------------------------------------------------------------------ routing
    def _dispatch(self, msg, now: float) -> list:
        b, a = self.bidder, self.auction
        if isinstance(msg, CmAnnounce):
            a.on_announce(msg, now)
            return b.on_announce(msg, now)
        if isinstance(msg, CmQuery):
            return b.on_query(msg, now)
        if isinstance(msg, CmCost):
            return b.on_cost(msg, now)
        if isinstance(msg, CmBid):
            a.on_bid(msg, now)
            return []
        if isinstance(msg, CmAward):
            return b.on_award(msg, now)
        if isinstance(msg, CmAck):
            return a.on_ack(msg, now)
        if isinstance(msg, CmResign):
            return a.on_resign(msg, now)
        if isinstance(msg, CmCancel):
            b.on_cancel(msg, now)
            return []
        if isinstance(msg, CmHold):
            return a.on_hold(msg, now)
        if isinstance(msg, CmDone):
            b.on_done(msg, now)
            a.on_done(msg, now)
            return []
        if isinstance(msg, CmSurvey):
            board = self.boards.get(msg.task)
            if board is None or msg.sender == self.robot_id:
                return []
            self._survey_heard[(msg.task, msg.sender)] = now
            target = msg.target - 1 if 0 < msg.target <= len(board.points) else None
            if board.merge(msg.sender, map(int.__sub__, msg.visited, itertools.repeat(1)), target, msg.claimed):
                self._status_at[msg.task] = self._choose_at[msg.task] = -math.inf
            return []
        if isinstance(msg, CmRegion):
            if msg.task in self.bidder.holdings:
                self.regions[msg.task] = (msg.x, msg.y, msg.radius)
            return []
        if isinstance(msg, CmStream):
            info = A.INFO_NAMES[msg.info]
            if msg.task in self.bidder.holdings and self.bidder.links(msg.task)[0].get(info) == msg.sender:
                key, memory = (msg.task, info), self.options.feed_memory
                prev = self.feeds.get(key)
                frames = [fr for fr in (prev[2] if prev is not None and prev[1] == msg.sender else ())
                          if now - fr[0] < memory]
                discs = np.asarray(msg.unpacked(), float).reshape(-1, 3)
                frames.append((now, shadowed(discs, (msg.ox, msg.oy), self.options.shadow_depth)))
                self.feeds[key] = (now, msg.sender, frames)
            else:
                self.dropped["stream for a chain I do not hold"] += 1
            return []
        return []

    def _route(self, msgs: list, now: float) -> list:
        """The messages for the wire; those for this robot are handled here (broadcasts both)."""
        return route(msgs, self.robot_id, lambda m: self._dispatch(m, now))


def make_agent(ctx: AgentContext, sensors: Sequence[str] | None = None) -> ComutarAgent:
    """The agent for a robot; ``sensors`` default to the kinds its host found (``ctx.sensors``: the base's and
    the ``sensors:`` entries'), else to what its base config has (``ctx.base``: a Pioneer's sonar ring,
    :func:`~runtime.allocation.comutar.actions.sensors_of`)."""
    if sensors is None and ctx.sensors is not None:
        sensors = tuple(ctx.sensors)
    if sensors is None and ctx.base is not None:
        sensors = A.sensors_of(ctx.base)
    return ComutarAgent(ctx, sensors)


def stream_order(discs: np.ndarray, own, region=None) -> np.ndarray:
    """The indices of ``discs`` in the order a stream packs them (it carries the first :data:`MAX_DISCS`): nearest
    ``own`` (the provider's x, y) first, or, when they are more than a stream carries (a laser's revolution) and the
    consumer's ``region`` (x, y) is known, nearest that: what the consumer may run into."""
    near = region if region is not None and len(discs) > MAX_DISCS else own
    return np.argsort(np.hypot(discs[:, 0] - near[0], discs[:, 1] - near[1]))


def shadowed(discs: np.ndarray, origin, depth: float, step: float = 0.15) -> np.ndarray:
    """``discs`` heard from ``origin`` (another robot's sensor) and what may hide behind each: the echo is the
    side of an obstacle facing that sensor, and the obstacle may reach ``depth`` m further away from it (a
    pillar seen from its far side ends nearer this robot than the echo says).  Each disc is repeated every
    ``step`` m along its beam, away from ``origin``, to ``depth``, with its own radius; ``depth`` 0 adds none."""
    discs = np.asarray(discs, float).reshape(-1, 3)
    n = int(math.ceil(depth / step - 1e-9)) if depth > 0 else 0
    if not len(discs) or n == 0:
        return discs
    ux, uy = discs[:, 0] - origin[0], discs[:, 1] - origin[1]
    norm = np.hypot(ux, uy)
    norm[norm < 1e-9] = np.inf                            # a disc at the sensor itself has no beam: no shadow
    ux, uy = ux / norm, uy / norm
    k = np.minimum(np.arange(1, n + 1) * step, depth)[:, None]
    behind = np.stack([discs[None, :, 0] + k * ux, discs[None, :, 1] + k * uy,
                       np.broadcast_to(discs[:, 2], (n, len(discs)))], axis=-1).reshape(-1, 3)
    return np.vstack([discs, behind])


def echo_discs(pose, ranges, max_range: float = math.inf) -> np.ndarray:
    """A robot's range readings ((bearing rad, robot frame; distance m) pairs) as discs in the fleet frame, one
    per echo: centred where it was heard, as wide as a sonar's 25 degree beam is there (at least 5 cm, at most
    30 cm).  Readings at or beyond ``max_range`` (no echo) and non-finite ones are left out."""
    if pose is None or not ranges:
        return np.zeros((0, 3))
    r = np.asarray([(b, d) for b, d in ranges if math.isfinite(b) and math.isfinite(d) and 0 < d < max_range - 1e-6],
                   float).reshape(-1, 2)
    x, y, th = pose
    a = th + r[:, 0]
    rad = np.clip(r[:, 1] * math.tan(math.radians(12.5)), 0.05, 0.3)
    return np.column_stack([x + r[:, 1] * np.cos(a), y + r[:, 1] * np.sin(a), rad])


COMUTAR = Method("comutar", "paper 003 CoMutaR: Contract Net over actions with constraint functions (several tasks "
                 "per robot)", ComutarOptions, make_agent, KINDS, WIRE_MESSAGES,
                 str(Path(__file__).with_name("comutar.xml")))
