"""The bids of one simultaneous auction round (paper 001, Table 1 step 3): checked as they arrive, kept
once per (task, coalition), and handed to winner determination when the round closes.

Shared by the in-process :class:`~runtime.allocation.coalition.wdp_auctioneer.SimultaneousAuctioneer`
and the daemon's auctioneer role (:mod:`runtime.allocation.coalition.auctioneer`), so both take and
solve bids the same way.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

from runtime.allocation.coalition import winner_determination as wd
from runtime.allocation.coalition.wdp_model import Problem, TaskBid

TAKEN, DUPLICATE, DROPPED, LATE = "bids", "duplicates", "dropped", "late"   # outcomes (AuctionStats fields)


@dataclass
class BidBook:
    """Bids of round ``round`` for ``tasks`` among ``robots``, taken until ``deadline``.  ``sizes`` (task ->
    robots it needs), when given, admits only coalitions of exactly that size."""
    round: int
    tasks: tuple
    robots: tuple
    deadline: float
    sizes: Mapping | None = None

    def __post_init__(self) -> None:
        self.received: dict[tuple, float] = {}      # (task, sorted robots) -> value
        self.closed = False                          # solved: every later bid is late

    def take(self, bid, now: float) -> str:
        """File ``bid`` (a :class:`CoalitionBid`); returns what became of it: TAKEN, DUPLICATE (same task and
        coalition heard again: the higher value is kept), DROPPED (wrong round, unknown task or robot, not from
        a member, wrong size, bad value) or LATE (after the deadline)."""
        try:
            robots = tuple(bid.robots)
            ok = (bid.round == self.round and bid.task in self.tasks and len(robots) > 0
                  and len(set(robots)) == len(robots) and all(r in self.robots for r in robots)
                  and bid.sender in robots and isinstance(bid.value, (int, float))
                  and not isinstance(bid.value, bool) and math.isfinite(bid.value) and bid.value >= 0
                  and (self.sizes is None or self.sizes.get(bid.task) == len(robots)))
        except TypeError:
            ok = False
        if not ok:
            return DROPPED
        if self.closed or now > self.deadline:
            return LATE
        key = (bid.task, tuple(sorted(robots)))
        if key in self.received:
            self.received[key] = max(self.received[key], float(bid.value))
            return DUPLICATE
        self.received[key] = float(bid.value)
        return TAKEN

    def bids(self) -> tuple[TaskBid, ...]:
        """The bids taken, in a fixed order (task, then coalition)."""
        return tuple(TaskBid(t, rs, v) for (t, rs), v in sorted(self.received.items()))

    def problem(self) -> Problem:
        return Problem(tuple(self.robots), tuple(self.tasks), self.bids())

    def solve(self, method: str = "auto") -> tuple[wd.Allocation, tuple[TaskBid, ...]]:
        """Close the round; winner determination over exactly the bids taken: the allocation and the bids it
        indexes."""
        self.closed = True
        problem = self.problem()
        return wd.solve(problem, method), problem.bids
