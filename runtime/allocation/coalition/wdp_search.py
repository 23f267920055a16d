"""Paper 001's bid tree, searched by IDA* with the admissible heuristic, and the BFS baseline.

Bid tree: depth d holds the bids for the d-th task (tasks in problem order; tasks nobody bid on
have no level).  A node's children are the bids for the next task whose coalition shares no robot
with the path so far, plus the dummy bid (empty coalition, value 0), so every root-to-leaf path is
one feasible allocation.  Node counts are nodes generated, root excluded; IDA* counts every
pass and also reports, for its last pass, the nodes generated and the nodes expanded (not cut).

Heuristic (equations 1-2): h(n) = sum over robots not on n's path of Contribute(r), where
Contribute(r) is the largest value/size over bids of the tasks below n's depth that include r.
A bid's value is the sum of value/size over its members, so h never underestimates.
"""
from __future__ import annotations

import math

from runtime.allocation.coalition.wdp_model import Compiled, SolverOutput, TimeUp, past

DUMMY = (-1, 0, 0.0)
MAX_OPEN = 2_000_000       # BFS nodes held at once (~300 bytes each): then it stops as at a time limit


class NodeCap(Exception):
    """A search generated more nodes than its cap."""


def levels(c: Compiled) -> list[list[tuple[int, int, float]]]:
    """Per tree depth, the (bid index, robot mask, value) of one task's bids, input order."""
    by_task: list[list[tuple[int, int, float]]] = [[] for _ in range(c.n_tasks)]
    for i in range(c.n_bids):
        by_task[c.task[i]].append((i, c.mask[i], c.value[i]))
    return [bl for bl in by_task if bl]


class Heuristic:
    """Equations 1-2 tabulated per depth: h(d, used) = total[d] - (contribution of used robots),
    looked up one byte of the robot mask at a time."""

    def __init__(self, n_robots: int, lv: list[list[tuple[int, int, float]]], deadline: float | None = None):
        depth = len(lv)
        contrib = [[0.0] * n_robots for _ in range(depth + 1)]
        for d in range(depth - 1, -1, -1):
            if past(deadline):
                raise TimeUp()
            row = list(contrib[d + 1])
            for _, m, v in lv[d]:
                size = m.bit_count()
                if not size:
                    continue
                share = v / size
                r = 0
                while m:
                    if m & 1 and share > row[r]:
                        row[r] = share
                    m >>= 1
                    r += 1
            contrib[d] = row
        self.n_bytes = max(1, (n_robots + 7) // 8)
        self.total = [math.fsum(row) for row in contrib]
        self.tables = []
        for row in contrib:
            if past(deadline):
                raise TimeUp((), self.total[0])
            self.tables.append([self._byte_table(row, j) for j in range(self.n_bytes)])

    @staticmethod
    def _byte_table(row: list[float], j: int) -> list[float]:
        part = row[8 * j: 8 * j + 8]
        table = [0.0] * 256
        for b in range(1, 256):
            low = (b & -b).bit_length() - 1
            table[b] = table[b & (b - 1)] + (part[low] if low < len(part) else 0.0)
        return table

    def __call__(self, d: int, used: int) -> float:
        tables = self.tables[d]
        s = 0.0
        for j in range(self.n_bytes):
            s += tables[j][(used >> (8 * j)) & 255]
        return self.total[d] - s


def solve_idastar(c: Compiled, node_limit: int | None = None, deadline: float | None = None) -> SolverOutput:
    """IDA* on the bid tree (maximisation): depth-first passes cut a branch when g + h is below
    the threshold; the next threshold is the largest cut value.  Exact unless capped.  Past ``deadline``
    it raises TimeUp with the best path found and the current threshold (no allocation is worth more)."""
    lv = levels(c)
    depth = len(lv)
    if depth == 0:
        return SolverOutput((), 0, False, 0)
    h = Heuristic(c.n_robots, lv, deadline)
    kids = [bl + [DUMMY] for bl in lv]
    eps = 1e-9 * max(1.0, h.total[0])
    state = {"nodes": 0, "expanded": 0, "best": 0.0, "best_path": ()}
    path: list[int] = []

    def dfs(d: int, used: int, g: float, thr: float, cut: list[float]) -> bool:
        if d == depth:
            if g >= thr - eps:
                return True
            if g > cut[0]:
                cut[0] = g
            return False
        for i, m, v in kids[d]:
            if m & used:
                continue
            state["nodes"] += 1
            if node_limit is not None and state["nodes"] > node_limit:
                raise NodeCap
            if not state["nodes"] & 0x3FF and past(deadline):
                raise TimeUp(state["best_path"], thr)
            g2 = g + v
            u2 = used | m
            f = g2 + h(d + 1, u2)
            if g2 > state["best"]:
                state["best"] = g2
                state["best_path"] = tuple(path) + ((i,) if i >= 0 else ())
            if f < thr - eps:
                if f > cut[0]:
                    cut[0] = f
                continue
            state["expanded"] += 1
            if i >= 0:
                path.append(i)
            if dfs(d + 1, u2, g2, thr, cut):
                return True
            if i >= 0:
                path.pop()
        return False

    thr = h(0, 0)
    iterations = 0
    try:
        while True:
            iterations += 1
            cut = [-math.inf]
            path.clear()
            start = state["nodes"]
            state["expanded"] = 0
            if dfs(0, 0, 0.0, thr, cut):
                return SolverOutput(tuple(path), state["nodes"], False, iterations, state["nodes"] - start,
                                    state["expanded"])
            if cut[0] == -math.inf:          # cannot happen: the all-dummy leaf always exists
                raise AssertionError("IDA* exhausted the bid tree without a leaf")
            thr = cut[0]
    except NodeCap:
        return SolverOutput(state["best_path"], node_limit, True, iterations, node_limit - start, state["expanded"])


def solve_bfs(c: Compiled, node_limit: int | None = None, deadline: float | None = None) -> SolverOutput:
    """Breadth-first generation of the whole bid tree; returns the first best leaf (past ``deadline``: raises
    TimeUp with the best path generated so far)."""
    lv = levels(c)
    frontier: list[tuple[int, float, tuple | None]] = [(0, 0.0, None)]
    nodes = 0
    capped = False
    for bl in lv:
        nxt: list[tuple[int, float, tuple | None]] = []
        for k, (used, g, chain) in enumerate(frontier):
            if not k & 0x3FF and (past(deadline) or len(frontier) + len(nxt) > MAX_OPEN):
                raise TimeUp(_path(max(frontier + nxt, key=lambda node: node[1])),
                             reason=None if past(deadline) else f"the limit of {MAX_OPEN} open BFS nodes")
            for i, m, v in bl:
                if not m & used:
                    nxt.append((used | m, g + v, (i, chain)))
            nxt.append((used, g, chain))
            if node_limit is not None and nodes + len(nxt) > node_limit:
                capped = True
                break
        nodes += len(nxt)
        frontier = nxt if not capped else frontier + nxt
        if capped:
            nodes = node_limit
            break
    return SolverOutput(_path(max(frontier, key=lambda node: node[1])), nodes, capped, 0)


def _path(node: tuple[int, float, tuple | None]) -> tuple[int, ...]:
    """The bid indices on a BFS node's path, root first."""
    chosen = []
    chain = node[2]
    while chain is not None:
        chosen.append(chain[0])
        chain = chain[1]
    return tuple(reversed(chosen))
