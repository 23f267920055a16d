"""A fleet on the in-memory bus: each robot is the daemon's :class:`~runtime.fleet.node.FleetNode` (task table +
the agent of any registered allocation method) with a kinematic stand-in for execution and the link's peer
timeout.  For tests and fast sweeps of every family; no physics, no sockets.

* Execution: a robot drives straight to its first commitment's point at ``speed`` (m/s), reports ``arrived``
  once within ``tolerance``, and ``done`` when its task kind's executor would
  (:meth:`~runtime.execution.goto.GotoExecutor.finishes_after`: a goto after its hold time, a rendezvous
  never: the agent ends it); bodies do not collide.  A disarmed robot stands still.
* Liveness: like the daemon's link, a peer heard once and then silent for ``heartbeat_timeout`` seconds is
  reported lost to the node (once per silence); every node broadcasts its ``RobotState`` each second.
* :meth:`SimFleet.kill` takes a robot off the bus (it neither sends nor receives again).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Mapping

from runtime import tasks as T
from runtime.allocation import registry
from runtime.allocation.agent import DONE, AgentContext
from runtime.allocation.bus import InMemoryBus
from runtime.execution import executor_class
from runtime.fleet.node import FleetNode
from runtime.tasks import ARRIVED, DONE as P_DONE, Estimate, Profile, Progress, Task
from runtime.tasks import estimate as task_estimate

MAV_FRAME_LOCAL_ENU = 4


class StraightLineEstimator:
    """The agent's estimator for a point robot: straight-line travel from its current position."""

    def __init__(self, profile: Profile, pose: Callable[[], tuple[float, float] | None]):
        self.profile = profile
        self.pose = pose

    def estimates(self, tasks) -> list[Estimate]:
        p = self.pose()
        if p is None:
            return [Estimate(math.inf, math.inf) for _ in tasks]
        return [task_estimate(t, self.profile, lambda x, y: math.hypot(x - p[0], y - p[1])) for t in tasks]


class SimRobot:
    """One robot on the bus (the bus calls ``on_message`` and ``on_tick``)."""

    def __init__(self, robot_id: int, peers, start: tuple[float, float], method, options,
                 speed: float = 0.25, radius: float = 0.17, tolerance: float = 0.05, heartbeat_timeout: float = 3.0):
        self.robot_id = int(robot_id)
        self.peers = tuple(p for p in peers if p != robot_id)
        self.pos = (float(start[0]), float(start[1]))
        self.speed, self.tolerance, self.timeout = speed, tolerance, heartbeat_timeout
        self.estimator = StraightLineEstimator(Profile(speed, radius), lambda: self.pos)
        self.agent = method.make(AgentContext(self.robot_id, self.peers, self.estimator, options))
        self.node = FleetNode(self.robot_id, self.agent, peers=self.peers)
        self.finished: set = set()              # commitments that reported done
        self.heard: dict[int, float] = {}
        self.lost: set[int] = set()
        self.arrived: dict = {}                 # commitments that reported arrival -> when
        self.driven = 0.0
        self._last: float | None = None

    def on_message(self, msg, now: float) -> list:
        if msg.sender in self.peers:
            self.heard[msg.sender] = now
            self.lost.discard(msg.sender)
        return self.node.on_message(msg, now)

    def on_tick(self, now: float) -> list:
        dt = 0.0 if self._last is None else now - self._last
        self._last = now
        out = []
        for p, t in sorted(self.heard.items()):
            if p not in self.lost and now - t > self.timeout:
                self.lost.add(p)
                out += self.node.on_peer_lost(p, now)
        self.node.begin(self.pos)
        out += self._drive(dt, now)
        return out + self.node.tick(now)

    def _drive(self, dt: float, now: float) -> list:
        commitments = self.agent.commitments if self.node.armed else ()
        self.arrived = {k: t for k, t in self.arrived.items() if k in commitments}
        if not commitments:
            return []
        c = commitments[0]
        gx, gy = c.task.position
        d = math.hypot(gx - self.pos[0], gy - self.pos[1])
        step = min(d, self.speed * dt)
        if d > 0:
            self.pos = (self.pos[0] + (gx - self.pos[0]) * step / d, self.pos[1] + (gy - self.pos[1]) * step / d)
            self.driven += step
        out = []
        if d - step <= self.tolerance and c not in self.arrived:
            self.arrived[c] = now
            out += self.node.on_progress(Progress(c.task_id, ARRIVED, now), now)
        hold = executor_class(c.task.kind).finishes_after(c.task)
        if c in self.arrived and c not in self.finished and hold is not None and now - self.arrived[c] >= hold:
            self.finished.add(c)
            out += self.node.on_progress(Progress(c.task_id, P_DONE, now), now)
        return out


@dataclass
class SimFleet:
    """Robots ``starts`` ({id: (x, y)}) running allocation ``method`` (its options: ``options``, default its
    defaults) on an :class:`InMemoryBus` with the given delay, drop, duplication."""
    starts: Mapping[int, tuple[float, float]]
    method: str = "coalition"
    options: object = None
    delay: float = 0.01
    jitter: float = 0.0
    drop: float = 0.0
    duplicate: float = 0.0
    seed: int = 0
    tick: float = 0.05
    speed: float = 0.25
    robot_class: type = SimRobot          # a SimRobot subclass with another kinematic execution

    def __post_init__(self) -> None:
        ids = tuple(sorted(self.starts))
        method = registry.method(self.method)
        self.options = method.options() if self.options is None else self.options
        self.robots = {r: self.robot_class(r, ids, self.starts[r], method, self.options, speed=self.speed)
                       for r in ids}
        self.bus = InMemoryBus(dict(self.robots), delay=self.delay, jitter=self.jitter, drop=self.drop,
                               duplicate=self.duplicate, seed=self.seed)

    @property
    def now(self) -> float:
        return self.bus.now

    def hand_in(self, to: int, specs, now: float | None = None) -> list[int]:
        """The operator hands tasks (their specs: ``Goto(x, y, hold)``, ``Rendezvous(x, y, robots, value)``
        ...) to robot ``to``, as an accepted mission upload would; returns their fleet ids."""
        now = self.bus.now if now is None else now
        node = self.robots[to].node
        before = set(node.table.entries)
        items = []
        for spec in specs:
            command, params = T.kind(_kind_of(spec)).to_item(spec)
            items.append((command, MAV_FRAME_LOCAL_ENU, params, spec.x, spec.y))
        out = node.add_items(items, now)
        self.bus.send(out, now)
        return sorted(set(node.table.entries) - before)

    def run(self, until: float, stop=None, observe=None) -> float:
        """Advance to ``until``; ``observe(fleet)`` is called at every bus step, ``stop(fleet)`` true ends early."""
        def check() -> bool:
            if observe is not None:
                observe(self)
            return bool(stop is not None and stop(self))
        return self.bus.run(until, self.tick, stop=check)

    def kill(self, rid: int) -> None:
        self.bus.down.add(rid)

    def live(self) -> list[int]:
        return [r for r in self.robots if r not in self.bus.down]

    def done(self) -> dict[int, tuple[int, ...]]:
        """Tasks reported done (by any robot's agent) -> the coalition that did them."""
        return {ev.task: ev.robots for r in self.robots.values() for ev in r.node.events if ev.what == DONE}

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


def _kind_of(spec) -> str:
    """The task kind whose Spec ``spec`` is."""
    for name in T.KINDS:
        if isinstance(spec, T.kind(name).Spec):
            return name
    raise TypeError(f"{spec!r} is not the spec of a task kind")
