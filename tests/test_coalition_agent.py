"""One CoalitionAgent at a time, messages handed in by hand: what each role answers."""
from __future__ import annotations

import math

from runtime.allocation.agent import AWARDED, DONE, RELEASED, AgentContext
from runtime.allocation.coalition import meeting
from runtime.allocation.coalition.family import CoalitionAgent
from runtime.allocation.coalition.options import CoalitionOptions
from tests.alloc_util import StraightLineEstimator
from runtime.allocation.coalition.wdp_messages import (AwardAck, AwardCancel, CoalitionAward, CoalitionBid,
                                                       CoalitionDone, MemberReport, TaskOffer)
from runtime.messages import IDLE, RobotState
from runtime.tasks import ARRIVED, Profile, Progress, Task
from runtime.tasks.rendezvous import Rendezvous

T1, T2 = 1 << 16 | 1, 1 << 16 | 2
R1 = 2 << 16 | 1            # a round of robot 2


def agent(rid: int, pos=(0.0, 0.0), peers=(1, 2, 3)) -> CoalitionAgent:
    est = StraightLineEstimator(Profile(0.25, 0.17), lambda: pos)
    a = CoalitionAgent(AgentContext(rid, peers, est, CoalitionOptions()))
    a.add_tasks([Task(T1, "rendezvous", Rendezvous(4.0, 0.0, 2, 100.0)),
                 Task(T2, "rendezvous", Rendezvous(0.0, 4.0, 2, 100.0))], 0.0)
    return a


def hear(a: CoalitionAgent, now: float, **positions) -> None:
    """Idle RobotStates from peers r<id> at the given positions."""
    for name, (x, y) in positions.items():
        a.on_message(RobotState(int(name[1:]), 0, IDLE, (), x, y, 2, 0), now)


def test_the_lowest_live_robot_offers_every_open_task_once_it_has_listened():
    a = agent(1)
    hear(a, 0.0, r2=(1.0, 0.0), r3=(2.0, 0.0))
    assert a.on_tick(0.0) == [] and a.on_tick(1.9) == []             # start_wait: listening for reports
    offers = a.on_tick(2.5)
    assert {type(m) for m in offers} == {TaskOffer} and sorted(m.task for m in offers) == [T1, T2]
    assert all(m.robots == (1, 2, 3) and m.dest == 0 for m in offers)
    b = agent(2)
    hear(b, 0.0, r1=(0.0, 0.0), r3=(2.0, 0.0))
    assert b.on_tick(2.5) == []                                      # robot 1 is live: robot 2 does not auction


def test_a_leader_bids_coalitions_with_higher_ids_valued_by_the_slowest_member():
    a = agent(2, pos=(3.0, 0.0))
    hear(a, 0.0, r1=(-5.0, 0.0), r3=(4.0, 1.0))
    a.on_message(TaskOffer(1, 0, 1 << 16 | 1, T1, 4.0, 0.0, 2, 1.0, (1, 2, 3)), 0.1)
    bids = a.on_tick(0.15)
    assert bids == [CoalitionBid(2, 1, 1 << 16 | 1, T1, (2, 3), 100.0 - 2 * 1.0)]


def test_an_award_commits_to_a_slot_on_the_ring_and_a_duplicate_is_acked_again():
    a = agent(3, pos=(6.0, 0.0))
    hear(a, 0.0, r1=(-5.0, 0.0), r2=(2.0, 0.0))
    award = CoalitionAward(1, 3, 1 << 16 | 1, T1, (3, 2), 96.0)
    assert a.on_message(award, 0.1) == [AwardAck(3, 1, 1 << 16 | 1, T1)]
    (c,) = a.commitments
    assert c.task_id == T1 and c.partners == (2,) and c.role == "slot 1/2"
    assert math.isclose(math.dist(c.task.position, (4.0, 0.0)), meeting.ring_radius(2, 0.17, 0.1))
    assert c.task.position[0] > 4.0                                  # slot 1 of 2 is east, the side robot 3 is on
    assert a.on_message(award, 0.2) == [AwardAck(3, 1, 1 << 16 | 1, T1)]
    assert a.commitments == (c,)
    other = CoalitionAward(1, 3, 1 << 16 | 1, T2, (3, 2), 90.0)
    assert a.on_message(other, 0.3) == [AwardCancel(3, 1, 1 << 16 | 1, T2)]     # busy: declined
    assert a.commitments == (c,)


def test_arrival_is_reported_and_done_frees_the_member():
    a = agent(3, pos=(6.0, 0.0))
    hear(a, 0.0, r1=(-5.0, 0.0), r2=(2.0, 0.0))
    a.on_message(CoalitionAward(1, 3, 7, T1, (3, 2), 96.0), 0.1)
    assert a.on_tick(0.2) == [MemberReport(3, 1, 7, T1, (3, 2), False)]
    assert a.on_tick(0.5) == []                                      # next report after report_period
    a.on_progress(Progress(T1, ARRIVED, 0.6), 0.6)
    assert a.on_tick(0.65) == [MemberReport(3, 1, 7, T1, (3, 2), True)]
    a.on_message(AwardCancel(2, 3, 7, T1), 0.7)                      # not from the auctioneer: ignored
    assert a.commitments
    a.on_message(CoalitionDone(1, 0, 7, T1, (3, 2)), 0.8)
    assert a.commitments == () and a.member.free


def _auctioneer_with_award():
    a = agent(1, pos=(-5.0, 0.0))
    hear(a, 0.0, r2=(3.0, 0.0), r3=(5.0, 0.0))
    a.on_tick(0.0)
    offers = a.on_tick(2.5)
    rid = offers[0].round
    a.on_message(CoalitionBid(2, 1, rid, T1, (2, 3), 98.0), 2.6)
    out = a.on_tick(3.6)
    awards = [m for m in out if isinstance(m, CoalitionAward)]
    assert {m.dest for m in awards} == {2, 3} and all(m.task == T1 for m in awards)
    assert all(m.robots == (3, 2) for m in awards)          # ring order: robot 3 is east of the point, 2 west
    assert [(e.what, e.task) for e in a.pop_events()] == [(AWARDED, T1)]
    return a, rid


def test_a_member_that_declines_releases_the_coalition_and_the_task_is_offered_again():
    a, rid = _auctioneer_with_award()
    out = a.on_message(AwardCancel(3, 1, rid, T1), 3.7)
    assert sorted(m.dest for m in out) == [2, 3] and all(isinstance(m, AwardCancel) for m in out)
    assert [(e.what, e.task) for e in a.pop_events()] == [(RELEASED, T1)]
    hear(a, 3.8, r2=(3.0, 0.0), r3=(5.0, 0.0))
    again = a.on_tick(3.9)
    assert T1 in [m.task for m in again if isinstance(m, TaskOffer)]
    # the member that did not hear the cancel reports its old award: told again
    assert a.on_message(MemberReport(2, 1, rid, T1, (2, 3), False), 4.0) == [AwardCancel(1, 2, rid, T1)]


def test_all_arrived_is_done_and_a_late_report_hears_so():
    a, rid = _auctioneer_with_award()
    a.on_message(MemberReport(2, 1, rid, T1, (2, 3), True), 4.0)
    assert a.pop_events() == []
    a.on_message(MemberReport(3, 1, rid, T1, (3, 2), True), 4.1)
    assert [(e.what, e.task, set(e.robots)) for e in a.pop_events()] == [(DONE, T1, {2, 3})]
    assert T1 not in a.view.tasks
    assert CoalitionDone in [type(m) for m in a.on_tick(4.2)]        # a cycle after the DONE event
    assert a.on_message(MemberReport(2, 1, rid, T1, (3, 2), True), 5.0) == [CoalitionDone(1, 2, rid, T1, (3, 2))]


def test_silent_members_lose_the_award_in_ack_timeout():
    a, rid = _auctioneer_with_award()
    a.on_message(AwardAck(2, 1, rid, T1), 3.7)
    resent = a.on_tick(4.2)
    assert [(type(m), m.dest) for m in resent] == [(CoalitionAward, 3)]       # re-sent to the silent one only
    out = a.on_tick(5.7)
    assert sorted(m.dest for m in out if isinstance(m, AwardCancel)) == [2, 3]
    assert [e.what for e in a.pop_events()] == [RELEASED]


def test_a_new_auctioneer_adopts_running_coalitions_from_reports_and_cancels_impossible_ones():
    b = agent(2, pos=(3.0, 0.0), peers=(1, 2, 3, 4))
    hear(b, 0.0, r1=(-5.0, 0.0), r3=(5.0, 0.0), r4=(0.0, 5.0))
    b.on_peer_lost(1, 1.0)
    b.on_tick(1.0)                                                   # robot 2 is the auctioneer now
    old = 1 << 16 | 1
    assert b.on_message(MemberReport(3, 2, old, T1, (3, 4), False), 1.1) == []
    assert b.auction.stats.adopted == 1 and b.auction.coalitions[T1].robots == (3, 4)
    # a coalition with the lost robot 1 in it cannot meet
    assert b.on_message(MemberReport(4, 2, old, T2, (1, 4), False), 1.2) == [AwardCancel(2, 4, old, T2)]
    offers = b.on_tick(3.5)
    assert T1 not in [m.task for m in offers if isinstance(m, TaskOffer)]   # adopted: not offered again
    b.on_message(MemberReport(3, 2, old, T1, (3, 4), True), 4.0)
    b.on_message(MemberReport(4, 2, old, T1, (3, 4), True), 4.1)
    assert (DONE, T1) in [(e.what, e.task) for e in b.pop_events()]


def test_a_disarmed_member_leaves_its_coalition():
    a = agent(3, pos=(6.0, 0.0))
    hear(a, 0.0, r1=(-5.0, 0.0), r2=(2.0, 0.0))
    a.on_message(CoalitionAward(1, 3, 7, T1, (3, 2), 96.0), 0.1)
    assert a.set_available(False, 0.2) == [AwardCancel(3, 1, 7, T1)]
    assert a.commitments == ()
    a.on_message(TaskOffer(1, 0, 8, T2, 0.0, 4.0, 1, 1.0, (1, 2, 3)), 0.3)
    assert a.on_tick(0.35) == []                                     # disarmed: no bids
