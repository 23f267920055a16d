"""The in-process host: N robot cores (:class:`~runtime.robot.core.RobotCore`, the daemon's logic) on the in-memory
bus, moved by a motion model, on one simulated clock.  Deterministic for a seed; no sockets, no threads.

It is the one way the project runs a fleet inside one process: the allocation tests and sweeps (kinematic motion,
:class:`Kinematic`), the paper 000 foraging experiments (:mod:`sitl.foraging.harness` puts the pybullet foraging
world in as the motion) and the property tests.  Only the lock-step SITL (:mod:`sitl.launcher`) hosts daemons
instead of bare cores, because the bytes on its device and MAVLink links are what it proves.

Each control period (:meth:`Fleet.step`):
1. messages due are delivered, each at its own time (:meth:`RobotCore.receive`);
2. the motion says what every live robot senses (its true pose, bumpers, ranges);
3. every live robot, in id order, runs one core cycle (:meth:`RobotCore.step`): peers the liveness tracker lost,
   the agent's tick, the executors -> the command to the motion, its messages to the bus, its progress to
   ``on_output``;
4. ``after_cycle(now)``; the motion advances one period; ``after_advance(now)``.

Liveness is the daemon's: each live robot sends a heartbeat to every peer once per ``heartbeat_period`` as its link
does (on a bus of their own, with the same delay, jitter and loss, so the agents' bus draws what it always drew);
a peer whose heartbeats are silent for ``heartbeat_timeout`` is reported to the core (:class:`Liveness`, the link's
rule), which loses it once its messages have been silent as long (:mod:`runtime.comms.liveness`); a peer never
heard is the core's own ``comms.startup_grace`` rule.

A robot can start mid-run (:meth:`Fleet.join`; its config may name no peers): cores built with ``joins=True`` take
it into their rosters at its first message, as over Zenoh.

A robot's commitments can also be given instead of allocated (:func:`fixed_method`: the foraging calibration's fixed
commitments), and ``bus=False`` runs robots that never talk (nothing is sent or delivered).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable, Mapping, Protocol, Sequence

import numpy as np

from runtime import tasks as T
from runtime.allocation.agent import DONE, AgentContext, Method
from runtime.allocation.bus import InMemoryBus
from runtime.config.robot import CommsConfig, ControlConfig, Peer, PlanningConfig, RobotConfig, RobotIdentity
from runtime.comms.liveness import Silence
from runtime.control import compiled
from runtime.control.cspace import advance
from runtime.drivers.base import BaseSensors
from runtime.robot.core import Inbox, Output, RobotCore, Sensed
from runtime.robot.ports import BaseFacts
from runtime.tasks import Commitment, Task

MAV_FRAME_LOCAL_ENU = 4


# ---------------------------------------------------------------------------------------------- robots

def robot_config(rid: int, ids: Sequence[int], options, *, speed: float = 0.25, lookahead: float = 0.35,
                 max_turn_rate: float = 2.0, goal_tolerance: float = 0.08, period: float = 0.05,
                 heartbeat_timeout: float = 3.0, planner: str = "euclid", inflate: float | None = None,
                 armed: bool = True) -> RobotConfig:
    """A robot config for a hosted robot: its id and peers, its control tunables, a straight-line planner (no map)
    and the allocation method's ``options``.  Built directly, not from YAML: the host's callers already checked
    what they pass."""
    return RobotConfig(robot=RobotIdentity(id=int(rid), armed=armed),
                       comms=CommsConfig(peers=tuple(Peer(int(p)) for p in ids if p != rid), gcs=None,
                                         heartbeat_timeout=heartbeat_timeout),
                       control=ControlConfig(rate=1.0 / period, lookahead=lookahead, cruise_speed=speed,
                                             max_turn_rate=max_turn_rate, goal_tolerance=goal_tolerance),
                       planning=PlanningConfig(planner=planner, inflate=inflate),
                       allocation=options)


class Liveness(Silence):
    """The daemon link's heartbeat timeout (:meth:`runtime.comms.link.MavlinkLink.peers_lost`): a peer heard once
    and then silent for ``timeout`` is lost (once per silence); hearing it again makes it live."""


@dataclass(frozen=True)
class Heartbeat:
    """What a robot's link sends its peers once per ``heartbeat_period`` (the host's stand-in for a HEARTBEAT)."""
    sender: int
    dest: int = 0


class Beats:
    """A robot's link end for heartbeats: what it hears goes to its :class:`Liveness` only."""

    def __init__(self, robot_id: int, liveness: Liveness):
        self.robot_id, self.liveness = robot_id, liveness

    def on_message(self, msg, now: float) -> list:
        self.liveness.hear(msg.sender, now)
        return []

    def on_tick(self, now: float) -> list:
        return []


class Hosted:
    """One robot on the bus: its core and its liveness tracker (the bus calls :meth:`on_message`)."""

    def __init__(self, core: RobotCore, timeout: float):
        self.core = core
        self.robot_id = core.id
        # a core that takes robots joining at run time hears any robot's heartbeats, as the daemon's link does
        self.liveness = Liveness(None if core.joins else [p.id for p in core.cfg.comms.peers], timeout)

    @property
    def node(self):
        return self.core.node

    @property
    def agent(self):
        return self.core.agent

    @property
    def executive(self):
        return self.core.executive

    @property
    def commitments(self) -> tuple[Commitment, ...]:
        """What the robot works on now (nothing while disarmed)."""
        return self.core.agent.commitments if self.core.node.armed else ()

    def on_message(self, msg, now: float) -> list:
        return self.core.receive(msg, now)

    def on_tick(self, now: float) -> list:        # the bus's own tick loop is not used: Fleet.step drives cores
        return []


# ---------------------------------------------------------------------------------------------- given commitments

class FixedAgent:
    """An agent that allocates nothing: it holds the commitments its host gives it (:attr:`commitments`) and
    ignores tasks, messages and peers.  The foraging calibration works fixed groups this way."""

    def __init__(self, ctx: AgentContext):
        self.robot_id = ctx.robot_id
        self.commitments: tuple[Commitment, ...] = ()
        self.converged = True
        self.dropped = 0

    def _nothing(self, *args) -> list:
        return []

    add_tasks = withdraw_tasks = on_message = on_tick = on_peer_lost = on_peer_joined = on_progress = set_available = \
        _nothing

    def pop_events(self):
        return []


@dataclass(frozen=True)
class FixedOptions:
    pass


def fixed_method(task_kinds: tuple[str, ...] = tuple(T.KINDS)) -> Method:
    """The method of :class:`FixedAgent` (never in the registry: no robot allocates this way)."""
    return Method("fixed", "commitments given by the host, nothing allocated", FixedOptions, FixedAgent, task_kinds)


# ---------------------------------------------------------------------------------------------- motion

class Motion(Protocol):
    """What moves the hosted robots: a world with bodies, or :class:`Kinematic`."""

    def sense(self, robots: Sequence[int]) -> dict[int, tuple[tuple[float, float, float], BaseSensors]]: ...
    def command(self, robot: int, v: float, w: float) -> None: ...
    def advance(self, dt: float) -> None: ...
    def remove(self, robot: int) -> None: ...


class Kinematic:
    """Unicycles with no bodies: each robot follows its command exactly (speed clipped to ``max_speed``, exact
    arcs over each period); robots pass through each other and through obstacles, and sense nothing but their
    pose.  For allocation tests and sweeps, where what matters is who does what and when."""

    def __init__(self, starts: Mapping[int, Sequence[float]], max_speed: float = 0.5):
        self.poses = {int(r): (float(p[0]), float(p[1]), float(p[2]) if len(p) > 2 else 0.0)
                      for r, p in starts.items()}
        self.max_speed = float(max_speed)
        self.commands: dict[int, tuple[float, float]] = {}
        self.driven = dict.fromkeys(self.poses, 0.0)

    def sense(self, robots):
        return {r: (self.poses[r], BaseSensors()) for r in robots}

    def command(self, robot, v, w):
        self.commands[robot] = (max(-self.max_speed, min(self.max_speed, float(v))), float(w))

    def advance(self, dt: float) -> None:
        for r, (v, w) in self.commands.items():
            x, y, th = self.poses[r]
            if abs(w) < 1e-9:
                x, y = x + v * dt * math.cos(th), y + v * dt * math.sin(th)
            else:
                th2 = th + w * dt
                x, y = x + v / w * (math.sin(th2) - math.sin(th)), y - v / w * (math.cos(th2) - math.cos(th))
                th = th2
            self.poses[r] = (x, y, math.remainder(th, math.tau))
            self.driven[r] += abs(v) * dt

    def remove(self, robot: int) -> None:
        self.commands.pop(robot, None)

    def add(self, robot: int, pose: Sequence[float]) -> None:
        """A robot that joins the fleet at run time, at ``pose`` (x, y[, heading])."""
        self.poses[int(robot)] = (float(pose[0]), float(pose[1]), float(pose[2]) if len(pose) > 2 else 0.0)
        self.driven.setdefault(int(robot), 0.0)


class Discs:
    """Discs of ``radius`` in the plane that never overlap, among static discs ``obstacles`` (x, y, radius): each
    robot follows its command on exact arcs over the period, then contacts are resolved in id order.  A disc
    whose new place would overlap another robot (at its new place if it already moved, else its old one) or an
    obstacle is pushed back out along the contact normal, so it slides along the other disc as rigid bodies
    without friction would; if that still overlaps something it stays put.  A head-on contact (the slide keeps
    less than a quarter of the move) keeps right: the move turned -90 deg is tried and taken if it gets further
    (else turned +90 deg, when a third disc blocks the right).  Each such move counts one contact.  A removed
    robot's disc stays where it stopped.  Senses nothing but the pose."""

    def __init__(self, starts: Mapping[int, Sequence[float]], radius: float, obstacles=()):
        self.ids = sorted(int(r) for r in starts)
        self.index = {r: i for i, r in enumerate(self.ids)}
        self.radius = float(radius)
        self.poses = np.array([list(map(float, starts[r]))[:3] for r in self.ids], dtype=float).reshape(-1, 3)
        self.static = np.asarray(obstacles, dtype=float).reshape(-1, 3)
        self.v = np.zeros(len(self.ids))
        self.w = np.zeros(len(self.ids))
        self.driven = np.zeros(len(self.ids))
        self.contacts = 0

    def sense(self, robots):
        return {r: (tuple(float(x) for x in self.poses[self.index[r]]), BaseSensors()) for r in robots}

    def command(self, robot, v, w):
        i = self.index[robot]
        self.v[i], self.w[i] = v, w

    def remove(self, robot):
        self.command(robot, 0.0, 0.0)

    def advance(self, dt: float) -> None:
        self.move(advance(self.poses, self.v, self.w, dt))

    def move(self, proposed) -> None:
        """Every robot to its ``proposed`` pose (n, 3), contacts resolved as the class says."""
        old = self.poses
        final = old.copy()
        final[:, 2] = proposed[:, 2]
        for i in range(len(self.ids)):
            want = proposed[i, :2]
            if np.hypot(*(want - old[i, :2])) < 1e-12:
                continue
            others = np.delete(final[:, :2], i, axis=0)
            discs = np.column_stack([others, np.full(len(others), self.radius)])
            if len(self.static):
                discs = np.vstack([discs, self.static])
            pos, touched = self._slide(old[i, :2], want, discs)
            step = want - old[i, :2]
            if touched and np.dot(pos - old[i, :2], step) < 0.25 * np.dot(step, step):
                for side in (np.array([step[1], -step[0]]), np.array([-step[1], step[0]])):    # right, then left
                    alt, _ = self._slide(old[i, :2], old[i, :2] + side, discs)
                    if np.hypot(*(alt - old[i, :2])) > max(np.hypot(*(pos - old[i, :2])), 0.25 * np.hypot(*step)):
                        pos = alt
                        break
            if touched:
                self.contacts += 1
            final[i, :2] = pos
        self.driven += np.hypot(final[:, 0] - old[:, 0], final[:, 1] - old[:, 1])
        self.poses = final

    def _slide(self, start, want, discs):
        """``want`` pushed out of every disc it overlaps along the contact normal (at most 3 pushes); ``start``
        if it still overlaps one.  Returns (position, touched)."""
        pos, touched = want.copy(), False
        for _ in range(3):
            gap = np.hypot(discs[:, 0] - pos[0], discs[:, 1] - pos[1]) - discs[:, 2] - self.radius
            j = int(np.argmin(gap)) if len(gap) else -1
            if j < 0 or gap[j] >= -1e-9:
                return pos, touched
            touched = True
            n = pos - discs[j, :2]
            norm = np.hypot(*n)
            n = n / norm if norm > 1e-12 else (start - discs[j, :2]) / max(np.hypot(*(start - discs[j, :2])), 1e-12)
            pos = discs[j, :2] + n * (discs[j, 2] + self.radius + 1e-9)
        gap = np.hypot(discs[:, 0] - pos[0], discs[:, 1] - pos[1]) - discs[:, 2] - self.radius
        return (start.copy() if len(gap) and gap.min() < -1e-9 else pos), touched


# ---------------------------------------------------------------------------------------------- the fleet

@dataclass
class Timing:
    """Wall seconds spent, by part (for benchmarks; never part of a result)."""
    deliver: float = 0.0
    sense: float = 0.0
    executive: float = 0.0
    robots: float = 0.0          # core cycles, the executive included
    motion: float = 0.0


class Fleet:
    """Robots ``cores`` ({id: RobotCore}) moved by ``motion`` on one clock of ``period`` s steps, talking over the
    in-memory bus (``delay``, ``jitter``, ``drop``, ``duplicate``, ``seed``; ``bus=False``: they never talk).
    ``profile``: also time the executives (:attr:`timing`).  ``on_output(robot, output, now)`` sees every core cycle's output; ``after_cycle(now)`` runs once all robots
    cycled, ``after_advance(now)`` once the motion advanced."""

    def __init__(self, cores: Mapping[int, RobotCore], motion: Motion, *, period: float = 0.05,
                 delay: float = 0.01, jitter: float = 0.0, drop: float = 0.0, duplicate: float = 0.0, seed: int = 0,
                 heartbeat_timeout: float = 3.0, heartbeat_period: float = 1.0, bus: bool = True,
                 profile: bool = False, links: Mapping | None = None,
                 on_output: Callable[[int, Output, float], None] | None = None,
                 after_cycle: Callable[[float], None] | None = None,
                 after_advance: Callable[[float], None] | None = None):
        compiled.enable()                   # many robots faster than real time: the executive's compiled kernels
        self.robots = {int(r): Hosted(c, heartbeat_timeout) for r, c in sorted(cores.items())}
        self.motion = motion
        self.period = float(period)
        self.talk = bool(bus)
        self.bus = InMemoryBus(dict(self.robots), delay=delay, jitter=jitter, drop=drop, duplicate=duplicate, seed=seed)
        self.heartbeat_period = float(heartbeat_period)
        self.beats = InMemoryBus({r: Beats(r, h.liveness) for r, h in self.robots.items()}, delay=delay, jitter=jitter,
                                 drop=drop, seed=seed + 0x5EED, down=self.bus.down)     # the links' heartbeats
        if links is not None:             # real links (and their transports) instead of the in-memory buses
            self.bus = LinkBus(self.robots, links)
            self.beats = LinkBus({}, {}, down=self.bus.down)      # the links heartbeat themselves
            self.heartbeat_period = math.inf
            for r, h in self.robots.items():
                h.liveness = LinkLiveness(links[r])
        self._next_beat = dict.fromkeys(self.robots, 0.0)
        self.on_output, self.after_cycle, self.after_advance = on_output, after_cycle, after_advance
        self.steps = 0
        self.timing = Timing()
        self._clock = time.perf_counter
        if profile:                         # the executive's share of the cores' time
            for h in self.robots.values():
                _time_executive(h.core, self.timing, self._clock)

    # ------------------------------------------------------------------ the clock
    @property
    def now(self) -> float:
        return self.steps * self.period

    def step(self) -> None:
        """One control period (see the module's docstring)."""
        clock, timing, now = self._clock, self.timing, self.now
        t0 = clock()
        if self.talk:
            self.beats.deliver(now)
            self.bus.deliver(now)
        t1 = clock()
        live = self.live()
        sensed = self.motion.sense(live)
        t2 = clock()
        for r in live:
            h = self.robots[r]
            pose, sensors = sensed[r]
            if self.talk and now >= self._next_beat[r] - 1e-9 and self.heartbeat_period < math.inf:
                self.beats.send([Heartbeat(r)], now)
                nxt = self._next_beat[r] + self.heartbeat_period      # the link's schedule: on time, or from now
                self._next_beat[r] = nxt if nxt > now else now + self.heartbeat_period
            out = h.core.step(now, Sensed(sensors=sensors, pose=pose),
                              Inbox(lost=h.liveness.due(now), alive=h.liveness.alive(now)))
            self.motion.command(r, *out.command)
            if self.on_output is not None:
                self.on_output(r, out, now)
            msgs = out.peer_messages()
            if msgs and self.talk:
                self.bus.send(msgs, now)
        t3 = clock()
        if self.after_cycle is not None:
            self.after_cycle(now)
        t4 = clock()
        self.motion.advance(self.period)
        t5 = clock()
        self.steps += 1
        if self.after_advance is not None:
            self.after_advance(self.now)
        timing.deliver += t1 - t0
        timing.sense += t2 - t1
        timing.robots += t3 - t2
        timing.motion += t5 - t4

    def run(self, until: float, stop: Callable[["Fleet"], bool] | None = None,
            observe: Callable[["Fleet"], None] | None = None) -> float:
        """Step until ``until`` s; ``observe(fleet)`` after every step, ``stop(fleet)`` true ends early (it is asked
        before every step).  Messages due by the time reached are delivered.  Returns the time reached."""
        while self.now < until - 1e-9:
            if stop is not None and stop(self):
                break
            self.step()
            if observe is not None:
                observe(self)
        if self.talk:
            self.beats.deliver(self.now)
            self.bus.deliver(self.now)        # what is due by now is heard now (the next step would, first thing)
        return self.now

    # ------------------------------------------------------------------ robots
    def kill(self, robot: int) -> None:
        """``robot`` fails now: it neither cycles, sends nor receives again, and the motion drops it."""
        if robot in self.bus.down:
            return
        self.bus.down.add(robot)
        if isinstance(self.bus, LinkBus):
            self.bus.links[robot].close()      # its session dies with it
        self.motion.remove(robot)

    def join(self, core: RobotCore, pose: Sequence[float], link=None) -> None:
        """Robot ``core`` starts now at ``pose``, mid-run (its config may name no peers): on the bus from its first
        cycle, heartbeating as the others do (``link``: its real link, for a fleet on links).  The robots already
        there take it into their rosters when its first message reaches them, if their cores take joins
        (``RobotCore(joins=True)``, or a transport that lets robots join).  The motion must take robots at run time
        (:meth:`Kinematic.add`)."""
        rid = core.id
        if rid in self.robots:
            raise ValueError(f"robot {rid} is already in the fleet")
        if not hasattr(self.motion, "add"):
            raise TypeError(f"{type(self.motion).__name__} cannot take a robot at run time")
        h = Hosted(core, core.cfg.comms.heartbeat_timeout)
        self.motion.add(rid, pose)
        self.robots[rid] = h
        if isinstance(self.bus, LinkBus):
            if link is None:
                raise ValueError(f"robot {rid}: a fleet on links needs the joiner's link")
            self.bus.links[rid] = link
            h.liveness = LinkLiveness(link)
        else:
            self.bus.agents[rid] = h
            self.beats.agents[rid] = Beats(rid, h.liveness)
        self._next_beat[rid] = self.now

    def live(self) -> list[int]:
        return sorted(r for r in self.robots if r not in self.bus.down)

    def upload(self, to: int, items, now: float | None = None) -> list[int]:
        """Mission items ``(command, frame, params, x, y)`` accepted by robot ``to`` as an operator's upload is;
        its table spreads them.  Returns the new tasks' fleet ids."""
        now = self.now if now is None else now
        node = self.robots[to].node
        before = set(node.table.entries)
        out = node.add_items(list(items), now)
        if self.talk:
            self.bus.send(out, now)
        return sorted(set(node.table.entries) - before)

    def hand_in(self, to: int, specs, now: float | None = None) -> list[int]:
        """Tasks by their kinds' specs (``Goto(x, y, hold)``, ``Rendezvous(x, y, robots, value)``,
        ``Transport(x, y, weight, deadline, u_max)``) uploaded to robot ``to``; returns their fleet ids."""
        items = []
        for spec in specs:
            command, params = T.kind(kind_of(spec)).to_item(spec)
            items.append((command, MAV_FRAME_LOCAL_ENU, params, spec.x, spec.y))
        return self.upload(to, items, now)

    # ------------------------------------------------------------------ what the fleet did
    def done(self) -> dict[int, tuple[int, ...]]:
        """Tasks reported done (by any robot's agent) -> the coalition that did them."""
        return {ev.task: ev.robots for h in self.robots.values() for ev in h.node.events if ev.what == DONE}

    def holders(self) -> dict[int, dict[int, tuple[int, ...]]]:
        """task -> {robot: its coalition (itself and its partners, sorted)} over the live robots' commitments."""
        out: dict[int, dict[int, tuple[int, ...]]] = {}
        for rid in self.live():
            for c in self.robots[rid].agent.commitments:
                out.setdefault(c.task_id, {})[rid] = tuple(sorted({rid, *c.partners}))
        return out

    def table_state(self, task: int) -> int | None:
        """The task's state in the table of the lowest live robot."""
        e = self.robots[min(self.live())].node.table.entries.get(task)
        return None if e is None else e.state

    def task(self, task_id: int) -> Task:
        return self.robots[min(self.live())].node.table.entries[task_id].task


class LinkBus:
    """The in-memory bus's interface over real links (:class:`runtime.comms.link.MavlinkLink`, any transport): a
    robot's messages go out on its own link, each robot's link is polled at :meth:`deliver`.  Messages arrive when
    the transport brings them (wall time), so a fleet on it is not deterministic; the links heartbeat as daemons'
    do (:class:`LinkLiveness` reads their verdicts)."""

    def __init__(self, robots: Mapping, links: Mapping, down: set | None = None):
        self.robots, self.links = robots, links
        self.down: set[int] = set() if down is None else down

    def send(self, msgs, now: float) -> None:
        by: dict[int, list] = {}
        for m in msgs:
            by.setdefault(m.sender, []).append(m)
        for r, batch in by.items():
            if r not in self.down:
                self.links[r].send_agent(batch, now)

    def deliver(self, now: float) -> None:
        for r, link in self.links.items():
            if r in self.down:
                continue
            for msg in link.poll(now):
                out = self.robots[r].on_message(msg, now)
                if out:
                    self.send(out, now)


class LinkLiveness:
    """A hosted robot's liveness verdicts from its link (heartbeats, and the transport's membership)."""

    def __init__(self, link):
        self.link = link

    def due(self, now: float) -> list[int]:
        return self.link.peers_lost(now)

    def alive(self, now: float) -> list[int]:
        return self.link.peers_alive

    def hear(self, sender: int, now: float) -> None:        # the link hears heartbeats itself
        pass


def _time_executive(core: RobotCore, timing: Timing, clock) -> None:
    """Count the wall time of ``core``'s executive steps into ``timing.executive`` (the core reads no clock)."""
    inner = core.executive.step

    def step(*args, **kwargs):
        t = clock()
        try:
            return inner(*args, **kwargs)
        finally:
            timing.executive += clock() - t

    core.executive.step = step


def kind_of(spec) -> str:
    """The task kind whose Spec ``spec`` is."""
    for name in T.KINDS:
        if isinstance(spec, T.kind(name).Spec):
            return name
    raise TypeError(f"{spec!r} is not the spec of a task kind")


# ---------------------------------------------------------------------------------------------- a kinematic fleet

def kinematic_core(rid: int, ids: Sequence[int], method: str | Method, options=None, *, speed: float = 0.25,
                   radius: float = 0.17, period: float = 0.1, heartbeat_timeout: float = 3.0,
                   joins: bool = False) -> RobotCore:
    """The core of robot ``rid`` of a :func:`kinematic` fleet whose roster is ``ids`` (``(rid,)``: a robot whose
    config names no peers, to :meth:`Fleet.join` a fleet whose cores take ``joins``)."""
    from runtime.allocation import registry

    m = registry.method(method) if isinstance(method, str) else method
    options = m.options() if options is None else options
    # ranging: the robot's (empty) range readings are the truth in a world without bodies, so an idle robot never
    # makes way for a peer's reported position (nothing can touch it)
    facts = BaseFacts(radius=radius, max_speed=max(speed, 0.5), ranging=True)
    return RobotCore(robot_config(rid, ids, options, speed=speed, period=period, heartbeat_timeout=heartbeat_timeout),
                     facts, method=m, base_config=None, joins=joins)


def kinematic(starts: Mapping[int, Sequence[float]], method: str | Method, options=None, *,
              speed: float = 0.25, radius: float = 0.17, period: float = 0.1, heartbeat_timeout: float = 3.0,
              joins: bool = False, **bus) -> Fleet:
    """A fleet of ``starts`` ({id: (x, y[, heading])}) running allocation ``method`` (a registry name or a Method;
    ``options`` default its defaults) with :class:`Kinematic` motion at cruise ``speed``: the real agents and
    executors, bodies of ``radius`` that never touch.  ``joins``: robots outside the roster may join at run time
    (:meth:`Fleet.join`).  ``bus``: the in-memory bus's delay, jitter, drop, duplicate, seed."""
    ids = tuple(sorted(int(r) for r in starts))
    cores = {r: kinematic_core(r, ids, method, options, speed=speed, radius=radius, period=period,
                               heartbeat_timeout=heartbeat_timeout, joins=joins) for r in ids}
    return Fleet(cores, Kinematic(starts, max(speed, 0.5)), period=period, heartbeat_timeout=heartbeat_timeout,
                 **bus)
