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

from dataclasses import dataclass

from runtime.messages import Amount, Count, Dest, Message, Number, RobotId, RobotIds, TaskId, is_finite

MAX_MEMBERS = 32                  # robots a LEADER_ALIVE can list
YIELD, NOT_MEMBER, EXHAUSTED, FINISHED = range(4)       # DrExitLeader.reason
REASONS = {YIELD: "yield", NOT_MEMBER: "not a member", EXHAUSTED: "object exhausted", FINISHED: "task done"}


@dataclass(frozen=True)
class DrLeaderRequest(Message):
    """Alg. 1: the sender asks to lead ``task``; ``capacity`` = its eq. 5 work capacity for it (wu/s)."""
    sender: RobotId
    dest: Dest
    task: TaskId
    capacity: Amount


@dataclass(frozen=True)
class DrBidRequest(Message):
    """Alg. 2 l.1: the leader of ``task`` opens auction ``round`` (leader id * 65536 + its count)."""
    sender: RobotId
    dest: Dest
    task: TaskId
    round: Count


@dataclass(frozen=True)
class DrBid(Message):
    """A free robot's bid in ``round``: its work capacity for the task (wu/s) and its distance to the object (m,
    the tie-break between equal capacities)."""
    sender: RobotId
    dest: Dest
    task: TaskId
    round: Count
    capacity: Amount
    distance: Amount


@dataclass(frozen=True)
class DrAward(Message):
    """Alg. 2 l.19: the leader bids ``value`` = U_j(predicted finish) for the robot ``dest``."""
    sender: RobotId
    dest: Dest
    task: TaskId
    round: Count
    value: Amount


@dataclass(frozen=True)
class DrRobotAlive(Message):
    """Alg. 3 l.10 and §5.5.3: the sender is a member of ``task``'s group (confirmation, then every
    ``member_alive_period``), with its bookkeeping entry for the task."""
    sender: RobotId
    dest: Dest
    task: TaskId
    loads: Count
    taken: Amount
    deliveries: Count
    delivered: Amount
    returned: Amount


@dataclass(frozen=True)
class DrRefuse(Message):
    """Alg. 3 l.12: the sender refuses the award of ``round``; round 0: a member leaves the group."""
    sender: RobotId
    dest: Dest
    task: TaskId
    round: Count


@dataclass(frozen=True)
class DrLeaderAlive(Message):
    """§5.5.1: the sender leads ``task`` (every ``leader_alive_period``).  ``left`` wu at the object, ``taken``
    and ``delivered`` wu in all; ``members`` the group (the leader among them); ``started_age`` s since the task's
    first leader was elected, ``appeared_age`` s since the task appeared, ``robot_seconds`` the integral of the
    group size over that time: a new leader carries these on."""
    sender: RobotId
    dest: Dest
    task: TaskId
    left: Amount
    taken: Amount
    delivered: Amount
    started_age: Amount
    appeared_age: Amount
    robot_seconds: Amount
    members: RobotIds

    def check(self) -> str | None:
        m = self.members
        if not 1 <= len(m) <= MAX_MEMBERS:
            return f"members: expected 1..{MAX_MEMBERS} robot ids"
        if self.sender not in m:
            return f"members {list(m)}: expected distinct robot ids 1..250 with the sender among them"
        return None


@dataclass(frozen=True)
class DrExitLeader(Message):
    """The sender no longer leads ``task`` for the robot ``dest`` (0: its whole group): ``reason`` 0 it yields to
    a leader of higher id (§5.5.1), 1 ``dest`` is not in its group, 2 the object is exhausted, 3 the task is done."""
    sender: RobotId
    dest: Dest
    task: TaskId
    reason: int

    def check(self) -> str | None:
        return None if self.reason in REASONS else f"reason {self.reason!r}: expected 0..3"


@dataclass(frozen=True)
class DrSvrSample(Message):
    """§5.3 on-line learning: the sender's sample number ``seq`` (1, 2, ...): ``n`` mean group size, ``d`` m from
    the object to the delivery point, ``interference`` I in wu/s."""
    sender: RobotId
    dest: Dest
    seq: Count
    n: float
    d: Amount
    interference: Number

    def check(self) -> str | None:
        return None if self.seq >= 1 and is_finite(self.n) and self.n > 0 else "seq/n: expected seq >= 1 and n > 0"


@dataclass(frozen=True)
class DrSampleRequest(Message):
    """A robot that missed sample ``seq`` of robot ``dest`` asks it to send it again."""
    sender: RobotId
    dest: Dest
    seq: Count


@dataclass(frozen=True)
class DrLoad(Message):
    """A robot loaded ``wu`` at ``task``'s object: its ``seq``-th load there (1, 2, ...).  The entry is the
    sender's before this load (``loads`` = seq - 1 is implied).  Resent until a ``DrLedger`` grants it."""
    sender: RobotId
    dest: Dest
    task: TaskId
    seq: Count
    wu: Amount
    taken: Amount
    deliveries: Count
    delivered: Amount
    returned: Amount

    def check(self) -> str | None:
        return None if self.seq >= 1 else "seq: expected >= 1"


@dataclass(frozen=True)
class DrDeliver(Message):
    """A robot unloaded ``wu`` of ``task`` at the delivery point (or put its load back: ``returned`` grew): its
    ``seq``-th report of the kind; the entry is the sender's after it.  Resent until acknowledged."""
    sender: RobotId
    dest: Dest
    task: TaskId
    seq: Count
    wu: Amount
    loads: Count
    taken: Amount
    delivered: Amount
    returned: Amount

    def check(self) -> str | None:
        return None if self.seq >= 1 else "seq: expected >= 1"


@dataclass(frozen=True)
class DrLedger(Message):
    """The leader's entry for ``robot`` on ``task`` (to every peer): grants a load, acknowledges a delivery, and
    replicates the bookkeeping so that any robot can take the lead with it; ``left`` wu at the object."""
    sender: RobotId
    dest: Dest
    task: TaskId
    robot: RobotId
    loads: Count
    taken: Amount
    deliveries: Count
    delivered: Amount
    returned: Amount
    left: Amount




WIRE_MESSAGES = (DrLeaderRequest, DrBidRequest, DrBid, DrAward, DrRobotAlive, DrRefuse, DrLeaderAlive, DrExitLeader,
                 DrSvrSample, DrSampleRequest, DrLoad, DrDeliver, DrLedger)
