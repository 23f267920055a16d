"""Simultaneous coalition auctioneer on the in-memory bus: optimal round, greedy leftovers, lost
bids, a robot that never answers, and malformed messages counted, never raised."""
from __future__ import annotations

import math

from hypothesis import given, settings, strategies as st

from runtime.allocation.coalition import winner_determination as wd
from runtime.allocation.bus import InMemoryBus
from runtime.allocation.coalition.wdp_auctioneer import CoalitionBidder, SimultaneousAuctioneer
from runtime.allocation.coalition.wdp_messages import AwardAck, CoalitionBid, TaskDone, TaskOffer
from runtime.allocation.coalition.wdp_model import Problem, TaskBid

AUCTIONEER = 100
# paper 001 Table 2 with tasks 1..3; each bid is sent by its lowest robot id (the coalition leader)
TABLE2 = {1: [((1, 2), 3), ((2, 3), 4), ((3,), 2)],
          2: [((1, 2), 4), ((2,), 5), ((3,), 3)],
          3: [((1, 3), 4), ((2, 3), 4), ((3,), 8)]}


def leader_bids(table):
    def for_robot(rid):
        return lambda task, x, y: [(rs, v) for rs, v in table.get(task, []) if min(rs) == rid]
    return for_robot


def fleet(table, robots, work=None, **kw):
    bids = leader_bids(table)
    auct = SimultaneousAuctioneer(AUCTIONEER, robots, {t: (float(t), 0.0) for t in table}, **kw)
    agents = {AUCTIONEER: auct}
    for r in robots:
        agents[r] = CoalitionBidder(r, bids(r), work or (lambda task: 2.0))
    return auct, agents


def test_round_is_optimal_and_the_leftover_goes_greedily():
    auct, agents = fleet(TABLE2, (1, 2, 3), bid_window=0.5)
    bus = InMemoryBus(agents, delay=0.01)
    bus.run(until=0.6)
    assert auct.round_value == 13.0
    assert {t: a.robots for t, a in auct.awards.items()} == {2: (2,), 3: (3,)}
    assert auct.leftover == {1}
    bus.run(until=10.0, stop=lambda: auct.finished)
    # robot 2 finishes task 2 at ~2.5 s; robots 1 and 2 are free and bid {1,2}=3 for task 1
    assert auct.completed == {2: (2,), 3: (3,), 1: (1, 2)}
    assert auct.stats.greedy_awards == 1 and auct.stats.cancelled == 0
    assert auct.stats.bids == 9 and auct.stats.dropped == 0
    assert sorted(agents[1].done) == [1] and sorted(agents[2].done) == [1, 2]


def test_lost_bids_round_is_optimal_for_the_bids_that_arrived():
    robots = tuple(range(1, 7))
    table = {t: [((r,), float(t + r)) for r in robots] + [((r, r % 6 + 1), float(3 * t + r)) for r in robots]
             for t in range(1, 5)}
    for seed in range(5):
        auct, agents = fleet(table, robots, bid_window=0.5)
        bus = InMemoryBus(agents, delay=0.01, drop=0.3, seed=seed)
        bus.run(until=0.6)
        heard = auct.stats.bids
        assert 0 < heard < sum(len(v) for v in table.values())          # some bids were lost
        got = Problem(robots, tuple(table), tuple(TaskBid(t, rs, v) for (t, rs), v in auct.received.items()))
        assert math.isclose(auct.round_value, wd.solve(got, "milp").value)
        full = Problem(robots, tuple(table), tuple(TaskBid(t, rs, v) for t, bl in table.items() for rs, v in bl))
        assert auct.round_value <= wd.solve(full).value
        awarded = [a.robots for a in auct.awards.values()]
        assert len({r for rs in awarded for r in rs}) == sum(len(rs) for rs in awarded)


def test_robot_that_never_answers_loses_its_award_and_the_task_is_reassigned():
    # robot 5 is down; robot 4 bids the coalition {4, 5} highest for task 1
    table = {1: [((4, 5), 50.0), ((1,), 10.0)], 2: [((2,), 10.0)], 3: [((3,), 10.0)]}
    robots = (1, 2, 3, 4, 5)
    auct, agents = fleet(table, robots, bid_window=0.5, ack_timeout=0.3)
    bus = InMemoryBus(agents, delay=0.01, down={5})
    bus.run(until=0.6)
    assert auct.awards[1].robots == (4, 5)
    bus.run(until=1.0)                                  # ack timeout passed
    assert auct.stats.cancelled == 1 and auct.unresponsive == {5}
    assert auct.awards[1].robots == (1,)                # greedy: the best bid without robot 5
    bus.run(until=10.0, stop=lambda: auct.finished)
    assert auct.completed == {1: (1,), 2: (2,), 3: (3,)}
    assert 1 not in agents[4].jobs and agents[4].done == []


def test_late_duplicate_and_foreign_bids_are_counted():
    auct = SimultaneousAuctioneer(AUCTIONEER, (1, 2), {7: (0.0, 0.0)}, bid_window=1.0)
    offers = auct.on_tick(0.0)
    assert [type(m) for m in offers] == [TaskOffer] and offers[0].deadline == 1.0
    a = offers[0].round
    assert auct.on_message(CoalitionBid(1, AUCTIONEER, a, 7, (1, 2), 4.0), 0.1) == []
    auct.on_message(CoalitionBid(1, AUCTIONEER, a, 7, (2, 1), 6.0), 0.2)          # same coalition
    auct.on_message(CoalitionBid(2, AUCTIONEER, a + 1, 7, (2,), 6.0), 0.2)        # wrong round
    auct.on_message(CoalitionBid(2, AUCTIONEER, a, 8, (2,), 6.0), 0.2)            # unknown task
    auct.on_message(CoalitionBid(1, AUCTIONEER, a, 7, (2,), 6.0), 0.2)            # sender not a member
    auct.on_message(CoalitionBid(2, AUCTIONEER, a, 7, (2,), 1.0), 1.5)            # after the deadline
    auct.on_message(AwardAck(2, AUCTIONEER, a, 7), 0.3)                           # nothing awarded yet
    assert (auct.stats.bids, auct.stats.duplicates, auct.stats.dropped, auct.stats.late, auct.stats.ignored) == (1, 1, 3, 1, 1)
    awards = auct.on_tick(1.0)
    assert {m.dest for m in awards} == {1, 2} and all(m.value == 6.0 for m in awards)


field = st.one_of(st.integers(-3, 300), st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=2), st.none())


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(["bid", "ack", "done", "other"]), field, field,
                          st.one_of(st.lists(field, max_size=4).map(tuple), field), field), max_size=30))
def test_random_messages_never_raise_and_are_counted(msgs):
    auct = SimultaneousAuctioneer(AUCTIONEER, (1, 2, 3), {1: (0, 0), 2: (1, 1)}, bid_window=1.0)
    auct.on_tick(0.0)
    for i, (kind, a, b, robots, value) in enumerate(msgs):
        now = 0.01 * i
        if kind == "bid":
            m = CoalitionBid(a if isinstance(a, int) else 1, AUCTIONEER, 1, b, robots, value)
        elif kind == "ack":
            m = AwardAck(a, AUCTIONEER, 1, b)
        elif kind == "done":
            m = TaskDone(a, AUCTIONEER, 1, b)
        else:
            m = (a, b, robots)
        assert auct.on_message(m, now) == []
    s = auct.stats
    assert s.bids + s.duplicates + s.dropped + s.late + s.ignored == len(msgs)
    out = auct.on_tick(2.0)                                 # the round still closes and solves
    assert auct.phase == "running" and all(m.dest in (1, 2, 3) for m in out)


def test_duplicated_and_reordered_messages_change_nothing():
    robots = tuple(range(1, 7))
    table = {t: [((r,), float(t * r % 7 + 1)) for r in robots] + [((r, r % 6 + 1), float(2 * t + r)) for r in robots]
             for t in range(1, 6)}
    full = Problem(robots, tuple(table), tuple(TaskBid(t, rs, v) for t, bl in table.items() for rs, v in bl))
    auct, agents = fleet(table, robots, bid_window=0.5)
    bus = InMemoryBus(agents, delay=0.02, jitter=0.015, duplicate=0.5, seed=3)
    bus.run(until=20.0, stop=lambda: auct.finished)
    assert bus.stats.duplicated > 0 and auct.stats.duplicates > 0
    assert auct.stats.bids == len(full.bids)
    assert math.isclose(auct.round_value, wd.solve(full, "milp").value)
    assert set(auct.completed) | auct.leftover == set(table) and auct.finished
    done = [t for r in robots for t in agents[r].done]
    assert sorted(done) == sorted(t for t, rs in auct.completed.items() for _ in rs)
