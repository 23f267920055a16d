"""Messages of the simultaneous coalition auction (paper 001, Table 1 steps 3-4).  Plain frozen
dataclasses, no I/O; ``sender`` and ``dest`` first as in :mod:`runtime.allocation.formation.messages`
(dest 0 = every peer).  ``robots`` is a tuple of robot ids (1..250); on MAVLink it travels as a zero-padded
uint8 array (``coalition.xml``).  ``round`` names one auction round fleet-wide: in the daemon it is the
auctioneer's id * 65536 + its count, in the in-process :mod:`wdp_auctioneer` a plain count.

Each class checks its own values once (``invalid()``, called by the codec when a frame is decoded and by
the agent for messages that did not come through the codec): a handler may trust what passes.

The protocol (see docs/coalition.md): the auctioneer offers every open task (``TaskOffer``, one per task,
naming the robots invited); coalition leaders bid (``CoalitionBid``); winner determination picks disjoint
coalitions and each member gets a ``CoalitionAward`` and accepts (``AwardAck``) or declines
(``AwardCancel`` to the auctioneer).  The auctioneer withdraws an award with ``AwardCancel`` to the
members.  A committed member reports its coalition and whether it has arrived (``MemberReport``) on each
change and periodically; when every member has arrived the auctioneer broadcasts ``CoalitionDone``.
``TaskDone`` is the in-process bidder's "my part is finished" (:class:`wdp_auctioneer.CoalitionBidder`);
it is not put on the wire.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

from runtime.messages import Amount, Dest, Kind, Message, Number, RobotId, RobotIds, is_int

MAX_COALITION = 8          # robots a bid, award or report can name (rendezvous.MAX_ROBOTS)
MAX_INVITED = 64           # robots a TaskOffer can invite

# a round (the auctioneer's id * 65536 + its count in the daemon, a count in-process) or a task id
Id = Annotated[int, Kind("an integer >= 0", lambda v: is_int(v) and v >= 0)]


def _size(robots: tuple, limit: int) -> str | None:
    """Why ``robots`` (distinct robot ids, checked by their kind) is empty or longer than ``limit``, or None."""
    if not robots:
        return "robots: expected a non-empty list of robot ids"
    return None if len(robots) <= limit else f"robots: expected at most {limit}, got {len(robots)}"


def _led(msg) -> str | None:
    """``robots`` a coalition that names its sender."""
    why = _size(msg.robots, MAX_COALITION)
    if why is None and msg.sender not in msg.robots:
        why = f"robots {list(msg.robots)}: expected the sender {msg.sender} among them"
    return why


@dataclass(frozen=True)
class TaskOffer(Message):
    """Auctioneer offers ``task`` at (x, y) in round ``round`` to the robots ``robots``; bids are taken
    until ``deadline`` (the auctioneer's clock: bidders answer at once and need not read it);
    ``n_tasks`` tasks are offered in the round."""
    sender: RobotId
    dest: Dest
    round: Id
    task: Id
    x: Number
    y: Number
    n_tasks: int
    deadline: float
    robots: RobotIds = ()

    def check(self) -> str | None:
        if not (isinstance(self.n_tasks, int) and not isinstance(self.n_tasks, bool) and self.n_tasks >= 1):
            return "n_tasks: expected >= 1"
        return _size(self.robots, MAX_INVITED) if self.robots else None


@dataclass(frozen=True)
class CoalitionBid(Message):
    """A coalition leader (``sender``, one of ``robots``) bids ``value`` for ``task`` on behalf
    of the coalition ``robots``."""
    sender: RobotId
    dest: Dest
    round: Id
    task: Id
    robots: RobotIds
    value: Amount

    def check(self) -> str | None:
        return _led(self)


@dataclass(frozen=True)
class CoalitionAward(Message):
    """``task`` goes to coalition ``robots`` (sent to each member).  In the daemon the order of ``robots``
    is the members' order on the meeting ring (:mod:`runtime.allocation.coalition.meeting`)."""
    sender: RobotId
    dest: Dest
    round: Id
    task: Id
    robots: RobotIds
    value: Number

    def check(self) -> str | None:
        return _size(self.robots, MAX_COALITION)


@dataclass(frozen=True)
class AwardAck(Message):
    """A member accepts its part of the award for ``task``."""
    sender: RobotId
    dest: Dest
    round: Id
    task: Id


@dataclass(frozen=True)
class AwardCancel(Message):
    """Auctioneer to members: the award of ``task`` is withdrawn (a member did not accept in time, was lost
    or left); members stop.  Member to auctioneer: the sender declines the award or leaves the coalition."""
    sender: RobotId
    dest: Dest
    round: Id
    task: Id


@dataclass(frozen=True)
class MemberReport(Message):
    """A member of the coalition ``robots`` awarded ``task`` in ``round`` tells the auctioneer it holds it and
    whether it has ``arrived`` at its meeting point.  Sent on every change and each ``report_period``, so an
    auctioneer that takes over rebuilds the running coalitions from these."""
    sender: RobotId
    dest: Dest
    round: Id
    task: Id
    robots: RobotIds
    arrived: bool

    def check(self) -> str | None:
        return _led(self) or (None if isinstance(self.arrived, bool) else "arrived: expected true/false")


@dataclass(frozen=True)
class CoalitionDone(Message):
    """Every member of ``robots`` has arrived: ``task`` is complete and the members are free."""
    sender: RobotId
    dest: Dest
    round: Id
    task: Id
    robots: RobotIds

    def check(self) -> str | None:
        return _size(self.robots, MAX_COALITION)


@dataclass(frozen=True)
class TaskDone(Message):
    """In-process bidders only (never on the wire, never checked): the sender finished its part of ``task`` and is
    free again."""
    sender: int
    dest: int
    round: int
    task: int


WDP_MESSAGES = (TaskOffer, CoalitionBid, CoalitionAward, AwardAck, AwardCancel, TaskDone)
WIRE_MESSAGES = (TaskOffer, CoalitionBid, CoalitionAward, AwardAck, AwardCancel, MemberReport, CoalitionDone)
