"""Messages of the Double Round auction (paper 000 §5; docs/dr.md).  Frozen dataclasses, ``sender`` and
``dest`` first (dest 0 = every peer); on MAVLink each is ``MRTA_DR_<NAME>`` of ``dr.xml`` (ids 44150-44162).
Tasks are named by fleet task id (every robot's table holds the same ids), not by position as in the paper.

Each class checks its own values once (``invalid()``: the codec calls it when a frame is decoded, the agent
for messages that did not come through the codec), so a handler may trust what passes.

Times between robots travel as ages (s before the sender's ``now``), never as clock readings, so robots
whose clocks differ still agree on when a task appeared or its first leader was elected.

Weight bookkeeping travels as each robot's cumulative *entry* for a task: ``loads`` (loads granted),
``taken`` (wu granted), ``deliveries`` (unloads reported), ``delivered`` (wu), ``returned`` (wu put back at
the object, by a robot that could not deliver or by a leader for a robot gone silent).  Entries only grow,
so a resent or duplicated report changes nothing and the replicas merge in any order (see ledger.py).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from runtime.fleet.messages import task_origin

MAX_MEMBERS = 32                  # robots a LEADER_ALIVE can list
MAX_COUNT = 0xFFFFFFFF            # a uint32 on the wire
YIELD, NOT_MEMBER, EXHAUSTED, FINISHED = range(4)       # DrExitLeader.reason
REASONS = {YIELD: "yield", NOT_MEMBER: "not a member", EXHAUSTED: "object exhausted", FINISHED: "task done"}


def _int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _common(msg) -> str | None:
    """Sender, destination and (where the message has one) task: robot ids and a fleet task id."""
    if not (_int(msg.sender) and 1 <= msg.sender <= 250 and _int(msg.dest) and 0 <= msg.dest <= 250):
        return "sender/dest: expected robot ids"
    task = getattr(msg, "task", None)
    if task is not None and not (_int(task) and 0 <= task <= MAX_COUNT and 1 <= task_origin(task) <= 250):
        return f"task {task}: expected a fleet task id"
    return None


def _values(msg, counts=(), amounts=(), numbers=()) -> str | None:
    """``counts``: integers 0..2^32-1; ``amounts``: finite numbers >= 0; ``numbers``: finite numbers."""
    for name in counts:
        v = getattr(msg, name)
        if not (_int(v) and 0 <= v <= MAX_COUNT):
            return f"{name} {v!r}: expected an integer 0..{MAX_COUNT}"
    for name in amounts:
        v = getattr(msg, name)
        if not (_finite(v) and v >= 0):
            return f"{name} {v!r}: expected a finite number >= 0"
    for name in numbers:
        if not _finite(getattr(msg, name)):
            return f"{name} {getattr(msg, name)!r}: expected a finite number"
    return None


def _entry(msg) -> str | None:
    return _values(msg, counts=("loads", "deliveries"), amounts=("taken", "delivered", "returned"))


@dataclass(frozen=True)
class DrLeaderRequest:
    """Alg. 1: the sender asks to lead ``task``; ``capacity`` = its eq. 5 work capacity for it (wu/s)."""
    sender: int
    dest: int
    task: int
    capacity: float

    def invalid(self) -> str | None:
        return _common(self) or _values(self, amounts=("capacity",))


@dataclass(frozen=True)
class DrBidRequest:
    """Alg. 2 l.1: the leader of ``task`` opens auction ``round`` (leader id * 65536 + its count)."""
    sender: int
    dest: int
    task: int
    round: int

    def invalid(self) -> str | None:
        return _common(self) or _values(self, counts=("round",))


@dataclass(frozen=True)
class DrBid:
    """A free robot's bid in ``round``: its work capacity for the task (wu/s) and its distance to the object (m,
    the tie-break between equal capacities)."""
    sender: int
    dest: int
    task: int
    round: int
    capacity: float
    distance: float

    def invalid(self) -> str | None:
        return _common(self) or _values(self, counts=("round",), amounts=("capacity", "distance"))


@dataclass(frozen=True)
class DrAward:
    """Alg. 2 l.19: the leader bids ``value`` = U_j(predicted finish) for the robot ``dest``."""
    sender: int
    dest: int
    task: int
    round: int
    value: float

    def invalid(self) -> str | None:
        return _common(self) or _values(self, counts=("round",), amounts=("value",))


@dataclass(frozen=True)
class DrRobotAlive:
    """Alg. 3 l.10 and §5.5.3: the sender is a member of ``task``'s group (confirmation, then every
    ``member_alive_period``), with its bookkeeping entry for the task."""
    sender: int
    dest: int
    task: int
    loads: int
    taken: float
    deliveries: int
    delivered: float
    returned: float

    def invalid(self) -> str | None:
        return _common(self) or _entry(self)


@dataclass(frozen=True)
class DrRefuse:
    """Alg. 3 l.12: the sender refuses the award of ``round``; round 0: a member leaves the group."""
    sender: int
    dest: int
    task: int
    round: int

    def invalid(self) -> str | None:
        return _common(self) or _values(self, counts=("round",))


@dataclass(frozen=True)
class DrLeaderAlive:
    """§5.5.1: the sender leads ``task`` (every ``leader_alive_period``).  ``left`` wu at the object, ``taken``
    and ``delivered`` wu in all; ``members`` the group (the leader among them); ``started_age`` s since the task's
    first leader was elected, ``appeared_age`` s since the task appeared, ``robot_seconds`` the integral of the
    group size over that time: a new leader carries these on."""
    sender: int
    dest: int
    task: int
    left: float
    taken: float
    delivered: float
    started_age: float
    appeared_age: float
    robot_seconds: float
    members: tuple[int, ...]

    def invalid(self) -> str | None:
        why = _common(self) or _values(self, amounts=("left", "taken", "delivered", "started_age",
                                                      "appeared_age", "robot_seconds"))
        if why:
            return why
        m = self.members
        if not isinstance(m, tuple) or not 1 <= len(m) <= MAX_MEMBERS:
            return f"members: expected 1..{MAX_MEMBERS} robot ids"
        if not all(_int(r) and 1 <= r <= 250 for r in m) or len(set(m)) != len(m) or self.sender not in m:
            return f"members {list(m)}: expected distinct robot ids 1..250 with the sender among them"
        return None


@dataclass(frozen=True)
class DrExitLeader:
    """The sender no longer leads ``task`` for the robot ``dest`` (0: its whole group): ``reason`` 0 it yields to
    a leader of higher id (§5.5.1), 1 ``dest`` is not in its group, 2 the object is exhausted, 3 the task is done."""
    sender: int
    dest: int
    task: int
    reason: int

    def invalid(self) -> str | None:
        return _common(self) or (None if self.reason in REASONS else f"reason {self.reason!r}: expected 0..3")


@dataclass(frozen=True)
class DrSvrSample:
    """§5.3 on-line learning: the sender's sample number ``seq`` (1, 2, ...): ``n`` mean group size, ``d`` m from
    the object to the delivery point, ``interference`` I in wu/s."""
    sender: int
    dest: int
    seq: int
    n: float
    d: float
    interference: float

    def invalid(self) -> str | None:
        why = _common(self) or _values(self, counts=("seq",), amounts=("d",), numbers=("interference",))
        if why is None and not (self.seq >= 1 and _finite(self.n) and self.n > 0):
            why = "seq/n: expected seq >= 1 and n > 0"
        return why


@dataclass(frozen=True)
class DrSampleRequest:
    """A robot that missed sample ``seq`` of robot ``dest`` asks it to send it again."""
    sender: int
    dest: int
    seq: int

    def invalid(self) -> str | None:
        return _common(self) or _values(self, counts=("seq",))


@dataclass(frozen=True)
class DrLoad:
    """A robot loaded ``wu`` at ``task``'s object: its ``seq``-th load there (1, 2, ...).  The entry is the
    sender's before this load (``loads`` = seq - 1 is implied).  Resent until a ``DrLedger`` grants it."""
    sender: int
    dest: int
    task: int
    seq: int
    wu: float
    taken: float
    deliveries: int
    delivered: float
    returned: float

    def invalid(self) -> str | None:
        why = _common(self) or _values(self, counts=("seq", "deliveries"),
                                       amounts=("wu", "taken", "delivered", "returned"))
        return why or (None if self.seq >= 1 else "seq: expected >= 1")


@dataclass(frozen=True)
class DrDeliver:
    """A robot unloaded ``wu`` of ``task`` at the delivery point (or put its load back: ``returned`` grew): its
    ``seq``-th report of the kind; the entry is the sender's after it.  Resent until acknowledged."""
    sender: int
    dest: int
    task: int
    seq: int
    wu: float
    loads: int
    taken: float
    delivered: float
    returned: float

    def invalid(self) -> str | None:
        why = _common(self) or _values(self, counts=("seq", "loads"), amounts=("wu", "taken", "delivered", "returned"))
        return why or (None if self.seq >= 1 else "seq: expected >= 1")


@dataclass(frozen=True)
class DrLedger:
    """The leader's entry for ``robot`` on ``task`` (to every peer): grants a load, acknowledges a delivery, and
    replicates the bookkeeping so that any robot can take the lead with it; ``left`` wu at the object."""
    sender: int
    dest: int
    task: int
    robot: int
    loads: int
    taken: float
    deliveries: int
    delivered: float
    returned: float
    left: float

    def invalid(self) -> str | None:
        why = _common(self) or _entry(self) or _values(self, amounts=("left",))
        return why or (None if _int(self.robot) and 1 <= self.robot <= 250 else "robot: expected a robot id 1..250")


WIRE_MESSAGES = (DrLeaderRequest, DrBidRequest, DrBid, DrAward, DrRobotAlive, DrRefuse, DrLeaderAlive, DrExitLeader,
                 DrSvrSample, DrSampleRequest, DrLoad, DrDeliver, DrLedger)
