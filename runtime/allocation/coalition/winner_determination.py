"""Winner determination for simultaneous coalition allocation (paper 001): reading, checking, solving.

Methods, all exact (IDA* and BFS unless capped):

* ``idastar`` - the paper's bid tree searched by IDA* with its admissible heuristic;
* ``bfs`` - the paper's baseline, the whole bid tree breadth first;
* ``dp`` - dynamic programming over robot subsets after bid and robot reductions (few robots);
* ``sparse`` - the same recursion in plain Python over the robot sets actually reached (small inputs);
* ``assignment`` - Hungarian method when every coalition is one robot;
* ``milp`` - the integer program solved by HiGHS (reference);
* ``auto`` - drops bids worth 0 and (for many bids) bids that bounds exclude from every optimum
  (``wdp_bounds``), splits the rest into independent parts (no shared robot or task), and per
  part picks ``best`` (one task), ``assignment`` (single robots), ``sparse`` (few bids, within a
  transition budget), ``dp`` (when the DP table is small) or else ``milp``.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from runtime.allocation.coalition import wdp_bounds, wdp_dp, wdp_milp, wdp_search
from runtime.allocation.coalition.wdp_model import (Compiled, Problem, SolverOutput, TaskBid, TimeUp,
                                                    compile_problem)
from runtime.errors import InputError
from runtime.jsonfile import read_json

DP_WORK_LIMIT = 30_000_000       # DP states touched before auto prefers HiGHS
SPARSE_MAX_BIDS = 60             # auto tries the plain-Python DP up to this many bids...
SPARSE_BUDGET = 6_000            # ...and this many transitions, then the numpy DP
ASSIGNMENT_MAX = 4_000_000       # robots x tasks of the Hungarian method's matrix (auto takes HiGHS above)
MAX_VALUE = 1e15                 # a bid's value: sums stay finite and far below HiGHS's infinity (1e20)


def _best_single(c: Compiled) -> SolverOutput:
    """One task: the best positive bid."""
    best = max(range(c.n_bids), key=lambda i: c.value[i], default=None)
    chosen = (best,) if best is not None and c.value[best] > 0 else ()
    return SolverOutput(chosen, c.n_bids)


DEADLINE_SOLVERS = {"idastar", "bfs", "dp", "sparse", "milp"}     # take ``deadline=`` and raise TimeUp
SOLVERS: dict[str, Callable[..., SolverOutput]] = {
    "idastar": wdp_search.solve_idastar,
    "bfs": wdp_search.solve_bfs,
    "dp": wdp_dp.solve_dp,
    "sparse": wdp_dp.solve_sparse,
    "assignment": wdp_milp.solve_assignment,
    "milp": wdp_milp.solve_milp,
    "best": _best_single,
}
METHODS = ("auto", "idastar", "bfs", "dp", "sparse", "assignment", "milp")


class TimeLimit(Exception):
    """:func:`solve` reached its time limit (or a solver's own limit, ``reason``).  ``value``: the total of the
    best feasible allocation found (0 when none was); ``bound``: no allocation is worth more; ``method``: the
    solver that was running."""

    def __init__(self, limit: float | None, value: float, bound: float, method: str, reason: str | None = None):
        self.limit, self.value, self.bound, self.method = limit, value, bound, method
        super().__init__(f"{reason or f'time limit of {limit:g} s'} reached ({method}): best value found "
                         f"{value:g}, optimum at most {bound:g}, not proven")


@dataclass(frozen=True)
class Allocation:
    """A solved problem: total ``value``, ``assignment`` task -> robots, the winning bid indices,
    the method that ran, nodes it generated and its wall time.  ``capped``: a node cap stopped the
    search, the allocation is feasible but not proven optimal."""
    value: float
    assignment: dict
    winners: tuple[int, ...]
    method: str
    nodes: int
    seconds: float
    capped: bool = False
    iterations: int = 0
    last_pass_nodes: int = 0
    last_pass_expanded: int = 0
    parts: int = field(default=1, compare=False)

    def to_json(self) -> dict[str, Any]:
        out = {"value": self.value, "assignment": {t: list(rs) for t, rs in self.assignment.items()},
               "method": self.method, "nodes": self.nodes, "seconds": self.seconds}
        if self.capped:
            out["capped"] = True
        return out


# ---------------------------------------------------------------- reading and checking input

def _is_id(x: Any) -> bool:
    return (isinstance(x, int) and not isinstance(x, bool)) or isinstance(x, str)


def _ids(obj: dict, key: str) -> tuple:
    raw = obj.get(key)
    if not isinstance(raw, list):
        raise InputError(f'"{key}": expected a list of ids, got {type(raw).__name__}')
    seen = set()
    for pos, x in enumerate(raw):
        if not _is_id(x):
            raise InputError(f'"{key}"[{pos}]: expected an integer or string id, got {x!r}')
        if x in seen:
            raise InputError(f'"{key}"[{pos}]: id {x!r} is listed twice')
        seen.add(x)
    return tuple(raw)


def parse_problem(obj: Any) -> Problem:
    """Check a decoded ``{"robots", "tasks", "bids"}`` document; bad input raises InputError naming
    the bid index and what was expected."""
    if not isinstance(obj, dict):
        raise InputError(f'expected an object with "robots", "tasks" and "bids", got {type(obj).__name__}')
    robots, tasks = _ids(obj, "robots"), _ids(obj, "tasks")
    robot_set, task_set = set(robots), set(tasks)
    raw = obj.get("bids")
    if not isinstance(raw, list):
        raise InputError(f'"bids": expected a list of bids, got {type(raw).__name__}')
    bids = []
    for i, b in enumerate(raw):
        if not isinstance(b, dict):
            raise InputError(f"bid {i}: expected an object with task, robots, value, got {type(b).__name__}")
        for key in ("task", "robots", "value"):
            if key not in b:
                raise InputError(f'bid {i}: missing "{key}"')
        task, members, value = b["task"], b["robots"], b["value"]
        if not _is_id(task) or task not in task_set:
            raise InputError(f"bid {i}: unknown task {task!r}, expected one of the listed tasks")
        if not isinstance(members, list):
            raise InputError(f'bid {i}: "robots" must be a list of robot ids, got {type(members).__name__}')
        if not members:
            raise InputError(f"bid {i}: empty coalition, expected at least one robot")
        seen = set()
        for r in members:
            if not _is_id(r) or r not in robot_set:
                raise InputError(f"bid {i}: unknown robot {r!r}, expected one of the listed robots")
            if r in seen:
                raise InputError(f"bid {i}: robot {r!r} appears twice in the coalition")
            seen.add(r)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value <= MAX_VALUE:
            shown = (repr(value) if not isinstance(value, int) or value.bit_length() < 64
                     else f"an integer of {int(value.bit_length() * math.log10(2)) + 1} digits")
            raise InputError(f"bid {i}: value must be a finite number >= 0 and <= {MAX_VALUE:g}, got {shown}")
        bids.append(TaskBid(task, tuple(members), float(value)))
    return Problem(robots, tasks, tuple(bids))


def load_problem(path: str | Path) -> Problem:
    """Read and check a bids JSON file (``-`` reads stdin)."""
    name = str(path)
    obj = read_json(path, "bids file")
    try:
        return parse_problem(obj)
    except InputError as exc:
        raise InputError(f"{name}: {exc}") from None


# ---------------------------------------------------------------- solving

def components(c: Compiled) -> list[Compiled]:
    """Split into parts that share no robot and no task; tasks are renumbered from 0 per part,
    robot bits are kept."""
    parent: dict = {}                 # union-find over ("r", robot) and ("t", task)

    def find(x):
        root = x
        while parent.get(root, root) != root:
            root = parent[root]
        while x != root:                   # path compression
            parent[x], x = root, parent.get(x, x)
        return root

    for t, m in zip(c.task, c.mask):
        a = find(("t", t))
        while m:
            low = m & -m
            b = find(("r", low.bit_length() - 1))
            if a != b:
                parent[b] = a
            m ^= low
    by_root: dict = {}
    for t in sorted(set(c.task)):
        by_root.setdefault(find(("t", t)), []).append(t)
    # in the order of each group's highest task (as merging groups task by task would leave them)
    groups = sorted(by_root.values(), key=lambda ts: ts[-1])
    if len(groups) <= 1:
        return [c] if c.n_bids else []
    part_of = [0] * c.n_tasks
    local_task = [0] * c.n_tasks
    for p, ts in enumerate(groups):
        for j, t in enumerate(ts):
            part_of[t], local_task[t] = p, j
    members: list[list[int]] = [[] for _ in groups]
    for b, t in enumerate(c.task):
        members[part_of[t]].append(b)
    return [Compiled(c.n_robots, len(ts), tuple(local_task[c.task[b]] for b in bids), tuple(c.mask[b] for b in bids),
                     tuple(c.value[b] for b in bids), tuple(c.bid_ids[b] for b in bids))
            for ts, bids in zip(groups, members)]


def choose_method(c: Compiled) -> str:
    """The method ``auto`` uses first for one independent part (``sparse`` falls back to
    :func:`choose_method_dense` when it runs over its budget)."""
    if c.n_tasks <= 1:
        return "best"
    if all(m & (m - 1) == 0 for m in c.mask):
        return "assignment" if c.n_robots * c.n_tasks <= ASSIGNMENT_MAX else "milp"
    if c.n_bids <= SPARSE_MAX_BIDS:
        return "sparse"
    return choose_method_dense(c)


def choose_method_dense(c: Compiled) -> str:
    """``dp`` when its table and work are small enough, else ``milp``."""
    n_layers = len(set(c.task))
    robots = 0
    for m in c.mask:
        robots |= m
    n = robots.bit_count()
    if n <= 12 or (n <= wdp_dp.MAX_BITS and wdp_dp.work_estimate(list(c.mask), n, n_layers) <= DP_WORK_LIMIT):
        return "dp"
    _, masks, _, _, bits = wdp_dp.reduce(c)
    if bits <= wdp_dp.MAX_BITS and wdp_dp.work_estimate(masks, bits, n_layers) <= DP_WORK_LIMIT:
        return "dp"
    return "milp"


def _solve_auto(c: Compiled, deadline: float | None = None) -> tuple[SolverOutput, str, int]:
    # work on local indices (bid_ids = position in c), so the answer indexes c
    positive = [b for b in range(c.n_bids) if c.value[b] > 0] if c.n_bids and min(c.value) <= 0 else None
    if positive is None:
        kept = Compiled(c.n_robots, c.n_tasks, c.task, c.mask, c.value)
    else:
        kept = Compiled(c.n_robots, c.n_tasks, tuple(c.task[b] for b in positive),
                        tuple(c.mask[b] for b in positive), tuple(c.value[b] for b in positive), tuple(positive))
    if kept.n_bids > SPARSE_MAX_BIDS:
        kept = wdp_bounds.prune(kept)
    chosen: list[int] = []
    nodes = 0
    used: list[str] = []
    parts = components(kept)
    for k, part in enumerate(parts):
        name = choose_method(part)
        try:
            if name == "sparse":
                try:
                    out = wdp_dp.solve_sparse(part, SPARSE_BUDGET, deadline)
                except wdp_dp.Budget:
                    name = choose_method_dense(part)
                    out = _run(name, part, deadline=deadline)
            else:
                out = _run(name, part, deadline=deadline)
        except TimeUp as exc:          # in terms of c: the parts done, this part's best, bounds for the rest
            bound = (c.total(chosen) + min(wdp_bounds.upper_bound(part), math.inf if exc.bound is None else exc.bound)
                     + math.fsum(wdp_bounds.upper_bound(p) for p in parts[k + 1:]))
            raise TimeUp(chosen + [part.bid_ids[i] for i in exc.chosen], bound, "auto:" + name, exc.reason) \
                from None
        chosen.extend(part.bid_ids[i] for i in out.chosen)
        nodes += out.nodes
        if name not in used:
            used.append(name)
    return SolverOutput(tuple(sorted(chosen)), nodes), "auto:" + "+".join(used or ["empty"]), len(parts)


def _run(name: str, c: Compiled, node_limit: int | None = None, deadline: float | None = None) -> SolverOutput:
    """Solver ``name`` on ``c``, with the options it takes."""
    options = {"deadline": deadline} if name in DEADLINE_SOLVERS else {}
    if name in ("idastar", "bfs"):
        options["node_limit"] = node_limit
    return SOLVERS[name](c, **options)


def solve_compiled(c: Compiled, method: str = "auto", node_limit: int | None = None,
                   deadline: float | None = None) -> tuple[SolverOutput, str]:
    """Solve a compiled problem; returns the solver output (indices into ``c``) and the method name.  Past
    ``deadline`` (``time.perf_counter()`` seconds) it raises TimeUp (indices into ``c``)."""
    if method == "auto":
        out, name, _ = _solve_auto(c, deadline)
        return out, name
    if method == "assignment" and c.n_robots * c.n_tasks > ASSIGNMENT_MAX:
        raise InputError(f"assignment: {c.n_robots} robots x {c.n_tasks} tasks exceed its {ASSIGNMENT_MAX} matrix "
                         "cells; expected a smaller problem (or method auto or milp)")
    if method in SOLVERS:
        try:
            return _run(method, c, node_limit, deadline), method
        except TimeUp as exc:
            bound = min(wdp_bounds.upper_bound(c), math.inf if exc.bound is None else exc.bound)
            raise TimeUp(exc.chosen, bound, method, exc.reason) from None
    raise InputError(f"method {method!r}: expected one of {', '.join(METHODS)}")


def solve(problem: Problem, method: str = "auto", node_limit: int | None = None,
          time_limit: float | None = None) -> Allocation:
    """Pick the winning bids of ``problem`` with ``method`` (see module doc).  Past ``time_limit`` seconds it
    raises :class:`TimeLimit` with the best value found and a bound on the optimum."""
    if method not in METHODS:
        raise InputError(f"method {method!r}: expected one of {', '.join(METHODS)}")
    t0 = time.perf_counter()
    deadline = None if time_limit is None else t0 + time_limit
    c = compile_problem(problem)
    parts = 1
    try:
        if method == "auto":
            out, name, parts = _solve_auto(c, deadline)
        else:
            try:
                out, name = solve_compiled(c, method, node_limit, deadline)
            except ValueError as exc:
                raise InputError(str(exc)) from None
    except TimeUp as exc:
        value = math.fsum(problem.bids[c.bid_ids[i]].value for i in exc.chosen)
        raise TimeLimit(time_limit, value, exc.bound, exc.method, exc.reason) from None
    seconds = time.perf_counter() - t0
    winners = tuple(sorted(c.bid_ids[i] for i in out.chosen))
    assignment = {problem.bids[b].task: problem.bids[b].robots for b in winners}
    value = math.fsum(problem.bids[b].value for b in winners)
    return Allocation(value, assignment, winners, name, out.nodes, seconds, out.capped, out.iterations,
                      out.last_pass_nodes, out.last_pass_expanded, parts)


def check_feasible(problem: Problem, winners: tuple[int, ...]) -> bool:
    """No robot in two winning bids and no task won twice."""
    robots: set = set()
    tasks: set = set()
    for b in winners:
        bid = problem.bids[b]
        if bid.task in tasks or robots.intersection(bid.robots):
            return False
        tasks.add(bid.task)
        robots.update(bid.robots)
    return True
