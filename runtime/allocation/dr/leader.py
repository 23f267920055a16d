"""The leader of one task (paper 000 §5.2, Alg. 2; §5.5 on the leader's side; §5.6): it is a member of its own
group and works like the others, runs the task's auctions, keeps its group, holds the task's books and ends it.

* **Auction for a task** (Alg. 2).  ``DrBidRequest`` to every peer; bids for ``time_auction``; then, from the
  group (the leader, its members, robots awarded and not answered yet), the bidders are added by work capacity
  (highest first, ties: nearer, then lower id) until eq. 8 holds; each gets ``DrAward`` carrying U_j at the
  predicted finish.  If eq. 8 cannot hold, every bidder is awarded (``late: all``, the paper), or (``late:
  fastest``, ours) only while each one brings the predicted finish forward: with real interference a larger
  group can be slower, and the paper's rule then piles every free robot onto the first late object.  ``auction: greedy`` awards every bidder.
  A bidder joins when its ``DrRobotAlive`` arrives; the award is resent to the silent ones and dropped after
  ``award_wait`` (a later confirmation is still taken: the award stood); a ``DrRefuse`` drops it at once.
* **Eq. 8 mid-task** (§5.6): ``(t - t_appeared) + WL(t) / groupCapacity <= DL`` with groupCapacity = the
  members' work capacities (eq. 4) less I(n, d) (eq. 3; 0 for the NI strategies).  WL(t) comes from eq. 9:
  monitoring (M_*) from the weight left at the object at the last load event, not monitoring (NM_*) from the
  whole weight at the first election.
* **Re-auction** (digest §8): a member lost or leaving (a), the group failing eq. 8 once the awards settle (b),
  and every ``time_auction`` after (with M_* that is the check against each load's real remaining weight (c)):
  a new round whenever eq. 8 fails, there is weight at the object and some peer's state says it is idle.
* **Faults** (§5.5).  ``DrLeaderAlive`` every ``leader_alive_period``, at once to a robot that asks to lead the
  task; a leader hearing another leader of its task with a higher id yields (``DrExitLeader`` to its group).
  A member silent for ``member_timeout`` (no ``DrRobotAlive``, report or state naming the task) is dropped.
* **Books** (ledger.py).  Loads are granted ``min(wu, left)`` and every grant and acknowledgement goes to every
  peer as ``DrLedger``; two entries are re-sent each ``leader_alive_period``.  The load of a robot heard from by
  nobody for ``member_timeout`` goes back to the object.  Once nothing is left, members not carrying are
  released (``DrExitLeader`` reason exhausted).
* **End.**  When all the weight is delivered: a DONE event, a :class:`Finish` record, ``DrExitLeader`` (done)
  to the group and, with on-line learning, the SVR sample (mean group size, d, I = n_mean wc - W / duration,
  duration from the task's first election to the last delivery).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from runtime.allocation.agent import AWARDED, DONE, RELEASED, TaskEvent
from runtime.allocation.dr import model as M
from runtime.allocation.dr.ledger import EPS
from runtime.allocation.dr.messages import (EXHAUSTED, FINISHED, MAX_MEMBERS, NOT_MEMBER, DrAward,
                                            DrBidRequest, DrExitLeader, DrLeaderAlive)
from runtime.messages import BROADCAST

RESEND_ENTRIES = 2          # ledger entries re-sent with each LEADER_ALIVE


@dataclass
class Joiner:
    capacity: float             # wu/s (its bid)
    distance: float             # m to the object when it bid
    since: float                # awarded (pending) or joined (member)
    heard: float                # last sign of it
    round: int = 0
    resent: float = -math.inf


@dataclass
class Round:
    id: int
    opened: float
    bids: dict = field(default_factory=dict)        # robot -> DrBid


@dataclass(frozen=True)
class Finish:
    """One task completed by this robot as its leader (times on this robot's clock, s)."""
    task: int
    leader: int
    appeared: float
    started: float              # the task's first leader elected
    finished: float             # the last delivery
    weight: float               # wu
    delivered: float            # wu
    mean_group: float           # robots, over started..finished
    max_group: int              # under this leader
    deadline: float             # s after it appeared
    utility: float              # U_j(finished - appeared)

    @property
    def time(self) -> float:
        """fT: s from appearing to done."""
        return self.finished - self.appeared


@dataclass(frozen=True)
class LeaderView:
    """What a leader knows of its task, for tests and experiments."""
    task: int
    members: tuple[int, ...]            # the group, the leader among them
    pending: tuple[int, ...]            # awarded, not confirmed yet
    left: float
    delivered: float
    on_the_way: float
    predicted_finish: float             # s after it appeared (eq. 2 with eq. 9), inf: never
    meets_deadline: bool
    auctioning: bool


class Leader:
    def __init__(self, host, info, now: float):
        self.host = host                 # the agent: robot_id, o, world, log, events, capacity(), interference()
        self.o = host.o
        self.me = host.robot_id
        self.info = info
        self.task = info.id
        self.since = now
        alive = info.alive
        inherit = alive is not None and alive.sender != self.me
        self.started = info.alive_at - alive.started_age if inherit else now
        self.robot_seconds = alive.robot_seconds if inherit else 0.0
        self._integrated = now
        self.members: dict[int, Joiner] = {}
        self.pending: dict[int, Joiner] = {}
        self.awarded: dict[int, Joiner] = {}        # every award of this leadership (late confirmations)
        self.round: Round | None = None
        self.count = 0
        self.wait_until = -math.inf
        self.next_check = math.inf                  # the first round opens at once (start)
        self.next_alive = now
        self.measured = (now, info.ledger.left)     # (t_m, WL(t_m)) of eq. 9 for monitoring
        self.max_group = 1
        self.settled: tuple[int, ...] = ()
        self.released: set[int] = set()
        self.rr = 0
        self._disowned: dict[int, float] = {}      # carrier whose state names the task no more -> since when
        self.finished: Finish | None = None
        self.mine = host.capacity(info)
        self._last_value = 0.0

    # ------------------------------------------------------------------ the group and eq. 8
    def group(self) -> tuple[int, ...]:
        return tuple(sorted({self.me, *self.members}))

    def _capacities(self) -> list[float]:
        return [self.mine] + [j.capacity for j in self.members.values()] + [j.capacity for j in self.pending.values()]

    def predict(self, capacities: list[float], now: float) -> tuple[float, bool]:
        """(predicted fT in s after the task appeared, whether eq. 8 holds) for a group of these capacities."""
        info, n = self.info, len(capacities)
        spec = info.task.spec
        interference = self.host.interference(n, info.distance) if self.o.interference else 0.0
        gc = M.group_capacity(M.ideal_capacity(capacities), interference)
        if self.o.monitoring:
            wl = M.remaining_prediction(self.measured[1], gc, now, self.measured[0])
        else:
            wl = M.remaining_prediction(spec.weight, gc, now, self.started)
        finish = (now - info.appeared) + M.expected_time(wl, gc)
        return finish, finish <= spec.deadline

    def utility(self, finish: float) -> float:
        spec = self.info.task.spec
        return M.UTILITIES[self.o.utility](finish, spec.deadline, spec.u_max)

    def _wants_more(self, now: float) -> bool:
        if self.info.ledger.left <= EPS:
            return False
        return self.o.auction == "greedy" or not self.predict(self._capacities(), now)[1]

    @property
    def working(self) -> bool:
        """There is weight at the object for the leader to fetch (else it only keeps the books)."""
        return self.info.ledger.left > EPS

    # ------------------------------------------------------------------ rounds
    def start(self, now: float) -> list:
        self.host.log.info("leading task %d (%.1f wu at %.2f m, deadline %.0f s, %.1f s gone)", self.task,
                           self.info.ledger.left, self.info.distance, self.info.task.spec.deadline,
                           now - self.info.appeared)
        if not self.working:                       # only the books to finish: nobody to recruit
            self.next_check = now + self.o.time_auction
            return self._alive(now)
        return self._open(now) + self._alive(now)

    def _open(self, now: float) -> list:
        self.count = self.count % 0xFFFF + 1
        self.round = Round(self.me << 16 | self.count, now)
        return [DrBidRequest(self.me, BROADCAST, self.task, self.round.id)]

    def on_bid(self, m, now: float) -> bool:
        r = self.round
        if r is None or m.round != r.id or m.sender in self.members or m.sender in self.pending:
            return False
        r.bids[m.sender] = m
        return True

    def _close(self, now: float) -> list:
        r, self.round = self.round, None
        taken = self.host.world.lost | set(self.members) | set(self.pending)
        bids = sorted((b for b in r.bids.values() if b.sender not in taken),
                      key=lambda b: (-b.capacity, b.distance, b.sender))
        caps = self._capacities()
        chosen = []
        finish, meets = self.predict(caps, now)
        for b in bids:
            if meets and self.o.auction != "greedy":
                break
            after, meets_after = self.predict(caps + [b.capacity], now)
            if (self.o.late == "fastest" and self.o.auction != "greedy" and not meets_after
                    and after >= finish - 1e-9):
                break                    # one more robot would not bring the finish forward: interference ate it
            chosen.append(b)
            caps.append(b.capacity)
            finish, meets = after, meets_after
        value = self.utility(finish)
        self.host.log.info("task %d round %d.%d: %d bids, awarding %s (predicted fT %.1f s, U %.2f, eq. 8 %s)",
                           self.task, self.me, r.id & 0xFFFF, len(bids), [b.sender for b in chosen], finish, value,
                           "holds" if meets else "fails")
        out = []
        for b in chosen:
            j = Joiner(b.capacity, b.distance, now, now, r.id, now)
            self.pending[b.sender] = self.awarded[b.sender] = j
            out.append(DrAward(self.me, b.sender, self.task, r.id, value))
        self.wait_until = now + self.o.award_wait
        self._last_value = value
        if not chosen:
            self._settle(now)
        return out

    def _settle(self, now: float) -> None:
        """The awards of a round are answered or expired: say who the group is, plan the next check (b)."""
        self._announce()
        self.next_check = now + self.o.time_auction

    def _announce(self) -> None:
        """The group, to whoever listens (a ground station hears "task a.b awarded to R1+R3"), when it changed."""
        group = self.group()
        if group != self.settled:
            self.settled = group
            self.host.events.append(TaskEvent(self.task, AWARDED, group, f"group of {len(group)}"))

    # ------------------------------------------------------------------ each tick
    def tick(self, now: float) -> list:
        self._integrate(now)
        out = []
        if self.round is not None and now - self.round.opened >= self.o.time_auction:
            out += self._close(now)
        out += self._awards(now)
        out += self._upkeep(now)
        if self.round is None and not self.pending and now >= self.next_check:
            self.next_check = now + self.o.time_auction
            if self._wants_more(now) and self.host.world.free_peers(now):
                out += self._open(now)
        if now >= self.next_alive:
            out += self._alive(now)
        if self.info.ledger.done and now - self.since >= 3 * self.o.leader_alive_period:
            out += self.finish(now)     # a leader of a few periods may be a second one: the first says DONE (its
        return out                      # EXIT_LEADER(task done) ends this one), or this one after the bound

    def _integrate(self, now: float) -> None:
        n = 1 + len(self.members)
        self.robot_seconds += n * max(0.0, now - self._integrated)
        self._integrated = now
        self.max_group = max(self.max_group, n)

    def _awards(self, now: float) -> list:
        if not self.pending:
            return []
        out = []
        if now >= self.wait_until:
            silent = sorted(self.pending)
            self.pending.clear()
            if silent:
                self.host.log.info("task %d: no ROBOT_ALIVE from %s within %.1f s", self.task, silent,
                                   self.o.award_wait)
            self._settle(now)
            return out
        for r, j in self.pending.items():
            if now - j.since >= self.o.time_bid_accepted and now - j.resent >= self.o.award_wait / 3:
                j.resent = now
                out.append(DrAward(self.me, r, self.task, j.round, self._last_value))
        return out

    def _upkeep(self, now: float) -> list:
        out = []
        world, ledger = self.host.world, self.info.ledger
        for r in [r for r, j in self.members.items() if now - j.heard > self.o.member_timeout]:
            self.drop(r, now, f"silent for {self.o.member_timeout:g} s")
        carriers = ledger.carriers()
        for r in list(self._disowned):
            if r not in carriers:
                del self._disowned[r]
        for r in carriers:
            if world.silent(r, now, self.o.member_timeout) and ledger.give_back(r):
                self.host.log.warning("task %d: robot %d silent for %.1f s: its load goes back to the object",
                                      self.task, r, self.o.member_timeout)
                out.append(ledger.message(self.me, self.task, r))
                self.next_check = now
            elif self._unclaimed(r, now) and ledger.give_back(r):
                # its state has not named the task for member_timeout: a load it never took (a DrLoad forged in
                # its name, in an unsigned fleet) or one it no longer carries goes back, as a silent robot's does
                self.host.log.warning("task %d: robot %d has not held it for %.1f s: its load goes back to the "
                                      "object", self.task, r, self.o.member_timeout)
                out.append(ledger.message(self.me, self.task, r))
                self.next_check = now
        if not self.working:
            for r in [r for r in self.members if ledger.entry(r).on_the_way <= EPS]:
                out.append(self._release(r, EXHAUSTED))
        return out

    def drop(self, r: int, now: float, why: str) -> None:
        self.members.pop(r, None)
        self.awarded.pop(r, None)
        self.host.log.warning("task %d: member %d dropped (%s)", self.task, r, why)
        self._announce()                           # else the group heard last keeps naming it until a round settles
        self.next_check = now                      # (a): re-check eq. 8 at once

    def _release(self, r: int, reason: int) -> DrExitLeader:
        self.members.pop(r, None)
        self.awarded.pop(r, None)
        self.released.add(r)
        return DrExitLeader(self.me, r, self.task, reason)

    def _alive(self, now: float) -> list:
        self.next_alive = now + self.o.leader_alive_period
        ledger, info = self.info.ledger, self.info
        group = self.group()[:MAX_MEMBERS]
        if self.me not in group:
            group = (self.me,) + group[:MAX_MEMBERS - 1]
        out = [DrLeaderAlive(self.me, BROADCAST, self.task, ledger.left, ledger.taken, ledger.delivered,
                             now - self.started, now - info.appeared, self.robot_seconds, group)]
        robots = sorted(ledger.entries)
        for k in range(min(RESEND_ENTRIES, len(robots))):
            out.append(ledger.message(self.me, self.task, robots[(self.rr + k) % len(robots)]))
        self.rr += RESEND_ENTRIES
        return out

    # ------------------------------------------------------------------ messages from robots
    def _unclaimed(self, r: int, now: float) -> bool:
        """Robot ``r`` (a carrier in the books) has stated, for ``member_timeout``, that it holds no share of this
        task: its last states named other tasks or none."""
        p = self.host.world.peers.get(r)
        if r == self.me or p is None or p.state is None or self.task in p.tasks:
            self._disowned.pop(r, None)
            return False
        return now - self._disowned.setdefault(r, now) > self.o.member_timeout

    def heard_from(self, r: int, now: float) -> None:
        """A sign that ``r`` still works on this task (a report, or its state naming the task)."""
        j = self.members.get(r)
        if j is not None:
            j.heard = now

    def on_robot_alive(self, m, now: float) -> list:
        r = m.sender
        out = self._merge(r, m.loads, m.taken, m.deliveries, m.delivered, m.returned)
        if r in self.members:
            self.members[r].heard = now
        elif r in self.awarded:
            j = self.pending.pop(r, None) or self.awarded[r]
            j.since = j.heard = now
            self.members[r] = j
            if not self.pending:
                self._settle(now)
        else:
            out.append(DrExitLeader(self.me, r, self.task, NOT_MEMBER))
        return out

    def on_refuse(self, m, now: float) -> None:
        r = m.sender
        if m.round == 0 and r in self.members:
            self.drop(r, now, "it left")
        elif r in self.pending and m.round == self.pending[r].round:
            del self.pending[r]
            self.awarded.pop(r, None)
            if not self.pending:
                self._settle(now)

    def _merge(self, r: int, *entry) -> list:
        """A robot's own view of its entry: the leader adopts what it did not know (after a change of leader)."""
        ledger = self.info.ledger
        return [ledger.message(self.me, self.task, r)] if ledger.merge(r, *entry) else []

    def on_load(self, m, now: float) -> list:
        ledger = self.info.ledger
        if not ledger.plausible(m.sender, m.taken, m.delivered, m.returned):
            self.host.dropped["entry beyond the object's weight"] += 1
            return []
        ledger.merge(m.sender, m.seq - 1, m.taken, m.deliveries, m.delivered, m.returned)
        before = ledger.entry(m.sender).loads
        ledger.grant(m.sender, m.seq, m.wu)
        self.heard_from(m.sender, now)
        if ledger.entry(m.sender).loads != before:         # a new load: a progress measurement (eq. 9, M_*)
            self.measured = (now, ledger.left)
            if self.o.monitoring:
                self.next_check = min(self.next_check, now)
        return [ledger.message(self.me, self.task, m.sender)]

    def on_deliver(self, m, now: float) -> list:
        ledger = self.info.ledger
        if not ledger.plausible(m.sender, m.taken, m.delivered, m.returned):
            self.host.dropped["entry beyond the object's weight"] += 1
            return []
        ledger.merge(m.sender, m.loads, m.taken, m.seq, m.delivered, m.returned)
        self.heard_from(m.sender, now)
        return [ledger.message(self.me, self.task, m.sender)]

    # ------------------------------------------------------------------ the end
    def resign(self, reason: int, now: float, why: str) -> list:
        """Stop leading (yield to a leader of higher id, disarmed): the group is told to leave."""
        self.host.log.info("task %d: no longer leading (%s)", self.task, why)
        self.host.events.append(TaskEvent(self.task, RELEASED, self.group(), why))
        return [DrExitLeader(self.me, BROADCAST, self.task, reason)]

    def finish(self, now: float) -> list:
        self._integrate(now)
        info, ledger = self.info, self.info.ledger
        spec = info.task.spec
        duration = max(now - self.started, 1e-9)
        mean = self.robot_seconds / duration
        self.finished = Finish(self.task, self.me, info.appeared, self.started, now, spec.weight, ledger.delivered,
                               mean, self.max_group, spec.deadline, self.utility(now - info.appeared))
        done_by = tuple(sorted(r for r, e in ledger.entries.items() if e.delivered > EPS)) or (self.me,)
        self.host.events.append(TaskEvent(self.task, DONE, done_by,
                                          f"{ledger.delivered:g} wu in {now - info.appeared:.1f} s"))
        self.host.log.info("task %d done: %.1f wu in %.1f s (deadline %.0f s), mean group %.2f%s", self.task,
                           ledger.delivered, now - info.appeared, spec.deadline, mean,
                           "" if ledger.overdelivered <= EPS else f" ({ledger.overdelivered:g} wu delivered twice)")
        interference = mean * self.mine - ledger.delivered / duration
        return ([DrExitLeader(self.me, BROADCAST, self.task, FINISHED)]
                + self.host.learning.originate(mean, info.distance, interference, now))

    def view(self, now: float) -> LeaderView:
        ledger = self.info.ledger
        finish, meets = self.predict(self._capacities(), now)
        return LeaderView(self.task, self.group(), tuple(sorted(self.pending)), ledger.left, ledger.delivered,
                          ledger.on_the_way, finish, meets, self.round is not None)
