"""The executive: starts and cancels executors to match the allocation agent's commitments, lets them and
the robot-wide behaviours vote in the DAMN arbiter, and returns the command and the progress to report.

Robot-wide behaviours: obstacle avoidance (bumpers, range readings) and standing still when no executor
is driving.  The arbiter's winning arc is replaced by the leading executor's exact command when that
command's arc won (the path follower won: no grid rounding).
"""
from __future__ import annotations

import math
import random
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Mapping

import numpy as np

from runtime.control.arbiter import Arbiter, ArcSet
from runtime.control.behaviours import AvoidObstacles, Stop
from runtime.control.pure_pursuit import PurePursuit
from runtime.execution import executor_class
from runtime.tasks import Commitment, Progress


@dataclass
class Tunables:
    """What a ground station may change while the robot runs (parameters)."""
    cruise_speed: float
    lookahead: float
    max_turn_rate: float
    goal_tolerance: float


@dataclass
class ExecContext:
    planner: object                   # runtime.planning.robot_planner.RobotPlanner
    tunables: Tunables
    log: object
    radius: float                     # m, the base's footprint (obstacle avoidance)
    seed: int = 0                     # the robot's own random choices (escape turns): its id on a robot
    robot_id: int | None = None       # the robot's fleet id, for executors that take turns with partners

    @property
    def goal_tolerance(self) -> float:
        return self.tunables.goal_tolerance

    def pursuit(self) -> PurePursuit:
        t = self.tunables
        return PurePursuit(lookahead=t.lookahead, cruise_speed=t.cruise_speed, max_turn_rate=t.max_turn_rate,
                           goal_tolerance=t.goal_tolerance)


NONE: Mapping = MappingProxyType({})      # no guidance from the allocation family

STALL_TIME = 4.0          # s over which a stall is judged
STALL_MOVE = 0.1          # m the path follower asked for, at least, in that time (turns at the robot's radius) ...
STALL_SHARE = 0.25        # ... of which the robot got less than this share: stalled
ESCAPE_TIME = 2.0         # s backing up and turning
MAKE_WAY_GAP = 0.35       # m from an idle robot's body: something this close makes it move off
MAKE_WAY_CLEAR = 0.2      # m: ... if the side it moves to is clear this far
MAKE_WAY_SPEED = 0.1      # m/s


@dataclass
class Executive:
    ctx: ExecContext
    executors: dict[int, object] = field(default_factory=dict)      # task id -> executor
    arbiter: Arbiter | None = None
    escapes: int = 0                  # stalls escaped by backing up
    make_way: bool = False            # idle, move off when something comes this close (the daemon: when armed)
    peers: tuple = ()                 # (bearing, distance) readings of where peers report they stand (making way)
    made_way: int = 0                 # cycles spent making way
    cspace: object = None             # CoMutaR's c-space behaviour, once an executor has constraints

    def __post_init__(self) -> None:
        self.avoid = AvoidObstacles(radius=self.ctx.radius)
        self._backing = False
        self._mark: tuple[tuple, float, float] | None = None  # (pose, time, m asked since) of the stall window
        self._last: tuple | None = None                         # (follower's command, time) of the last cycle
        self._rng = random.Random(self.ctx.seed)
        self._pose_at: tuple | None = None                      # (pose, time) of the last cycle
        self._rebuild_arbiter()

    def _arcs(self) -> ArcSet:
        t = self.ctx.tunables
        return ArcSet.uniform(max_speed=t.cruise_speed, max_turn_rate=t.max_turn_rate)

    def _rebuild_arbiter(self) -> None:
        lead = self._lead()
        follows = [b for e in self.executors.values() for b in e.behaviours]
        stop = [Stop(lead.follow)] if lead is not None else []
        cspace = [e for e in self.executors.values() if e.window is not None]
        if cspace:
            if self.cspace is None:
                from runtime.execution.cspace_vote import CspaceVote
                self.cspace = CspaceVote(cspace[0].window, self.ctx.log)
            follows.append(self.cspace)
        if self.arbiter is None:
            self.arbiter = Arbiter(self._arcs(), follows + [self.avoid] + stop)
        else:
            self.arbiter.behaviours = follows + [self.avoid] + stop

    def _lead(self):
        """The executor whose path follower leads (the first that has one), or None."""
        return next((e for e in self.executors.values() if e.follow is not None), None)

    def tune(self, **changes) -> None:
        """Apply changed tunables now: running executors' followers and the arbiter's arcs too."""
        for k, v in changes.items():
            setattr(self.ctx.tunables, k, v)
        for e in self.executors.values():
            if e.follow is None:
                continue
            p = e.follow.follower
            t = self.ctx.tunables
            p.lookahead, p.cruise_speed, p.max_turn_rate, p.goal_tolerance = (t.lookahead, t.cruise_speed,
                                                                              t.max_turn_rate, t.goal_tolerance)
            p.slow_radius, p.min_speed = 2.0 * t.lookahead, 0.15 * t.cruise_speed
            e.retune()                            # the executor's own adjustments to its follower
        self.arbiter.arcs = self._arcs()

    # ------------------------------------------------------------------ commitments
    def sync(self, commitments: tuple[Commitment, ...], now: float, guidance: Mapping = NONE) -> None:
        """Start executors for new commitments, cancel those whose commitment ended.  A commitment that changed
        but keeps its task goes to its executor's ``recommit``, which carries on with it (a transport keeps its
        load when its coalition changes) or asks to be restarted.  ``guidance``: what the allocation family wrote
        for each task this cycle (task id -> data), given to its executor as ``guide``."""
        want = {c.task_id: c for c in commitments}
        changed = False
        for tid in list(self.executors):
            ex = self.executors[tid]
            c = want.get(tid)
            if c is None or (c != ex.commitment and not ex.recommit(c, now)):
                self.executors.pop(tid).cancel(now)
                changed = True
        for tid, c in want.items():
            if tid not in self.executors:
                ex = self.executors[tid] = executor_class(c.task.kind)(c, self.ctx)
                ex.guide = guidance.get(tid)
                changed = True
        if changed:
            self._rebuild_arbiter()

    @property
    def idle(self) -> bool:
        return not self.executors

    # ------------------------------------------------------------------ one control cycle
    def step(self, pose, sensors, now: float, guidance: Mapping = NONE) -> tuple[tuple[float, float], list[Progress]]:
        """The command for this cycle and the progress to report.  ``pose`` None or no executor: stand still.
        ``sensors``: a :class:`~runtime.drivers.base.BaseSensors` (the core's: the base's readings and its range
        sensors').  ``guidance``: as for :meth:`sync`."""
        if pose is None or not self.executors:
            return self._make_way(sensors, now), []
        for tid, e in self.executors.items():
            e.guide = guidance.get(tid)
        for e in self.executors.values():
            e.begin(pose, now)
        self.avoid.on_bumpers(sensors.bump_left, sensors.bump_right, now)
        ranges = sensors.ranges
        if ranges:
            self.avoid.on_ranges(ranges, now)
        lead = self._lead()
        goal = None
        if lead is not None:
            goal = lead.goal or (lead.follow.path[-1] if lead.follow.path else None)
        self.avoid.goal_distance = math.hypot(goal[0] - pose[0], goal[1] - pose[1]) if goal else math.inf
        self._track_speed(pose, now)
        if lead is not None:
            self._check_stall(pose, now)
        backing = self.avoid.backing_up(now)
        if self._backing and not backing:
            for e in self.executors.values():
                e.bump_ended(pose, now)
        self._backing = backing
        progress = []
        for e in self.executors.values():
            progress += e.update(pose, now)
        if self.cspace is not None:
            self.cspace.set([c for e in self.executors.values() for c in e.constraints()])
        d = self.arbiter.decide(now)
        if lead is None:
            c = self.cspace.choice if self.cspace is not None else None
            if c is not None and not backing and np.isfinite(d.scores[self.arbiter.arcs.nearest(c.v[0], c.w[0])]):
                return (float(c.v[0]), float(c.w[0])), progress   # the c-space's choice, where nothing else vetoes it
            return (d.v, d.w), progress
        cmd = lead.follow.command
        if cmd is not None and not backing and d.arc == self.arbiter.arcs.nearest(*cmd):
            return cmd, progress          # the path follower won: pass its exact command, not the arc's grid value
        return (d.v, d.w), progress

    def _make_way(self, sensors, now: float) -> tuple[float, float]:
        """An idle robot stands still, unless (``make_way``) something is within ``MAKE_WAY_GAP`` of its body:
        then it creeps straight away from the nearest reading, if that side is clear.  A robot with nothing to do
        parked on a mark (the delivery point, a goal) moves off when another robot comes to it.  Readings are the
        base's ranges and, for a robot that has none, where the peers report they stand (``peers``)."""
        ranges = tuple(sensors.ranges) + tuple(self.peers)
        if not self.make_way or not ranges:
            return 0.0, 0.0
        r = self.ctx.radius
        near = [(b, d) for b, d in ranges if math.isfinite(b) and math.isfinite(d) and 0 <= d < r + MAKE_WAY_GAP]
        if not near:
            return 0.0, 0.0
        b, d = min(near, key=lambda x: x[1])
        ahead = math.cos(b) > 0
        away = [(bb, dd) for bb, dd in ranges if math.isfinite(bb) and (math.cos(bb) > 0) != ahead
                and math.isfinite(dd) and 0 <= dd < r + MAKE_WAY_CLEAR]
        if away:
            return 0.0, 0.0                      # boxed in: stay
        self.made_way += 1
        return (-MAKE_WAY_SPEED if ahead else MAKE_WAY_SPEED), 0.0

    def _track_speed(self, pose, now: float) -> None:
        """The robot's forward speed from its last two poses, for the avoidance behaviour (what closes on it
        faster than it drives comes towards it)."""
        last, self._pose_at = self._pose_at, (pose, now)
        if last is not None and now > last[1]:
            (x, y, _), t = last
            th = pose[2]
            self.avoid.speed = ((pose[0] - x) * math.cos(th) + (pose[1] - y) * math.sin(th)) / (now - t)

    def _check_stall(self, pose, now: float) -> None:
        """A robot whose path follower has asked for at least ``STALL_MOVE`` m of driving (turning counts at the
        robot's radius) and that got less than ``STALL_SHARE`` of it over ``STALL_TIME`` s backs up for
        ``ESCAPE_TIME`` s, turning to a side drawn at random (robots stalled against each other draw apart, not
        in step); the executors then re-plan from where it ends, as after a bump.  A slow final approach asks
        for little and is left alone."""
        cmd = self._lead().follow.command
        mark, last = self._mark, self._last
        self._last = (cmd, now)
        if cmd is None or self.avoid.backing_up(now) or mark is None:
            self._mark = (pose, now, 0.0)
            return
        if last is not None and last[0] is not None:
            v, w = last[0]
            self._mark = mark = (mark[0], mark[1], mark[2] + (abs(v) + self.ctx.radius * abs(w)) * (now - last[1]))
        (x, y, th), t, wanted = mark
        turned = abs((pose[2] - th + math.pi) % (2 * math.pi) - math.pi)
        got = math.hypot(pose[0] - x, pose[1] - y) + self.ctx.radius * turned
        if now - t < STALL_TIME:
            return
        if wanted >= STALL_MOVE and got < STALL_SHARE * wanted:
            turn = self._rng.choice((-1.0, 1.0)) * self.avoid.backup_turn
            self.ctx.log.info("stalled: %.2f m in %.0f s of %.2f m asked; backing up %.0f s turning %+.1f rad/s",
                              got, now - t, wanted, ESCAPE_TIME, turn)
            self.avoid.escape(turn, ESCAPE_TIME, now)
            self.escapes += 1
        self._mark = (pose, now, 0.0)

    @property
    def arrived(self) -> bool:
        lead = self._lead()
        return lead is not None and lead.follow.done
