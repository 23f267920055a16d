"""Messages of the CoMutaR bidding protocol (paper 003 Alg. 1; the paper names none: these are the digest's).

Plain frozen dataclasses named ``Cm*`` (their MAVLink names ``MRTA_CM_*`` stay clear of the other
families'), ``sender`` and ``dest`` first (dest 0 = every peer), fields bool / int / float /
``tuple[int, ...]`` as :mod:`runtime.comms.codec` carries them (``comutar.xml`` is their MAVLink block).
Each class checks its own values once (``invalid()``); :func:`runtime.messages.why_invalid` never raises.

Names used below:

* ``auction``: ``auctioneer id << 16 | its count``: one announcement of one task.
* a *slot* is one action instance pre-allocated (or allocated) on one robot for one auction; its reference
  is ``robot << 16 | number`` (never 0), so a coalition travels as a list of slot references.
* ``info``: the code of an information type (:data:`~runtime.allocation.comutar.actions.INFO`).

The exchange: ``CmAnnounce`` (auctioneer, broadcast) -> actions that can do the task pre-allocate and, for
each unconnected input, ``CmQuery`` (broadcast; recursive down the input chain) -> ``CmCost`` (provider to
requester: a sub-coalition and its cost) -> ``CmBid`` (to the auctioneer) -> ``CmAward`` (broadcast: every slot
named allocates, every other slot of the auction is released) -> ``CmAck`` (each robot named), re-sent
until acknowledged; ``CmResign`` (a holder gives the task up), ``CmCancel`` (the auctioneer takes it back),
``CmHold`` (a holder's periodic report, so lost cancels and a new auctioneer are caught up), ``CmDone``.
Execution: ``CmSurvey`` (visits and the claimed waypoint, broadcast), ``CmRegion`` (a consumer
tells its providers the region to keep in view) and ``CmStream`` (a provider's range data or obstacle list for
its consumer).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

from runtime.messages import Amount, Dest, Kind, Message, RobotId, TaskId, is_finite, is_int, is_robot

MAX_SLOTS = 48             # slot references one message can name (uint32[48])
MAX_VISITED = 200          # waypoints a CmSurvey can name (uint8[200], index + 1)

# an auction id: the auctioneer's robot id in the upper 16 bits
AuctionId = Annotated[int, Kind("an auctioneer id 1..250 in its upper 16 bits",
                                lambda v: is_int(v) and 1 <= v >> 16 <= 250 and v <= 0xFFFFFFFF)]


def slot_robot(ref: int) -> int:
    return ref >> 16


def _slots(slots, need: int | None = None) -> str | None:
    if not isinstance(slots, tuple) or not slots:
        return "slots: expected a non-empty list of slot references"
    if len(slots) > MAX_SLOTS:
        return f"slots: expected at most {MAX_SLOTS}, got {len(slots)}"
    if not all(is_int(s) and 1 <= s >> 16 <= 250 and s & 0xFFFF and s <= 0xFFFFFFFF for s in slots) \
            or len(set(slots)) != len(slots):
        return "slots: expected distinct references robot << 16 | n (robot 1..250, n 1..65535)"
    if need is not None and slot_robot(slots[0]) != need:
        return f"slots: expected the first to be the sender's ({need})"
    return None


class _SendersSlots(Message):
    """A message naming a coalition of slots, the sender's first."""

    def check(self) -> str | None:
        return _slots(self.slots, self.sender)


@dataclass(frozen=True)
class CmAnnounce(Message):
    """The auctioneer opens ``auction`` for ``task``; bids are taken for ``timeout`` seconds from now (a
    duration, so no clocks need agree); ``attempt`` counts its announcements."""
    sender: RobotId
    dest: Dest
    auction: AuctionId
    task: TaskId
    timeout: float
    attempt: int

    def check(self) -> str | None:
        if not (is_finite(self.timeout) and 0 < self.timeout <= 600):
            return f"timeout {self.timeout}: expected 0..600 s"
        return None if is_int(self.attempt) and self.attempt >= 1 else "attempt: expected >= 1"


@dataclass(frozen=True)
class CmQuery(Message):
    """An action pre-allocated for ``auction`` asks who can produce ``info`` for it (query id ``query``, unique
    per sender).  ``depth``: the requester's place in the input chain (1: the task's action); ``budget``: the
    seconds the requester waits for answers; ``expires``: seconds until its pre-allocation lapses.  The
    region (``x``, ``y`` in the fleet frame) is the surroundings of robot ``owner``, the chain's consumer: a
    reader on another robot must keep it in view."""
    sender: RobotId
    dest: Dest
    auction: AuctionId
    query: int
    info: int
    depth: int
    budget: float
    expires: float
    owner: int
    x: float
    y: float

    def check(self) -> str | None:
        if not (is_int(self.query) and self.query >> 16 == self.sender and self.query & 0xFFFF):
            return f"query {self.query}: expected sender << 16 | n"
        if not (is_int(self.info) and 1 <= self.info <= 255 and is_int(self.depth) and 1 <= self.depth <= 8):
            return "info/depth: expected 1..255 / 1..8"
        if not (is_finite(self.budget) and 0 <= self.budget <= 600 and is_finite(self.expires) and 0 <= self.expires <= 600):
            return "budget/expires: expected 0..600 s"
        if not (is_robot(self.owner) and is_finite(self.x) and is_finite(self.y)):
            return "region: expected a robot id and a finite position"
        return None


@dataclass(frozen=True)
class CmCost(Message):
    """Answer to ``query``: ``slots`` (the provider's slot producing the information first, then the inputs
    it connected, recursively) can produce it for ``cost`` seconds, streaming ``rate`` Mb/s."""
    sender: RobotId
    dest: Dest
    auction: int
    query: int
    cost: Amount
    rate: Amount
    slots: tuple[int, ...]

    def check(self) -> str | None:
        if not (is_int(self.auction) and is_int(self.query) and 1 <= self.query >> 16 <= 250):
            return "auction/query: expected ids"
        return _slots(self.slots, self.sender)


@dataclass(frozen=True)
class CmBid(_SendersSlots):
    """The coalition ``slots`` (the sender's action for the task first) bids ``cost`` (s) for ``task``."""
    sender: RobotId
    dest: Dest
    auction: AuctionId
    task: TaskId
    cost: Amount
    slots: tuple[int, ...]


@dataclass(frozen=True)
class CmAward(Message):
    """``task`` goes to the coalition(s) ``slots``: each slot named allocates its resources; a robot's other
    slots of ``auction`` are released.  Broadcast once, then re-sent to robots that have not acknowledged."""
    sender: RobotId
    dest: Dest
    auction: AuctionId
    task: TaskId
    slots: tuple[int, ...]

    def check(self) -> str | None:
        return _slots(self.slots)


@dataclass(frozen=True)
class _TaskNote(Message):
    """A note about one task under one auction: the fields of CmAck, CmResign, CmCancel and CmDone."""
    sender: RobotId
    dest: Dest
    auction: AuctionId
    task: TaskId


@dataclass(frozen=True)
class CmAck(_TaskNote):
    """The sender allocated its slots of the award."""


@dataclass(frozen=True)
class CmResign(_TaskNote):
    """The sender gives ``task`` up (its slots no longer fit, a provider was lost, it failed or was disarmed)."""


@dataclass(frozen=True)
class CmCancel(_TaskNote):
    """The auctioneer takes the award of ``auction`` back: the receiver releases its slots of it."""


@dataclass(frozen=True)
class CmHold(_SendersSlots):
    """A holder's periodic report to the task's auctioneer: it holds ``task`` under ``auction`` with its
    ``slots`` (so a lost cancel is repeated, and an auctioneer that took over rebuilds the award)."""
    sender: RobotId
    dest: Dest
    auction: AuctionId
    task: TaskId
    slots: tuple[int, ...]


@dataclass(frozen=True)
class CmDone(_TaskNote):
    """The auctioneer: ``task`` is complete; holders release it."""


@dataclass(frozen=True)
class CmSurvey(Message):
    """A surveillance holder's copy of ``task``: the waypoints it knows visited (index + 1) and the one it
    heads for (``target``, index + 1; 0: none) since ``claimed`` (s, the sender's clock: earlier claims win)."""
    sender: RobotId
    dest: Dest
    task: TaskId
    target: int
    claimed: float
    visited: tuple[int, ...] = ()

    def check(self) -> str | None:
        if not (is_int(self.target) and 0 <= self.target <= MAX_VISITED and is_finite(self.claimed)):
            return "target/claimed: expected 0..200 and a finite time"
        vis = self.visited
        if not isinstance(vis, tuple) or len(vis) > MAX_VISITED or \
                (vis and (set(map(type, vis)) != {int} or min(vis) < 1 or max(vis) > MAX_VISITED)):
            return "visited: expected at most 200 waypoint numbers 1..200"
        return None


@dataclass(frozen=True)
class CmRegion(Message):
    """The consumer of ``task``'s chain: keep the disc (``x``, ``y``, ``radius``) around me in view."""
    sender: RobotId
    dest: Dest
    task: TaskId
    x: float
    y: float
    radius: float

    def check(self) -> str | None:
        if not (is_finite(self.x) and is_finite(self.y) and is_finite(self.radius) and 0 <= self.radius <= 100):
            return "region: expected a finite position and a radius 0..100 m"
        return None


MAX_DISCS = 32             # discs one CmStream carries (uint32[32])
DISC_XY = 0.02             # m per unit of a packed disc's x and y (12 bits, signed: +-40.96 m from the origin)
DISC_R = 0.01              # m per unit of its radius (8 bits: 0.01 .. 2.55 m)


def pack_disc(x: float, y: float, r: float, ox: float, oy: float) -> int | None:
    """One disc (fleet frame, m) as a uint32 relative to the origin (ox, oy); None when it is too far from it."""
    ix, iy = round((x - ox) / DISC_XY), round((y - oy) / DISC_XY)
    if not (-2048 <= ix < 2048 and -2048 <= iy < 2048):
        return None
    ir = min(255, max(1, round(r / DISC_R)))
    return ((ix & 0xFFF) << 20) | ((iy & 0xFFF) << 8) | ir


def unpack_disc(v: int, ox: float, oy: float) -> tuple[float, float, float]:
    ix, iy, ir = (v >> 20) & 0xFFF, (v >> 8) & 0xFFF, v & 0xFF
    ix, iy = ix - 4096 if ix >= 2048 else ix, iy - 4096 if iy >= 2048 else iy
    return ox + ix * DISC_XY, oy + iy * DISC_XY, ir * DISC_R


@dataclass(frozen=True)
class CmStream(Message):
    """A provider's output for ``task``'s consumer: ``info`` 1 (range data: one disc per echo) or 2 (an
    obstacle list), sensed at ``stamp`` (the provider's clock), as discs packed relative to (``ox``, ``oy``)
    (:func:`pack_disc`; an empty list is news too: nothing seen).  The origin is where the provider was: the
    point the discs were heard from (its consumer puts their shadows on the far side)."""
    sender: RobotId
    dest: Dest
    task: TaskId
    info: int
    stamp: float
    ox: float
    oy: float
    discs: tuple[int, ...] = ()

    def check(self) -> str | None:
        if self.info not in (1, 2):
            return f"info {self.info}: expected 1 (range data) or 2 (obstacle list)"
        if not (is_finite(self.stamp) and is_finite(self.ox) and is_finite(self.oy)):
            return "stamp/origin: expected finite numbers"
        d = self.discs
        if not isinstance(d, tuple) or len(d) > MAX_DISCS or not all(is_int(v) and 0 < v <= 0xFFFFFFFF and v & 0xFF
                                                                      for v in d):
            return f"discs: expected at most {MAX_DISCS} packed discs with a radius"
        return None

    def unpacked(self) -> list[tuple[float, float, float]]:
        return [unpack_disc(v, self.ox, self.oy) for v in self.discs]


WIRE_MESSAGES = (CmAnnounce, CmQuery, CmCost, CmBid, CmAward, CmAck, CmResign, CmCancel, CmHold, CmDone, CmSurvey,
                 CmRegion, CmStream)
