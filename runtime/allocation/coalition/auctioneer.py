"""The auctioneer role of the coalition agent (paper 001, Table 1 steps 3 and 4), run by the lowest-id live
robot.  Sans-IO: every input carries ``now``; the output is the messages to send.

* **Rounds** (step 3).  When there are open tasks nobody holds and free robots (idle, in no coalition),
  the auctioneer offers every such task at once (``TaskOffer`` per task, naming the invited robots), takes
  coalition bids for ``bid_window`` seconds (:class:`~runtime.allocation.coalition.bidbook.BidBook`: only
  coalitions of the task's size, of invited robots, led by a member), then solves winner determination
  over exactly the bids received and awards each winning coalition to every member.  Each round is kept
  in :attr:`Auctioneer.rounds` and logged as one INFO line of JSON.
* **Awards.**  A member accepts (``AwardAck`` or a ``MemberReport``) or declines (``AwardCancel``); the
  award is re-sent to silent members every quarter of ``ack_timeout``, and when a member has not accepted
  within ``ack_timeout`` the coalition is released: ``AwardCancel`` to every member, and the task goes back
  to the next round.  So it does when a member is lost, is disarmed (it leaves with ``AwardCancel``) or
  has not reported for ``member_timeout`` seconds.  The remaining members are released too: they are free
  again and bid in the next round like everyone else (usually winning again, being close).
* **Completion.**  Members report arrival; once all have arrived the task is done: a DONE event (the
  fleet table marks it done) and, one tick later, ``CoalitionDone`` to everyone.
* **Leftovers** (step 4).  Tasks not won stay open and are offered in the next round, which opens as
  soon as robots are free again (paper's Delta t = 0: a rendezvous member is free only when its coalition
  is done).  A round that awarded nothing is not repeated for the same tasks and robots before a back-off
  (1 s doubling to 30 s).
* **Take-over.**  The role's state is soft: a robot that becomes the auctioneer (the previous one lost)
  waits ``start_wait`` seconds, rebuilding the running coalitions from the members' periodic reports;
  tasks that live robots say they hold (``RobotState``) are never offered.  A report of a coalition it
  does not know is adopted if its members are live and free of other coalitions, else answered with
  ``AwardCancel`` (or ``CoalitionDone`` for a task it completed).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

from runtime.allocation.agent import AWARDED, DONE, RELEASED, TaskEvent
from runtime.allocation.coalition import meeting
from runtime.allocation.coalition.bidbook import DROPPED, BidBook
from runtime.allocation.coalition.proposals import own_pose
from runtime.allocation.coalition.wdp_messages import (MAX_INVITED, AwardCancel, CoalitionAward, CoalitionDone,
                                                       TaskOffer)
from runtime.allocation.coalition.wdp_model import TaskBid
from runtime.messages import BROADCAST

MAX_OFFER = 32              # tasks one round offers (lowest ids first; the rest wait for the next)
MAX_BACKOFF = 30.0


@dataclass
class Coalition:
    round: int
    task: int
    robots: tuple[int, ...]            # ring order
    value: float
    since: float
    acked: set = field(default_factory=set)
    arrived: set = field(default_factory=set)
    heard: dict = field(default_factory=dict)        # member -> last ack or report
    resent: float = -math.inf


@dataclass(frozen=True)
class RoundRecord:
    """One closed round: what was offered to whom, exactly the bids winner determination saw, its value."""
    id: int
    opened: float
    closed: float
    tasks: tuple[int, ...]
    robots: tuple[int, ...]
    bids: tuple[TaskBid, ...]
    value: float
    winners: dict                      # task -> robots
    method: str

    def to_json(self) -> dict:
        return {"round": round_name(self.id), "tasks": list(self.tasks), "robots": list(self.robots),
                "bids": [[b.task, list(b.robots), b.value] for b in self.bids], "value": self.value,
                "winners": {str(t): list(rs) for t, rs in self.winners.items()}, "method": self.method}


@dataclass
class AuctionStats:
    bids: int = 0
    duplicates: int = 0
    dropped: int = 0
    late: int = 0
    ignored: int = 0            # acks, reports, cancels for nothing this auctioneer runs
    awards: int = 0
    released: int = 0
    adopted: int = 0
    completed: int = 0


def round_name(round_id: int) -> str:
    return f"{round_id >> 16}.{round_id & 0xFFFF}"


class Auctioneer:
    def __init__(self, robot_id: int, view, options, estimator, events: list, log):
        self.robot_id = robot_id
        self.view = view
        self.o = options
        self.estimator = estimator
        self.events = events
        self.log = log
        self.active = False
        self.since = math.inf
        self.count = 0
        self.book: BidBook | None = None
        self.opened = 0.0
        self.coalitions: dict[int, Coalition] = {}
        self.finished: dict[int, tuple[int, tuple[int, ...]]] = {}     # task -> (round, robots)
        self.cancelled: set[tuple[int, int]] = set()                   # (round, task)
        self.rounds: list[RoundRecord] = []
        self._too_big: set[int] = set()
        self.deferred: list[tuple[float, object]] = []                 # (when, message): sent at a later tick
        self.stats = AuctionStats()
        self._backoff: tuple = ((), -math.inf, 1.0)                    # (key, until, wait)

    # ------------------------------------------------------------------ role
    def update_role(self, now: float) -> None:
        am = self.view.auctioneer() == self.robot_id
        if am and not self.active:
            self.active, self.since = True, now
            self.log.info("auctioneer role taken: offering tasks after %.1f s of reports", self.o.start_wait)
        elif not am and self.active:
            self.active = False
            self.log.info("auctioneer role left to robot %d", self.view.auctioneer())
            self.book, self.coalitions = None, {}

    @property
    def busy(self) -> set[int]:
        return {r for c in self.coalitions.values() for r in c.robots}

    @property
    def pending(self) -> bool:
        """A round is open or an award waits for acceptance."""
        return self.book is not None or any(len(c.acked) < len(c.robots) for c in self.coalitions.values())

    # ------------------------------------------------------------------ each tick
    def tick(self, now: float, me_free: bool) -> list:
        out = [m for t, m in self.deferred if t < now]
        self.deferred = [(t, m) for t, m in self.deferred if t >= now]
        if not self.active:
            return out
        out += self._expire(now)
        if self.book is not None and now >= self.book.deadline:
            out += self._close(now)
        if self.book is None and now - self.since >= self.o.start_wait:
            out += self._open(now, me_free)
        return out

    def _expire(self, now: float) -> list:
        out = []
        for c in list(self.coalitions.values()):
            silent = [r for r in c.robots if r not in c.acked]
            if silent and now - c.since >= self.o.ack_timeout:
                out += self._release(c, f"robots {silent} did not accept in {self.o.ack_timeout:g} s")
                continue
            quiet = [r for r in c.robots if now - c.heard.get(r, c.since) > self.o.member_timeout]
            if quiet:
                out += self._release(c, f"robots {quiet} silent for {self.o.member_timeout:g} s")
                continue
            if silent and now - c.resent >= self.o.ack_timeout / 4:
                c.resent = now
                out += [CoalitionAward(self.robot_id, r, c.round, c.task, c.robots, c.value) for r in silent]
        return out

    def _offerable(self) -> list[int]:
        """Open tasks nobody holds, lowest ids first."""
        taken = self.view.held() | set(self.coalitions) | set(self.finished)
        return [t for t in sorted(self.view.tasks) if t not in taken][:MAX_OFFER]

    def _free(self, me_free: bool) -> list[int]:
        busy = self.busy
        peers = [p for p in sorted(self.view.peers) if self.view.idle(p) and p not in busy]
        return sorted(([self.robot_id] if me_free and self.robot_id not in busy else []) + peers)[:MAX_INVITED]

    def _open(self, now: float, me_free: bool) -> list:
        robots = self._free(me_free)
        offerable = self._offerable()
        self._warn_too_big(offerable)
        tasks = [t for t in offerable if self.view.tasks[t].spec.robots <= len(robots)]
        if not tasks:
            return []
        key, until, wait = self._backoff
        if key == (tuple(tasks), tuple(robots)) and now < until:
            return []
        self.count = self.count % 0xFFFF + 1
        rid = self.robot_id << 16 | self.count
        sizes = {t: int(self.view.tasks[t].spec.robots) for t in tasks}
        self.book = BidBook(rid, tuple(tasks), tuple(robots), now + self.o.bid_window, sizes)
        self.opened = now
        self.log.info("round %s: offering tasks %s to robots %s", round_name(rid), tasks, robots)
        out = []
        for t in tasks:
            x, y = self.view.tasks[t].position
            out.append(TaskOffer(self.robot_id, BROADCAST, rid, t, x, y, len(tasks), self.book.deadline,
                                 tuple(robots)))
        return out

    def _warn_too_big(self, tasks) -> None:
        """Say once per task when it needs more robots than the fleet has live: it waits, it is not dropped."""
        live = len(self.view.live())
        for t in tasks:
            k = self.view.tasks[t].spec.robots
            if k > live and t not in self._too_big:
                self._too_big.add(t)
                self.log.warning("task %d needs %d robots, %d are live: it waits for more", t, k, live)

    def _close(self, now: float) -> list:
        book, self.book = self.book, None
        gone = [k for k in book.received if not all(self.view.is_live(r) for r in k[1])]
        for k in gone:                       # bids naming robots lost since: no coalition of theirs can meet
            del book.received[k]
        result, bids = book.solve(self.o.wdp)
        winners = {bids[b].task: bids[b].robots for b in result.winners}
        rec = RoundRecord(book.round, self.opened, now, book.tasks, book.robots, bids, result.value, winners,
                          result.method)
        self.rounds.append(rec)
        self.log.info("round %s bids %s value %.3f", round_name(book.round), json.dumps(rec.to_json()), result.value)
        out = []
        busy = self.busy
        for b in result.winners:
            bid = bids[b]
            if bid.task not in self.view.tasks or bid.task in self.coalitions or busy & set(bid.robots):
                continue                     # withdrawn or taken meanwhile
            out += self._award(book.round, bid, now)
            busy |= set(bid.robots)
        key = (book.tasks, book.robots)
        if out:
            self._backoff = ((), -math.inf, 1.0)
        else:
            wait = min(2 * self._backoff[2], MAX_BACKOFF) if self._backoff[0] == key else 1.0
            self._backoff = (key, now + wait, wait)
            if not bids:
                self.log.warning("round %s: no bids from robots %s for tasks %s (none worth doing, or lost)",
                                 round_name(book.round), list(book.robots), list(book.tasks))
        return out

    def _award(self, rid: int, bid: TaskBid, now: float) -> list:
        point = self.view.tasks[bid.task].position
        positions = {r: p for r in bid.robots if (p := self._position(r)) is not None}
        robots = meeting.ring_order(point, bid.robots, positions)
        c = Coalition(rid, bid.task, robots, bid.value, now, heard={r: now for r in robots}, resent=now)
        self.coalitions[bid.task] = c
        self.stats.awards += 1
        self.events.append(TaskEvent(bid.task, AWARDED, robots, f"round {round_name(rid)} value {bid.value:.1f}"))
        return [CoalitionAward(self.robot_id, r, rid, bid.task, robots, bid.value) for r in robots]

    def _position(self, rid: int):
        return own_pose(self.estimator) if rid == self.robot_id else self.view.position(rid)

    def _release(self, c: Coalition, why: str) -> list:
        self.coalitions.pop(c.task, None)
        self.cancelled.add((c.round, c.task))
        self.stats.released += 1
        self._backoff = ((), -math.inf, 1.0)
        self.log.warning("task %d: coalition %s released (%s); offering it again", c.task, list(c.robots), why)
        self.events.append(TaskEvent(c.task, RELEASED, c.robots, why))
        return [AwardCancel(self.robot_id, r, c.round, c.task) for r in c.robots]

    def _complete(self, c: Coalition, now: float) -> list:
        del self.coalitions[c.task]
        self.finished[c.task] = (c.round, c.robots)
        self.view.tasks.pop(c.task, None)
        self.stats.completed += 1
        self.log.info("task %d done: coalition %s met", c.task, list(c.robots))
        self.events.append(TaskEvent(c.task, DONE, c.robots))
        # the fleet table's DONE record (sent by the node this cycle) reaches the members first: they still hold
        # the task then, so every robot records the whole coalition as who did it; CoalitionDone follows
        self.deferred.append((now, CoalitionDone(self.robot_id, BROADCAST, c.round, c.task, c.robots)))
        return []

    # ------------------------------------------------------------------ messages
    def on_bid(self, m, now: float) -> None:
        outcome = DROPPED if not self.active or self.book is None else self.book.take(m, now)
        setattr(self.stats, outcome, getattr(self.stats, outcome) + 1)

    def _mine(self, m) -> Coalition | None:
        c = self.coalitions.get(m.task) if self.active else None
        return c if c is not None and c.round == m.round and m.sender in c.robots else None

    def on_ack(self, m, now: float) -> list:
        c = self._mine(m)
        if c is None:
            self.stats.ignored += 1
            return [AwardCancel(self.robot_id, m.sender, m.round, m.task)] if (m.round, m.task) in self.cancelled else []
        c.acked.add(m.sender)
        c.heard[m.sender] = now
        return []

    def on_cancel(self, m, now: float) -> list:
        """A member declines or leaves."""
        c = self._mine(m)
        if c is None:
            self.stats.ignored += 1
            return []
        return self._release(c, f"robot {m.sender} declined or left")

    def on_report(self, m, now: float) -> list:
        if not self.active:
            self.stats.ignored += 1
            return []
        c = self.coalitions.get(m.task)
        if c is None:
            return self._unknown_report(m, now)
        if c.round != m.round:
            if m.sender in c.robots:
                return []                    # a late report of its previous coalition
            return [AwardCancel(self.robot_id, m.sender, m.round, m.task)]      # holds it in another coalition
        if m.sender not in c.robots:
            self.stats.ignored += 1
            return []
        c.acked.add(m.sender)
        c.heard[m.sender] = now
        (c.arrived.add if m.arrived else c.arrived.discard)(m.sender)
        if c.arrived >= set(c.robots):
            return self._complete(c, now)
        return []

    def _unknown_report(self, m, now: float) -> list:
        done = self.finished.get(m.task)
        if done is not None:
            return [CoalitionDone(self.robot_id, m.sender, done[0], m.task, done[1])]
        if (m.round, m.task) in self.cancelled:
            return [AwardCancel(self.robot_id, m.sender, m.round, m.task)]
        task = self.view.tasks.get(m.task)
        if task is None:
            self.stats.ignored += 1            # my table is behind, or the task was withdrawn
            return []
        robots = tuple(m.robots)
        why = None
        if len(robots) != task.spec.robots:
            why = f"{len(robots)} robots for a task needing {task.spec.robots}"
        elif not all(self.view.is_live(r) for r in robots):
            why = "a member is lost"
        elif self.busy & set(robots):
            why = "a member is in another coalition"
        if why is not None:
            self.cancelled.add((m.round, m.task))
            self.log.info("task %d: not adopting coalition %s (%s)", m.task, list(robots), why)
            return [AwardCancel(self.robot_id, m.sender, m.round, m.task)]
        c = Coalition(m.round, m.task, robots, 0.0, now, acked=set(robots), heard={r: now for r in robots})
        if m.arrived:
            c.arrived.add(m.sender)
        self.coalitions[m.task] = c
        self.stats.adopted += 1
        self.log.info("task %d: adopted coalition %s of round %s from its reports", m.task, list(robots),
                      round_name(m.round))
        return []

    def on_done(self, m, now: float) -> None:
        """Another auctioneer completed a task (roles changed hands).  Only a task this robot knows open is
        recorded finished: a ``CoalitionDone`` naming any other (one not handed in yet) must not keep it from ever
        being offered.  Nor is a coalition this robot runs as the auctioneer ended by another's word: its members
        report to it, and a task really done elsewhere leaves the table as done."""
        if m.sender == self.robot_id:
            return                           # my own, routed back to me: _complete recorded it
        if m.task not in self.view.tasks or self.active or m.sender != self.view.auctioneer():
            # nor is it taken from a robot that is not the auctioneer as far as I know, or while I am: a
            # CoalitionDone forged in an unsigned fleet would keep a task I offer from ever being offered again
            self.stats.ignored += 1
            return
        c = self.coalitions.get(m.task)
        if c is not None and c.round == m.round:
            del self.coalitions[m.task]
        self.finished.setdefault(m.task, (m.round, tuple(m.robots)))

    # ------------------------------------------------------------------ fleet changes
    def on_peer_lost(self, rid: int, now: float) -> list:
        out = []
        for c in list(self.coalitions.values()):
            if rid in c.robots:
                out += self._release(c, f"robot {rid} lost")
        return out

    def withdraw(self, task_ids) -> None:
        for t in task_ids:
            self.coalitions.pop(t, None)
