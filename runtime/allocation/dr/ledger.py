"""Weight bookkeeping of virtual objects (docs/dr.md, "Weight").

Objects are marks on the floor: the weight at an object exists only in the robots' books.  The leader of a task
is the authority that grants loads; the books themselves are per robot and only grow, so they survive message
loss, duplication, reordering and a change of leader:

* :class:`Entry` - one robot's cumulative account for one task: ``loads`` granted and the wu ``taken`` with
  them, ``deliveries`` reported and the wu ``delivered``, and wu ``returned`` to the object (a robot that could
  not deliver its load, or one its leader heard nothing from for ``member_timeout``).  Two views of an entry
  merge by taking the one with more loads (then more taken), more deliveries (then more delivered) and the larger
  ``returned``: a resent or duplicated report changes nothing.
* :class:`Ledger` - a task's entries on one robot.  Every robot keeps one for every task: the leader's grants
  and acknowledgements (``DrLedger``) go to every peer and the leader re-sends its entries round-robin, so a robot
  that takes over the task has the books.  The weight left at the object is ``W - sum(taken - returned)``, the
  weight on its way ``sum(taken - delivered - returned)``; the task is done when both are 0.
* :class:`Outbox` - one robot's reports for one task, strictly in order: ``DrLoad`` after each load (resent until
  the leader grants it: the grant is ``min(wu, left)``, 0 when the object is exhausted), ``DrDeliver`` after
  each unload or when it puts its load back.  A load whose grant is not known yet is carried and delivered all
  the same; its delivery is reported once the grant is known.  Reports wait while the task has no leader and go
  to whoever leads it next.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field, replace

from runtime.allocation.dr.messages import DrDeliver, DrLedger, DrLoad

EPS = 1e-6              # wu: weights closer than this are equal (weights travel as float32)


@dataclass
class Entry:
    loads: int = 0
    taken: float = 0.0
    deliveries: int = 0
    delivered: float = 0.0
    returned: float = 0.0

    @property
    def on_the_way(self) -> float:
        """wu granted and neither delivered nor returned (negative: delivered twice, see Ledger.overdelivered)."""
        return self.taken - self.delivered - self.returned

    def merge(self, loads: int, taken: float, deliveries: int, delivered: float, returned: float) -> bool:
        """Take another view of this entry; True if anything grew."""
        before = self.key()
        if (loads, taken) > (self.loads, self.taken):
            self.loads, self.taken = int(loads), float(taken)
        if (deliveries, delivered) > (self.deliveries, self.delivered):
            self.deliveries, self.delivered = int(deliveries), float(delivered)
        self.returned = max(self.returned, float(returned))
        return self.key() != before

    def key(self) -> tuple:
        return self.loads, self.taken, self.deliveries, self.delivered, self.returned


@dataclass
class Ledger:
    weight: float | None = None                       # W, wu (None until the task is in this robot's table)
    entries: dict[int, Entry] = field(default_factory=dict)

    def entry(self, robot: int) -> Entry:
        return self.entries.setdefault(robot, Entry())

    def plausible(self, robot: int, taken: float, delivered: float, returned: float) -> bool:
        """A view of ``robot``'s entry that the object's weight allows: no more taken, delivered or returned than W,
        and no more taken (less returned) by the whole group than W.  Entries only grow, so one view beyond these
        (forged, in an unsigned fleet) would stay for good and make every genuine report after it look stale;
        such a view is refused instead.  True while W is unknown (the task is not in this robot's table yet)."""
        if self.weight is None:
            return True
        top = self.weight * (1 + 1e-5) + EPS           # the wire's float32 rounds each value by ~6e-8 of it
        if max(taken, delivered, returned) > top:
            return False
        others = sum(e.taken - e.returned for r, e in self.entries.items() if r != robot)
        mine = self.entries.get(robot, Entry())
        return others + max(taken, mine.taken) - max(returned, mine.returned) <= top

    def merge(self, robot: int, loads, taken, deliveries, delivered, returned) -> bool:
        if not self.plausible(robot, taken, delivered, returned):
            return False
        if not (loads or deliveries or returned) and robot not in self.entries:
            return False                              # an empty entry adds nothing
        return self.entry(robot).merge(loads, taken, deliveries, delivered, returned)

    @property
    def taken(self) -> float:
        return sum(e.taken for e in self.entries.values())

    @property
    def delivered(self) -> float:
        return sum(e.delivered for e in self.entries.values())

    @property
    def left(self) -> float:
        """wu at the object: W less what was taken and not returned."""
        if self.weight is None:
            return 0.0
        return max(0.0, self.weight - sum(e.taken - e.returned for e in self.entries.values()))

    @property
    def on_the_way(self) -> float:
        return sum(max(0.0, e.on_the_way) for e in self.entries.values())

    @property
    def overdelivered(self) -> float:
        """wu delivered beyond what was taken: loads returned for a robot that then delivered them after all."""
        return sum(max(0.0, -e.on_the_way) for e in self.entries.values())

    @property
    def done(self) -> bool:
        return self.weight is not None and self.left <= EPS and self.on_the_way <= EPS

    def carriers(self) -> list[int]:
        return sorted(r for r, e in self.entries.items() if e.on_the_way > EPS)

    # ------------------------------------------------------------------ the leader's decisions
    def grant(self, robot: int, seq: int, wu: float) -> Entry:
        """The robot's ``seq``-th load of ``wu``: grant ``min(wu, left)`` once (a resent load is granted again
        as before).  Returns its entry."""
        e = self.entry(robot)
        if seq == e.loads + 1:
            e.loads, e.taken = seq, e.taken + min(max(0.0, wu), self.left)
        return e

    def give_back(self, robot: int) -> bool:
        """The robot's load on its way goes back to the object (it cannot deliver, or has gone silent)."""
        e = self.entries.get(robot)
        if e is None or e.on_the_way <= EPS:
            return False
        e.returned = e.taken - e.delivered
        return True

    def message(self, sender: int, task: int, robot: int, dest: int = 0) -> DrLedger:
        e = self.entry(robot)
        return DrLedger(sender, dest, task, robot, e.loads, e.taken, e.deliveries, e.delivered, e.returned,
                        self.left)


LOAD, DELIVER, RETURN = "load", "deliver", "return"


@dataclass
class Outbox:
    """This robot's reports on one task (see the module docstring)."""
    robot: int
    task: int
    mine: Entry = field(default_factory=Entry)        # my entry as far as granted and acknowledged
    queue: deque = field(default_factory=deque)       # (LOAD, wu) | (DELIVER,) | (RETURN,)
    loaded: bool = False                              # carrying a load (LOADED seen, not yet unloaded)
    carried: float | None = None                      # the grant of the last load acknowledged
    head: object = None                               # the report being sent, resent until acknowledged
    sent: float = float("-inf")

    # ------------------------------------------------------------------ execution
    def loaded_now(self, wu: float) -> None:
        self.queue.append((LOAD, float(wu)))
        self.loaded = True

    def unloaded_now(self) -> None:
        if self.loaded:
            self.queue.append((DELIVER,))
            self.loaded = False

    def put_back(self) -> None:
        """Could not deliver (disarmed, failed): the load on board goes back to the object."""
        if self.loaded:
            self.queue.append((RETURN,))
            self.loaded = False

    @property
    def idle(self) -> bool:
        return not self.queue and self.head is None and not self.loaded

    # ------------------------------------------------------------------ reports
    def _prepare(self):
        """The next report to send, made from the head of the queue (None: nothing to report yet)."""
        while self.head is None and self.queue:
            item = self.queue[0]
            m = self.mine
            if item[0] == LOAD:
                self.head = DrLoad(self.robot, 0, self.task, m.loads + 1, item[1], m.taken, m.deliveries,
                                   m.delivered, m.returned)
                break
            self.queue.popleft()
            wu = self.carried or 0.0
            if wu <= EPS:
                continue                                  # nothing was granted: nothing to deliver
            m.deliveries += 1
            if item[0] == DELIVER:
                m.delivered += wu
            else:
                m.returned += wu
            self.head = DrDeliver(self.robot, 0, self.task, m.deliveries, wu if item[0] == DELIVER else 0.0,
                                  m.loads, m.taken, m.delivered, m.returned)
        return self.head

    def due(self, to: int | None, now: float, resend: float) -> list:
        """The report to send to ``to`` (the task's leader; None: nobody leads it now), at most every
        ``resend`` s."""
        head = self._prepare()
        if head is None or to is None or now - self.sent < resend:
            return []
        self.sent = now
        return [replace(head, dest=to)]

    def on_ledger(self, e: DrLedger) -> float | None:
        """The leader's entry for me: acknowledges the report in flight.  Returns the grant of a load it
        acknowledged, else None."""
        head, granted = self.head, None
        if isinstance(head, DrLoad) and e.loads >= head.seq:
            granted = min(head.wu, max(0.0, e.taken - self.mine.taken))
            self.queue.popleft()
            self.head, self.sent = None, float("-inf")
            self.mine.loads, self.mine.taken = head.seq, self.mine.taken + granted
            self.carried = granted
            if granted <= EPS and not any(item[0] == LOAD for item in self.queue):
                self.loaded = False                     # the load on board is nothing: drive on empty
        elif isinstance(head, DrDeliver) and e.deliveries >= head.seq:
            self.head, self.sent = None, float("-inf")
        self.mine.returned = max(self.mine.returned, e.returned)
        return granted
