"""Shared set-ups of the dr tests (runtime/allocation/dr): fleets of robot cores on the in-process host with
kinematic motion (runtime/inprocess.py: the real agents and transport executors, bodies that never touch) and
single agents fed by hand."""
from __future__ import annotations

import copy
import math
from types import SimpleNamespace

from runtime.allocation.agent import AgentContext
from runtime.allocation.dr.family import DrAgent
from runtime.allocation.dr.options import DrOptions
from runtime.inprocess import Fleet, kinematic
from runtime.tasks import Profile, Task
from runtime.tasks.transport import Transport
from tests.alloc_util import StraightLineEstimator

_BUSY = None


def put(f: Fleet, to: int, objects) -> list[int]:
    """Objects ``(x, y, weight wu, deadline s, u_max)`` handed to robot ``to`` (mission items 31001); their ids."""
    return f.hand_in(to, [Transport(*map(float, o)) for o in objects])


def delivered(f: Fleet) -> dict[int, float]:
    """task -> wu delivered, summed over every robot's own account (the loads it was granted and unloaded)."""
    out: dict[int, float] = {}
    for r in f.robots.values():
        for task, e in r.agent.accounts.items():
            out[task] = out.get(task, 0.0) + e.delivered
    return out


def busy_fleet() -> Fleet:
    """Five robots working on two objects (groups formed, loads on the way), built once; callers may poke it."""
    global _BUSY
    if _BUSY is None:
        f = kinematic({1: (-2, -1), 2: (-2, 0), 3: (-2, 1), 4: (2, -1), 5: (2, 0)}, "dr", period=0.1,
                           options=DrOptions(strategy="NM_NI"))
        f.run(0.5)
        put(f, 1, [(1.5, 1.5, 30, 60, 100), (-1.5, 1.0, 30, 60, 100)])
        f.run(25.0)
        roles = [r.agent.role(t) for r in f.robots.values() for t in r.agent.world.tasks]
        assert roles.count("leader") == 2 and "member" in roles
        _BUSY = f
    return copy.deepcopy(_BUSY)


def agent(robot_id: int = 1, peers=(1, 2, 3, 4, 5), pos=(0.0, 0.0), speed: float = 0.25, **options) -> DrAgent:
    """A lone agent at ``pos`` whose peers are ``peers``; ``options`` are DrOptions fields."""
    where = {"pos": pos}
    est = StraightLineEstimator(Profile(speed, 0.2), lambda: where["pos"])
    a = DrAgent(AgentContext(robot_id, tuple(peers), est, DrOptions(**options)))
    a.where = where                    # tests move the robot by where["pos"] = ...
    return a


def transport(task_id: int, x: float, y: float, weight: float = 10.0, deadline: float = 100.0,
              u_max: float = 100.0) -> Task:
    return Task(task_id, "transport", Transport(x, y, weight, deadline, u_max))


class Watch:
    """Called at every bus step: checks the invariants a dr fleet keeps and records when leaders come and go.

    * no robot is in two groups in its own view, nor holds two commitments;
    * a leader's member list names a robot that is not (as it sees itself) its member or carrying the task's load
      for at most ``member_timeout`` (+ ``slack``);
    * no task has two leaders for longer than 3 ``leader_alive_period`` s.
    """

    def __init__(self, options, slack: float = 0.35):
        self.o = options
        self.slack = slack
        self.violations: list[str] = []
        self.stale: dict[tuple, float] = {}          # (leader, member, task) -> since
        self.dual: dict[int, float] = {}             # task -> since when it has two leaders
        self.leaders: dict[int, list[tuple[float, int]]] = {}   # task -> [(when first seen leading, robot)]
        self.longest_dual = 0.0
        self.longest_stale = 0.0

    def __call__(self, f) -> None:
        now = f.now
        leading: dict[int, list[int]] = {}
        live = set(f.live())
        for rid in live:
            a = f.robots[rid].agent
            if len(a.coalitions()) > 1 or len(a.commitments) > 1:
                self.violations.append(f"t={now:.2f} robot {rid} in {a.coalitions()} holding {a.commitments}")
            if a.lead is not None:
                t = a.lead.task
                leading.setdefault(t, []).append(rid)
                if not any(r == rid for _, r in self.leaders.get(t, [])[-1:]):
                    self.leaders.setdefault(t, []).append((now, rid))
                for m in list(a.lead.members):
                    b = f.robots[m].agent
                    ms = b.membership
                    ok = m in live and ((ms is not None and (ms.task, ms.leader) == (t, rid)) or b.carrying == t)
                    key = (rid, m, t)
                    if ok:
                        self.stale.pop(key, None)
                        continue
                    since = self.stale.setdefault(key, now)
                    self.longest_stale = max(self.longest_stale, now - since)
                    if now - since > self.o.member_timeout + self.slack:
                        self.violations.append(f"t={now:.2f} leader {rid} of {t} still lists {m} since {since:.2f}")
        for t, rs in leading.items():
            if len(rs) > 1:
                since = self.dual.setdefault(t, now)
                self.longest_dual = max(self.longest_dual, now - since)
                if now - since > 3 * self.o.leader_alive_period:
                    self.violations.append(f"t={now:.2f} task {t} led by {rs} since {since:.2f}")
            else:
                self.dual.pop(t, None)
        for t in list(self.dual):
            if t not in leading:
                del self.dual[t]


class DaemonsWatch(Watch):
    """:class:`Watch` over a lock-step SITL run: call it with the launcher's Fleet after every control cycle (as
    ``launcher.run_lockstep``'s ``on_step``); the daemons' agents, the world's clock, the daemons not stopped."""

    def __init__(self, slack: float = 0.35):
        super().__init__(None, slack)

    def __call__(self, f) -> None:
        robots = {rid: SimpleNamespace(agent=r.daemon.core.node.agent) for rid, r in f.robots.items()}
        if self.o is None:
            self.o = next(iter(robots.values())).agent.o
        super().__call__(SimpleNamespace(now=f.world.t, robots=robots,
                                         live=lambda: [rid for rid in f.robots if rid not in f.stopped]))


def forage(f, objects: int, present: int, rnd, weight=(8.0, 16.0), deadline: float = 60.0, until: float = 900.0,
           observe=None, start: float = 0.5) -> dict[int, float]:
    """Hand objects to the fleet ``present`` at a time, a new one as soon as one is done (paper 000 §6.2), until
    ``objects`` have been handed in and all are done.  Returns {task: weight}."""
    from runtime.messages import DONE as T_DONE

    f.run(start)
    handed: dict[int, float] = {}

    def top_up(fl):
        open_ = [t for t in handed if fl.table_state(t) != T_DONE]
        while len(open_) < present and len(handed) < objects:
            r, a = rnd.uniform(1.0, 3.0), rnd.uniform(0, 6.283)
            w = round(rnd.uniform(*weight))
            (t,) = put(fl, min(fl.live()), [(r * math.cos(a), r * math.sin(a), w, deadline, 100.0)])
            handed[t] = w
            open_.append(t)

    def step(fl):
        top_up(fl)
        if observe is not None:
            observe(fl)

    def finished(fl):
        return len(handed) == objects and all(fl.table_state(t) == T_DONE for t in handed)

    f.run(until, stop=finished, observe=step)
    return handed
