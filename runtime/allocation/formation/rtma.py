"""RTMA, the Robot and Task Mean Allocation algorithm of paper 002 (section II-B, Algorithm 1).

Same auctions as BS (:mod:`runtime.allocation.formation.bs`: parallel, resale to the best bid worse than the
seller's own), with the two changes of the paper:

* bid = cost - mean of this robot's costs to all N_T tasks (equation 1); the mean is built from the
  task notifications (``TaskInfo``) the initial auctioneer broadcasts before announcing;
* a robot holding two tasks keeps the one that is better for the team: the one with the lower
  (my bid - mean of all bids for that task), i.e. the paper's inequality
  ``mean_i - D(R_k, T_i) > mean_j - D(R_k, T_j)`` keeps T_i.  The auctioneer sends the mean of the bids
  in the ``Award``.  (Algorithm 1 as printed has the comparison the other way round; the text's
  inequality is the one that makes the rule "less selfish", and it is the one used here.)

A robot bids only once it knows all N_T tasks.  One that is still missing some after ``bid_timeout``
broadcasts ``Status(auction=0, task=NO_TASK, converged=False)``; the initial auctioneer answers by
broadcasting the task notifications again (at most once per ``bid_timeout``).
"""
from __future__ import annotations

import math

from runtime.allocation.formation.assignment import NO_TASK
from runtime.allocation.formation.bs import BSAgent
from runtime.allocation.formation.messages import Announce, Status, TaskInfo
from runtime.messages import BROADCAST


class RTMAAgent(BSAgent):
    """One robot's RTMA negotiator (a BS agent with the paper's bid and keep rules)."""

    method = "rtma"

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._mean: float | None = None
        self._pending: dict[tuple[int, int], Announce] = {}   # announces waiting for the task set
        self._last_request = -math.inf
        self._served = -math.inf                             # when the task set was last re-sent
        self._initiator = False

    # ------------------------------------------------------------------ the paper's two rules
    def mean_cost(self) -> float | None:
        """Mean of my costs to all N_T tasks (the finite ones); None until the task set is complete."""
        if self._mean is None and self.book.complete:
            finite = [c for c in (self.book.cost(t) for t in self.book.positions) if math.isfinite(c)]
            self._mean = sum(finite) / len(finite) if finite else 0.0
        return self._mean

    def bid_value(self, task: int) -> float | None:
        mean = self.mean_cost()
        if mean is None:
            return None
        cost = self.book.cost(task)
        return cost - mean if math.isfinite(cost) else math.inf

    def keep_key(self, task: int):
        bid = self.won[task]
        return (bid - self.means.get(task, bid), bid, task)

    # ------------------------------------------------------------------ task notifications
    def _notify(self, now: float) -> list:
        self._initiator = True
        return self._task_set(BROADCAST)

    def _task_set(self, dest: int) -> list:
        n = len(self.book.positions)
        return [TaskInfo(self.robot_id, dest, t, x, y, n) for t, (x, y) in sorted(self.book.positions.items())]

    def _on_taskinfo(self, m: TaskInfo, now: float) -> list:
        out = super()._on_taskinfo(m, now)
        return out + self._flush(now)

    def _on_announce(self, m: Announce, now: float) -> list:
        out = super()._on_announce(m, now)
        return out + self._flush(now)

    def _bid(self, m: Announce, now: float) -> list:
        if self.mean_cost() is None:
            self._pending[(m.sender, m.auction)] = m
            return []
        return super()._bid(m, now)

    def _flush(self, now: float) -> list:
        if not self._pending or self.mean_cost() is None:
            return []
        pending, self._pending = self._pending, {}
        out = []
        for m in pending.values():
            out += self._bid(m, now)
        return out

    def _waiting(self) -> bool:
        return bool(self._pending)

    def _tick_extra(self, now: float) -> list:
        if not self._active or self.book.complete:
            return []
        if self._last_request == -math.inf:          # start waiting for the notifications
            self._last_request = now
        elif now - self._last_request >= self.bid_timeout:
            self._last_request = now
            return [Status(self.robot_id, BROADCAST, 0, NO_TASK, False)]
        return []

    def _on_status_broadcast(self, m: Status, now: float) -> list:
        if m.task != NO_TASK or m.converged:
            self.dropped["unexpected status"] += 1
            return []
        if not self._initiator or now - self._served < self.bid_timeout:
            return []
        self._served = now                 # one broadcast serves every robot that asked meanwhile
        return self._task_set(BROADCAST)
