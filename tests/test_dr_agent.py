"""Alg. 1-3, the books and §5.5 on single dr agents fed hand-made message sequences (no bus)."""
from __future__ import annotations

import math

import pytest

from runtime.allocation.agent import AWARDED, DONE, RELEASED
from runtime.allocation.dr import model as M
from runtime.allocation.dr.interference import InterferenceModel
from runtime.allocation.dr.messages import (EXHAUSTED, FINISHED, NOT_MEMBER, YIELD, DrAward, DrBid, DrBidRequest,
                                            DrDeliver, DrExitLeader, DrLeaderAlive, DrLeaderRequest, DrLedger,
                                            DrLoad, DrRefuse, DrRobotAlive, DrSampleRequest, DrSvrSample)
from runtime.messages import IDLE, RobotState
from runtime.tasks import Progress

from tests.dr_util import agent, transport

T1, T2 = 2 << 16 | 1, 2 << 16 | 2
WC = M.work_capacity(2.0, 0.25, 1.4, 0.12)          # a robot's eq. 5 capacity on an object 1.4 m from delivery


def of(msgs, cls):
    return [m for m in msgs if isinstance(m, cls)]


def elect(a, task, now=0.0):
    """Make ``a`` the leader of ``task`` (already added); returns (time, the first round's id)."""
    out = a.on_tick(now)
    assert of(out, DrLeaderRequest) and a.role(task) == "candidate"
    now += a.o.time_leadership + 0.05
    out = a.on_tick(now)
    assert a.role(task) == "leader"
    (req,) = of(out, DrBidRequest)
    return now, req.round


def idle(rid, now):
    return RobotState(rid, 0, IDLE, (), 0.0, 0.0, 0, 0)


# ------------------------------------------------------------------------------------------------ Alg. 1
def test_a_free_robot_asks_to_lead_the_nearest_task_and_leads_after_time_leadership():
    a = agent(3, pos=(0.0, 0.0))
    a.add_tasks([transport(T1, 3.0, 0.0), transport(T2, 1.0, 1.0)], 0.0)
    (req,) = of(a.on_tick(0.1), DrLeaderRequest)
    assert (req.task, req.dest) == (T2, 0)
    assert req.capacity == pytest.approx(M.work_capacity(2.0, 0.25, math.hypot(1, 1), 0.12))
    assert a.role(T2) == "candidate" and a.allocating and a.commitments == ()
    assert not of(a.on_tick(1.25), DrBidRequest)                        # 1.15 s <= TIME_LEADERSHIP
    out = a.on_tick(1.35)
    assert a.role(T2) == "leader" and of(out, DrBidRequest) and of(out, DrLeaderAlive)
    (c,) = a.commitments
    assert c.task.id == T2 and c.role == "leader" and c.param("load") == 2.0 and c.param("delivery") == (0.0, 0.0)


@pytest.mark.parametrize("other, capacity, gives_up", [
    (2, 2.0, True),                # higher capacity
    (2, 0.5, False),               # lower capacity
    (4, 1.0, True),                # equal capacity, higher id
    (2, 1.0, False),               # equal capacity, lower id
])
def test_a_candidate_gives_up_to_a_better_one(other, capacity, gives_up):
    a = agent(3)
    a.add_tasks([transport(T1, 1.4, 0.0)], 0.0)
    (req,) = of(a.on_tick(0.0), DrLeaderRequest)
    a.on_message(DrLeaderRequest(other, 0, T1, req.capacity * capacity), 0.5)
    assert (a.role(T1) is None) == gives_up
    a.on_tick(1.3)
    assert (a.role(T1) == "leader") != gives_up
    if gives_up:                                                      # the other's claim keeps it from asking again
        assert not of(a.on_tick(1.4), DrLeaderRequest)


def test_a_candidate_gives_up_when_the_task_has_a_leader_and_a_leader_answers_requests_at_once():
    a = agent(3)
    a.add_tasks([transport(T1, 1.4, 0.0)], 0.0)
    a.on_tick(0.0)
    a.on_message(DrLeaderAlive(2, 0, T1, 10, 0, 0, 1, 1, 1, (2,)), 0.4)
    assert a.role(T1) is None and not of(a.on_tick(1.3), DrLeaderRequest)   # it has a leader
    b = agent(1)
    b.add_tasks([transport(T1, 1.4, 0.0)], 0.0)
    now, _ = elect(b, T1)
    b.on_tick(now + 0.1)
    b.on_message(DrLeaderRequest(5, 0, T1, 9.0), now + 0.2)          # a late request, even a better one
    (alive,) = of(b.on_tick(now + 0.25), DrLeaderAlive)
    assert alive.task == T1 and b.role(T1) == "leader"


# ------------------------------------------------------------------------------------------------ Alg. 2
def _bids(a, rid, now, bids):
    for robot, cap, dist in bids:
        a.on_message(DrBid(robot, 1, T1, rid, cap, dist), now)


def test_the_leader_adds_bidders_by_capacity_until_eq8_holds_and_awards_the_expected_utility():
    a = agent(1, pos=(1.4, 0.0), strategy="NM_NI")
    a.add_tasks([transport(T1, 1.4, 0.0, weight=30.0, deadline=80.0, u_max=70.0)], 0.0)
    now, rid = elect(a, T1)
    # 4 bids the most; 2 and 3 tie on capacity and 3 is nearer; leader + 4 + 3 meet eq. 8, leader + 4 do not
    _bids(a, rid, now + 0.1, [(2, WC, 3.0), (3, WC, 1.0), (4, 1.2 * WC, 5.0)])
    assert not of(a.on_tick(now + 1.0), DrAward)                 # still collecting
    out = a.on_tick(now + 1.25)
    awards = of(out, DrAward)
    assert sorted(m.dest for m in awards) == [3, 4]
    finish, meets = a.lead.predict([WC, 1.2 * WC, WC], now + 1.25)
    assert meets and finish < 80.0 and {m.value for m in awards} == {70.0}
    assert not a.lead.predict([WC, 1.2 * WC], now + 1.25)[1]
    assert a.leader_view(T1).pending == (3, 4) and a.leader_view(T1).members == (1,)


def test_every_bidder_is_awarded_when_the_deadline_cannot_be_met_and_greedy_awards_all():
    for options, weight, want in [({"auction": "dr"}, 300.0, [2, 3, 4]), ({"auction": "greedy"}, 5.0, [2, 3, 4]),
                                  ({"auction": "dr"}, 5.0, [])]:
        a = agent(1, pos=(1.4, 0.0), strategy="NM_NI", **options)
        a.add_tasks([transport(T1, 1.4, 0.0, weight=weight, deadline=80.0, u_max=50.0)], 0.0)
        now, rid = elect(a, T1)
        _bids(a, rid, now + 0.1, [(2, WC, 3.0), (3, WC, 1.0), (4, WC, 5.0)])
        awards = of(a.on_tick(now + 1.25), DrAward)
        assert sorted(m.dest for m in awards) == want, options
        if weight == 300.0:
            assert awards[0].value == pytest.approx(M.utility_soft(a.lead.predict([WC] * 4, now + 1.25)[0], 80, 50))


def test_late_fastest_awards_a_late_task_only_the_bidders_that_bring_its_finish_forward():
    """With interference growing steeply (I(n) = 0.8 n^2 WC / 4 here), the 3rd and 4th robots make the group slower:
    ``late: fastest`` stops at the fastest group; ``late: all`` (the paper) awards every bidder."""
    class Steep(InterferenceModel):
        def predict(self, n, d):
            return 0.2 * n * n * WC if n > 1 else 0.0

    for late, want in [("fastest", [3]), ("all", [2, 3, 4])]:
        a = agent(1, pos=(1.4, 0.0), strategy="NM_I", late=late)
        a.model = Steep()                        # (set_model would copy it into a plain model)
        a.add_tasks([transport(T1, 1.4, 0.0, weight=300.0, deadline=80.0, u_max=50.0)], 0.0)
        now, rid = elect(a, T1)
        _bids(a, rid, now + 0.1, [(2, WC, 3.0), (3, WC, 1.0), (4, WC, 5.0)])
        awards = of(a.on_tick(now + 1.25), DrAward)
        assert sorted(m.dest for m in awards) == want, late


def _leader_with_awards(**options):
    a = agent(1, pos=(1.4, 0.0), strategy="NM_NI", **options)
    a.add_tasks([transport(T1, 1.4, 0.0, weight=30.0, deadline=80.0)], 0.0)
    now, rid = elect(a, T1)
    _bids(a, rid, now + 0.1, [(3, WC, 1.0), (4, 1.2 * WC, 5.0)])
    a.on_tick(now + 1.25)
    return a, now + 1.25, rid


def test_robots_join_on_robot_alive_silent_ones_are_reawarded_then_dropped_and_a_late_one_still_joins():
    a, t, rid = _leader_with_awards()
    a.on_message(DrRobotAlive(3, 1, T1, 0, 0, 0, 0, 0), t + 0.3)
    assert a.leader_view(T1).members == (1, 3) and a.leader_view(T1).pending == (4,)
    resent = of(a.on_tick(t + 0.7), DrAward)                        # after TIME_BID_ACCEPTED, to the silent one
    assert [m.dest for m in resent] == [4]
    a.on_tick(t + a.o.award_wait + 0.05)
    assert a.leader_view(T1).pending == () and a.leader_view(T1).members == (1, 3)
    ev = [e for e in a.pop_events() if e.what == AWARDED]
    assert ev[-1].robots == (1, 3)
    a.on_message(DrRobotAlive(4, 1, T1, 0, 0, 0, 0, 0), t + 2.0)    # its confirmation was late: the award stood
    assert a.leader_view(T1).members == (1, 3, 4)
    out = a.on_message(DrRobotAlive(5, 1, T1, 0, 0, 0, 0, 0), t + 2.0)   # never awarded
    assert out == [DrExitLeader(1, 5, T1, NOT_MEMBER)]


def test_a_refusal_drops_the_award_and_the_leader_auctions_again_while_a_peer_is_idle():
    a, t, rid = _leader_with_awards()
    a.on_message(DrRobotAlive(3, 1, T1, 0, 0, 0, 0, 0), t + 0.3)
    a.on_message(DrRefuse(4, 1, T1, rid), t + 0.4)
    assert a.leader_view(T1).pending == () and not a.leader_view(T1).meets_deadline
    assert not of(a.on_tick(t + 1.0), DrBidRequest)                 # TIME_AUCTION not over
    assert not of(a.on_tick(t + 1.7), DrBidRequest)                 # nobody idle
    a.on_message(idle(5, t + 1.8), t + 1.8)
    (again,) = of(a.on_tick(t + 3.0), DrBidRequest)
    assert again.round != rid


def test_a_silent_member_is_dropped_after_member_timeout_and_eq8_failing_reopens_the_auction():
    a, t, rid = _leader_with_awards()
    for r in (3, 4):
        a.on_message(DrRobotAlive(r, 1, T1, 0, 0, 0, 0, 0), t + 0.3)
    assert a.leader_view(T1).meets_deadline
    a.on_message(idle(5, t + 1.0), t + 1.0)
    k = t + 0.3
    while k + 1.2 < t + 0.3 + a.o.member_timeout:       # 3 keeps alive, 4 is silent
        k += 1.2
        a.on_message(DrRobotAlive(3, 1, T1, 0, 0, 0, 0, 0), k)
        a.on_message(idle(5, k), k)
        assert not of(a.on_tick(k), DrBidRequest)
    out = []
    while not out and k < t + 7:
        k += 0.1
        out = of(a.on_tick(k), DrBidRequest)
    assert a.leader_view(T1).members == (1, 3) and out
    assert k - (t + 0.3) == pytest.approx(a.o.member_timeout, abs=0.25)


def test_a_dropped_member_leaves_the_announced_group_at_once_with_no_round_to_settle():
    """The group a ground station hears ("awarded to") is told the drop, even when no new round follows."""
    a, t, rid = _leader_with_awards()
    for r in (3, 4):
        a.on_message(DrRobotAlive(r, 1, T1, 0, 0, 0, 0, 0), t + 0.3)
    assert [e.robots for e in a.pop_events() if e.what == AWARDED] == [(1, 3, 4)]
    a.on_peer_lost(4, t + 1.0)
    assert not of(a.on_tick(t + 1.1), DrBidRequest)                 # nobody idle: no round, nothing settles
    assert [e.robots for e in a.pop_events() if e.what == AWARDED] == [(1, 3)]


# ------------------------------------------------------------------------------------------------ Alg. 3
def _free_robot(**options):
    a = agent(2, pos=(0.0, 0.0), **options)
    a.add_tasks([transport(T1, 1.0, 0.0), transport(T2, 2.0, 0.0), transport(T2 + 1, 1.0, 1.0)], 0.0)
    for t, leader in ((T1, 1), (T2, 4), (T2 + 1, 5)):   # every task has a leader: the robot does not ask to lead
        a.on_message(DrLeaderAlive(leader, 0, t, 10, 0, 0, 1, 1, 1, (leader,)), 0.0)
    assert not of(a.on_tick(0.05), DrLeaderRequest)
    return a


def test_dr_robots_collect_awards_for_time_bid_accepted_and_join_the_greatest_bid():
    a = _free_robot()
    assert a.on_message(DrAward(1, 2, T1, 7, 50.0), 1.0) == []
    assert a.allocating
    (bid,) = a.on_message(DrBidRequest(5, 0, T2 + 1, 9), 1.1)      # still bids while it waits
    assert isinstance(bid, DrBid) and bid.dest == 5
    a.on_message(DrAward(4, 2, T2, 3, 80.0), 1.2)
    assert a.on_tick(1.55) == [] and a.membership is None
    out = a.on_tick(1.65)
    assert of(out, DrRobotAlive)[0].dest == 4 and [m.dest for m in of(out, DrRefuse)] == [1]
    assert a.role(T2) == "member" and a.commitments[0].role == "member"
    assert of(a.on_message(DrAward(5, 2, T2 + 1, 9, 99.0), 1.7), DrRefuse)      # late: refused
    assert a.on_message(DrBidRequest(5, 0, T2 + 1, 10), 1.8) == []               # a member does not bid


@pytest.mark.parametrize("awards, best", [
    ([(1, T1, 50.0), (5, T2 + 1, 50.0)], 1),       # equal values: the nearer object (T1 at 1 m, T2+1 at 1.41 m)
    ([(5, T2 + 1, 50.0), (4, T2, 50.0)], 5),
    ([(4, T2, 10.0), (1, T1, 9.0)], 4),            # the value first
])
def test_award_ties_go_to_the_nearest_object_then_the_lower_leader(awards, best):
    a = _free_robot()
    for leader, task, value in awards:
        a.on_message(DrAward(leader, 2, task, 1, value), 1.0)
    out = a.on_tick(1.7)
    assert of(out, DrRobotAlive)[0].dest == best


def test_sr_and_greedy_robots_take_the_first_award():
    for auction in ("sr", "greedy"):
        a = _free_robot(auction=auction)
        (ok,) = a.on_message(DrAward(1, 2, T1, 7, 10.0), 1.0)
        assert isinstance(ok, DrRobotAlive) and ok.dest == 1 and a.role(T1) == "member"
        assert of(a.on_message(DrAward(4, 2, T2, 3, 90.0), 1.01), DrRefuse)
        assert of(a.on_message(DrAward(1, 2, T1, 7, 10.0), 1.02), DrRobotAlive)     # a resent one: confirmed again


# ------------------------------------------------------------------------------------------------ books
def test_loads_are_granted_min_wu_left_once_and_the_last_one_gets_what_is_left():
    a = agent(1, pos=(1.4, 0.0))
    a.add_tasks([transport(T1, 1.4, 0.0, weight=5.0)], 0.0)
    now, rid = elect(a, T1)
    out = a.on_message(DrLoad(3, 1, T1, 1, 2.0, 0, 0, 0, 0), now + 1)
    assert out == [DrLedger(1, 0, T1, 3, 1, 2.0, 0, 0.0, 0.0, 3.0)]
    assert a.on_message(DrLoad(3, 1, T1, 1, 2.0, 0, 0, 0, 0), now + 1.5) == out      # a resend: same grant
    a.on_progress(Progress(T1, "loaded", now + 2, data={"wu": 2.0}), now + 2)       # the leader's own load
    assert a.leader_view(T1).left == pytest.approx(1.0)
    (e,) = a.on_message(DrLoad(4, 1, T1, 1, 2.0, 0, 0, 0, 0), now + 3)
    assert (e.taken, e.left) == (1.0, 0.0)
    (e,) = a.on_message(DrLoad(5, 1, T1, 1, 2.0, 0, 0, 0, 0), now + 3)
    assert (e.taken, e.left) == (0.0, 0.0)                                         # exhausted
    assert a.leader_view(T1).on_the_way == pytest.approx(5.0)


def test_a_member_reports_in_order_resends_until_acknowledged_and_leaves_when_nothing_is_left():
    a = _free_robot(auction="sr")
    a.on_message(DrAward(1, 2, T1, 7, 10.0), 1.0)
    (load,) = of(a.on_progress(Progress(T1, "loaded", 2.0, data={"wu": 2.0}), 2.0), DrLoad)
    assert (load.dest, load.seq, load.wu) == (1, 1, 2.0)
    assert of(a.on_tick(2.3), DrLoad) == [] and of(a.on_tick(2.55), DrLoad)      # resent every report_resend
    a.on_progress(Progress(T1, "delivered", 3.0, data={"wu": 2.0}), 3.0)            # unloaded before the grant came
    assert not of(a.on_tick(3.0), DrDeliver)
    a.on_message(DrLedger(1, 0, T1, 2, 1, 1.5, 0, 0, 0, 0.0), 3.1)                  # granted 1.5 wu; nothing left
    (deliver,) = of(a.on_tick(3.2), DrDeliver)
    assert (deliver.seq, deliver.wu, deliver.delivered) == (1, 1.5, 1.5)
    assert a.role(T1) is None and a.commitments == ()                               # nothing left, nothing on board
    a.on_message(DrLedger(1, 0, T1, 2, 1, 1.5, 1, 1.5, 0, 0.0), 3.3)
    assert not of(a.on_tick(4.0), DrDeliver) and a.accounts[T1].delivered == 1.5


def test_a_zero_grant_releases_the_member_and_the_leader_releases_members_with_nothing_to_fetch():
    a = _free_robot(auction="sr")
    a.on_message(DrAward(1, 2, T1, 7, 10.0), 1.0)
    a.on_progress(Progress(T1, "loaded", 2.0, data={"wu": 2.0}), 2.0)
    a.on_tick(2.0)
    a.on_message(DrLedger(1, 0, T1, 2, 1, 0.0, 0, 0, 0, 0.0), 2.1)
    assert a.role(T1) is None and a.commitments == ()
    b = agent(1, pos=(1.4, 0.0), auction="greedy")
    b.add_tasks([transport(T1, 1.4, 0.0, weight=2.0)], 0.0)
    now, rid = elect(b, T1)
    _bids(b, rid, now + 0.1, [(3, WC, 1.0)])
    b.on_tick(now + 1.25)
    b.on_message(DrRobotAlive(3, 1, T1, 0, 0, 0, 0, 0), now + 1.3)
    b.on_progress(Progress(T1, "loaded", now + 2, data={"wu": 2.0}), now + 2)       # the leader takes it all
    out = b.on_tick(now + 2.1)
    assert DrExitLeader(1, 3, T1, EXHAUSTED) in out
    assert b.role(T1) == "leader" and b.commitments[0].role == "leader"           # it carries the last load


def test_the_task_is_done_when_all_is_delivered_and_the_online_sample_goes_to_all():
    a = agent(1, pos=(1.4, 0.0), online=True)
    a.add_tasks([transport(T1, 1.4, 0.0, weight=4.0, deadline=100.0)], 0.0)
    now, rid = elect(a, T1)
    a.on_tick(now + 1.25)
    a.on_message(DrLoad(3, 1, T1, 1, 2.0, 0, 0, 0, 0), now + 2)
    a.on_progress(Progress(T1, "loaded", now + 2, data={"wu": 2.0}), now + 2)
    a.on_progress(Progress(T1, "delivered", now + 9, data={"wu": 2.0}), now + 9)
    assert a.role(T1) == "leader" and not [e for e in a.pop_events() if e.what == DONE]
    a.on_message(DrDeliver(3, 1, T1, 1, 2.0, 1, 2.0, 2.0, 0.0), now + 10)
    out = a.on_tick(now + 10.05)
    (ev,) = [e for e in a.pop_events() if e.what == DONE]
    assert ev.task == T1 and ev.robots == (1, 3)
    assert DrExitLeader(1, 0, T1, FINISHED) in out
    (sample,) = of(out, DrSvrSample)
    fin = a.finished[T1]
    duration = fin.finished - fin.started
    assert fin.delivered == 4.0 and fin.started == pytest.approx(now)
    assert sample.n == pytest.approx(fin.mean_group) and sample.d == pytest.approx(1.4)
    assert sample.interference == pytest.approx(fin.mean_group * WC - 4.0 / duration)
    assert a.model.samples[-1] == (sample.n, sample.d, sample.interference)
    assert a.role(T1) is None


# ------------------------------------------------------------------------------------------------ §5.5
def test_of_two_leaders_the_lower_id_yields_and_tells_its_group():
    a = agent(3)
    a.add_tasks([transport(T1, 1.4, 0.0)], 0.0)
    t, rid = elect(a, T1)
    a.on_message(DrLeaderAlive(2, 0, T1, 30, 0, 0, 1, 1, 1, (2,)), t + 0.5)     # lower id: it yields to me
    assert a.role(T1) == "leader" and of(a.on_tick(t + 0.55), DrLeaderAlive)
    out = a.on_message(DrLeaderAlive(5, 0, T1, 30, 0, 0, 1, 1, 1, (5,)), t + 0.6)
    assert out == [DrExitLeader(3, 0, T1, YIELD)] and a.role(T1) is None
    assert [e.what for e in a.pop_events()][-1] == RELEASED


def test_a_bid_request_shows_a_leader_as_leader_alive_does():
    """Only a leader of the task auctions it: a candidate that hears another's BID_REQUEST gives up (and bids),
    and of two leaders the lower id yields on it too.  With 10 % loss two candidates both became leaders and the
    lower one missed every LEADER_ALIVE of the other for 3.8 s, though it had heard its BID_REQUEST."""
    a = agent(3)
    a.add_tasks([transport(T1, 1.4, 0.0)], 0.0)
    a.on_tick(0.0)
    assert a.role(T1) == "candidate"
    (bid,) = of(a.on_message(DrBidRequest(5, 0, T1, 5 * 65536 + 1), 0.4), DrBid)
    assert a.role(T1) is None and bid.dest == 5 and not of(a.on_tick(1.3), DrLeaderRequest)
    b = agent(3)
    b.add_tasks([transport(T1, 1.4, 0.0)], 0.0)
    t, _ = elect(b, T1)
    assert b.on_message(DrBidRequest(2, 0, T1, 2 * 65536 + 1), t + 0.5) == []     # lower id: it yields to me
    assert b.role(T1) == "leader" and of(b.on_tick(t + 0.55), DrLeaderAlive)
    assert b.on_message(DrBidRequest(5, 0, T1, 5 * 65536 + 1), t + 0.6) == [DrExitLeader(3, 0, T1, YIELD)]
    assert b.role(T1) is None


def _member(leader=1, **options):
    a = _free_robot(auction="sr", **options)
    a.on_message(DrAward(leader, 2, T1, 7, 10.0), 1.0)
    return a


def test_a_member_leaves_a_silent_leader_and_keeps_its_load_for_the_next_leader():
    a = _member()
    a.on_progress(Progress(T1, "loaded", 1.5, data={"wu": 2.0}), 1.5)
    a.on_tick(1.5)
    a.on_message(DrLedger(1, 0, T1, 2, 1, 2.0, 0, 0, 0, 8.0), 1.6)                  # granted
    t = 1.6
    while a.role(T1) == "member":
        t += 0.1
        a.on_tick(t)
    assert t - 1.6 == pytest.approx(a.o.leader_timeout, abs=0.15)
    assert a.role(T1) == "carrier" and a.commitments[0].role == "carrier"
    a.on_progress(Progress(T1, "delivered", t + 1, data={"wu": 2.0}), t + 1)
    assert a.role(T1) is None and a.commitments == ()
    assert not of(a.on_tick(t + 1.1), DrDeliver)                                   # nobody leads T1: it waits
    a.on_message(DrLeaderAlive(3, 0, T1, 8, 2, 0, 9, 9, 9, (3,)), t + 2)
    (d,) = of(a.on_tick(t + 2.05), DrDeliver)
    assert d.dest == 3 and d.wu == 2.0


@pytest.mark.parametrize("carrier_leads", [False, True])
def test_a_carrier_asks_to_lead_its_own_task_only_with_carrier_leads(carrier_leads):
    """§5.5.2: a free robot takes a leaderless task over, so the dead leader's member that still has a load on
    board waits until it has delivered it (17.6 s to a new leader in SITL at 10 % loss, seed 8).  With
    ``carrier_leads`` it asks at once, for the task of its load only, and leads it with the load on board."""
    a = _member(carrier_leads=carrier_leads)
    a.on_progress(Progress(T1, "loaded", 1.5, data={"wu": 2.0}), 1.5)
    a.on_tick(1.5)
    a.on_message(DrLedger(1, 0, T1, 2, 1, 2.0, 0, 0, 0, 8.0), 1.6)                  # granted
    t, asked = 1.6, []
    while not asked and t < 12.0:
        t += 0.1
        asked += of(a.on_tick(t), DrLeaderRequest)
    if not carrier_leads:
        assert a.role(T1) == "carrier" and asked == []
        return
    assert [r.task for r in asked] == [T1] and a.request.task == T1 and a.carrying == T1
    assert t - 1.6 == pytest.approx(a.o.leader_timeout, abs=0.25)                   # asked as soon as it left
    while a.role(T1) != "leader" and t < 12.0:
        t += 0.1
        a.on_tick(t)
    assert a.role(T1) == "leader" and a.carrying is None
    (c,) = a.commitments
    assert c.role == "leader" and c.task_id == T1                                    # the load is the leader's now
    a.on_progress(Progress(T1, "delivered", t + 1, data={"wu": 2.0}), t + 1)
    assert a.leader_view(T1).delivered == pytest.approx(2.0) and a.leader_view(T1).on_the_way == pytest.approx(0.0)


def test_exit_leader_and_a_lost_leader_free_the_member():
    a = _member()
    a.on_message(DrExitLeader(4, 0, T1, YIELD), 1.2)                                # not its leader
    assert a.role(T1) == "member"
    a.on_message(DrExitLeader(1, 0, T1, YIELD), 1.3)
    assert a.role(T1) is None
    b = _member()
    b.on_peer_lost(1, 1.5)
    assert b.role(T1) is None


def test_a_leader_gives_back_the_load_of_a_robot_silent_for_member_timeout():
    a, t, rid = _leader_with_awards()
    a.on_message(DrRobotAlive(3, 1, T1, 0, 0, 0, 0, 0), t + 0.3)
    a.on_message(DrLoad(3, 1, T1, 1, 2.0, 0, 0, 0, 0), t + 1.0)
    assert a.leader_view(T1).left == 28.0
    k = t + 1.0
    while a.leader_view(T1).left < 30.0 and k < t + 10:
        k += 0.1
        a.on_tick(k)
    assert a.leader_view(T1).left == 30.0 and k - (t + 1.0) == pytest.approx(a.o.member_timeout, abs=0.15)


def test_a_disarmed_member_leaves_and_puts_its_load_back():
    a = _member()
    a.on_progress(Progress(T1, "loaded", 1.5, data={"wu": 2.0}), 1.5)
    a.on_tick(1.5)
    a.on_message(DrLedger(1, 0, T1, 2, 1, 2.0, 0, 0, 0, 8.0), 1.6)
    out = a.set_available(False, 2.0)
    assert DrRefuse(2, 1, T1, 0) in out and a.role(T1) is None and a.commitments == ()
    (d,) = of(a.on_tick(2.1) + out, DrDeliver)
    assert (d.wu, d.returned) == (0.0, 2.0)
    assert a.on_message(DrAward(4, 2, T2, 1, 50.0), 2.2)[0] == DrRefuse(2, 4, T2, 1)
    assert not of(a.on_tick(5.0), DrLeaderRequest)


# ------------------------------------------------------------------------------------------------ learning
def test_a_missed_sample_is_asked_for_and_resent_and_the_last_is_repeated():
    a = agent(2, online=True)
    assert a.on_message(DrSvrSample(4, 0, 1, 2.0, 1.4, 0.1), 1.0) == []
    out = a.on_message(DrSvrSample(4, 0, 3, 3.0, 1.4, 0.2), 2.0)
    assert out == [DrSampleRequest(2, 4, 2)] and a.model.samples == [(2.0, 1.4, 0.1), (3.0, 1.4, 0.2)]
    assert a.on_message(DrSvrSample(4, 0, 3, 3.0, 1.4, 0.2), 5.0) == []          # asked once per sample_period
    assert len(a.model.samples) == 2                                              # a repeat is learnt once
    assert a.on_message(DrSvrSample(4, 0, 3, 3.0, 1.4, 0.2), 12.5) == [DrSampleRequest(2, 4, 2)]
    a.on_message(DrSvrSample(4, 2, 2, 2.5, 1.4, 0.3), 12.6)
    assert a.model.samples[-1] == (2.5, 1.4, 0.3) and a.on_message(DrSvrSample(4, 0, 3, 3, 1.4, .2), 30) == []
    b = agent(4, online=True)
    b.learning.originate(2.0, 1.4, 0.1, 1.0)
    b.learning.originate(2.5, 1.4, 0.1, 1.1)
    (again,) = b.on_message(DrSampleRequest(2, 4, 1), 3.0)
    assert (again.dest, again.seq, again.n) == (2, 1, 2.0)
    assert b.on_tick(5.0) == [] and of(b.on_tick(11.2), DrSvrSample)[0].seq == 2


def test_samples_are_learnt_only_online():
    a = agent(2, online=False)
    a.on_message(DrSvrSample(4, 0, 1, 2.0, 1.4, 0.1), 1.0)
    assert a.model.samples == []


# ------------------------------------------------------------------------------------------------ config
def test_the_allocation_section_builds_options_and_the_model_path_is_relative_to_the_config(tmp_path):
    from runtime.config.build import ConfigError
    from runtime.config.robot import load_robot
    from runtime.allocation.agent import AgentContext
    from runtime.allocation.dr.family import DrAgent
    from runtime.errors import InputError

    InterferenceModel.from_samples([(1.0, 1.0, 0.0), (4.0, 1.0, 0.2)], search=False).save(tmp_path / "i.json")
    cfg = tmp_path / "robot.yaml"
    cfg.write_text("allocation: {method: dr, auction: sr, strategy: M_I, utility: hard, online: true,\n"
                   "             speed_belief: 0.0667, delivery: [1.0, -2.0], model: i.json, time_auction: 2.5}\n")
    o = load_robot(cfg).allocation
    assert (o.auction, o.strategy, o.utility, o.online, o.delivery, o.time_auction) == ("sr", "M_I", "hard", True,
                                                                                         (1.0, -2.0), 2.5)
    assert o.monitoring and o.interference and o.model_path() == tmp_path / "i.json"
    a = DrAgent(AgentContext(1, (2,), agent().estimator, o))
    assert a.model.samples == [(1.0, 1.0, 0.0), (4.0, 1.0, 0.2)] and a.speed == pytest.approx(0.0667)
    cfg.write_text("allocation: {method: dr, strategy: X}\n")
    with pytest.raises(ConfigError, match="allocation.strategy"):
        load_robot(cfg)
    cfg.write_text("allocation: {method: dr, model: missing.json}\n")
    with pytest.raises(InputError) as exc:
        DrAgent(AgentContext(1, (2,), agent().estimator, load_robot(cfg).allocation))
    assert str(exc.value).startswith(f"{cfg}: allocation.model: ") and "missing.json" in str(exc.value)


def test_speed_belief_is_what_eq5_uses():
    a = agent(1, speed_belief=M.speed_from_paper(0.8))
    a.add_tasks([transport(T1, 1.4, 0.0)], 0.0)
    assert a.capacity(a.world.tasks[T1]) == pytest.approx(0.27 * WC, rel=0.02)
    assert agent(1).capacity(agent(1).world.add(transport(T1, 1.4, 0.0), 0.0)) == pytest.approx(WC)


def test_a_disarmed_leader_tells_its_group_and_the_task_is_free_to_lead_at_once():
    a = agent(3)
    a.add_tasks([transport(T1, 1.4, 0.0)], 0.0)
    t, rid = elect(a, T1)
    (alive,) = of(a.on_tick(t + 0.1) + a.lead._alive(t + 0.1), DrLeaderAlive)
    b = agent(2)
    b.add_tasks([transport(T1, 1.4, 0.0)], 0.0)
    b.on_message(alive, t + 0.1)
    assert not of(b.on_tick(t + 0.2), DrLeaderRequest)            # it has a leader
    out = a.set_available(False, t + 0.3)
    assert out == [DrExitLeader(3, 0, T1, YIELD)] and a.role(T1) is None and a.commitments == ()
    b.on_message(out[0], t + 0.3)
    assert of(b.on_tick(t + 0.4), DrLeaderRequest)                # no leader_timeout to wait


def test_a_leader_of_an_exhausted_object_keeps_the_books_without_recruiting():
    a = agent(3)
    a.add_tasks([transport(T1, 1.4, 0.0, weight=4.0, deadline=1.0)], 0.0)          # late, and all taken
    for robot in (1, 2):
        a.on_message(DrLedger(1, 0, T1, robot, 1, 2.0, 0, 0.0, 0.0, 0.0), 0.1)
    a.on_message(DrExitLeader(1, 0, T1, YIELD), 0.2)
    out = a.on_tick(0.3)
    assert of(out, DrLeaderRequest)
    out = a.on_tick(1.6)
    assert a.role(T1) == "leader" and not of(out, DrBidRequest) and a.commitments == ()
    a.on_message(idle(5, 2.0), 2.0)
    assert not of(a.on_tick(4.0), DrBidRequest)
    for robot in (1, 2):
        a.on_message(DrDeliver(robot, 3, T1, 1, 2.0, 1, 2.0, 2.0, 0.0), 5.0)
    a.on_tick(5.1)                  # all delivered, but it has led for less than three LEADER_ALIVE periods ...
    assert a.role(T1) == "leader" and T1 not in a.finished
    a.on_tick(1.7 + 3 * a.o.leader_alive_period)        # ... in case another leader finishes it: now it does
    assert a.role(T1) is None and a.finished[T1].delivered == 4.0
    assert [e.what for e in a.pop_events()].count(DONE) == 1


def test_a_new_leader_that_hears_another_finish_the_task_says_no_done():
    """With loss a robot can take over a task whose leader lives, as its last load arrives: both see the books
    close.  The older leader says DONE at once; the new one waits three LEADER_ALIVE periods, and another's
    EXIT_LEADER(task done) ends its lead with no DONE of its own (seed 3814 raised DONE twice without this)."""
    a = agent(3)
    a.add_tasks([transport(T1, 1.4, 0.0, weight=4.0, deadline=1.0)], 0.0)
    for robot in (1, 2):
        a.on_message(DrLedger(1, 0, T1, robot, 1, 2.0, 0, 0.0, 0.0, 0.0), 0.1)
    a.on_message(DrExitLeader(1, 0, T1, YIELD), 0.2)
    a.on_tick(0.3)
    a.on_tick(1.6)
    assert a.role(T1) == "leader"
    for robot in (1, 2):
        a.on_message(DrDeliver(robot, 3, T1, 1, 2.0, 1, 2.0, 2.0, 0.0), 2.0)
    a.on_tick(2.1)
    a.on_message(DrExitLeader(4, 0, T1, FINISHED), 2.2)
    a.on_tick(10.0)
    assert a.role(T1) is None and T1 not in a.finished
    assert DONE not in [e.what for e in a.pop_events()]


def test_with_a_delivery_area_distances_run_to_its_edge_and_the_executor_unloads_there():
    """``delivery_reach`` makes D an area: eq. 5 (and the model's input) use the way to its edge, and the
    commitment tells the executor to unload within it; without it D is a point, unloaded within ``reach``."""
    a = agent(1, delivery_reach=1.0)
    info = a.world.add(transport(T1, 2.4, 0.0), 0.0)
    assert info.distance == pytest.approx(1.4) and a.capacity(info) == pytest.approx(WC)
    assert agent(1, delivery_reach=1.0).world.add(transport(T1, 0.5, 0.0), 0.0).distance == 0.0    # inside it
    point = agent(1)
    assert point.world.add(transport(T1, 1.4, 0.0), 0.0).distance == pytest.approx(1.4)
    t, _ = elect(a, T1)
    (c,) = a.commitments
    assert c.param("delivery_reach") == 1.0 and c.param("reach") == a.o.reach
    t, _ = elect(point, T1)
    (c,) = point.commitments
    assert c.param("delivery_reach") == point.o.reach
