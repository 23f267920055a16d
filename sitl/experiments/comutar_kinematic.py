"""The paper 003 reproduction's fleet: the real CoMutaR agents on the in-memory bus, each robot a
differential-drive disc (Pioneer-sized: 0.25 m radius) commanded through the c-space grids, the whole fleet's
constraints evaluated in one batch each frame (the reproduction's joint solver, not the daemon's executors).

Each frame (the window's ``T_f``):

1. every robot senses (pose; obstacles seen by its own range sensor); the bus runs one frame: messages
   delivered, every agent ticks each ``tick`` (the daemon's 20 Hz cycle: the protocol's timers, 0.3 s per
   query level, need finer steps than a 0.2 s frame);
2. every commitment becomes its
   c-space constraint: the survey (Alg. 2) toward the waypoint the agent claimed, the obstacle avoider
   (Alg. 4) over the discs the *provider's* sensor sees (range and field of view from the provider's pose:
   robots and static obstacles; a robot without an avoidance commitment ignores obstacles), and a reader
   serving another robot keeping that robot's region in view (Alg. 3);
3. the whole fleet's constraints are evaluated in one batch and each robot takes its best command
   (:func:`~runtime.control.cspace.choose`); a conflict (empty intersection) stops it;
4. robots move on exact arcs as the in-process host's non-overlapping discs (:class:`runtime.inprocess.Discs`:
   a robot that would overlap another or a static obstacle slides along it; head-on, it keeps right; each such
   move is counted as a contact);
5. a robot holding a surveillance task within ``visit_radius`` of an open waypoint reports it visited.

No sensing noise, no wheel slip: runs differ by their start poses and the bus's seeded jitter.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from runtime.allocation.agent import AgentContext
from runtime.allocation.bus import InMemoryBus
from runtime.allocation.comutar import actions as A
from runtime.control import cspace as C
from runtime.inprocess import Discs
from runtime.allocation.comutar.options import ComutarOptions
from runtime.allocation.comutar.protocol import VISITED, ComutarAgent
from runtime.tasks import Profile, Progress, Task

PIONEER_RADIUS = 0.25          # m: a Pioneer 3-DX fits a 0.26 m circle


class _Estimator:
    def __init__(self, profile: Profile):
        self.profile = profile

    def estimates(self, tasks):
        return []


@dataclass
class Plan:
    """What one robot's commitments ask of its motion this frame."""
    survey: tuple[int, ...] = ()                  # surveillance tasks held
    avoid_from: int | None = None                 # the robot whose sensor feeds my obstacle avoider
    watch: tuple | None = None                    # (sensor, robot, x, y, radius): a region I keep in view


@dataclass
class KinematicFleet:
    starts: Mapping[int, Sequence[float]]                   # robot -> (x, y, heading)
    sensors: Mapping[int, Sequence[str]] = field(default_factory=dict)
    options: ComutarOptions = field(default_factory=ComutarOptions)
    obstacles: Sequence[Sequence[float]] = ()               # static discs (x, y, radius)
    radius: float = PIONEER_RADIUS
    delay: float = 0.01
    jitter: float = 0.002
    drop: float = 0.0
    seed: int = 0
    trace: bool = False                                     # keep every robot's poses (for plots)
    tick: float = 0.05                                      # s between agent ticks (the daemon's cycle)

    def __post_init__(self) -> None:
        self.ids = sorted(int(r) for r in self.starts)
        self.index = {r: i for i, r in enumerate(self.ids)}
        self.win = C.Window(v_max=self.options.speed, w_max=self.options.turn_rate)
        profile = Profile(self.options.speed, self.radius)
        self.agents = {r: ComutarAgent(AgentContext(r, tuple(i for i in self.ids if i != r), _Estimator(profile),
                                                    self.options), tuple(self.sensors.get(r, ())))
                       for r in self.ids}
        self.bus = InMemoryBus(dict(self.agents), delay=self.delay, jitter=self.jitter, drop=self.drop, seed=self.seed)
        self.motion = Discs(self.starts, self.radius, self.obstacles)      # the in-process host's disc bodies
        self.static = self.motion.static
        self.now = 0.0
        self.conflicts = 0
        self.visits: dict[int, dict[int, tuple[float, int]]] = {}   # task -> waypoint -> (time, robot) first visit
        self.revisits = 0
        self.tracks: list[np.ndarray] = [self.poses.copy()] if self.trace else []
        self._points: dict[int, np.ndarray] = {}
        self._plans: dict[int, Plan] = {}
        self._plans_at = -math.inf
        self._check_start()

    def _check_start(self) -> None:
        p = self.poses[:, :2]
        d = np.hypot(p[:, None, 0] - p[None, :, 0], p[:, None, 1] - p[None, :, 1]) + np.eye(len(p)) * 1e9
        if len(p) > 1 and d.min() < 2 * self.radius:
            raise ValueError("start poses: robots overlap")

    # ------------------------------------------------------------------ tasks
    def hand_in(self, tasks: Sequence[Task]) -> None:
        """Every robot learns the tasks (what the fleet table's replication does in the daemon)."""
        for t in tasks:
            if t.kind == "surveillance":
                self._points[t.id] = t.spec.waypoints()
                self.visits.setdefault(t.id, {})
        for a in self.agents.values():
            self.bus.send(a.add_tasks(tasks, self.now), self.now)

    def covered(self, task_id: int) -> bool:
        return len(self.visits.get(task_id, {})) >= len(self._points.get(task_id, ()))

    def finished_at(self, task_id: int) -> float:
        v = self.visits.get(task_id, {})
        return max(t for t, _ in v.values()) if v and self.covered(task_id) else math.nan

    # ------------------------------------------------------------------ one frame
    def step(self) -> None:
        T = self.win.period
        for i, r in enumerate(self.ids):
            self.agents[r].sense(self.poses[i], self._seen_by(r))
        self.bus.run(self.now + T, tick=self.tick)
        self.now = self.bus.now = self.now + T
        if self.now - self._plans_at >= 0.5:
            self._plans = {r: self._plan(r) for r in self.ids}
            self._plans_at = self.now
        choice = C.choose(self.win, self._constraints(), len(self.ids))
        self.conflicts += int(choice.conflict.sum())
        self._move(C.advance(self.poses, choice.v, choice.w, T))
        self._visit()
        if self.trace:
            self.tracks.append(self.poses.copy())

    def run(self, until: float, stop=None) -> float:
        while self.now < until - 1e-9:
            self.step()
            if stop is not None and stop(self):
                break
        return self.now

    # ------------------------------------------------------------------ commitments -> constraints
    def _plan(self, r: int) -> Plan:
        plan = Plan()
        surveys = []
        for c in self.agents[r].commitments:
            p = dict(c.params)
            acts = p.get("actions", ())
            if "survey" in acts:
                surveys.append(c.task_id)
            if "obstacle_avoider" in acts:
                ins = dict(p.get("inputs", ()))
                src = ins.get(A.OBSTACLE_LIST)
                if src == r:                                         # my own detector: who reads for it
                    src = self._reader_of(r, c.task_id)
                plan.avoid_from = src
            region = p.get("region")
            if region is not None:
                reader = next(a for a in acts if a.endswith("_reader"))
                plan.watch = (A.catalogue(("laser", "sonar")).by_name(reader).sensor,) + tuple(region)
        plan.survey = tuple(surveys)
        return plan

    def _reader_of(self, r: int, task_id: int) -> int | None:
        ins = dict(self.agents[r].bidder.links(task_id)[0])
        return ins.get(A.RANGE_DATA)

    def _sensor_of(self, r: int) -> C.Sensor | None:
        have = self.agents[r].catalogue.sensors
        return A.SENSORS[have[0]] if have else None

    def _discs(self) -> np.ndarray:
        robots = np.column_stack([self.poses[:, :2], np.full(len(self.ids), self.radius)])
        return np.vstack([robots, self.static]) if len(self.static) else robots

    def _visible(self, reader: int) -> np.ndarray:
        """Which discs (robots, then static obstacles) ``reader``'s sensor sees now (itself excluded)."""
        discs = self._discs()
        sensor = self._sensor_of(reader)
        if sensor is None:
            return np.zeros(len(discs), dtype=bool)
        i = self.index[reader]
        ex, ey = discs[:, 0] - self.poses[i, 0], discs[:, 1] - self.poses[i, 1]
        d = np.hypot(ex, ey) - discs[:, 2]
        b = C.wrap(np.arctan2(ey, ex) - self.poses[i, 2])
        seen = d <= sensor.range
        if sensor.fov < 2 * math.pi - 1e-9:
            seen &= np.abs(b) <= sensor.fov / 2 + np.arcsin(np.clip(discs[:, 2] / np.maximum(d + discs[:, 2], 1e-9), 0, 1))
        seen[i] = False
        return seen

    def _seen_by(self, r: int) -> np.ndarray:
        return self._discs()[self._visible(r)] if self._sensor_of(r) is not None else np.zeros((0, 3))

    def _constraints(self) -> list[C.Constraint]:
        n = len(self.ids)
        targets = np.full((n, 2), np.nan)
        ignore = np.ones((n, n + len(self.static)), dtype=bool)
        watch: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        for i, r in enumerate(self.ids):
            plan = self._plans.get(r, Plan())
            for tid in plan.survey:
                point = self.agents[r].survey_target(tid)
                if point is not None:
                    targets[i] = point
                    break
            if plan.avoid_from is not None and plan.avoid_from in self.index:
                ignore[i] = ~self._visible(plan.avoid_from)
                ignore[i, i] = True
            if plan.watch is not None:
                kind, _, x, y, rad = plan.watch
                reg, rr = watch.setdefault(kind, (np.full((n, 2), np.nan), np.zeros(n)))
                reg[i], rr[i] = (x, y), rad
        out = [C.survey(self.win, self.poses, targets)]
        if not ignore.all():
            avoid = C.avoid(self.win, self.poses, self._discs(), self.radius, ignore)
            avoid.weight = A.AVOIDER.weight
            out.append(avoid)
        for kind, (reg, rr) in watch.items():
            c = C.sensor_view(self.win, self.poses, reg, rr, A.SENSORS[kind])
            c.weight = A.READERS[kind].weight
            out.append(c)
        return out

    # ------------------------------------------------------------------ motion and visits
    @property
    def poses(self) -> np.ndarray:
        return self.motion.poses

    @property
    def contacts(self) -> int:
        return self.motion.contacts

    @property
    def driven(self) -> np.ndarray:
        return self.motion.driven

    def _move(self, proposed: np.ndarray) -> None:
        self.motion.move(proposed)

    def _visit(self) -> None:
        rad = self.options.visit_radius
        for i, r in enumerate(self.ids):
            plan = self._plans.get(r, Plan())
            for tid in plan.survey:
                pts = self._points.get(tid)
                if pts is None:
                    continue
                d = np.hypot(pts[:, 0] - self.poses[i, 0], pts[:, 1] - self.poses[i, 1])
                for w in np.flatnonzero(d <= rad):
                    w = int(w)
                    board = self.agents[r].boards.get(tid)
                    if board is not None and w in board.visited:
                        continue
                    first = self.visits[tid]
                    if w in first:
                        self.revisits += 1
                    else:
                        first[w] = (self.now, r)
                    msgs = self.agents[r].on_progress(Progress(tid, VISITED, self.now, data={"waypoint": w}), self.now)
                    self.bus.send(msgs, self.now)
