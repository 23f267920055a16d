"""Alg. 1 on one robot: its actions answer announcements and queries, pre-allocate, connect their inputs,
bid, and allocate what they are awarded.  Sans-IO: every input carries ``now``; the output is messages.

* **Announcement.**  Each action of this robot that can accomplish the task applies its constraint functions
  to this robot's resources (:class:`~runtime.allocation.comutar.resources.Ledger`); if they fit it
  pre-allocates them as a *slot* (expiring ``award_grace`` after the auction closes).  An action with
  inputs sends one ``CmQuery`` per input and waits ``budget`` seconds (``query_wait`` per level still below it)
  before composing; one without bids at once.
* **Query.**  Each action producing the information asked checks and pre-allocates in turn (a reader for
  another robot's region must have it within its sensor's range and constrains this robot's c-space to keep
  it in view, Alg. 3; a stream to another robot costs bandwidth on this robot's link), queries its own inputs
  with a shorter budget, and answers ``CmCost`` with each sub-coalition it can form.  So the query recurses down the chain (laser reader -> obstacle detector
  -> obstacle avoider).
* **Composing.**  The ``max_options`` cheapest answers per input are combined; a combination whose remote
  inputs do not fit this robot's link is dropped; the slot's hold grows to the largest combination kept.
  Each combination goes up as a ``CmCost`` (or, for the task's own action, a ``CmBid`` to the auctioneer).
* **Award.**  Slots named allocate (an expired one is admitted afresh if it still fits) and the robot
  acknowledges; its other slots of the auction are released.  If a slot no longer fits, the robot releases
  everything of the award and resigns.  A held task is reported (``CmHold``) to its auctioneer every
  ``report_period``.  When the auctioneer of my award announces the task in a later auction, it has let that
  award go (its cancel was lost): I drop it and bid; another auctioneer's announcement gets a ``CmHold``.

Every pre-allocation expires: slots not awarded vanish at their expiry (the record is kept a while so a late
award can still be taken up, afresh).  An action's processor share is held once for its running instance,
however many consumers (slots) it serves; streams and c-space constraints are held per slot.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

from runtime.allocation.comutar import actions as A
from runtime.allocation.comutar.messages import (CmAck, CmBid, CmCost, CmHold, CmQuery, CmResign, slot_robot)

KEEP_EXPIRED = 30.0          # s an expired slot's record is kept for a late award


@dataclass
class Answer:
    robot: int
    slots: tuple[int, ...]
    cost: float
    rate: float


@dataclass
class Slot:
    ref: int
    auction: int
    task: int
    spec: A.ActionSpec
    auctioneer: int
    requester: int | None                  # robot whose query it answers; None: the task's own action
    query: int | None                      # the query it answers
    info: str | None                       # what it provides the requester
    region: tuple[int, float, float]       # (robot, x, y): whose surroundings the chain serves
    depth: int
    expires: float
    compose_at: float | None = None
    queries: dict = field(default_factory=dict)       # my query id -> input info
    answers: dict = field(default_factory=dict)       # input info -> [Answer]
    combos: list = field(default_factory=list)        # (slots, cost, {info: Answer})
    held: bool = False
    expired: bool = False
    chosen: dict = field(default_factory=dict)        # input info -> Answer (after the award)

    @property
    def provides_remote(self) -> bool:
        return self.requester is not None and self.requester != slot_robot(self.ref)


@dataclass
class Holding:
    """A task this robot holds: the award it holds it under and its own slots in it."""
    task: int
    auction: int
    award: tuple[int, ...]
    mine: tuple[int, ...]
    since: float
    next_report: float = -math.inf
    links: tuple | None = None             # ({input: provider}, {output: consumer}), once known


@dataclass
class BidderStats:
    announcements: int = 0
    bids: int = 0
    answers: int = 0
    refused: int = 0            # admission tests that failed (an action that could not run as expected)
    awards: int = 0
    declined: int = 0           # awards resigned at once: a slot no longer fitted or was gone
    ignored: int = 0            # announcements of unknown tasks, costs for no query of mine, stale awards


class Bidder:
    def __init__(self, agent):
        self.a = agent
        self.me = agent.robot_id
        self.o = agent.options
        self.slots: dict[int, Slot] = {}
        self.holdings: dict[int, Holding] = {}          # task -> holding
        self.done: dict[int, int] = {}                  # task -> the auction its auctioneer said completed it
        self._n = itertools.count(1)
        self._q = itertools.count(1)
        self.stats = BidderStats()

    # ------------------------------------------------------------------ slots
    def _ref(self) -> int:
        n = next(self._n) % 0xFFFF or next(self._n) % 0xFFFF
        return self.me << 16 | n

    def _demands(self, slot: Slot, link_in: float = 0.0) -> dict:
        """What one slot holds: its streams on this robot's link and its c-space constraint.  The processor
        belongs to the action's running instance (:meth:`_instance`), shared by all its consumers."""
        me = self.me
        d = {}
        link = link_in + (slot.spec.rate(slot.info) if slot.provides_remote else 0.0)
        if link:
            d[(me, "link")] = link
        if slot.spec.motion is not None:
            d[(me, "cspace")] = lambda now, s=slot: self.a.cspace_mask(s, now)
        return d

    def _instance(self, spec: A.ActionSpec) -> tuple:
        """The ledger holder of an action's running instance: one reader or detector serves every consumer,
        so its processor share is held once however many slots (consumers) it has."""
        return ("run", spec.name)

    def _rivals(self, auction: int) -> set:
        """Holders the slots of ``auction`` need not fit beside: the other candidates of that auction on this
        robot (they cannot all win; digest §7's per-coalition check), and action instances only they keep."""
        pre = {r for r, s in self.slots.items() if s.auction == auction and not s.held and not s.expired}
        out = set(pre)
        for spec in {self.slots[r].spec.name: self.slots[r].spec for r in pre}.values():
            alive = [r for r, s in self.slots.items() if s.spec.name == spec.name and (s.held or not s.expired)]
            if set(alive) <= pre:
                out.add(self._instance(spec))
        return out

    def _admit(self, slots: list, now: float, link_in: float = 0.0) -> str | None:
        """Why ``slots`` (one coalition's slots on this robot, of one auction; the first receiving ``link_in``
        Mb/s from other robots) cannot run together beside every allocation and every other auction's
        pre-allocation, or None."""
        led = self.a.ledger
        rivals = self._rivals(slots[0].auction)
        demands = [self._demands(s, link_in if i == 0 else 0.0) for i, s in enumerate(slots)]
        for spec in {s.spec.name: s.spec for s in slots}.values():
            inst = self._instance(spec)
            if inst not in led.holds or inst in rivals:
                demands.append({(self.me, "processor"): spec.processor})
        joined = led.join(demands, now)
        why = led.check(joined, now, exclude=rivals | {s.ref for s in slots})
        if why is not None:
            self.stats.refused += 1
        return why

    def _open(self, slot: Slot, now: float) -> bool:
        why = self._admit([slot], now)
        if why is not None:
            self.a.log.debug("%s cannot run (auction %s): %s", slot.spec.name, _auction_name(slot.auction), why)
            return False
        led, inst = self.a.ledger, self._instance(slot.spec)
        led.holds.pop(slot.ref, None)
        self._hold(slot, self._demands(slot), now)
        if inst not in led.holds:
            led.preallocate(inst, {(self.me, "processor"): slot.spec.processor}, now, slot.expires,
                            exclude=self._rivals(slot.auction))
        self.slots[slot.ref] = slot
        self._sync(slot.spec)
        return True

    def _hold(self, slot: Slot, demands: dict, now: float) -> None:
        """Hold what :meth:`_admit` admitted (the check is done: rivals of the auction are not counted)."""
        self.a.ledger.preallocate(slot.ref, demands, now, slot.expires, (slot.auction, slot.task),
                                  exclude=self._rivals(slot.auction))

    def _sync(self, spec: A.ActionSpec) -> None:
        """Keep the instance's hold matching its slots: allocated while one is held, pre-allocated until the
        last pre-allocated one expires, released when none is left."""
        led, inst = self.a.ledger, self._instance(spec)
        alive = [s for s in self.slots.values() if s.spec.name == spec.name and (s.held or not s.expired)]
        hold = led.holds.get(inst)
        if not alive:
            led.release(inst)
        elif hold is not None:
            hold.expires = None if any(s.held for s in alive) else max(s.expires for s in alive)

    def _run(self, spec: A.ActionSpec, now: float) -> str | None:
        """Allocate the action's instance (admitted afresh if its pre-allocation lapsed)."""
        led, inst = self.a.ledger, self._instance(spec)
        if inst in led.holds:
            led.holds[inst].expires = None
            return None
        return led.allocate(inst, now, {(self.me, "processor"): spec.processor})

    def release(self, refs) -> None:
        specs = {}
        for ref in refs:
            self.a.ledger.release(ref)
            slot = self.slots.pop(ref, None)
            if slot is not None:
                specs[slot.spec.name] = slot.spec
        for spec in specs.values():
            self._sync(spec)

    def release_auction(self, auction: int, keep=()) -> None:
        self.release([r for r, s in self.slots.items() if s.auction == auction and r not in keep and not s.held])

    # ------------------------------------------------------------------ announcements and queries
    def on_announce(self, m, now: float) -> list:
        self.stats.announcements += 1
        task = self.a.tasks.get(m.task)
        done = self.done.get(m.task)
        if task is None or (done is not None and done >> 16 == m.auction >> 16 and not _later(m.auction, done)):
            self.stats.ignored += 1
            return []
        held = self.holdings.get(m.task)
        if held is not None and held.auction >> 16 == m.sender and _later(m.auction, held.auction):
            # the auctioneer of my award announces the task anew: it has let that award go (its cancel was lost)
            self.a.log.info("task %d: announced again as auction %s: my award %s is over", m.task,
                            _auction_name(m.auction), _auction_name(held.auction))
            self.drop(m.task)
            held = None
        if held is not None:                  # announced by another auctioneer (adopting it): say I hold it
            return [CmHold(self.me, m.sender, held.auction, m.task, held.mine)]
        if not self.a.can_bid:
            return []
        out = []
        for spec in self.a.catalogue.accomplishing(task.kind):
            if not self.a.serves(spec, task):
                continue
            x, y = self.a.position
            slot = Slot(self._ref(), m.auction, m.task, spec, m.sender, None, None, None, (self.me, x, y), 1,
                        now + m.timeout + self.o.award_grace)
            if not self._open(slot, now):
                continue
            budget = min((self.o.max_depth - 1) * self.o.query_wait, m.timeout - self.o.query_wait / 2)
            out += self._connect(slot, now, budget)
        return out

    def on_query(self, m, now: float) -> list:
        info = A.INFO_NAMES.get(m.info)
        if info is None or not self.a.available:
            return []
        out = []
        for spec in self.a.catalogue.producing(info):
            if m.depth + 1 > self.o.max_depth:
                continue
            if spec.inputs and m.budget - self.o.query_wait < self.o.query_wait / 2:
                continue                       # no time left to connect its own inputs
            if spec.sensor is not None and m.owner != self.me and not self.a.in_range(spec, m.x, m.y):
                continue                       # the region is out of its sensor's range: it cannot run as expected
            slot = Slot(self._ref(), m.auction, 0, spec, 0, m.sender, m.query, info, (m.owner, m.x, m.y),
                        m.depth + 1, now + m.expires)
            if not self._open(slot, now):
                continue
            out += self._connect(slot, now, m.budget - self.o.query_wait)
        return out

    def _connect(self, slot: Slot, now: float, budget: float) -> list:
        """Query every input of ``slot`` (answers composed after ``budget`` s), or answer/bid at once."""
        if not slot.spec.inputs:
            return self._compose(slot, now)
        owner, x, y = slot.region
        out = []
        for info in slot.spec.inputs:
            qid = self.me << 16 | (next(self._q) % 0xFFFF or 1)
            slot.queries[qid] = info
            slot.answers[info] = []
            out.append(CmQuery(self.me, 0, slot.auction, qid, A.INFO[info], slot.depth, max(0.0, budget),
                               max(0.0, slot.expires - now), owner, x, y))
        slot.compose_at = now + max(0.0, budget)
        return out

    def on_cost(self, m, now: float) -> list:
        for slot in self.slots.values():
            info = slot.queries.get(m.query)
            if info is not None and slot.compose_at is not None and slot.auction == m.auction:
                slot.answers[info].append(Answer(m.sender, tuple(m.slots), float(m.cost), float(m.rate)))
                self.stats.answers += 1
                return []
        self.stats.ignored += 1                # late (composed already) or not mine
        return []

    # ------------------------------------------------------------------ composing
    def tick(self, now: float) -> list:
        lapsed = {}
        for ref in self.a.ledger.expire(now):
            slot = self.slots.get(ref)
            if slot is not None:
                slot.expired = True
                lapsed[slot.spec.name] = slot.spec
        for spec in lapsed.values():
            self._sync(spec)
        for ref, slot in list(self.slots.items()):
            if slot.expired and now > slot.expires + KEEP_EXPIRED:
                del self.slots[ref]
        out = []
        for slot in [s for s in self.slots.values() if s.compose_at is not None and now >= s.compose_at]:
            slot.compose_at = None
            if not slot.expired:
                out += self._compose(slot, now)
        return out + self._reports(now)

    def _link_in(self, chosen) -> float:
        return sum(a.rate for a in chosen.values() if a.robot != self.me)

    def _compose(self, slot: Slot, now: float) -> list:
        inputs = slot.spec.inputs
        def price(a: Answer) -> tuple:
            return a.cost + self.a.link_cost(a.rate, a.robot), a.robot != self.me, a.robot

        options = [sorted(slot.answers.get(i, []), key=price)[:self.o.max_options] for i in inputs]
        combos = []
        for pick in itertools.product(*options):
            chosen = dict(zip(inputs, pick))
            refs = (slot.ref,) + tuple(r for a in pick for r in a.slots)
            if len(set(refs)) != len(refs):
                continue
            link_in = self._link_in(chosen)
            local = [slot] + [self.slots[r] for r in refs[1:] if slot_robot(r) == self.me and r in self.slots]
            if (link_in or len(local) > 1) and self._admit(local, now, link_in) is not None:
                continue
            cost = self.a.own_cost(slot) + sum(a.cost + self.a.link_cost(a.rate, a.robot) for a in pick)
            combos.append((refs, cost, chosen))
        if not combos:
            self.release([slot.ref])
            return []
        widest = max(self._link_in(c[2]) for c in combos)
        if widest:
            self._hold(slot, self._demands(slot, widest), now)
        slot.combos = sorted(combos, key=lambda c: c[1])[:self.o.max_options]
        if slot.requester is None:
            self.stats.bids += len(slot.combos)
            return [CmBid(self.me, slot.auctioneer, slot.auction, slot.task, c[1], c[0][:48]) for c in slot.combos
                    if len(c[0]) <= 48]
        rate = slot.spec.rate(slot.info) if slot.provides_remote else 0.0
        return [CmCost(self.me, slot.requester, slot.auction, slot.query, c[1], rate, c[0]) for c in slot.combos
                if len(c[0]) <= 48]

    # ------------------------------------------------------------------ awards
    def on_award(self, m, now: float) -> list:
        mine = tuple(r for r in m.slots if slot_robot(r) == self.me)
        held = self.holdings.get(m.task)
        if held is not None and held.auction == m.auction:
            return [CmAck(self.me, m.sender, m.auction, m.task)] if mine else []      # a re-send: ack again
        if not mine:
            self.release_auction(m.auction)
            return []
        self.stats.awards += 1
        if held is not None:                   # a newer award of a task I still hold: the old one is over
            self.drop(m.task)
        self.release_auction(m.auction, keep=mine)         # the losers first: the winners must fit beside the rest
        why = self._allocate(mine, m, now)
        if why is not None:
            self.stats.declined += 1
            self.a.log.info("resigning task %d: %s", m.task, why)
            self.release(mine)
            self.release_auction(m.auction)
            return [CmResign(self.me, m.sender, m.auction, m.task)]
        self.holdings[m.task] = Holding(m.task, m.auction, tuple(m.slots), mine, now)
        self.a.log.info("holding task %d (auction %s) with %s", m.task, _auction_name(m.auction),
                        "+".join(self.slots[r].spec.name for r in mine))
        return [CmAck(self.me, m.sender, m.auction, m.task)]

    def _allocate(self, mine, m, now: float) -> str | None:
        award = set(m.slots)
        done = []
        for ref in mine:
            slot = self.slots.get(ref)
            if slot is None:
                why = "a slot of the award is gone"
            elif not self.a.available:
                why = "disarmed"
            else:
                chosen = {}
                for info in slot.spec.inputs:
                    pick = [a for a in slot.answers.get(info, []) if a.slots[0] in award]
                    if pick:
                        chosen[info] = pick[0]
                if len(chosen) != len(slot.spec.inputs):
                    why = f"{slot.spec.name}: the award connects no provider to an input"
                else:
                    why = self._run(slot.spec, now) or self.a.ledger.allocate(
                        ref, now, self._demands(slot, self._link_in(chosen)), (slot.auction, m.task))
                    if why is None:
                        slot.held, slot.expired, slot.chosen, slot.task = True, False, chosen, m.task
                        done.append(ref)
            if why is not None:
                for r in done:
                    self.slots[r].held = False
                for r in mine:
                    if r in self.slots:
                        self._sync(self.slots[r].spec)
                return why
        return None

    def drop(self, task_id: int) -> Holding | None:
        """Stop holding ``task_id`` (cancelled, done, withdrawn, resigned): release its slots."""
        h = self.holdings.pop(task_id, None)
        if h is not None:
            self.release(h.mine)
        return h

    def resign(self, task_id: int, why: str) -> list:
        h = self.drop(task_id)
        if h is None:
            return []
        self.a.log.warning("resigning task %d: %s", task_id, why)
        return [CmResign(self.me, self.a.auctioneer_of(task_id), h.auction, task_id)]

    def on_cancel(self, m, now: float) -> None:
        if m.auction >> 16 != m.sender:                 # only an auction's auctioneer takes its award back
            self.stats.ignored += 1
            return
        h = self.holdings.get(m.task)
        if h is not None and h.auction == m.auction:
            self.a.log.info("task %d: award %s cancelled by robot %d", m.task, _auction_name(m.auction), m.sender)
            self.drop(m.task)
        self.release_auction(m.auction)

    def on_done(self, m, now: float) -> None:
        """The task's auctioneer says it is complete: release it, and take no announcement of it up to that auction
        (a later one, which only an auctioneer that still has the task makes, is taken: so a CmDone forged in an
        unsigned fleet keeps the task from nobody for good).  From any other robot: ignored."""
        if m.sender != self.a.auctioneer_of(m.task) or m.auction >> 16 != m.sender:
            self.stats.ignored += 1
            return
        if m.task not in self.done or _later(m.auction, self.done[m.task]):
            self.done[m.task] = m.auction
        h = self.holdings.get(m.task)
        if h is None or not _later(h.auction, m.auction):
            self.drop(m.task)

    def _reports(self, now: float) -> list:
        out = []
        for h in self.holdings.values():
            if now >= h.next_report:
                h.next_report = now + self.o.report_period
                out.append(CmHold(self.me, self.a.auctioneer_of(h.task), h.auction, h.task, h.mine))
        return out

    # ------------------------------------------------------------------ what the holdings say
    def links(self, task_id: int) -> tuple[dict, dict]:
        """The connections of my slots in ``task_id``: ({input info: provider robot}, {output info: consumer})."""
        h = self.holdings.get(task_id)
        if h is None:
            return {}, {}
        if h.links is not None:
            return h.links
        ins, outs = {}, {}
        for ref in h.mine:
            slot = self.slots.get(ref)
            if slot is None:
                continue
            for info, ans in slot.chosen.items():
                ins[info] = ans.robot
            if slot.requester is not None:
                outs[slot.info] = slot.requester
        h.links = (ins, outs)                  # the award fixed them
        return ins, outs

    def held_slots(self, task_id: int) -> list[Slot]:
        h = self.holdings.get(task_id)
        return [] if h is None else [self.slots[r] for r in h.mine if r in self.slots]

    @property
    def pending(self) -> bool:
        """Slots still pre-allocated (an auction of theirs not settled)."""
        return any(not s.held and not s.expired for s in self.slots.values())


def _later(a: int, b: int) -> bool:
    """Is auction ``a`` later than ``b`` of the same auctioneer (16-bit serial numbers, which wrap)?"""
    return 0 < (a - b) & 0xFFFF < 0x8000


def _auction_name(auction: int) -> str:
    return f"{auction >> 16}.{auction & 0xFFFF}"
