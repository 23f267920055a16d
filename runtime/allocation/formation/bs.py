"""BS, the basic market-based algorithm of paper 002 (section II-A), as a sans-IO agent.

An auctioneer announces a task, every other live robot bids its cost, the lowest bid wins.  A robot
that holds two tasks keeps the cheaper one and sells the other in an auction of its own, to the best
bid WORSE than its own bid for that task: every resale moves a task to a robot with a strictly larger
(bid, robot id), so no task can circle between two robots (paper Fig. 2) and negotiation ends.
Auctions run in parallel; the initial auctioneer is the robot on which :meth:`BSAgent.start` is called.

Wire use of the shared messages (``runtime.allocation.formation.messages``):

* ``Announce`` (broadcast): ``reserve`` = +inf for an open auction (lowest bid wins, the auctioneer's
  own bid counts); a finite ``reserve`` is the seller's own bid, and only worse bids can win;
  ``reserve`` = -inf offers the task to robots that hold none (see below).
* ``Bid`` (to the auctioneer): ``cost`` = the bid; +inf means "cannot do this task" (or, to a -inf
  offer, "I hold a task").
* ``Award`` (to the winner): ``cost`` = the winning bid, ``mean`` = mean of all bids heard.  A winner takes
  an award only for an auction it bid in, at exactly the bid it sent (both travel as float32); anything else
  is dropped and counted.
* ``Status`` to an auctioneer: "I hold that task", with ``auction`` = the id of the auction it
  answers - the winner's reply to an ``Award`` (sent again for every duplicate), or a holder's reply
  to an ``Announce`` for a task it already holds (the auction is then cancelled).  The auctioneer
  matches it by auction id, never by task alone: a late or duplicated reply to an auction already
  closed cannot touch a newer auction for the same task.  A ``Status`` naming an auction the
  auctioneer does not have open, or a task other than that auction's, is dropped ("stale status").
  Broadcast ``Status`` (``dest`` 0) carries ``auction`` 0.

A resale that finds no bid worse than the seller's cannot happen with fixed costs and every bid heard
(the resales are task-proposing deferred acceptance, and some robot is still free).  It can when a bid
was missed: a peer silent through every re-announce, or one that said "cannot" and later can (an RRT bid
tree that missed).  The free robot is then skipped.  The seller does not drop the task: it offers it
once more with ``reserve`` = -inf, where only robots holding no task bid.  The winner was free, so it
sells nothing and no chain restarts: a robot never becomes free again once it holds a task, so these
offers are bounded by the number of free robots.  A free robot that cannot bid yet answers +inf, as do
the robots holding a task, so an offer with no finite bid is re-armed like an open auction; once it has
been ``max_retries`` times and every live robot answered (all hold a task: more tasks than live robots), the
task is left unallocated.  While some robot's answer is missing (lost), the offer goes on: that robot may be
the free one (found by hypothesis: RTMA, 7 robots, 30 % loss, 2 retries, seed 1206, left a task unallocated
beside a free robot).

Loss, duplication and reordering: an auction closes when every live peer has bid, else it is
re-announced every ``bid_timeout`` (bidders re-send the same bid) up to ``max_retries`` times, to the
silent peers only when they are fewer than half; an award is re-sent every ``bid_timeout`` until
acknowledged or the winner is declared lost.  Everything is keyed by (auctioneer, auction id), so
duplicates change nothing.  A lost peer's task is re-auctioned by whoever awarded it.
"""
from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field, replace
from typing import Callable, Mapping, Sequence

from runtime.allocation.formation.assignment import LOST_PROBES, TaskBook
from runtime.allocation.formation.messages import (Announce, Award, Bid, Status, TaskInfo, addressed_to,
                                         wire_float)
from runtime.log import get_logger
from runtime.messages import BROADCAST

INF = math.inf


@dataclass
class _Auction:
    id: int
    task: int
    reserve: float                        # +inf: open auction
    expected: set[int]                    # live peers whose bids are awaited
    deadline: float
    bids: dict[int, float] = field(default_factory=dict)
    tries: int = 0
    rearms: int = 0                       # times it closed with no bid it could take and was re-armed
    award: Award | None = None            # sent, waiting for the winner's Status
    lost_holder: int | None = None        # re-auctioning the task of this lost peer: asked too, LOST_PROBES times


class BSAgent:
    """One robot's BS negotiator.  See the module docstring for the protocol."""

    method = "bs"

    def __init__(self, robot_id: int, peers: Sequence[int], cost: Callable[[int], float], *,
                 bid_timeout: float = 1.0, quiet: float | None = None, max_retries: int = 10,
                 resell_to_worse: bool = True, held_elsewhere: Callable[[int], bool] | None = None):
        self.robot_id = int(robot_id)
        self.held_elsewhere = held_elsewhere        # task -> a live robot says it holds it (outside this protocol)
        self.peers = sorted({int(p) for p in peers} - {self.robot_id})
        self.alive = set(self.peers)
        self.bid_timeout = float(bid_timeout)
        self.quiet = self.bid_timeout if quiet is None else float(quiet)
        self.max_retries = int(max_retries)
        self.resell_to_worse = resell_to_worse      # False: the naive rule that loops in Fig. 2
        self.book = TaskBook(cost)
        self.won: dict[int, float] = {}             # task -> my bid when I won it
        self.means: dict[int, float] = {}           # task -> mean of the bids in the auction I won
        self.selling: dict[int, int] = {}           # task -> my resale auction id
        self.auctions: dict[int, _Auction] = {}     # my auctions, open or awarding
        self.awarded_to: dict[int, int] = {}        # task -> robot that acknowledged my award
        self.dropped: Counter = Counter()           # messages ignored, by reason
        self.sent = 0
        self.idle_offers = 0                        # resales that found no worse bid (see module doc)
        self._next_auction = 1
        self._bids_sent: dict[tuple[int, int], Bid] = {}
        self._awards_seen: dict[tuple[int, int], int] = {}
        self._active = False
        self._last_activity = -INF
        self._now = 0.0
        self.log = get_logger(f"alloc.{self.method}", self.robot_id)

    # ------------------------------------------------------------------ method-specific rules
    def bid_value(self, task: int) -> float | None:
        """My bid for ``task``: its cost (BS).  None: not computable yet."""
        return self.book.cost(task)

    def my_bid(self, task: int) -> float | None:
        """:meth:`bid_value` at wire precision: what peers will see, so what I compare with."""
        value = self.bid_value(task)
        return None if value is None else wire_float(value)

    def keep_key(self, task: int):
        """Sort key of won tasks, lowest is kept: BS keeps the cheapest."""
        return (self.won[task], task)

    def _notify(self, now: float) -> list:
        return []

    # ------------------------------------------------------------------ agent interface
    @property
    def assignment(self) -> int | None:
        held = [t for t in self.won if t not in self.selling]
        return min(held, key=self.keep_key) if held else None

    @property
    def converged(self) -> bool:
        return (self._active and not self.auctions and not self._waiting()
                and self._now - self._last_activity >= self.quiet)

    def _waiting(self) -> bool:
        return False

    def start(self, tasks: Mapping[int, tuple[float, float]], now: float) -> list:
        self._now = now
        self._touch(now)
        self.book.set_all(tasks)
        out = self._notify(now)
        for task in sorted(self.book.positions):
            out += self._open(task, INF, now)
        return self._out(out)

    def on_message(self, msg, now: float) -> list:
        self._now = now
        if not addressed_to(msg, self.robot_id):
            self.dropped["not for me"] += 1
            return []
        sender = msg.sender
        handler = {Announce: self._on_announce, Bid: self._on_bid, Award: self._on_award,
                   Status: self._on_status, TaskInfo: self._on_taskinfo}.get(type(msg))
        if handler is None:
            self.dropped["unexpected type"] += 1
            return []
        if sender in self.peers:
            self.alive.add(sender)       # heard again: a peer thought lost is back
        return self._out(handler(msg, now))

    def on_tick(self, now: float) -> list:
        self._now = now
        out = []
        for a in list(self.auctions.values()):
            if now < a.deadline:
                continue
            if a.award is None:
                if a.lost_holder is not None and a.tries + 1 >= LOST_PROBES:
                    a.expected.discard(a.lost_holder)            # not heard: lost indeed
                missing = a.expected - set(a.bids)
                if missing and a.tries < self.max_retries:
                    a.tries += 1
                    a.deadline = now + self.bid_timeout
                    if 2 * len(missing) < len(a.expected):      # ask only those not heard
                        out += [replace(self._announce(a), dest=r) for r in sorted(missing)]
                    else:
                        out.append(self._announce(a))
                else:
                    out += self._close(a, now)
            else:
                # Sent until acknowledged, or until the winner is declared lost (on_peer_lost).  Assuming
                # it arrived would strand the task whenever every copy was lost.
                a.tries += 1
                a.deadline = now + self.bid_timeout
                if a.tries == self.max_retries:
                    self.log.warning("no acknowledgement of task %d from robot %d after %d awards: still sending",
                                     a.task, a.award.winner, a.tries)
                out.append(a.award)
        out += self._tick_extra(now)
        return self._out(out)

    def _tick_extra(self, now: float) -> list:
        return []

    def heard(self, robot_id: int, now: float) -> None:
        """Robot ``robot_id`` was heard by my daemon outside my messages.  Nothing to do: a lost holder's task waits
        for the holder's own answer (``LOST_PROBES``), which only a message to me gives."""

    def on_peer_lost(self, robot_id: int, now: float) -> list:
        self._now = now
        self.alive.discard(robot_id)
        out = []
        for a in list(self.auctions.values()):
            a.expected.discard(robot_id)
            a.bids.pop(robot_id, None)
            if a.award is not None and a.award.winner == robot_id:
                a.award = None
                out += self._close(a, now)
            elif a.award is None and not (a.expected - set(a.bids)) and a.lost_holder is None:
                out += self._close(a, now)
        for task, winner in list(self.awarded_to.items()):
            if winner == robot_id:
                del self.awarded_to[task]
                if task in self.won:               # it came back to me by resales since: nothing to re-auction
                    continue
                if self.held_elsewhere is not None and self.held_elsewhere(task):
                    self.log.info("robot %d lost; task %d I once awarded it is held by a live robot", robot_id, task)
                    continue
                self.log.info("robot %d lost holding task %d: re-auctioning it", robot_id, task)
                out += self._open(task, INF, now, lost_holder=robot_id)
        return self._out(out)

    # ------------------------------------------------------------------ auctioneer side
    def _open(self, task: int, reserve: float, now: float, lost_holder: int | None = None) -> list:
        """Auction ``task``.  ``lost_holder``: the peer that was lost holding it.  A peer is declared lost after a
        silence, which a lossy link makes now and then for a live one; were the auction to close on the other
        bids alone, which come at once, the holder's "I hold it" would come too late and the task would be held
        twice.  So the auction runs its whole bid timeout, where a robot holding the task (the lost one, or one it
        was resold to) has time to say so and cancel it, and the lost one is asked again each bid timeout, for
        ``LOST_PROBES`` of them; at its close, a task a live robot is known to hold by then is not awarded."""
        self._touch(now)
        aid = self._next_auction
        self._next_auction += 1
        a = _Auction(aid, task, reserve, set(self.alive) | ({lost_holder} if lost_holder is not None else set()),
                     now + self.bid_timeout, lost_holder=lost_holder)
        if reserve == INF:
            mine = self.my_bid(task)
            if mine is not None:
                a.bids[self.robot_id] = mine
        else:
            self.selling[task] = aid
        self.auctions[aid] = a
        out = [self._announce(a)]
        if not a.expected:
            out += self._close(a, now)
        return out

    def _announce(self, a: _Auction) -> Announce:
        x, y = self.book.positions.get(a.task, (0.0, 0.0))
        return Announce(self.robot_id, BROADCAST, a.id, a.task, x, y, a.reserve)

    def _candidates(self, a: _Auction) -> list[tuple[float, int]]:
        bids = [(b, r) for r, b in a.bids.items() if math.isfinite(b)]
        if a.reserve == INF:
            return bids
        if self.resell_to_worse:
            return [k for k in bids if k > (a.reserve, self.robot_id)]
        return [k for k in bids if k[1] != self.robot_id]

    def _close(self, a: _Auction, now: float) -> list:
        self._touch(now)
        if a.lost_holder is not None and self.held_elsewhere is not None and self.held_elsewhere(a.task):
            self.log.info("task %d is held by a live robot after all: cancelling auction %d", a.task, a.id)
            del self.auctions[a.id]
            return []
        cands = self._candidates(a)
        if not cands:
            if a.reserve == -INF and a.rearms >= self.max_retries and not (a.expected - set(a.bids)):
                # every live robot answered, and each holds a task: more tasks than robots
                self.log.warning("task %d: no robot without a task bid for it: leaving it unallocated", a.task)
                del self.auctions[a.id]
                self._release(a.task)
                return []
            if not math.isfinite(a.reserve):      # nobody (free) can take it yet: ask again later
                (self.log.warning if a.rearms == 0 else self.log.debug)(
                    "task %d: no robot%s can take it yet; announcing again", a.task,
                    " without a task" if a.reserve == -INF else "")
                a.rearms += 1
                a.bids = {r: b for r, b in a.bids.items() if math.isfinite(b)}
                a.expected = set(self.alive)
                a.deadline = now + self.bid_timeout
                a.tries = 0
                return []
            self.log.info("task %d: no bid worse than mine (%.3f): offering it to robots holding no task",
                          a.task, a.reserve)
            del self.auctions[a.id]
            self.idle_offers += 1
            return self._open(a.task, -INF, now)
        bid, winner = min(cands)
        heard = [b for b in a.bids.values() if math.isfinite(b)]
        if math.isfinite(a.reserve):
            heard.append(a.reserve)
        mean = wire_float(sum(heard) / len(heard))
        if winner == self.robot_id:
            del self.auctions[a.id]
            return self._win(a.task, bid, mean, now)
        a.award = Award(self.robot_id, winner, a.id, a.task, winner, bid, mean)
        a.deadline = now + self.bid_timeout
        a.tries = 0
        return [a.award]

    def _acknowledged(self, a: _Auction, holder: int, now: float) -> list:
        self._touch(now)
        self.auctions.pop(a.id, None)
        self.awarded_to[a.task] = holder
        self._release(a.task)
        return []

    def _release(self, task: int) -> None:
        if self.selling.get(task) is not None and self.selling[task] not in self.auctions:
            del self.selling[task]
            self.won.pop(task, None)
            self.means.pop(task, None)

    def _on_bid(self, m: Bid, now: float) -> list:
        a = self.auctions.get(m.auction)
        if a is None or a.task != m.task or a.award is not None:
            self.dropped["stale bid"] += 1
            return []
        self._touch(now)
        a.bids[m.sender] = float(m.cost)
        a.expected.add(m.sender)
        if not (a.expected - set(a.bids)) and a.lost_holder is None:
            return self._close(a, now)
        return []

    def _on_status(self, m: Status, now: float) -> list:
        if m.dest == BROADCAST:
            return self._on_status_broadcast(m, now)
        a = self.auctions.get(m.auction)
        if a is None or a.task != m.task:          # an auction closed since, or not mine at all
            self.dropped["stale status"] += 1
            return []
        if a.award is not None:
            if a.award.winner == m.sender:         # the winner acknowledges my award
                return self._acknowledged(a, m.sender, now)
            self.dropped["stale status"] += 1      # awarded to another robot meanwhile
            return []
        # another robot already holds the task: this auction is a duplicate
        self.log.info("task %d is held by robot %d: cancelling auction %d", m.task, m.sender, a.id)
        return self._acknowledged(a, m.sender, now)

    def _on_status_broadcast(self, m: Status, now: float) -> list:
        self.dropped["unexpected status"] += 1
        return []

    # ------------------------------------------------------------------ bidder side
    def _on_announce(self, m: Announce, now: float) -> list:
        if not self.book.learn(m.task, m.x, m.y):
            self.dropped["unknown task"] += 1
            return []
        self._touch(now)
        key = (m.sender, m.auction)
        if key in self._bids_sent:
            return [self._bids_sent[key]]
        if m.task in self.won and m.task not in self.selling:
            return [Status(self.robot_id, m.sender, m.auction, m.task, False)]
        return self._bid(m, now)

    def _bid(self, m: Announce, now: float) -> list:
        if m.reserve == -INF and self.assignment is not None:     # an offer to free robots only
            return [Bid(self.robot_id, m.sender, m.auction, m.task, INF)]
        value = self.my_bid(m.task)
        if value is None:
            return []
        bid = Bid(self.robot_id, m.sender, m.auction, m.task, value)
        if math.isfinite(value):      # "cannot" is asked again: the cost may become known later
            self._bids_sent[(m.sender, m.auction)] = bid
        return [bid]

    def _on_award(self, m: Award, now: float) -> list:
        if m.winner != self.robot_id:
            return []
        key = (m.sender, m.auction)
        ack = Status(self.robot_id, m.sender, m.auction, m.task, False)
        if key in self._awards_seen:
            return [ack]
        sent = self._bids_sent.get(key)
        if sent is None or sent.task != m.task:
            self.dropped["award without bid"] += 1
            return []
        if m.cost != sent.cost:                    # an auctioneer awards the winner's own bid, as it heard it
            self.dropped["award at a cost I did not bid"] += 1
            return []
        self._awards_seen[key] = m.task
        return [ack] + self._win(m.task, sent.cost, float(m.mean), now)

    def _win(self, task: int, bid: float, mean: float, now: float) -> list:
        self._touch(now)
        if task in self.won:
            return []
        self.awarded_to.pop(task, None)            # awarded away once, back to me by resales
        self.won[task] = bid
        self.means[task] = mean
        out = []
        held = sorted((t for t in self.won if t not in self.selling), key=self.keep_key)
        for t in held[1:]:
            out += self._open(t, self.won[t], now)
        return out

    def _on_taskinfo(self, m: TaskInfo, now: float) -> list:
        if not self.book.learn(m.task, m.x, m.y, m.n_tasks):
            self.dropped["contradicts task set"] += 1
            return []
        self._touch(now)
        return []

    # ------------------------------------------------------------------ helpers
    def _touch(self, now: float) -> None:
        self._active = True
        self._last_activity = max(self._last_activity, now)

    def _out(self, msgs: list) -> list:
        self.sent += len(msgs)
        return msgs
