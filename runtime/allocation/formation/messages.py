"""Messages the allocation agents exchange.  Plain frozen dataclasses, no I/O.

Every message carries ``sender`` (robot id, 1..250) and ``dest`` (0 = every peer).  The comms layer
maps each class to one MAVLink message of the private dialect with the same field names
(see ``runtime/comms/codec.py``); the in-memory bus in tests passes the objects as they are.

Ids: ``task`` and ``auction`` are unsigned 16/32-bit integers chosen by the sender; an auction id
is unique per auctioneer and never 0, so (sender, auction) names one auction fleet-wide.  ``Status``
answers an auction rather than running one: there (dest, auction) names it, and auction 0 = none.

Values: costs, bids and prices are seconds of travel (the daemon's estimator); a finite one beyond
``MAX_VALUE`` in magnitude (11.6 days) is outside the protocol, as is a negative price (prices start at 0 and
only rise) and a bid of -inf.  What a message says about a round (its task indices, robots, task set) is
checked by the formation family, which knows the round (:mod:`runtime.allocation.formation.family`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated

import numpy as np

from runtime.messages import BROADCAST, Kind, Message, Number

MAX_VALUE = 1e6          # s: the largest finite cost, bid or price the protocol carries


def _value_reason(name: str, v) -> str:
    if math.isnan(v):
        return f"{name}: expected a number, got NaN"
    if v == -math.inf:
        return f"{name}: expected a number or +inf (cannot), got -inf"
    if not math.isfinite(v):
        return f"{name} {v}: expected a finite number"
    return f"{name} {v}: expected at most {MAX_VALUE:g} in magnitude"


# a task's index in the round (0xFFFF: none), a robot id, and the protocol's values (seconds of travel)
Index = Annotated[int, Kind("0..65534", lambda v: 0 <= v < 0xFFFF)]
_ROBOT = Kind("1..250", lambda v: 1 <= v <= 250, lambda name, v: f"robot {v}: expected 1..250")
Robot = Annotated[int, _ROBOT]
Reserve = Annotated[float, Kind("", lambda v: not math.isnan(v) and not (math.isfinite(v) and abs(v) > MAX_VALUE),
                                _value_reason)]            # +inf or -inf: none / cannot
Cost = Annotated[float, Kind("", lambda v: not math.isnan(v) and v != -math.inf
                             and not (math.isfinite(v) and abs(v) > MAX_VALUE), _value_reason)]   # +inf: cannot
Value = Annotated[float, Kind("", lambda v: math.isfinite(v) and abs(v) <= MAX_VALUE, _value_reason)]
PriceValue = Annotated[float, Kind(f"0..{MAX_VALUE:g}", lambda v: 0.0 <= v <= MAX_VALUE,
                               lambda name, v: f"price {v}: expected 0..{MAX_VALUE:g}")]


@dataclass(frozen=True)
class TaskInfo(Message):
    """A task exists at (x, y) in the fleet frame; ``n_tasks`` is the size of the task set
    (RTMA uses it for each robot's mean cost)."""
    sender: int
    dest: int
    task: Index
    x: Number
    y: Number
    n_tasks: int
    round: int = 0          # the daemon's allocation round (0 in sweeps and tests)

    def check(self) -> str | None:
        return None if 0 < self.n_tasks <= 0xFFFF else f"n_tasks {self.n_tasks}: expected 1..65535"


@dataclass(frozen=True)
class Announce(Message):
    """Auctioneer offers ``task``.  ``reserve`` is the auctioneer's own cost for it (+inf if it has
    none); BS sells a task back only to a bid worse than that."""
    sender: int
    dest: int
    auction: int
    task: Index
    x: Number
    y: Number
    reserve: Reserve
    round: int = 0          # the daemon's allocation round (0 in sweeps and tests)


@dataclass(frozen=True)
class Bid(Message):
    sender: int
    dest: int
    auction: int
    task: Index
    cost: Cost
    round: int = 0          # the daemon's allocation round (0 in sweeps and tests)


@dataclass(frozen=True)
class Award(Message):
    """``winner`` gets ``task`` at ``cost``; ``mean`` is the mean of all bids heard (RTMA)."""
    sender: int
    dest: int
    auction: int
    task: Index
    winner: Robot
    cost: Value
    mean: Value
    round: int = 0          # the daemon's allocation round (0 in sweeps and tests)


@dataclass(frozen=True)
class Price(Message):
    """Auction-algorithm price update: ``holder`` holds ``task`` at ``price``.  ``phase`` is the
    sender's epsilon-scaling rung: phases it has left above the final epsilon (0 = on it, 0xFFFF =
    it does not know the task set yet)."""
    sender: int
    dest: int
    task: Index
    holder: Robot
    price: PriceValue
    phase: int
    round: int = 0          # the daemon's allocation round (0 in sweeps and tests)


@dataclass(frozen=True)
class Status(Message):
    """A robot's allocation state: the task it holds (or 0xFFFF for none) and whether it believes
    the allocation has converged.  ``auction`` is the id of the auction this status answers (the
    ``Award`` it acknowledges, or the ``Announce`` of a task the sender already holds), so with
    ``dest`` it names the auctioneer's auction; 0 = it answers no auction (broadcasts)."""
    sender: int
    dest: int
    auction: int
    task: int
    converged: bool
    round: int = 0          # the daemon's allocation round (0 in sweeps and tests)


@dataclass(frozen=True)
class RoundStart(Message):
    """``sender`` starts round ``round`` over the fleet tasks ``tasks`` (a task's index in the round's other
    messages is its position here) among ``robots`` (itself included).

    A round that names more tasks or robots than one frame holds (``MAX_ROUND`` of each) is announced in parts
    ``0..last``: part k carries the k-th ``MAX_ROUND`` of each list, and the round is the parts' lists joined in
    order (:func:`split_round`, :func:`join_round`).  One frame is part 0 of last 0, what a frame without the two
    fields decodes to.  A part alone is checked for what it can say; the joined round for the rest."""
    sender: int
    dest: int
    round: int
    tasks: tuple[int, ...]
    robots: tuple[int, ...]
    part: int = 0
    last: int = 0

    def check(self) -> str | None:
        if not 0 <= self.part <= self.last < MAX_PARTS:
            return f"part {self.part} of last {self.last}: expected 0 <= part <= last <= {MAX_PARTS - 1}"
        if len(set(self.tasks)) != len(self.tasks) or (not self.tasks and not self.last):
            return f"tasks {list(self.tasks)}: expected distinct fleet task ids"
        if len(set(self.robots)) != len(self.robots) or (not self.last and self.sender not in self.robots):
            return f"robots {list(self.robots)}: expected distinct ids, the sender's among them"
        return next(filter(None, map(_bad_robot, self.robots)), None)


@dataclass(frozen=True)
class RoundLeave(Message):
    """``sender`` takes no (further) part in round ``round``."""
    sender: int
    dest: int
    round: int


def _bad_robot(robot: int) -> str | None:
    return None if _ROBOT.ok(robot) else _ROBOT.why("robot", robot)


AGENT_MESSAGES = (TaskInfo, Announce, Bid, Award, Price, Status)
ROUND_MESSAGES = (RoundStart, RoundLeave)
MAX_ROUND = 40          # tasks and robots one RoundStart frame can name (its MAVLink arrays)
MAX_PARTS = 7           # frames a round's RoundStart may take: 7 x 40 ids name every robot id (1..250)


def split_round(sender: int, dest: int, rid: int, tasks: tuple[int, ...], robots: tuple[int, ...]) -> list[RoundStart]:
    """Round ``rid`` as the ``RoundStart`` frames that announce it (one unless a list is longer than ``MAX_ROUND``)."""
    n = max(1, -(-max(len(tasks), len(robots)) // MAX_ROUND))
    return [RoundStart(sender, dest, rid, tuple(tasks[k * MAX_ROUND:(k + 1) * MAX_ROUND]),
                       tuple(robots[k * MAX_ROUND:(k + 1) * MAX_ROUND]), k, n - 1) for k in range(n)]


def join_round(parts: list[RoundStart]) -> RoundStart:
    """The round that parts ``0..last`` of one round announce, as one ``RoundStart`` (part 0 of last 0); check it with
    ``invalid()`` (a list may repeat an id across parts, or leave out the sender)."""
    first = parts[0]
    return RoundStart(first.sender, first.dest, first.round, tuple(t for p in parts for t in p.tasks),
                      tuple(r for p in parts for r in p.robots))


def wire_float(value: float) -> float:
    """``value`` at the precision the dialect carries it (MAVLink ``float``: IEEE single).  An agent that
    compares its own bid with bids it received must hold its own at that precision too: otherwise two
    bids that tie on the wire differ at home, and "only a worse bid can win" can exclude every robot."""
    with np.errstate(over="ignore"):
        return float(np.float32(value))


def addressed_to(msg, robot_id: int) -> bool:
    """True if ``msg`` is a well-formed message from another robot, for ``robot_id`` or for everyone."""
    sender = getattr(msg, "sender", None)
    return (isinstance(sender, int) and sender != robot_id
            and getattr(msg, "dest", None) in (BROADCAST, robot_id))
