"""A toy allocation method, added the way docs/architecture.md says a method is added: this package plus one
line in ``runtime.allocation.registry.METHODS`` (tests/test_toy_method.py puts the line there).

Nearest-claim: a free robot claims the open ``goto`` task it can reach at the least cost and tells every peer
(``ToyClaim``); of two claims on one task the cheaper wins (then the lower robot id); the loser forgets its claim
and claims again.  A robot lost to the fleet loses its claims.  Not optimal, not for use: it shows the seams.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from runtime.allocation.agent import AWARDED, DONE, AgentContext, Method, TaskEvent
from runtime.tasks import Commitment
from tests.toy_method.messages import ToyClaim

BROADCAST = 0


@dataclass(frozen=True)
class ToyOptions:
    method: str = "toy"


class ToyAgent:
    def __init__(self, ctx: AgentContext):
        self.robot_id = ctx.robot_id
        self.estimator = ctx.estimator
        self.tasks: dict = {}                       # open task id -> Task
        self.claims: dict[int, tuple[float, int]] = {}   # task -> (cost, robot) of the best claim heard
        self.mine: int | None = None
        self.available = True
        self._events: list[TaskEvent] = []

    # ------------------------------------------------------------------ the Agent protocol
    def add_tasks(self, tasks, now: float) -> list:
        self.tasks.update({t.id: t for t in tasks if t.kind == "goto"})
        return self._claim(now)

    def withdraw_tasks(self, task_ids, now: float) -> list:
        for t in task_ids:
            self.tasks.pop(t, None)
            self.claims.pop(t, None)
            if self.mine == t:
                self.mine = None
        return self._claim(now)

    def on_message(self, msg, now: float) -> list:
        if not isinstance(msg, ToyClaim) or msg.task not in self.tasks:
            return []
        bid = (float(msg.cost), int(msg.sender))
        if bid < self.claims.get(msg.task, (float("inf"), 1 << 30)):
            self.claims[msg.task] = bid
            if self.mine == msg.task:
                self.mine = None                     # outbid: claim another
        return self._claim(now)

    def on_tick(self, now: float) -> list:
        return self._claim(now)

    def on_peer_lost(self, robot_id: int, now: float) -> list:
        self.claims = {t: c for t, c in self.claims.items() if c[1] != robot_id}
        return self._claim(now)

    def on_progress(self, p, now: float) -> list:
        if p.event == "done" and p.task == self.mine:
            self._events.append(TaskEvent(p.task, DONE, (self.robot_id,)))
            self.tasks.pop(p.task, None)
            self.mine = None
        return []

    def set_available(self, available: bool, now: float) -> list:
        self.available = bool(available)
        if not available:
            self.mine = None
        return []

    @property
    def commitments(self) -> tuple[Commitment, ...]:
        return (Commitment(self.tasks[self.mine]),) if self.mine is not None and self.available else ()

    @property
    def converged(self) -> bool:
        return self.mine is not None or not self._free()

    def pop_events(self) -> list[TaskEvent]:
        out, self._events = self._events, []
        return out

    # ------------------------------------------------------------------ the method
    def _free(self) -> list:
        return [t for tid, t in sorted(self.tasks.items()) if self.claims.get(tid, (0, self.robot_id))[1]
                == self.robot_id or tid not in self.claims]

    def _claim(self, now: float) -> list:
        if self.mine is not None or not self.available:
            return []
        free = self._free()
        costs = self.estimator.estimates(free) if free else []
        best = min(((e.cost, t.id) for e, t in zip(costs, free) if e.cost < float("inf")), default=None)
        if best is None:
            return []
        cost, tid = best
        self.mine = tid
        self.claims[tid] = (cost, self.robot_id)
        self._events.append(TaskEvent(tid, AWARDED, (self.robot_id,)))
        return [ToyClaim(self.robot_id, BROADCAST, tid, cost)]


TOY = Method(name="toy", summary="toy nearest-claim method (tests only)", options=ToyOptions, make=ToyAgent,
             task_kinds=("goto",), messages=(ToyClaim,), dialect=str(Path(__file__).with_name("toy.xml")))
