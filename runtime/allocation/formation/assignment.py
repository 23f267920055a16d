"""The initial-formation assignment problem (paper 002, section II) and the task set agents learn.

Problem side: an n x n cost matrix (robot x task), its optimum by the Hungarian method
(``scipy.optimize.linear_sum_assignment``), straight-line costs, global cost and % error.
Agent side: :class:`TaskBook`, the tasks one robot knows from ``start()`` or messages, with its own
costs cached so that bids stay the same for the whole negotiation.
"""
from __future__ import annotations

import math
from typing import Callable, Mapping, Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

NO_TASK = 0xFFFF          # Status.task when a robot holds nothing
MAX_TASKS = 0xFFFF        # task ids are 0 .. MAX_TASKS - 1
LOST_PROBES = 3           # bid timeouts a solver asks a peer declared lost holding a task before it takes it for lost


def straight_line_costs(robots: Sequence[Sequence[float]], tasks: Sequence[Sequence[float]]) -> np.ndarray:
    """Euclidean distance from every robot (row) to every task (column)."""
    r = np.asarray(robots, dtype=float).reshape(-1, 2)
    t = np.asarray(tasks, dtype=float).reshape(-1, 2)
    return np.hypot(r[:, None, 0] - t[None, :, 0], r[:, None, 1] - t[None, :, 1])


def check_costs(costs) -> np.ndarray:
    """``costs`` as a float array if it is a non-empty square matrix of finite non-negative numbers;
    else ValueError with one line saying what is wrong."""
    if not isinstance(costs, (list, tuple, np.ndarray)) or len(costs) == 0:
        raise ValueError("costs: expected a non-empty list of rows")
    n = len(costs)
    for i, row in enumerate(costs):
        if not isinstance(row, (list, tuple, np.ndarray)):
            raise ValueError(f"costs row {i}: expected a list of {n} numbers")
        if len(row) != n:
            raise ValueError(f"costs row {i}: has {len(row)} entries, expected {n} (square: one column per task)")
        for j, c in enumerate(row):
            if isinstance(c, bool) or not isinstance(c, (int, float, np.integer, np.floating)):
                raise ValueError(f"costs[{i}][{j}]: expected a number, got {c!r:.40}")
            try:
                ok = math.isfinite(c)
            except OverflowError:      # an integer too large for a float
                ok = False
            if not ok:
                raise ValueError(f"costs[{i}][{j}]: expected a finite number, got {c}")
            if c < 0:
                raise ValueError(f"costs[{i}][{j}]: expected a non-negative number, got {c}")
    return np.asarray(costs, dtype=float)


def hungarian(costs) -> tuple[list[int], float]:
    """Optimal assignment (task index per robot) and its total cost."""
    c = np.asarray(costs, dtype=float)
    rows, cols = linear_sum_assignment(c)
    assignment = [-1] * c.shape[0]
    for r, t in zip(rows, cols):
        assignment[int(r)] = int(t)
    return assignment, float(c[rows, cols].sum())


def global_cost(costs, assignment: Sequence[int]) -> float:
    """Sum of each robot's cost for its task (paper 002's global cost); robots with -1 add nothing."""
    c = np.asarray(costs, dtype=float)
    return float(sum(c[r, t] for r, t in enumerate(assignment) if t >= 0))


def percent_error(cost: float, optimum: float) -> float:
    """How much worse than the optimum, in %; 0 when both are 0."""
    if optimum == 0:
        return 0.0 if cost == 0 else math.inf
    return 100.0 * (cost - optimum) / optimum


def is_permutation(assignment: Sequence[int | None], n: int) -> bool:
    """Every robot holds a distinct task in 0..n-1."""
    return len(assignment) == n and sorted(a if a is not None else -1 for a in assignment) == list(range(n))


class TaskBook:
    """Tasks one robot knows (id -> position), the size of the set once told, and this robot's costs.

    Costs come from the daemon's ``cost(task)`` and are cached once finite: a bid must not change while
    the negotiation runs (termination of the resale chains relies on it).
    """

    def __init__(self, cost: Callable[[int], float]):
        self._cost_fn = cost
        self._costs: dict[int, float] = {}
        self.positions: dict[int, tuple[float, float]] = {}
        self.n_tasks: int | None = None

    def set_all(self, tasks: Mapping[int, tuple[float, float]]) -> None:
        for t, (x, y) in tasks.items():
            self.positions[int(t)] = (float(x), float(y))
        self.n_tasks = len(self.positions)

    def learn(self, task: int, x: float, y: float, n_tasks: int | None = None) -> bool:
        """Record a task; False if the message contradicts what is known (it is then ignored)."""
        if n_tasks is not None:
            if self.n_tasks is not None and self.n_tasks != n_tasks:
                return False
            if n_tasks < len(self.positions) or task >= MAX_TASKS:
                return False
            self.n_tasks = n_tasks
        if self.n_tasks is not None and task not in self.positions and len(self.positions) >= self.n_tasks:
            return False
        self.positions.setdefault(task, (float(x), float(y)))
        return True

    @property
    def complete(self) -> bool:
        return self.n_tasks is not None and len(self.positions) >= self.n_tasks

    def cost(self, task: int) -> float:
        c = self._costs.get(task)
        if c is None:
            try:
                c = float(self._cost_fn(task))
            except (KeyError, IndexError, ValueError, TypeError):
                c = math.inf
            if math.isnan(c):
                c = math.inf
            if math.isfinite(c):
                self._costs[task] = c
        return c
