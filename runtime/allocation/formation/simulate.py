"""Run formation-assignment agents to convergence on the in-memory bus.

:func:`solve` is what the CLI and the experiments call: n robots (ids 1..n, robot 1 starts the
negotiation) and n tasks (ids 0..n-1), costs from a matrix or straight lines, a bus that may delay,
reorder, drop and duplicate.  The run stops when every live agent reports converged and the live
robots hold distinct tasks (or at ``until`` sim seconds).  It reports the messages agents sent (a
broadcast counts once) and the rounds: the longest causal chain of messages (Lamport depth), which does
not depend on the bus delay.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from runtime.allocation import registry
from runtime.allocation.bus import InMemoryBus
from runtime.allocation.formation.assignment import check_costs, global_cost, hungarian, straight_line_costs

# the registered methods that solve the formation problem in-process (their Method.solver), and Hungarian
SOLVERS = {m.name: m.solver for m in registry.all_methods() if m.solver is not None}
METHODS = (*SOLVERS, "hungarian")


@dataclass(frozen=True)
class BusParams:
    delay: float = 0.01          # mean one-way delay (s)
    jitter: float = 0.0          # +- uniform; > 0 reorders
    drop: float = 0.0            # probability a copy is lost
    duplicate: float = 0.0       # probability a copy is delivered twice
    seed: int = 0


@dataclass
class Result:
    method: str
    assignment: list[int]        # task index per robot (row order), -1 where none
    cost: float                  # global cost of that assignment
    messages: int                # messages agents handed to the bus
    rounds: int                  # longest causal chain of messages
    sim_time: float              # sim seconds until the stop condition
    converged: bool
    bus: dict = field(default_factory=dict)    # delivered / dropped / duplicated copies


def agent_class(method: str):
    if method not in SOLVERS:
        raise ValueError(f"method: expected one of {', '.join(METHODS)}, got {method!r}")
    return SOLVERS[method]


def make_agents(method: str, costs, bid_timeout: float = 1.0, **options) -> dict[int, object]:
    """One agent per row of ``costs``: robot id i + 1, cost(task j) = costs[i][j].  A solver may choose
    options for the matrix (``options_for``: the auction's cost unit)."""
    c = np.asarray(costs, dtype=float)
    cls = agent_class(method)
    options = {**getattr(cls, "options_for", lambda costs: {})(c), **options}
    ids = list(range(1, c.shape[0] + 1))
    agents = {}
    for i, rid in enumerate(ids):
        row = [float(v) for v in c[i]]
        agents[rid] = cls(rid, [p for p in ids if p != rid], row.__getitem__, bid_timeout=bid_timeout, **options)
    return agents


class _Lamport:
    """Wraps an agent; stamps every message it sends with 1 + the largest stamp it has seen."""

    def __init__(self, agent, stamps: dict):
        self.agent, self.robot_id, self.stamps, self.clock = agent, agent.robot_id, stamps, 0

    def _stamp(self, msgs: list) -> list:
        for m in msgs:
            self.stamps[id(m)] = (m, self.clock + 1)
        if msgs:
            self.clock += 1
        return msgs

    def start(self, tasks, now):
        return self._stamp(self.agent.start(tasks, now))

    def on_message(self, msg, now):
        self.clock = max(self.clock, self.stamps.get(id(msg), (None, 0))[1])
        return self._stamp(self.agent.on_message(msg, now))

    def on_tick(self, now):
        return self._stamp(self.agent.on_tick(now))


def run(agents: Mapping[int, object], tasks: Mapping[int, tuple[float, float]], bus: BusParams = BusParams(),
        initiator: int | None = None, until: float = 600.0, tick: float = 0.05,
        failures: Mapping[int, float] | None = None, detect: float = 3.0) -> tuple[dict, InMemoryBus, int, bool]:
    """Start ``initiator`` (default: lowest id) and run until converged or ``until``.

    ``failures``: robot id -> sim time it goes silent; the others get ``on_peer_lost`` ``detect``
    seconds later (a heartbeat timeout).  Returns (assignment by robot id, bus, rounds, converged).
    """
    stamps: dict = {}
    wrapped = {rid: _Lamport(a, stamps) for rid, a in agents.items()}
    b = InMemoryBus(wrapped, delay=bus.delay, jitter=bus.jitter, drop=bus.drop, duplicate=bus.duplicate,
                    seed=bus.seed)
    first = min(agents) if initiator is None else initiator
    b.send(wrapped[first].start(dict(tasks), 0.0), 0.0)
    events = sorted(((t, rid) for rid, t in (failures or {}).items()))
    check = {"next": 0.0}
    n_tasks = len(tasks)

    def done() -> bool:
        if b.now < check["next"]:
            return False
        check["next"] = b.now + tick
        live = [a for rid, a in agents.items() if rid not in b.down]
        held = [a.assignment for a in live]
        if not all(a.converged for a in live):
            return False
        if len(live) <= n_tasks and (None in held or len(set(held)) != len(held)):
            return False
        return True

    for t_fail, rid in events:
        b.run(min(t_fail, until), tick=tick)
        b.down.add(rid)
        b.run(min(t_fail + detect, until), tick=tick)
        for other, a in agents.items():
            if other not in b.down:
                b.send(wrapped[other]._stamp(a.on_peer_lost(rid, b.now)), b.now)
    b.run(until, tick=tick, stop=done)
    check["next"] = 0.0
    converged = done()
    rounds = max((w.clock for w in wrapped.values()), default=0)
    return {rid: a.assignment for rid, a in agents.items() if rid not in b.down}, b, rounds, converged


def solve(method: str, costs=None, *, robots: Sequence[Sequence[float]] | None = None,
          tasks: Sequence[Sequence[float]] | None = None, bus: BusParams = BusParams(),
          bid_timeout: float = 1.0, until: float = 600.0, tick: float = 0.05, **options) -> Result:
    """Assign n robots to n tasks with ``method`` (bs, rtma, auction or hungarian).

    Give ``costs`` (n x n, robot x task) or ``robots`` and ``tasks`` positions (straight-line costs;
    with both, the positions only label the tasks in messages).
    """
    if costs is None:
        if robots is None or tasks is None:
            raise ValueError("solve: give costs, or robots and tasks")
        costs = straight_line_costs(robots, tasks)
    c = check_costs(np.asarray(costs, dtype=float).tolist())
    n = c.shape[0]
    if method != "hungarian" and n > 250:
        raise ValueError(f"solve: at most 250 robots for {method} (MAVLink system ids), got {n}")
    if method == "hungarian":
        assignment, total = hungarian(c)
        return Result(method, assignment, total, 0, 0, 0.0, True)
    agents = make_agents(method, c, bid_timeout=bid_timeout, **options)
    if tasks is not None and len(tasks) == n:
        task_xy = {j: (float(tasks[j][0]), float(tasks[j][1])) for j in range(n)}
    else:
        task_xy = {j: (float(j), 0.0) for j in range(n)}
    held, b, rounds, converged = run(agents, task_xy, bus, until=until, tick=tick)
    assignment = [held.get(rid) for rid in sorted(agents)]
    assignment = [-1 if t is None else int(t) for t in assignment]
    return Result(method, assignment, global_cost(c, assignment), b.stats.sent, rounds, b.now, converged,
                  {"delivered": b.stats.delivered, "dropped": b.stats.dropped, "duplicated": b.stats.duplicated})
