"""Paper 001's simultaneous coalition auction as a daemon allocation method (``coalition``) for ``rendezvous``
tasks.

:class:`CoalitionAgent` is one robot's sans-IO agent.  Every robot runs both roles over one shared
:class:`~runtime.allocation.coalition.view.FleetView`:

* the :class:`~runtime.allocation.coalition.auctioneer.Auctioneer`, active on the lowest-id live robot:
  offers every open unheld task at once, solves winner determination over the coalition bids, awards,
  tracks arrivals, completes tasks, re-offers leftovers and released tasks;
* the :class:`~runtime.allocation.coalition.member.Member`: proposes and bids coalitions it leads, accepts
  awards, meets its partners on a ring around the task's point, reports to the auctioneer.

Messages a role addresses to this robot itself (the auctioneer bidding, being awarded, reporting) are
handled here without touching the wire; broadcasts go to the wire and to this robot.  Every message from
outside is checked once more (``invalid()``: in-memory tests hand over objects the codec never made) and
counted in :attr:`CoalitionAgent.dropped` when it cannot be acted on.  The roles drop and count what does not
fit their state (``Member.stats``, ``Auctioneer.stats``): offers of tasks not open in the table or placed
elsewhere than the table says, awards from a robot that is not the auctioneer, a ``CoalitionDone`` for a task
not open here, from a robot that is not an auctioneer, or ending a coalition this auctioneer runs.  A message
within all of these in the auctioneer's or a member's name (an award, a report the auctioneer adopts) cannot
be told from a genuine one without signing, the fleet's default.  See docs/coalition.md.
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

from runtime.allocation.agent import FAILED, AgentContext, Method, TaskEvent, route
from runtime.allocation.coalition.auctioneer import Auctioneer
from runtime.allocation.coalition.member import Member
from runtime.allocation.coalition.options import CoalitionOptions
from runtime.allocation.coalition.view import FleetView
from runtime.allocation.coalition.wdp_messages import (WIRE_MESSAGES, AwardAck, AwardCancel, CoalitionAward,
                                                       CoalitionBid, CoalitionDone, MemberReport, TaskOffer)
from runtime.log import get_logger
from runtime.messages import BROADCAST, RobotState, task_origin, why_invalid
from runtime.tasks import Commitment, Progress, Task

KINDS = ("rendezvous",)


class CoalitionAgent:
    """One robot's coalition-family agent (see the module docstring)."""

    def __init__(self, ctx: AgentContext):
        self.robot_id = int(ctx.robot_id)
        self.options: CoalitionOptions = ctx.options
        self.estimator = ctx.estimator
        self.log = get_logger("alloc.coalition", self.robot_id)
        self.view = FleetView(self.robot_id, ctx.peers)
        self._events: list[TaskEvent] = []
        self.member = Member(self.robot_id, self.view, self.options, self.estimator, self.log)
        self.auction = Auctioneer(self.robot_id, self.view, self.options, self.estimator, self._events, self.log)
        self.dropped = 0            # messages from outside that could not be acted on
        self._refused: set[int] = set()

    # ------------------------------------------------------------------ what the daemon reads
    @property
    def commitments(self) -> tuple[Commitment, ...]:
        return self.member.commitments

    @property
    def converged(self) -> bool:
        return not self.auction.pending and not self.member.offers

    @property
    def rounds(self):
        """Every round this robot closed as auctioneer (:class:`~.auctioneer.RoundRecord`), oldest first."""
        return self.auction.rounds

    def pop_events(self) -> list[TaskEvent]:
        out = list(self._events)
        self._events.clear()
        return out

    # ------------------------------------------------------------------ inputs
    def add_tasks(self, tasks: Sequence[Task], now: float) -> list:
        for t in tasks:
            if t.kind in KINDS:
                if t.id not in self.auction.finished:
                    self.view.tasks[t.id] = t
            elif t.id not in self._refused:
                self._refused.add(t.id)
                self.log.warning("task %d is a %s: the coalition method allocates %s tasks only", t.id, t.kind,
                                 "|".join(KINDS))
                if task_origin(t.id) == self.robot_id:        # reported once, by the robot that took it in
                    self._events.append(TaskEvent(t.id, FAILED, (self.robot_id,),
                                                  f"{t.kind} tasks are not allocated by the coalition method"))
        return []

    def withdraw_tasks(self, task_ids: Sequence[int], now: float) -> list:
        ids = set(task_ids)
        for t in ids:
            self.view.tasks.pop(t, None)
        self.member.withdraw(ids)
        self.auction.withdraw(ids)
        return []

    def set_available(self, available: bool, now: float) -> list:
        self.member.available = bool(available)
        return [] if available else self._route(self.member.leave("disarmed"), now)

    def set_localized(self, localized: bool) -> None:
        self.member.localized = bool(localized)

    def on_peer_lost(self, robot_id: int, now: float) -> list:
        self.view.on_lost(robot_id)
        self.auction.update_role(now)
        return self._route(self.auction.on_peer_lost(robot_id, now), now)

    def on_peer_joined(self, robot_id: int, now: float) -> list:
        """A robot joined the fleet: its messages count from now.  A round open now keeps the robots it invited; the
        next call for bids invites it once its state says it is idle, and its bids are counted from then.  A joiner
        with a lower id than the auctioneer takes the role once heard, as a lower robot coming back does."""
        self.view.join(robot_id)
        return []

    def on_progress(self, p: Progress, now: float) -> list:
        return self._route(self.member.on_progress(p, now), now)

    def on_message(self, msg, now: float) -> list:
        sender = getattr(msg, "sender", None)
        if isinstance(msg, RobotState):
            if self.view.known(sender) and self.view.on_state(msg):
                self.view.heard(sender, now)
            else:
                self.dropped += 1
            return []
        if (not isinstance(msg, WIRE_MESSAGES) or not self.view.known(sender)
                or getattr(msg, "dest", None) not in (BROADCAST, self.robot_id) or why_invalid(msg)):
            self.dropped += 1
            return []
        self.view.heard(sender, now)
        return self._route(self._dispatch(msg, now), now)

    def on_tick(self, now: float) -> list:
        self.auction.update_role(now)
        out = self.member.bids(now) + self.member.tick(now)
        out += self.auction.tick(now, self.member.free)
        return self._route(out, now)

    # ------------------------------------------------------------------ routing
    def _dispatch(self, msg, now: float) -> list:
        a, m = self.auction, self.member
        if isinstance(msg, TaskOffer):
            m.on_offer(msg, now)
            return []
        if isinstance(msg, CoalitionBid):
            a.on_bid(msg, now)
            return []
        if isinstance(msg, CoalitionAward):
            return m.on_award(msg, now)
        if isinstance(msg, AwardAck):
            return a.on_ack(msg, now)
        if isinstance(msg, AwardCancel):          # a member leaving (to the auctioneer) or a withdrawal (to members)
            out = a.on_cancel(msg, now)
            m.on_cancel(msg, now)
            return out
        if isinstance(msg, MemberReport):
            return a.on_report(msg, now)
        if isinstance(msg, CoalitionDone):
            a.on_done(msg, now)
            m.on_done(msg, now)
        return []

    def _route(self, msgs: list, now: float) -> list:
        """The messages for the wire; those for this robot are handled here (broadcasts both)."""
        return route(msgs, self.robot_id, lambda m: self._dispatch(m, now))


def _make(ctx: AgentContext) -> CoalitionAgent:
    return CoalitionAgent(ctx)


# no Method.solver: that slot holds the formation problem's in-process solvers (mrta assign, the formation
# experiments); the coalition family's in-process runs are runtime.inprocess
COALITION = Method("coalition", "paper 001 simultaneous coalition auction: rendezvous tasks by coalitions of robots",
                   CoalitionOptions, _make, KINDS, WIRE_MESSAGES, str(Path(__file__).with_name("coalition.xml")))
