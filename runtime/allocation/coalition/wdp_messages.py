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

import math
from dataclasses import dataclass

MAX_COALITION = 8          # robots a bid, award or report can name (rendezvous.MAX_ROBOTS)
MAX_INVITED = 64           # robots a TaskOffer can invite


def _int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _robots(robots, limit: int) -> str | None:
    """Why ``robots`` is not a list of distinct robot ids 1..250 of at most ``limit``, or None."""
    if not isinstance(robots, tuple) or not robots:
        return "robots: expected a non-empty list of robot ids"
    if len(robots) > limit:
        return f"robots: expected at most {limit}, got {len(robots)}"
    if not all(_int(r) and 1 <= r <= 250 for r in robots) or len(set(robots)) != len(robots):
        return f"robots {list(robots)}: expected distinct robot ids 1..250"
    return None


def _ids(msg) -> str | None:
    if not (_int(msg.sender) and 1 <= msg.sender <= 250 and _int(msg.dest) and 0 <= msg.dest <= 250):
        return "sender/dest: expected robot ids"
    if not (_int(msg.round) and msg.round >= 0 and _int(msg.task) and msg.task >= 0):
        return "round/task: expected non-negative integers"
    return None


def _led(msg) -> str | None:
    """Ids, and ``robots`` a coalition that names its sender."""
    why = _ids(msg) or _robots(msg.robots, MAX_COALITION)
    if why is None and msg.sender not in msg.robots:
        why = f"robots {list(msg.robots)}: expected the sender {msg.sender} among them"
    return why


@dataclass(frozen=True)
class TaskOffer:
    """Auctioneer offers ``task`` at (x, y) in round ``round`` to the robots ``robots``; bids are taken
    until ``deadline`` (the auctioneer's clock: bidders answer at once and need not read it);
    ``n_tasks`` tasks are offered in the round."""
    sender: int
    dest: int
    round: int
    task: int
    x: float
    y: float
    n_tasks: int
    deadline: float
    robots: tuple[int, ...] = ()

    def invalid(self) -> str | None:
        why = _ids(self)
        if why:
            return why
        if not (_number(self.x) and _number(self.y)):
            return "position: expected finite x, y"
        if not (_int(self.n_tasks) and self.n_tasks >= 1):
            return "n_tasks: expected >= 1"
        return _robots(self.robots, MAX_INVITED) if self.robots else None


@dataclass(frozen=True)
class CoalitionBid:
    """A coalition leader (``sender``, one of ``robots``) bids ``value`` for ``task`` on behalf
    of the coalition ``robots``."""
    sender: int
    dest: int
    round: int
    task: int
    robots: tuple[int, ...]
    value: float

    def invalid(self) -> str | None:
        why = _led(self)
        if why is None and not (_number(self.value) and self.value >= 0):
            why = f"value {self.value}: expected a finite number >= 0"
        return why


@dataclass(frozen=True)
class CoalitionAward:
    """``task`` goes to coalition ``robots`` (sent to each member).  In the daemon the order of ``robots``
    is the members' order on the meeting ring (:mod:`runtime.allocation.coalition.meeting`)."""
    sender: int
    dest: int
    round: int
    task: int
    robots: tuple[int, ...]
    value: float

    def invalid(self) -> str | None:
        why = _ids(self) or _robots(self.robots, MAX_COALITION)
        if why:
            return why
        return None if _number(self.value) else f"value {self.value}: expected a finite number"


@dataclass(frozen=True)
class AwardAck:
    """A member accepts its part of the award for ``task``."""
    sender: int
    dest: int
    round: int
    task: int

    def invalid(self) -> str | None:
        return _ids(self)


@dataclass(frozen=True)
class AwardCancel:
    """Auctioneer to members: the award of ``task`` is withdrawn (a member did not accept in time, was lost
    or left); members stop.  Member to auctioneer: the sender declines the award or leaves the coalition."""
    sender: int
    dest: int
    round: int
    task: int

    def invalid(self) -> str | None:
        return _ids(self)


@dataclass(frozen=True)
class MemberReport:
    """A member of the coalition ``robots`` awarded ``task`` in ``round`` tells the auctioneer it holds it and
    whether it has ``arrived`` at its meeting point.  Sent on every change and each ``report_period``, so an
    auctioneer that takes over rebuilds the running coalitions from these."""
    sender: int
    dest: int
    round: int
    task: int
    robots: tuple[int, ...]
    arrived: bool

    def invalid(self) -> str | None:
        return _led(self) or (None if isinstance(self.arrived, bool) else "arrived: expected true/false")


@dataclass(frozen=True)
class CoalitionDone:
    """Every member of ``robots`` has arrived: ``task`` is complete and the members are free."""
    sender: int
    dest: int
    round: int
    task: int
    robots: tuple[int, ...]

    def invalid(self) -> str | None:
        return _ids(self) or _robots(self.robots, MAX_COALITION)


@dataclass(frozen=True)
class TaskDone:
    """In-process bidders only: the sender finished its part of ``task`` and is free again."""
    sender: int
    dest: int
    round: int
    task: int


WDP_MESSAGES = (TaskOffer, CoalitionBid, CoalitionAward, AwardAck, AwardCancel, TaskDone)
WIRE_MESSAGES = (TaskOffer, CoalitionBid, CoalitionAward, AwardAck, AwardCancel, MemberReport, CoalitionDone)


def why_invalid(msg) -> str | None:
    """``msg.invalid()`` for a message that did not come through the codec: never raises."""
    try:
        return msg.invalid()
    except Exception as exc:          # values of types the protocol never sends
        return f"malformed: {type(exc).__name__}"
