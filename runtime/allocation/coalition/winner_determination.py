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
from runtime.allocation.coalition.wdp_model import Compiled, Problem, SolverOutput, TaskBid, compile_problem
from runtime.errors import InputError
from runtime.jsonfile import read_json

DP_WORK_LIMIT = 30_000_000       # DP states touched before auto prefers HiGHS
SPARSE_MAX_BIDS = 60             # auto tries the plain-Python DP up to this many bids...
SPARSE_BUDGET = 6_000            # ...and this many transitions, then the numpy DP


def _best_single(c: Compiled) -> SolverOutput:
    """One task: the best positive bid."""
    best = max(range(c.n_bids), key=lambda i: c.value[i], default=None)
    chosen = (best,) if best is not None and c.value[best] > 0 else ()
    return SolverOutput(chosen, c.n_bids)


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
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
            raise InputError(f"bid {i}: value must be a finite number >= 0, got {value!r}")
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
    tmask = [0] * c.n_tasks
    has_bid = [False] * c.n_tasks
    for t, m in zip(c.task, c.mask):
        tmask[t] |= m
        has_bid[t] = True
    groups: list[tuple[int, list[int]]] = []          # (robot mask, tasks)
    for t in range(c.n_tasks):
        if not has_bid[t]:
            continue
        m, ts, rest = tmask[t], [t], []
        for gm, gts in groups:
            if gm & m:
                m |= gm
                ts += gts
            else:
                rest.append((gm, gts))
        groups = rest + [(m, ts)]
    if len(groups) <= 1:
        return [c] if c.n_bids else []
    part_of = [0] * c.n_tasks
    local_task = [0] * c.n_tasks
    for p, (_, ts) in enumerate(groups):
        for j, t in enumerate(sorted(ts)):
            part_of[t], local_task[t] = p, j
    members: list[list[int]] = [[] for _ in groups]
    for b, t in enumerate(c.task):
        members[part_of[t]].append(b)
    return [Compiled(c.n_robots, len(ts), tuple(local_task[c.task[b]] for b in bids), tuple(c.mask[b] for b in bids),
                     tuple(c.value[b] for b in bids), tuple(c.bid_ids[b] for b in bids))
            for (_, ts), bids in zip(groups, members)]


def choose_method(c: Compiled) -> str:
    """The method ``auto`` uses first for one independent part (``sparse`` falls back to
    :func:`choose_method_dense` when it runs over its budget)."""
    if c.n_tasks <= 1:
        return "best"
    if all(m & (m - 1) == 0 for m in c.mask):
        return "assignment"
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


def _solve_auto(c: Compiled) -> tuple[SolverOutput, str, int]:
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
    for part in parts:
        name = choose_method(part)
        if name == "sparse":
            try:
                out = wdp_dp.solve_sparse(part, SPARSE_BUDGET)
            except wdp_dp.Budget:
                name = choose_method_dense(part)
                out = SOLVERS[name](part)
        else:
            out = SOLVERS[name](part)
        chosen.extend(part.bid_ids[i] for i in out.chosen)
        nodes += out.nodes
        if name not in used:
            used.append(name)
    return SolverOutput(tuple(sorted(chosen)), nodes), "auto:" + "+".join(used or ["empty"]), len(parts)


def solve_compiled(c: Compiled, method: str = "auto", node_limit: int | None = None) -> tuple[SolverOutput, str]:
    """Solve a compiled problem; returns the solver output (indices into ``c``) and the method name."""
    if method == "auto":
        out, name, _ = _solve_auto(c)
        return out, name
    if method in ("idastar", "bfs"):
        return SOLVERS[method](c, node_limit=node_limit), method
    if method in SOLVERS:
        return SOLVERS[method](c), method
    raise InputError(f"method {method!r}: expected one of {', '.join(METHODS)}")


def solve(problem: Problem, method: str = "auto", node_limit: int | None = None) -> Allocation:
    """Pick the winning bids of ``problem`` with ``method`` (see module doc)."""
    if method not in METHODS:
        raise InputError(f"method {method!r}: expected one of {', '.join(METHODS)}")
    t0 = time.perf_counter()
    c = compile_problem(problem)
    parts = 1
    if method == "auto":
        out, name, parts = _solve_auto(c)
    else:
        try:
            out, name = solve_compiled(c, method, node_limit)
        except ValueError as exc:
            raise InputError(str(exc)) from None
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
