"""What one robot knows: the open transport tasks (from the fleet table) with what it heard about each (its
leader, leadership requests, the books), and its peers (when each was last heard, its last ``RobotState``).

A task can be talked about before the table has brought it here (a leader's messages overtake the table's
replication): its :class:`TaskInfo` then exists without a ``task`` until it arrives, at most
:data:`MAX_UNKNOWN` such at a time.  Tasks done or withdrawn are ``closed``: messages about them are dropped.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from runtime.allocation.dr.ledger import Ledger
from runtime.allocation.dr.messages import DrLeaderAlive
from runtime.messages import IDLE, RobotState
from runtime.tasks import Task

MAX_UNKNOWN = 64


@dataclass
class TaskInfo:
    id: int
    task: Task | None = None
    appeared: float = math.inf              # when it appeared, this robot's clock (earliest heard)
    distance: float = math.nan              # m from the object to the delivery area (its edge)
    ledger: Ledger = field(default_factory=Ledger)
    leader: int | None = None               # the leader last heard of, and when
    leader_heard: float = -math.inf
    alive: DrLeaderAlive | None = None      # its last LEADER_ALIVE, and when
    alive_at: float = -math.inf
    left_heard: float | None = None         # wu at the object as the leader last said
    claims: dict = field(default_factory=dict)   # robot -> (capacity, when) of leadership requests heard

    @property
    def known(self) -> bool:
        return self.task is not None


@dataclass
class Peer:
    heard: float = -math.inf
    state: int | None = None
    tasks: tuple[int, ...] = ()


class World:
    def __init__(self, robot_id: int, peers, options):
        self.robot_id = int(robot_id)
        self.configured = frozenset(int(p) for p in peers) - {self.robot_id}
        self.o = options
        self.tasks: dict[int, TaskInfo] = {}
        self.closed: set[int] = set()
        self.peers: dict[int, Peer] = {}
        self.lost: set[int] = set()

    # ------------------------------------------------------------------ tasks
    def add(self, task: Task, now: float) -> TaskInfo:
        info = self.tasks.get(task.id) or TaskInfo(task.id)
        self.tasks[task.id] = info
        if info.task is None:
            info.task = task
            info.appeared = min(info.appeared, now)
            dx, dy = self.o.delivery
            # the way to drive: to the edge of the delivery area (eqs. 5 and the model's input)
            info.distance = max(0.0, math.hypot(task.spec.x - dx, task.spec.y - dy) - self.o.area)
            info.ledger.weight = float(task.spec.weight)
        return info

    def info(self, task_id: int) -> TaskInfo | None:
        """The task's record, made for a task not in the table yet (None for a closed task or too many unknown)."""
        info = self.tasks.get(task_id)
        if info is not None or task_id in self.closed:
            return info
        unknown = [t for t, i in self.tasks.items() if i.task is None]
        if len(unknown) >= MAX_UNKNOWN:
            return None
        info = self.tasks[task_id] = TaskInfo(task_id)
        return info

    def close(self, task_id: int) -> None:
        self.tasks.pop(task_id, None)
        self.closed.add(task_id)

    def open_tasks(self) -> list[TaskInfo]:
        return [i for _, i in sorted(self.tasks.items()) if i.task is not None]

    def leader_of(self, info: TaskInfo, now: float) -> int | None:
        """The task's leader if heard within ``leader_timeout`` (and not lost since)."""
        if info.leader is None or now - info.leader_heard > self.o.leader_timeout or info.leader in self.lost:
            return None
        return info.leader

    def claimed(self, info: TaskInfo, now: float) -> bool:
        """Someone asked to lead the task recently enough to be its leader by now or soon."""
        window = self.o.time_leadership + self.o.leader_alive_period + self.o.time_auction
        return any(now - at <= window for _, at in info.claims.values())

    # ------------------------------------------------------------------ peers
    def known(self, rid) -> bool:
        return isinstance(rid, int) and not isinstance(rid, bool) and rid in self.configured

    def join(self, rid: int) -> None:
        """A robot that joined the fleet at run time: a peer from now on."""
        if rid != self.robot_id:
            self.configured |= {int(rid)}
            self.lost.discard(rid)

    def heard(self, rid: int, now: float) -> None:
        self.lost.discard(rid)
        self.peers.setdefault(rid, Peer()).heard = now

    def mentioned(self, rid: int, now: float) -> None:
        """A robot named in the books, never heard yet: its silence counts from now."""
        if rid in self.configured and rid not in self.peers:
            self.peers[rid] = Peer(heard=now)

    def on_state(self, m: RobotState) -> bool:
        try:
            ok = m.invalid() is None and all(isinstance(t, int) for t in m.tasks)
        except (TypeError, ValueError, AttributeError):
            ok = False
        if ok:
            p = self.peers.setdefault(m.sender, Peer())
            p.state, p.tasks = m.state, tuple(m.tasks)
        return ok

    def silent(self, rid: int, now: float, timeout: float) -> bool:
        """Not heard (any message) for ``timeout`` s, or never heard."""
        if rid == self.robot_id:
            return False
        p = self.peers.get(rid)
        return p is None or now - p.heard > timeout

    def free_peers(self, now: float) -> list[int]:
        """Peers heard lately whose last state says idle and holding nothing: robots that would bid."""
        return sorted(r for r, p in self.peers.items()
                      if r not in self.lost and now - p.heard <= self.o.member_timeout and p.state == IDLE
                      and not p.tasks)
