"""Winner determination data model: coalition bids, the problem, and its compiled bitmask form.

A problem has robots, tasks and bids; a bid offers one task to one coalition (a set of robots) for
a value >= 0.  A solution picks bids so that no robot is in two picked bids and no task is picked
twice, maximising the total value (paper 001, Table 1 step 3).

Solvers work on :class:`Compiled`: robots become bit positions, tasks become indices 0..k-1, and
each bid is (task index, robot bitmask, value) kept in input order so a solver's answer is a tuple
of bid indices into the problem.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Hashable, Sequence

Id = Hashable


@dataclass(frozen=True)
class TaskBid:
    """Coalition ``robots`` offers to do ``task`` for ``value``."""
    task: Id
    robots: tuple
    value: float


@dataclass(frozen=True)
class Problem:
    robots: tuple
    tasks: tuple
    bids: tuple[TaskBid, ...]


@dataclass(frozen=True)
class Compiled:
    """Bitmask form of a problem (or of one independent part of it).

    ``bid_ids[i]`` is bid i's index in the original problem, so a part can be solved alone and its
    answer mapped back.  ``n_robots``/``n_tasks`` count bit positions / task indices in use."""
    n_robots: int
    n_tasks: int
    task: tuple[int, ...]
    mask: tuple[int, ...]
    value: tuple[float, ...]
    bid_ids: tuple[int, ...] = field(default=())

    def __post_init__(self):
        if not self.bid_ids:
            object.__setattr__(self, "bid_ids", tuple(range(len(self.task))))

    @property
    def n_bids(self) -> int:
        return len(self.task)

    def total(self, chosen: Sequence[int]) -> float:
        """Sum of the values of the chosen bids (local indices)."""
        return float(sum(self.value[i] for i in chosen))

    def feasible(self, chosen: Sequence[int]) -> bool:
        """True when no robot and no task is used twice by the chosen bids (local indices)."""
        used_robots = 0
        used_tasks: set[int] = set()
        for i in chosen:
            if self.mask[i] & used_robots or self.task[i] in used_tasks:
                return False
            used_robots |= self.mask[i]
            used_tasks.add(self.task[i])
        return True


def compile_problem(problem: Problem) -> Compiled:
    """Map robot and task ids to bit positions / indices (in the order the problem lists them)."""
    rbit = {r: i for i, r in enumerate(problem.robots)}
    tidx = {t: i for i, t in enumerate(problem.tasks)}
    tasks, masks, values = [], [], []
    for b in problem.bids:
        m = 0
        for r in b.robots:
            m |= 1 << rbit[r]
        tasks.append(tidx[b.task])
        masks.append(m)
        values.append(float(b.value))
    return Compiled(len(problem.robots), len(problem.tasks), tuple(tasks), tuple(masks), tuple(values))


class TimeUp(Exception):
    """A solver passed its deadline (or, with ``reason``, another limit of its own such as the states it may
    hold): ``chosen`` is the best allocation it had found (local bid indices, empty when it had none) and
    ``bound`` an upper bound on the optimum it had proven (None: none)."""

    def __init__(self, chosen: Sequence[int] = (), bound: float | None = None, method: str = "",
                 reason: str | None = None):
        super().__init__(reason or "time limit reached")
        self.chosen, self.bound, self.method, self.reason = tuple(chosen), bound, method, reason


def past(deadline: float | None) -> bool:
    """Whether ``deadline`` (``time.perf_counter()`` seconds; None: none) has passed."""
    return deadline is not None and time.perf_counter() > deadline


@dataclass
class SolverOutput:
    """What one solver returns: chosen local bid indices, nodes it generated, and whether it hit
    its node cap (then ``chosen`` is the best found so far, not proven optimal).  IDA* also
    reports its passes and, for its last pass, the nodes generated and those expanded (g + h at
    or above the threshold, so searched below)."""
    chosen: tuple[int, ...]
    nodes: int
    capped: bool = False
    iterations: int = 0
    last_pass_nodes: int = 0
    last_pass_expanded: int = 0
