"""A small stand-in allocation agent for the foraging harness tests (never a registered method): each free robot
joins the nearest object that has fewer than ``cap`` live robots on it and stays on it until it is done; robots
on an object broadcast what they loaded and delivered; the lowest-id live robot on an object reports it DONE
once everything is delivered and nobody carries any more.  A lost robot's loads that it never delivered are
not counted delivered (the harness puts them back on the pile)."""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

from runtime.allocation.agent import DONE, Method, TaskEvent
from runtime.tasks import Commitment
from runtime.tasks.transport import DELIVERED, LOADED


@dataclass(frozen=True)
class Cargo:
    sender: int
    dest: int
    task: int
    loaded: float         # wu this robot loaded from the task, in all
    delivered: float      # of them, delivered
    carrying: bool
    on: bool = True       # it works on the task (False: it left it)


@dataclass
class StandInOptions:
    delivery: tuple[float, float] = (0.0, 0.0)
    load: float = 2.0
    load_time: float = 0.12
    reach: float = 0.3
    period: float = 1.0             # s between repeats of a robot's own cargo record
    cap: int = 2                    # robots per object at most


class StandIn:
    def __init__(self, ctx):
        self.robot_id = ctx.robot_id
        self.estimator = ctx.estimator
        self.o = ctx.options
        self.tasks: dict = {}                       # open tasks
        self.cargo: dict[int, dict[int, Cargo]] = {}   # task -> robot -> its latest record
        self.lost: set[int] = set()
        self.mine: int | None = None
        self.available = True
        self.events: list[TaskEvent] = []
        self.reported: set[int] = set()
        self.full: dict[int, frozenset] = {}         # tasks I left to lower ids that chose them with me: which
        self._next_repeat = 0.0

    # ------------------------------------------------------------------ what the node asks
    @property
    def commitments(self):
        if self.mine is None or self.mine not in self.tasks:
            return ()
        partners = tuple(sorted(r for r in self.cargo.get(self.mine, {}) if r != self.robot_id and r not in self.lost))
        params = (("delivery", self.o.delivery), ("load", self.o.load), ("load_time", self.o.load_time),
                  ("reach", self.o.reach))
        return (Commitment(self.tasks[self.mine], partners, "member", params),)

    @property
    def converged(self) -> bool:
        return True

    def pop_events(self):
        out, self.events = self.events, []
        return out

    # ------------------------------------------------------------------ inputs
    def add_tasks(self, tasks, now):
        for t in tasks:
            if t.kind == "transport" and t.id not in self.reported:
                self.tasks[t.id] = t
        return []

    def withdraw_tasks(self, task_ids, now):
        for tid in task_ids:
            self.tasks.pop(tid, None)
            self.reported.add(tid)
            if self.mine == tid:
                self.mine = None
        return []

    def set_available(self, available, now):
        self.available = bool(available)
        return []

    def on_peer_lost(self, robot_id, now):
        self.lost.add(robot_id)
        self.full = {t: who for t, who in self.full.items() if robot_id not in who}    # look at it again
        return []

    def on_message(self, msg, now):
        if isinstance(msg, Cargo):
            self.lost.discard(msg.sender)
            self.cargo.setdefault(msg.task, {})[msg.sender] = msg
        return []

    def on_progress(self, p, now):
        if p.task != self.mine:
            return []
        me = self._me(p.task)
        wu = float(p.data.get("wu", 0.0))
        if p.event == LOADED:
            me = Cargo(self.robot_id, 0, p.task, me.loaded + wu, me.delivered, True)
        elif p.event == DELIVERED:
            me = Cargo(self.robot_id, 0, p.task, me.loaded, me.delivered + wu, False)
        self.cargo[p.task][self.robot_id] = me
        return [me]

    def on_tick(self, now):
        out = []
        for tid in list(self.tasks):
            self._maybe_done(tid)
        if self.mine is not None and self._me(self.mine).loaded == 0:
            ahead = [r for r in self._members(self.mine) if r < self.robot_id]
            if len(ahead) >= self.o.cap:              # others chose it at the same time: lower ids keep it
                self.full[self.mine] = frozenset(ahead)
                left = Cargo(self.robot_id, 0, self.mine, 0.0, 0.0, False, on=False)
                self.cargo[self.mine][self.robot_id] = left
                out.append(left)
                self.mine = None
        if self.mine is None and self.available:
            self._choose()
            if self.mine is not None:
                out.append(replace(self._me(self.mine), on=True))
                self.cargo[self.mine][self.robot_id] = out[-1]
        if self.mine is not None and now >= self._next_repeat:
            self._next_repeat = now + self.o.period
            out.append(self._me(self.mine))
        return out

    # ------------------------------------------------------------------ the logic
    def _me(self, tid: int) -> Cargo:
        return self.cargo.setdefault(tid, {}).get(self.robot_id) or Cargo(self.robot_id, 0, tid, 0.0, 0.0, False)

    def _records(self, tid: int):
        return self.cargo.get(tid, {})

    def _members(self, tid: int) -> list[int]:
        return [r for r, c in self._records(tid).items() if c.on and r not in self.lost]

    def _choose(self) -> None:
        open_ = [t for t in self.tasks.values() if t.id not in self.full and len(self._members(t.id)) < self.o.cap]
        if not open_:
            return
        costs = self.estimator.estimates(open_)
        best = min(range(len(open_)), key=lambda k: (costs[k].cost, open_[k].id))
        if math.isfinite(costs[best].cost):
            self.mine = open_[best].id

    def _maybe_done(self, tid: int) -> None:
        recs = self._records(tid)
        workers = [r for r in recs if r not in self.lost]
        if tid in self.reported or not workers or min(workers) != self.robot_id:
            return
        delivered = sum(c.delivered for c in recs.values())
        busy = any(c.carrying for r, c in recs.items() if r not in self.lost)
        if delivered >= self.tasks[tid].spec.weight and not busy:
            self.events.append(TaskEvent(tid, DONE, tuple(sorted(workers))))
            self.withdraw_tasks([tid], 0.0)


STANDIN = Method(name="standin", summary="test stand-in: join the nearest object", options=StandInOptions,
                 make=StandIn, task_kinds=("transport",), messages=(Cargo,))
