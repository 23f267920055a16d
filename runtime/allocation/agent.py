"""The interface every allocation family implements, and what a registry entry says about a method.

An :class:`Agent` is a sans-IO state machine for one robot: built from an :class:`AgentContext` (robot
id, configured peers, estimator, options), it takes tasks at any time, messages, ticks, lost peers, joined
peers, progress from execution and the operator's arm/disarm; it returns the messages to send and exposes the
robot's :class:`~runtime.tasks.Commitment` s.

The roster the agent is built with is the config's ``comms.peers``.  Over a transport that lets robots join at
run time (:mod:`runtime.comms.transport`, ``joins``: Zenoh) the robot core hands it each robot that joins, once,
with :meth:`Agent.on_peer_joined`, before that robot's first message (the mirror of :meth:`Agent.on_peer_lost`):
the family decides what a join means (a new round includes it, the next call for bids counts its bids).  A peer
lost and heard again is not a join: each family takes it back by its messages, as before.  Two members are
optional.  ``on_peer_joined``: an agent without it keeps the roster it was built with (messages from a joiner are
then dropped by the family as from a robot outside the fleet).  ``quiet(now)``: True only when ``on_tick(now)``
would send nothing and change nothing; the fleet node then skips the tick (:meth:`runtime.fleet.node.FleetNode.idle`,
held to it by ``FleetNode.check_idle`` in tests/test_fleet_idle.py); an agent without it is ticked every period.  It never opens a socket, sleeps or reads the wall clock:
every input carries ``now``.  The same agent runs in the daemon, in tests on the in-memory bus, and in
fast experiment loops.

What the fleet should hear about tasks (awarded, done, failed) an agent queues as :class:`TaskEvent` s;
the daemon drains them with :meth:`Agent.pop_events` (done tasks leave the fleet's task table; each event
becomes a STATUSTEXT line for the ground station).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Protocol, Sequence

from runtime.tasks import Commitment, Estimate, Profile, Progress, Task

AWARDED, DONE, FAILED, RELEASED = "awarded", "done", "failed", "released"


@dataclass(frozen=True)
class TaskEvent:
    task: int
    what: str                          # AWARDED | DONE | FAILED | RELEASED
    robots: tuple[int, ...] = ()       # who holds / did it
    detail: str = ""


class Estimator(Protocol):
    """How a robot prices tasks: its profile and a batch of estimates (one planner search for all)."""
    profile: Profile

    def estimates(self, tasks: Sequence[Task]) -> list[Estimate]: ...


@dataclass
class AgentContext:
    robot_id: int
    peers: tuple[int, ...]             # configured peers (robot ids), not this robot; joins come later
    estimator: Estimator
    options: Any                       # the method's options dataclass (the config's allocation section)
    base: Any = None                   # the robot config's base section (what the robot is and senses), if known
    sensors: tuple[str, ...] | None = None   # the sensor kinds the robot carries ("sonar", "laser", "gps"), if known


class Agent(Protocol):
    robot_id: int

    def add_tasks(self, tasks: Sequence[Task], now: float) -> list: ...
    def withdraw_tasks(self, task_ids: Sequence[int], now: float) -> list: ...
    def on_message(self, msg: Any, now: float) -> list: ...
    def on_tick(self, now: float) -> list: ...
    def on_peer_lost(self, robot_id: int, now: float) -> list: ...
    def on_peer_joined(self, robot_id: int, now: float) -> list: ...       # optional (the module docstring)
    def quiet(self, now: float) -> bool: ...                                # optional (the module docstring)
    def on_progress(self, progress: Progress, now: float) -> list: ...
    def set_available(self, available: bool, now: float) -> list: ...

    @property
    def commitments(self) -> tuple[Commitment, ...]: ...

    @property
    def converged(self) -> bool: ...

    def pop_events(self) -> list[TaskEvent]: ...


@dataclass(frozen=True)
class Method:
    """A registry entry: everything the runtime needs to know about one allocation method."""
    name: str
    summary: str                                   # one line for --help and docs
    options: type                                  # options dataclass = the config schema of `allocation:`
    make: Callable[[AgentContext], Agent]          # the daemon's agent
    task_kinds: tuple[str, ...]                    # task kinds it can allocate
    messages: tuple[type, ...] = ()                # message dataclasses it puts on the wire
    dialect: str | None = None                     # its MAVLink XML (path), included in the fleet dialect
    solver: type | None = None                     # bare sans-IO solver for in-process sweeps, if any
    extra: dict = field(default_factory=dict)


def route(msgs: list, robot_id: int, handle: Callable[[Any], list]) -> list:
    """The messages for the wire among ``msgs``; those addressed to ``robot_id`` are handed to ``handle`` here (a
    broadcast, dest 0, both), and so are the messages that handling returns, until none is left."""
    wire, todo = [], list(msgs)
    while todo:
        msg = todo.pop(0)
        if msg.dest != robot_id:
            wire.append(msg)
        if msg.dest in (robot_id, 0):
            todo.extend(handle(msg))
    return wire
