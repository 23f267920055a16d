"""Sans-IO simultaneous coalition auction (paper 001, Table 1 steps 3-4) and a coalition bidder.

:class:`SimultaneousAuctioneer` offers every task at once, collects coalition bids until a
deadline, solves winner determination over the bids it received, and awards each winning
coalition (one message per member).  A member that does not accept within ``ack_timeout`` is
marked unresponsive, the award is withdrawn and the task joins the leftovers.  Leftover tasks go
greedily, as robots report their tasks done: the best received bid for a leftover task whose
coalition is wholly free and responsive wins, repeatedly.

:class:`CoalitionBidder` is the robot side used by tests and experiments: it bids the coalitions a
``bids_for(task, x, y)`` function gives, accepts awards, and reports done after ``work_time``.

Both only take ``on_message(msg, now)`` / ``on_tick(now)`` and return messages to send.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Iterable

from runtime.allocation.coalition.bidbook import BidBook
from runtime.allocation.coalition.wdp_messages import (AwardAck, AwardCancel, CoalitionAward, CoalitionBid, TaskDone,
                                                       TaskOffer)
from runtime.log import get_logger
from runtime.messages import BROADCAST


@dataclass
class AuctionStats:
    bids: int = 0            # bids accepted into the round
    duplicates: int = 0      # same coalition and task heard again (kept the higher value)
    dropped: int = 0         # malformed, unknown task/robot, wrong round, not from a member
    late: int = 0            # bids after the deadline
    ignored: int = 0         # acks/done for nothing we track, unknown message types
    awards: int = 0          # awards sent (optimal round + greedy)
    greedy_awards: int = 0
    cancelled: int = 0


@dataclass
class _Award:
    task: int
    robots: tuple[int, ...]
    value: float
    sent: float
    acked: set = field(default_factory=set)
    done: set = field(default_factory=set)


class SimultaneousAuctioneer:
    """Offers ``tasks`` ({task id: (x, y)}) to ``robots`` in one round starting at ``start``."""

    def __init__(self, robot_id: int, robots: Iterable[int], tasks: dict[int, tuple[float, float]],
                 bid_window: float = 1.0, ack_timeout: float = 0.5, start: float = 0.0, method: str = "auto"):
        if bid_window <= 0 or ack_timeout <= 0:
            raise ValueError("bid_window and ack_timeout must be > 0")
        self.robot_id = robot_id
        self.robots = tuple(robots)
        self.tasks = dict(tasks)
        self.bid_window = bid_window
        self.ack_timeout = ack_timeout
        self.start = start
        self.method = method
        self.auction = 0
        self.phase = "idle"              # idle -> bidding -> running
        self.deadline = math.inf
        self.book: BidBook | None = None
        self.awards: dict[int, _Award] = {}          # task -> current award
        self.completed: dict[int, tuple[int, ...]] = {}
        self.leftover: set[int] = set()
        self.busy: set[int] = set()
        self.unresponsive: set[int] = set()
        self.round_value = 0.0
        self.stats = AuctionStats()
        self.log = get_logger("allocation.wdp_auctioneer", robot_id)

    # ------------------------------------------------------------------ agent interface
    def on_tick(self, now: float) -> list:
        out: list = []
        if self.phase == "idle" and now >= self.start:
            out += self._open(now)
        elif self.phase == "bidding" and now >= self.deadline:
            out += self._close(now)
        if self.phase == "running":
            out += self._expire_awards(now)
        return out

    @property
    def received(self) -> dict[tuple[int, tuple[int, ...]], float]:
        """The bids of the round: (task, sorted coalition) -> value."""
        return {} if self.book is None else self.book.received

    def on_message(self, msg, now: float) -> list:
        if getattr(msg, "sender", None) in self.unresponsive:
            self.unresponsive.discard(msg.sender)       # heard again: eligible for leftovers
        if isinstance(msg, CoalitionBid):
            self._take_bid(msg, now)
            return []
        if isinstance(msg, AwardAck):
            award = self.awards.get(msg.task)
            if msg.round != self.auction or award is None or msg.sender not in award.robots:
                self.stats.ignored += 1
                return []
            award.acked.add(msg.sender)
            return []
        if isinstance(msg, TaskDone):
            return self._done(msg, now)
        self.stats.ignored += 1
        return []

    @property
    def finished(self) -> bool:
        """Every task completed, or no awards running and no bid can take a leftover task."""
        if self.phase != "running" or self.awards:
            return False
        return not self.leftover or self._greedy_pick() is None

    # ------------------------------------------------------------------ round
    def _open(self, now: float) -> list:
        self.auction += 1
        self.phase = "bidding"
        self.deadline = now + self.bid_window
        self.book = BidBook(self.auction, tuple(sorted(self.tasks)), self.robots, self.deadline)
        self.log.info("round %d: offering %d tasks until %.3f", self.auction, len(self.tasks), self.deadline)
        return [TaskOffer(self.robot_id, BROADCAST, self.auction, t, float(x), float(y), len(self.tasks), self.deadline,
                          self.robots) for t, (x, y) in sorted(self.tasks.items())]

    def _take_bid(self, bid: CoalitionBid, now: float) -> None:
        outcome = "dropped" if self.book is None else self.book.take(bid, now)
        setattr(self.stats, outcome, getattr(self.stats, outcome) + 1)

    def _close(self, now: float) -> list:
        self.phase = "running"
        result, bids = self.book.solve(self.method)
        self.round_value = result.value
        self.leftover = set(self.tasks) - set(result.assignment)
        self.log.info("round %d: %d bids, value %.3f by %s, %d tasks left over", self.auction, len(bids),
                      result.value, result.method, len(self.leftover))
        out: list = []
        for b in result.winners:
            out += self._award(bids[b].task, bids[b].robots, bids[b].value, now)
        return out + self._greedy(now)

    def _award(self, task: int, robots: tuple[int, ...], value: float, now: float) -> list:
        self.awards[task] = _Award(task, robots, value, now)
        self.busy.update(robots)
        self.stats.awards += 1
        return [CoalitionAward(self.robot_id, r, self.auction, task, robots, value) for r in robots]

    def _expire_awards(self, now: float) -> list:
        out: list = []
        for task, award in list(self.awards.items()):
            if len(award.acked) == len(award.robots) or now < award.sent + self.ack_timeout:
                continue
            silent = set(award.robots) - award.acked
            self.unresponsive |= silent
            self.busy -= set(award.robots) - silent
            del self.awards[task]
            self.leftover.add(task)
            self.stats.cancelled += 1
            self.log.warning("task %d: robots %s did not accept, award withdrawn", task, sorted(silent))
            out += [AwardCancel(self.robot_id, r, self.auction, task) for r in award.robots]
        if out:
            out += self._greedy(now)
        return out

    def _done(self, msg: TaskDone, now: float) -> list:
        award = self.awards.get(msg.task)
        if msg.round != self.auction or award is None or msg.sender not in award.robots:
            self.stats.ignored += 1
            return []
        award.acked.add(msg.sender)          # finishing implies it had accepted
        award.done.add(msg.sender)
        self.busy.discard(msg.sender)
        if len(award.done) == len(award.robots):
            self.completed[msg.task] = award.robots
            del self.awards[msg.task]
        return self._greedy(now)

    # ------------------------------------------------------------------ leftovers
    def _greedy_pick(self):
        best = None
        for (task, robots), value in self.received.items():
            if task not in self.leftover or any(r in self.busy or r in self.unresponsive for r in robots):
                continue
            if best is None or (value, -task) > (best[2], -best[0]):
                best = (task, robots, value)
        return best

    def _greedy(self, now: float) -> list:
        out: list = []
        while (pick := self._greedy_pick()) is not None:
            task, robots, value = pick
            self.leftover.discard(task)
            self.stats.greedy_awards += 1
            self.log.info("task %d: greedy award to %s (%.3f)", task, list(robots), value)
            out += self._award(task, robots, value, now)
        return out


@dataclass
class _Job:
    task: int
    round: int
    auctioneer: int
    until: float


class CoalitionBidder:
    """Robot side: bids what ``bids_for(task, x, y)`` returns (coalitions it leads, with values),
    accepts awards, and reports each task done after ``work_time(task)`` seconds."""

    def __init__(self, robot_id: int, bids_for: Callable[[int, float, float], list[tuple[tuple[int, ...], float]]],
                 work_time: Callable[[int], float] = lambda task: 1.0):
        self.robot_id = robot_id
        self.bids_for = bids_for
        self.work_time = work_time
        self.jobs: dict[int, _Job] = {}
        self.done: list[int] = []
        self.ignored = 0

    def on_message(self, msg, now: float) -> list:
        if isinstance(msg, TaskOffer):
            return [CoalitionBid(self.robot_id, msg.sender, msg.round, msg.task, tuple(robots), float(value))
                    for robots, value in self.bids_for(msg.task, msg.x, msg.y)]
        if isinstance(msg, CoalitionAward) and self.robot_id in msg.robots:
            if msg.task not in self.jobs:
                self.jobs[msg.task] = _Job(msg.task, msg.round, msg.sender, now + self.work_time(msg.task))
            return [AwardAck(self.robot_id, msg.sender, msg.round, msg.task)]
        if isinstance(msg, AwardCancel):
            self.jobs.pop(msg.task, None)
            return []
        self.ignored += 1
        return []

    def on_tick(self, now: float) -> list:
        out = []
        for task, job in list(self.jobs.items()):
            if now >= job.until:
                del self.jobs[task]
                self.done.append(task)
                out.append(TaskDone(self.robot_id, job.auctioneer, job.round, task))
        return out
