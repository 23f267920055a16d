"""Runs a paper 000 foraging experiment in-process, lock-stepped with :class:`~sitl.foraging.world.ForagingWorld`,
deterministic for a seed.

The robots are the in-process host's (:class:`runtime.inprocess.Fleet`): each one the daemon's
:class:`~runtime.robot.core.RobotCore` (the agent of any registered allocation method that allocates
``transport`` tasks, a straight-line planner, the executive running the real
:class:`~runtime.execution.transport.TransportExecutor`) on the world's true pose, bumpers and sonar, talking over
the in-memory bus (delay, jitter, drop, duplication) with the daemon link's peer timeout and a state broadcast
each ``state_period``.  This module is the scenario and the world's bookkeeping: objects, piles, cargo, records.

Each control period (``control_period`` s of simulated time): kills due; messages due are delivered (each at its
own time); every live robot senses and runs one core cycle; what its executors loaded and unloaded is accounted;
done objects are replaced; then the world advances one control period.

Scenario: ``objects`` transport tasks present at once, each handed as a mission item (31001, param1 weight,
param2 deadline, param3 maximum utility) to the lowest-id live robot's node, as an operator's upload is; when
the fleet reports one done (its DONE task event, from any robot), a new one appears at once.  The run ends at
``time_limit`` or when ``max_objects`` are done.

The world keeps the truth about weight.  An object is a pile of ``weight`` wu: a robot's load takes what is
left (at most what its executor reports loading), an unload credits what it carried to the object, and a
robot that fails or drops its commitment while carrying puts its load back on the pile (objects are virtual:
what was not delivered is still to be moved).  So ``delivered`` is the weight that really reached the
delivery point, whatever the agents believe.

``method=None`` is the calibration mode: no allocation, no bus (:func:`runtime.inprocess.fixed_method`); every robot holds a fixed commitment to one object
of unlimited weight (``fixed_object``) from the start, or, the last robots, to ``background`` objects worked at the
same time.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import numpy as np

from runtime import tasks as T
from runtime.allocation import registry
from runtime.allocation.agent import DONE, Method
from runtime.allocation.bus import BusStats
from runtime.drivers.base import BaseSensors
from runtime.errors import InputError
from runtime.execution.transport import TO_DELIVERY, TO_OBJECT
from runtime.inprocess import Fleet, Hosted, fixed_method, robot_config
from runtime.log import get_logger
from runtime.robot.core import RobotCore
from runtime.robot.ports import BaseFacts
from runtime.tasks import Commitment, Progress, Task
from runtime.tasks.transport import DELIVERED, LOADED, MAX_WEIGHT, Transport
from sitl.foraging import scenario
from sitl.sensing import sonar_ring as sonar
from sitl.foraging.scenario import Dist
from sitl.foraging.world import DT, RADIUS, SOLVER_ITERATIONS, ForagingWorld

MAV_FRAME_LOCAL_ENU = 4
STALL_SPEED = 0.02        # m/s: a robot that wants to drive and moves slower than this ...
STALL_TURN = 0.1          # rad/s ... while turning slower than this is stalled
FIXED_TASK = (1 << 16) | 1

log = get_logger("foraging.harness")


@dataclass
class ForagingConfig:
    """One foraging run.  Units: m, s, wu (1 tu = 0.12 s, 1 du = 1 cm: :mod:`sitl.foraging.scenario`)."""
    robots: int | Sequence[int] = 10          # a count (ids 1..n) or the ids
    method: str | Method | None = "auction"   # registry name or Method; None: fixed commitments (calibration)
    options: object = None                    # the method's options (default: its defaults)
    seed: int = 0
    time_limit: float = 3600.0                # s of simulated time
    max_objects: int | None = None            # end once this many objects are done
    objects: int = 3                          # present at once
    weight: Dist = Dist.const(40.0)           # wu
    deadline: Dist = Dist.const(108.0)        # s after the object appears (900 tu)
    u_max: Dist = Dist.integers(50, 150)
    size: float = 10.0                        # m, side of the square arena centred on the origin
    delivery: tuple[float, float] = (0.0, 0.0)
    min_distance: float = scenario.MIN_DISTANCE   # m, objects at least this far from the delivery point ...
    min_angle: float = scenario.MIN_ANGLE     # deg, ... and this far apart seen from it
    wall_margin: float = 0.5                  # m, and this far from the walls
    starts: Mapping[int, tuple[float, float, float]] | None = None   # default: seeded, spread over the arena
    fixed_object: tuple[float, float] = (1.4, 0.0)     # calibration mode: the object's place
    background: tuple[tuple[float, float, int], ...] = ()  # calibration mode: other objects (x, y, robots) worked
                                              # at the same time by the last robots (traffic the model then sees)
    load: float = 2.0                         # wu per trip (calibration mode's commitments)
    load_time: float = 0.12                   # s per wu
    reach: float = 0.3                        # m, loads this close to the object (calibration mode's commitments)
    delivery_reach: float = scenario.DELIVERY_AREA   # m, unloads this close to the delivery point
    speed: float = 0.25                       # m/s cruise (the paper's 3 du/tu)
    lookahead: float = 0.3                    # m (pure pursuit; it slows down within 2 x this of a mark)
    max_turn_rate: float = 2.0                # rad/s (arc set and pursuit; the drive ramps at 100 deg/s^2)
    goal_tolerance: float = 0.12
    control_period: float = 0.1               # s
    dt: float = DT                            # s, physics step
    solver_iterations: int = SOLVER_ITERATIONS
    delay: float = 0.01                       # bus: mean one-way delay (s), jitter, loss and duplication
    jitter: float = 0.0
    drop: float = 0.0
    duplicate: float = 0.0
    heartbeat_timeout: float = 3.0            # s of silence before a heard peer is lost
    state_period: float = 1.0                 # s between a node's state broadcasts
    kills: tuple[tuple[float, int], ...] = ()  # (time, robot): the robot fails then (gone, radio-silent)
    sonar: bool = True                        # feed the sonar ring to the executive (False: bumpers only)

    @property
    def ids(self) -> tuple[int, ...]:
        return tuple(range(1, self.robots + 1)) if isinstance(self.robots, int) else tuple(sorted(self.robots))

    def params(self) -> tuple[tuple[str, object], ...]:
        """The transport executor's parameters the calibration's fixed commitments carry."""
        return (("delivery", tuple(self.delivery)), ("load", self.load), ("load_time", self.load_time),
                ("reach", self.reach), ("delivery_reach", self.delivery_reach))


@dataclass
class ObjectRecord:
    task: int                                 # fleet task id
    x: float
    y: float
    weight: float
    deadline: float
    u_max: float
    appeared: float
    finished: float | None = None             # the fleet's DONE
    done_by: tuple[int, ...] = ()
    delivered: float = 0.0                    # wu that reached the delivery point
    pile: float = 0.0                         # wu still on the object
    coalition: list[tuple[float, int]] = field(default_factory=list)    # (time, robots committed) at changes

    @property
    def elapsed(self) -> float | None:
        return None if self.finished is None else self.finished - self.appeared

    @property
    def utility_soft(self) -> float:
        e = self.elapsed
        return 0.0 if e is None else scenario.utility_soft(e, self.deadline, self.u_max)

    @property
    def utility_hard(self) -> float:
        e = self.elapsed
        return 0.0 if e is None else scenario.utility_hard(e, self.deadline, self.u_max)

    def mean_coalition(self, end: float) -> float:
        """Time-averaged number of robots committed, from appearance to finish (or ``end``)."""
        stop = self.finished if self.finished is not None else end
        if stop <= self.appeared or not self.coalition:
            return 0.0
        total = 0.0
        for (t, n), nxt in zip(self.coalition, self.coalition[1:] + [(stop, 0)]):
            total += n * (min(nxt[0], stop) - t)
        return total / (stop - self.appeared)


@dataclass
class RobotRecord:
    robot: int
    trips: int = 0                            # unloads at the delivery point
    delivered: float = 0.0                    # wu it delivered
    empty_loads: int = 0                      # loads that found the pile empty (took less than reported)
    distance: float = 0.0                     # m driven
    stalled: float = 0.0                      # s wanting to drive (a driving phase) but neither moving nor turning
    killed_at: float | None = None


@dataclass
class ForagingResult:
    config: ForagingConfig
    end: float                                # simulated s
    objects: list[ObjectRecord]
    robots: dict[int, RobotRecord]
    messages: BusStats
    timing: dict[str, float]                  # wall s: physics, sonar, executive, agents, harness, total

    @property
    def finished(self) -> list[ObjectRecord]:
        return [o for o in self.objects if o.finished is not None]

    @property
    def moved(self) -> float:
        """wu delivered, over every object."""
        return sum(o.delivered for o in self.objects)

    def utility(self, hard: bool = False) -> float:
        return sum(o.utility_hard if hard else o.utility_soft for o in self.finished)

    def within(self, factor: float = 1.0) -> float:
        """Fraction of the finished objects done within ``factor`` times their deadline."""
        done = self.finished
        return sum(o.elapsed <= factor * o.deadline for o in done) / len(done) if done else math.nan


class _WorldMotion:
    """The foraging world as the in-process host's motion: true poses, bumpers and (``sonar``) the sonar ring."""

    def __init__(self, world: ForagingWorld, sonar_on: bool):
        self.world = world
        self.sonar_on = sonar_on

    def sense(self, robots):
        world = self.world
        ranges = world.sonar()
        bumps = world.bumpers()
        poses = world.poses.tolist()
        bumps = bumps.tolist()
        seen = sonar.readings_all(ranges) if self.sonar_on else None
        out = {}
        for r in robots:
            k = world.index[r]
            out[r] = (tuple(poses[k]), BaseSensors(bump_left=bumps[k][0], bump_right=bumps[k][1],
                                                   ranges=seen[k] if seen is not None else ()))
        return out

    def command(self, robot, v, w):
        self.world.command(robot, v, w)

    def advance(self, dt):
        self.world.advance(dt)

    def remove(self, robot):
        self.world.remove(robot)


class ForagingRun:
    """A foraging run being simulated: :meth:`run` it (or :meth:`step` it), :meth:`kill` robots on the way, read
    :meth:`result`.  ``world(starts, cfg)`` builds the world (default :class:`ForagingWorld`; a benchmark puts
    a peer with the same methods in its place)."""

    def __init__(self, cfg: ForagingConfig, world: Callable | None = None):
        self.cfg = cfg
        ids = cfg.ids
        if not ids:
            raise InputError("foraging robots: expected at least one robot")
        if not (math.isfinite(cfg.control_period) and cfg.control_period >= cfg.dt):
            raise InputError(f"control_period {cfg.control_period!r}: expected a time >= the physics step {cfg.dt}")
        self.method = self._method(cfg.method)
        options = cfg.options
        if self.method is not None and options is None:
            options = self.method.options()
        starts = self._starts(ids)
        self.world = (world or _fast_world)(starts, cfg)
        self.host = Fleet(self._cores(ids, options), _WorldMotion(self.world, cfg.sonar), period=cfg.control_period,
                          delay=cfg.delay, jitter=cfg.jitter, drop=cfg.drop, duplicate=cfg.duplicate, seed=cfg.seed,
                          heartbeat_timeout=cfg.heartbeat_timeout, bus=self.method is not None, profile=True,
                          on_output=self._output, after_cycle=self._after_cycle, after_advance=self._after_advance)
        self.robots = self.host.robots
        self.bus = self.host.bus
        self.records = {r: RobotRecord(r) for r in ids}
        self._rng = np.random.default_rng([cfg.seed, 1])
        self.objects: dict[int, ObjectRecord] = {}      # task id -> record, present and past, in order
        self.present: list[int] = []
        self.cargo: dict[int, tuple[int, float]] = {}   # robot -> (task, wu on board)
        self._events_seen = {r: 0 for r in ids}
        self._kills = sorted(cfg.kills)
        self._before: np.ndarray | None = None
        self._harness_time = 0.0                        # wall s in this module's bookkeeping ...
        self._account_time = 0.0                        # ... of which inside the robots' cycles (accounting)
        for r, h in self.robots.items():
            h.core.locate(self._pose(r))
        if self.method is None:
            self._fixed_object()
        else:
            for _ in range(cfg.objects):
                self._spawn(0.0)

    def _cores(self, ids, options) -> dict[int, RobotCore]:
        """Each robot's core: the method's agent (calibration mode: fixed commitments), a straight-line planner,
        the executive with the run's tunables and its own seed."""
        cfg = self.cfg
        method = self.method if self.method is not None else fixed_method(("transport",))
        facts = BaseFacts(radius=RADIUS, max_speed=cfg.speed, ranging=True)    # the sonar ring (off: bumpers only)
        return {r: RobotCore(robot_config(r, ids, options, speed=cfg.speed, lookahead=cfg.lookahead,
                                          max_turn_rate=cfg.max_turn_rate, goal_tolerance=cfg.goal_tolerance,
                                          period=cfg.control_period, heartbeat_timeout=cfg.heartbeat_timeout),
                             facts, method=method, seed=cfg.seed * 1000 + r, base_config=None,
                             state_period=cfg.state_period)
                for r in ids}

    # ------------------------------------------------------------------ building
    @staticmethod
    def _method(method) -> Method | None:
        if method is None:
            return None
        m = registry.method(method) if isinstance(method, str) else method
        if "transport" not in m.task_kinds:
            raise InputError(f"allocation method {m.name}: expected one that allocates transport tasks, it takes "
                             f"{'|'.join(m.task_kinds) or 'none'}")
        return m

    def _starts(self, ids) -> dict[int, tuple[float, float, float]]:
        cfg = self.cfg
        if cfg.starts is not None:
            missing = [r for r in ids if r not in cfg.starts]
            if missing:
                raise InputError(f"foraging starts: expected a start for every robot, none for {missing}")
            return {r: tuple(cfg.starts[r]) for r in ids}
        return scenario.starts(np.random.default_rng([cfg.seed, 0]), ids, cfg.size, RADIUS)

    def _fixed_object(self) -> None:
        """Calibration mode: the fixed object (first record) worked by the first robots, each background object by
        as many of the last robots as it names; every robot's partners are its own group."""
        cfg = self.cfg
        ids = list(self.robots)
        extra = sum(int(n) for _, _, n in cfg.background)
        if any(int(n) < 1 for _, _, n in cfg.background) or extra >= len(ids):
            raise InputError(f"foraging background {cfg.background!r}: expected groups of at least one robot, fewer "
                             f"than the {len(ids)} robots in all (the fixed object keeps one at the least)")
        groups = [(cfg.fixed_object, len(ids) - extra)] + [((x, y), int(n)) for x, y, n in cfg.background]
        for k, ((x, y), n) in enumerate(groups):
            task = Task(FIXED_TASK + k, "transport", Transport(float(x), float(y), MAX_WEIGHT, 1e6, 0.0))
            rec = ObjectRecord(task.id, float(x), float(y), math.inf, math.inf, 0.0, 0.0, pile=math.inf)
            rec.coalition.append((0.0, n))
            self.objects[task.id] = rec
            self.present.append(task.id)
            group, ids = ids[:n], ids[n:]
            for r in group:
                partners = tuple(q for q in group if q != r)
                self.robots[r].agent.commitments = (Commitment(task, partners=partners, role="member",
                                                               params=cfg.params()),)

    def _spawn(self, now: float) -> None:
        """A new object, handed to the lowest-id live robot as an operator's one-item upload."""
        cfg = self.cfg
        live = self.live()
        if not live:
            return
        x, y = scenario.object_place(self._rng, cfg.size, cfg.delivery, cfg.min_distance, cfg.wall_margin,
                                     [(self.objects[t].x, self.objects[t].y) for t in self.present], cfg.min_angle)
        weight, deadline, u_max = (d.draw(self._rng) for d in (cfg.weight, cfg.deadline, cfg.u_max))
        spec = Transport(x, y, weight, deadline, u_max)
        command, params = T.kind("transport").to_item(spec)
        (tid,) = self.host.upload(live[0], [(command, MAV_FRAME_LOCAL_ENU, params, x, y)], now)
        self.objects[tid] = ObjectRecord(tid, x, y, weight, deadline, u_max, now, pile=weight, coalition=[(now, 0)])
        self.present.append(tid)

    # ------------------------------------------------------------------ running
    @property
    def now(self) -> float:
        return self.host.now

    def live(self) -> list[int]:
        return self.host.live()

    def kill(self, robot: int) -> None:
        """``robot`` fails now: it leaves the bus and the world; whatever it carried goes back to its pile."""
        if robot in self.host.bus.down:
            return
        self.host.kill(robot)
        self.records[robot].killed_at = self.now
        self._drop_cargo(robot)
        log.info("robot %d killed at %.1f s", robot, self.now)

    def done(self) -> bool:
        cfg = self.cfg
        if self.now >= cfg.time_limit - 1e-9:
            return True
        return cfg.max_objects is not None and sum(o.finished is not None for o in self.objects.values()) >= cfg.max_objects

    def run(self, observe: Callable[["ForagingRun"], None] | None = None) -> ForagingResult:
        """Step until the time limit or ``max_objects``; ``observe(run)`` after every control period."""
        while not self.done():
            self.step()
            if observe is not None:
                observe(self)
        return self.result()

    def step(self) -> None:
        """One control period: kills due, then the host's step (messages due, every live robot's cycle, done
        objects replaced, the world advanced)."""
        now = self.now
        while self._kills and self._kills[0][0] <= now + 1e-9:
            self.kill(self._kills.pop(0)[1])
        self.host.step()

    def _output(self, robot: int, out, now: float) -> None:
        """A robot's cycle: what its executors loaded and unloaded is accounted against the piles."""
        t = time.perf_counter()
        for pr in out.progress:
            self._account(robot, pr)
        self._check_cargo(robot)
        t = time.perf_counter() - t
        self._harness_time += t
        self._account_time += t

    def _after_cycle(self, now: float) -> None:
        t = time.perf_counter()
        if self.method is not None:
            self._finish_done(now)
        self._coalitions(now)
        self._before = self.world.poses.copy()
        self._harness_time += time.perf_counter() - t

    def _after_advance(self, now: float) -> None:
        t = time.perf_counter()
        self._read_poses(self._before)
        self._harness_time += time.perf_counter() - t

    def _pose(self, robot: int) -> tuple[float, float, float]:
        p = self.world.poses[self.world.index[robot]]
        return (float(p[0]), float(p[1]), float(p[2]))

    def _read_poses(self, before: np.ndarray) -> None:
        """Distance driven and time stalled, from the poses before and after the world's step."""
        poses = self.world.poses
        period = self.cfg.control_period
        for r in self.live():
            k = self.world.index[r]
            step = math.hypot(poses[k, 0] - before[k, 0], poses[k, 1] - before[k, 1])
            rec = self.records[r]
            rec.distance += step
            turn = abs(math.remainder(poses[k, 2] - before[k, 2], math.tau))
            if step < STALL_SPEED * period and turn < STALL_TURN * period and self._driving(self.robots[r]):
                rec.stalled += period

    @staticmethod
    def _driving(rb: Hosted) -> bool:
        return any(getattr(e, "phase", None) in (TO_OBJECT, TO_DELIVERY) for e in rb.executive.executors.values())

    # ------------------------------------------------------------------ weight, objects, coalitions
    def _account(self, robot: int, pr: Progress) -> None:
        obj = self.objects.get(pr.task)
        if obj is None:
            return
        rec = self.records[robot]
        wu = float(pr.data.get("wu", 0.0))
        if pr.event == LOADED:
            self._drop_cargo(robot)                      # a second load without an unload: the first goes back
            took = min(wu, obj.pile)
            obj.pile -= took
            if took < wu:
                rec.empty_loads += 1
            self.cargo[robot] = (pr.task, took)
        elif pr.event == DELIVERED:
            task, wu_on = self.cargo.pop(robot, (pr.task, 0.0))
            if task in self.objects:
                self.objects[task].delivered += wu_on
            rec.trips += 1
            rec.delivered += wu_on

    def _check_cargo(self, robot: int) -> None:
        """A robot whose commitment ended while it carried: the load goes back to the pile."""
        c = self.cargo.get(robot)
        if c is not None and c[0] not in self.robots[robot].executive.executors:
            self._drop_cargo(robot)

    def _drop_cargo(self, robot: int) -> None:
        task, wu = self.cargo.pop(robot, (None, 0.0))
        if task in self.objects and self.objects[task].finished is None:
            self.objects[task].pile += wu

    def _finish_done(self, now: float) -> None:
        for r in self.robots:
            node = self.robots[r].node
            events = node.events
            for ev in events[self._events_seen[r]:]:
                obj = self.objects.get(ev.task)
                if ev.what == DONE and obj is not None and obj.finished is None:
                    obj.finished, obj.done_by = now, tuple(ev.robots)
                    obj.coalition.append((now, 0))
                    self.present.remove(ev.task)
                    log.debug("object %d done at %.1f s (%.1f s after it appeared, %.1f/%.1f wu delivered)",
                              ev.task, now, obj.elapsed, obj.delivered, obj.weight)
                    if self.cfg.max_objects is None or len(self.objects) < self.cfg.max_objects:
                        self._spawn(now)
            self._events_seen[r] = len(events)

    def _coalitions(self, now: float) -> None:
        if self.method is None:
            return
        count = dict.fromkeys(self.present, 0)
        for r in self.live():
            for c in self.robots[r].commitments:
                if c.task_id in count:
                    count[c.task_id] += 1
        for tid, n in count.items():
            co = self.objects[tid].coalition
            if co[-1][1] != n:
                co.append((now, n))

    def result(self) -> ForagingResult:
        t = self.host.timing
        timing = {"physics": t.motion, "sonar": t.sense, "executive": t.executive,
                  "agents": t.deliver + t.robots - t.executive - self._account_time, "harness": self._harness_time}
        timing["total"] = sum(timing.values())
        return ForagingResult(self.cfg, self.now, list(self.objects.values()), dict(self.records), self.bus.stats,
                              timing)

    def close(self) -> None:
        self.world.close()


def _fast_world(starts, cfg: ForagingConfig) -> ForagingWorld:
    return ForagingWorld(starts, size=cfg.size, dt=cfg.dt, solver_iterations=cfg.solver_iterations)


def run(cfg: ForagingConfig, observe=None) -> ForagingResult:
    """Build, run and close one foraging run."""
    fr = ForagingRun(cfg)
    try:
        return fr.run(observe)
    finally:
        fr.close()
