"""Messages of the simultaneous coalition auction (paper 001, Table 1 steps 3-4).  Plain frozen
dataclasses, no I/O; ``sender`` and ``dest`` first as in :mod:`runtime.allocation.formation.messages`
(dest 0 = every peer).  ``robots`` is a tuple of robot ids (1..250); on MAVLink it maps to a
uint8 array with its length.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class TaskOffer:
    """Auctioneer offers ``task`` at (x, y) in round ``auction``; bids are taken until
    ``deadline`` (auctioneer time); ``n_tasks`` tasks are offered in the round."""
    sender: int
    dest: int
    auction: int
    task: int
    x: float
    y: float
    n_tasks: int
    deadline: float


@dataclass(frozen=True)
class CoalitionBid:
    """A coalition leader (``sender``, one of ``robots``) bids ``value`` for ``task`` on behalf
    of the coalition ``robots``."""
    sender: int
    dest: int
    auction: int
    task: int
    robots: tuple[int, ...]
    value: float


@dataclass(frozen=True)
class CoalitionAward:
    """``task`` goes to coalition ``robots`` (sent to each member)."""
    sender: int
    dest: int
    auction: int
    task: int
    robots: tuple[int, ...]
    value: float


@dataclass(frozen=True)
class AwardAck:
    """A member accepts its part of the award for ``task``."""
    sender: int
    dest: int
    auction: int
    task: int


@dataclass(frozen=True)
class AwardCancel:
    """The award of ``task`` is withdrawn (a member did not accept in time); members stop."""
    sender: int
    dest: int
    auction: int
    task: int


@dataclass(frozen=True)
class TaskDone:
    """The sender finished its part of ``task`` and is free again."""
    sender: int
    dest: int
    auction: int
    task: int


WDP_MESSAGES = (TaskOffer, CoalitionBid, CoalitionAward, AwardAck, AwardCancel, TaskDone)
