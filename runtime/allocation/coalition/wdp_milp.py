"""Reference solvers from scipy: the integer program for HiGHS, and the assignment special case.

Integer program: one binary x_b per bid, maximise sum v_b x_b subject to, for every robot and every
task, the bids that use it summing to at most 1 (``scipy.optimize.milp``, HiGHS branch and cut).
When every coalition is a single robot the problem is a rectangular assignment and
``scipy.optimize.linear_sum_assignment`` solves it in polynomial time.
"""
from __future__ import annotations

import time

import numpy as np
from scipy.optimize import Bounds, LinearConstraint, linear_sum_assignment, milp
from scipy.sparse import csr_matrix

from runtime.allocation.coalition.wdp_model import Compiled, SolverOutput, TimeUp


def milp_matrix(c: Compiled) -> csr_matrix:
    """Rows: robots then tasks; column b has a 1 for each robot of bid b and for its task."""
    rows, cols = [], []
    for b in range(c.n_bids):
        rows.append(c.n_robots + c.task[b])
        cols.append(b)
        m = c.mask[b]
        while m:
            low = m & -m
            rows.append(low.bit_length() - 1)
            cols.append(b)
            m ^= low
    return csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(c.n_robots + c.n_tasks, c.n_bids))


def solve_milp(c: Compiled, deadline: float | None = None) -> SolverOutput:
    """Exact optimum by HiGHS; ``nodes`` is HiGHS's branch-and-bound node count.  HiGHS stops at ``deadline``
    (``time.perf_counter()`` seconds): TimeUp with its incumbent and its dual bound."""
    if c.n_bids == 0:
        return SolverOutput((), 0)
    options = {} if deadline is None else {"time_limit": max(deadline - time.perf_counter(), 1e-3)}
    res = milp(
        -np.asarray(c.value, dtype=float),
        constraints=LinearConstraint(milp_matrix(c), -np.inf, 1.0),
        integrality=np.ones(c.n_bids),
        bounds=Bounds(0.0, 1.0),
        options=options,
    )
    if res.status == 1 and deadline is not None:          # the time limit
        chosen = () if res.x is None else tuple(int(b) for b in np.flatnonzero(res.x > 0.5))
        bound = getattr(res, "mip_dual_bound", None)
        raise TimeUp(chosen, -bound if bound is not None and np.isfinite(bound) else None)
    if res.status != 0 or res.x is None:
        raise RuntimeError(f"milp: HiGHS did not prove optimality ({res.message})")
    chosen = tuple(int(b) for b in np.flatnonzero(res.x > 0.5))
    return SolverOutput(chosen, int(getattr(res, "mip_node_count", 0) or 0))


def solve_assignment(c: Compiled) -> SolverOutput:
    """Exact optimum when every bid's coalition is one robot (raises ValueError otherwise)."""
    if any(m.bit_count() != 1 for m in c.mask):
        raise ValueError("assignment: every coalition must be a single robot")
    if c.n_bids == 0:
        return SolverOutput((), 0)
    weight = np.zeros((c.n_robots, c.n_tasks))
    which = np.full((c.n_robots, c.n_tasks), -1, dtype=np.int64)
    for b in range(c.n_bids):
        r, t = c.mask[b].bit_length() - 1, c.task[b]
        if which[r, t] < 0 or c.value[b] > weight[r, t]:
            weight[r, t] = c.value[b]
            which[r, t] = b
    rows, cols = linear_sum_assignment(weight, maximize=True)
    chosen = tuple(sorted(int(which[r, t]) for r, t in zip(rows, cols) if which[r, t] >= 0 and weight[r, t] > 0))
    return SolverOutput(chosen, len(rows))
