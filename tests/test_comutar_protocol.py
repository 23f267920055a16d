"""Paper 003 Alg. 1 as sans-IO agents on the in-memory bus: coalitions of actions across robots, several
commitments per robot, lost messages (awards included), expiring pre-allocations, capacities never exceeded,
unservable tasks reported, and nonsense input counted, never raised."""
from __future__ import annotations

import math
import random

import numpy as np
import pytest
from hypothesis import example, given, settings, strategies as st

from runtime.allocation.agent import AWARDED, FAILED, AgentContext
from runtime.allocation.bus import InMemoryBus
from runtime.allocation.comutar import messages as M
from runtime.allocation.comutar.auctioneer import SERVED
from runtime.tasks.avoid_obstacles import AvoidObstacles
from runtime.allocation.comutar.options import ComutarOptions
from runtime.allocation.comutar.protocol import COMUTAR, VISITED, ComutarAgent
from runtime.tasks.surveillance import Surveillance
from runtime.tasks import Profile, Progress, Task
from runtime.messages import why_invalid


class Est:
    profile = Profile(0.25, 0.25)

    def estimates(self, tasks):
        return []


def fleet(sensors: dict, poses: dict, options=None, **bus):
    """Agents for robots ``sensors`` ({id: sensors}) at ``poses`` on a bus; ``options`` for all, or {id: options}."""
    ids = sorted(sensors)
    per = options if isinstance(options, dict) else {r: options or ComutarOptions() for r in ids}
    agents = {r: ComutarAgent(AgentContext(r, tuple(i for i in ids if i != r), Est(), per[r]), sensors[r])
              for r in ids}
    for r, a in agents.items():
        a.sense(poses[r])
    return agents, InMemoryBus(agents, **bus)


def hand_in(agents, tasks, now=0.0):
    """The fleet table's part: every robot learns every task."""
    for a in agents.values():
        a.add_tasks(tasks, now)


def tid(origin: int, n: int) -> int:
    return origin << 16 | n


def holders(agents, task_id):
    return {r: a.bidder.holdings[task_id] for r, a in agents.items() if task_id in a.bidder.holdings}


def test_a_create_without_sensors_borrows_a_laser_two_robots_away_and_holds_two_tasks():
    """Figs. 6-7: robot 1 (no range sensor) surveys; its obstacle avoidance is a second task whose chain is
    obstacle avoider (robot 1) <- obstacle detector <- laser reader (robot 2)."""
    agents, bus = fleet({1: (), 2: ("laser",)}, {1: (0, 0, 0), 2: (3, 0, math.pi)})
    survey = Task(tid(1, 1), "surveillance", Surveillance(0, 0, 4, 4, 2, robots=1))
    avoid = Task(tid(1, 2), "avoid_obstacles", AvoidObstacles(1))
    hand_in(agents, [survey, avoid])
    bus.run(8.0)
    kinds = {c.task.kind: c for c in agents[1].commitments}
    assert set(kinds) == {"surveillance", "avoid_obstacles"}
    assert kinds["avoid_obstacles"].role == "obstacle_avoider"
    assert dict(kinds["avoid_obstacles"].params)["inputs"] == (("obstacle_list", 2),)
    helper = {c.task_id: c for c in agents[2].commitments}[avoid.id]
    p = dict(helper.params)
    assert set(p["actions"]) == {"obstacle_detector", "laser_reader"}
    assert ("obstacle_list", 1) in p["outputs"] and p["region"][0] == 1
    # the laser's stream is charged to robot 2's link, and the obstacle list to both links
    assert agents[2].ledger.used((2, "link"), 8.0) > 0 and agents[1].ledger.used((1, "link"), 8.0) > 0
    # "robots: 1": exactly one robot surveys
    assert list(holders(agents, survey.id)) in ([1], [2])
    assert {e.what for e in agents[1].pop_events()} == {AWARDED}
    # the consumer keeps its provider told where to look
    assert agents[2].region(avoid.id)[0] == 1


def test_the_cheapest_coalition_wins_a_local_chain_beats_a_remote_one():
    agents, bus = fleet({1: ("sonar",), 2: ("laser",)}, {1: (0, 0, 0), 2: (1, 0, 0)})
    hand_in(agents, [Task(tid(1, 1), "avoid_obstacles", AvoidObstacles(1))])
    bus.run(5.0)
    (c,) = agents[1].commitments
    assert set(dict(c.params)["actions"]) == {"obstacle_avoider", "obstacle_detector", "sonar_reader"}
    assert c.partners == () and not agents[2].commitments
    assert not agents[2].ledger.holds                      # robot 2's pre-allocations expired


def test_a_link_too_narrow_for_the_laser_stream_refuses_that_chain():
    """0.02 Mb/s cannot carry the laser's 0.029 Mb/s: only the chain that sends the obstacle list (0.008) fits."""
    opts = ComutarOptions(link_capacity=0.02)
    agents, bus = fleet({1: (), 2: ("laser",)}, {1: (0, 0, 0), 2: (2, 0, 0)}, opts)
    hand_in(agents, [Task(tid(1, 1), "avoid_obstacles", AvoidObstacles(1))])
    bus.run(5.0)
    (c,) = agents[2].commitments
    assert set(dict(c.params)["actions"]) == {"obstacle_detector", "laser_reader"}
    assert agents[2].bidder.stats.refused > 0           # its laser could not stream to robot 1
    agents, bus = fleet({1: (), 2: ("laser",)}, {1: (0, 0, 0), 2: (2, 0, 0)}, ComutarOptions(link_capacity=0.005))
    hand_in(agents, [Task(tid(1, 1), "avoid_obstacles", AvoidObstacles(1))])
    bus.run(30.0)
    (ev,) = [e for e in agents[1].pop_events() if e.what == FAILED]
    assert "unservable" in ev.detail


def test_a_processor_too_small_for_detector_and_laser_puts_the_detector_on_the_other_robot():
    """Robot 2 gives 0.18 of a core: its laser reader (0.05) and an obstacle detector (0.15) do not fit
    together, so the coalition reads the laser on robot 2 and detects obstacles on robot 1."""
    opts = {1: ComutarOptions(), 2: ComutarOptions(processor=0.18)}
    agents, bus = fleet({1: (), 2: ("laser",)}, {1: (0, 0, 0), 2: (2, 0, 0)}, opts)
    hand_in(agents, [Task(tid(1, 1), "avoid_obstacles", AvoidObstacles(1))])
    bus.run(5.0)
    assert dict(agents[1].commitments[0].params)["actions"] == ("obstacle_avoider", "obstacle_detector")
    assert dict(agents[2].commitments[0].params)["actions"] == ("laser_reader",)
    assert agents[2].bidder.stats.refused > 0
    assert agents[2].ledger.used((2, "processor"), 5.0) == pytest.approx(0.05)


def test_one_reader_serves_several_consumers_for_one_processor_share():
    agents, bus = fleet({1: (), 2: ("laser",), 3: ()}, {1: (0, 0, 0), 2: (2, 0, 0), 3: (0, 2, 0)})
    hand_in(agents, [Task(tid(1, 1), "avoid_obstacles", AvoidObstacles(1)),
                     Task(tid(3, 1), "avoid_obstacles", AvoidObstacles(3))])
    bus.run(10.0)
    assert len(agents[2].commitments) == 2
    assert agents[2].ledger.used((2, "processor"), 10.0) == pytest.approx(0.15 + 0.05)
    assert agents[2].ledger.used((2, "link"), 10.0) > 0


def test_a_task_no_robot_can_do_is_reported_unservable_with_a_reason():
    agents, bus = fleet({1: (), 2: ()}, {1: (0, 0, 0), 2: (1, 1, 0)})
    hand_in(agents, [Task(tid(2, 1), "avoid_obstacles", AvoidObstacles(2))])      # nobody has range data
    bus.run(40.0)
    events = agents[2].pop_events()
    assert [e.what for e in events] == [FAILED] and "avoid_obstacles" in events[0].detail
    assert not agents[1].ledger.holds and not agents[2].ledger.holds


def test_auctions_of_one_auctioneer_are_at_least_delta_t_apart():
    agents, bus = fleet({1: ("sonar",), 2: ("sonar",)}, {1: (0, 0, 0), 2: (1, 1, 0)})
    starts = []
    orig = agents[1].auction._announce

    def spy(job, now):
        starts.append(now)
        return orig(job, now)

    agents[1].auction._announce = spy
    hand_in(agents, [Task(tid(1, n), "avoid_obstacles", AvoidObstacles(1 + n % 2)) for n in range(1, 5)])
    bus.run(15.0)
    assert len(starts) == 4
    assert min(np.diff(starts)) >= ComutarOptions().insert_interval - 1e-9


def test_surveillance_is_served_by_every_robot_and_done_when_every_waypoint_is_visited():
    agents, bus = fleet({1: (), 2: (), 3: ()}, {1: (0, 0, 0), 2: (4, 0, 0), 3: (0, 4, 0)})
    task = Task(tid(1, 1), "surveillance", Surveillance(2, 2, 4, 4, 2))          # 3 x 3 waypoints
    hand_in(agents, [task])
    bus.run(4.0)
    assert set(holders(agents, task.id)) == {1, 2, 3}
    targets = {r: a.survey_target(task.id) for r, a in agents.items()}
    assert len(set(targets.values())) == 3                  # first claim wins: three different waypoints
    # visits reported by execution spread to everyone; the auctioneer ends the task
    points = task.spec.waypoints()
    for i in range(len(points)):
        r = 1 + i % 3
        bus.send(agents[r].on_progress(Progress(task.id, VISITED, bus.now, data={"waypoint": i}), bus.now), bus.now)
        bus.run(bus.now + 0.2)
    bus.run(bus.now + 3.0)
    assert not holders(agents, task.id)
    assert any(e.what == "done" for e in agents[1].events)


def _invariants(agents, now, opts):
    life = opts.auction_timeout + opts.award_grace + 1e-6
    for a in agents.values():
        me = a.robot_id
        assert a.ledger.used((me, "processor"), now, allocated_only=True) <= opts.processor + 1e-9
        assert a.ledger.used((me, "link"), now, allocated_only=True) <= opts.link_capacity + 1e-9
        for hold in a.ledger.preallocated().values():
            assert hold.expires - now <= life                # every pre-allocation ends with its auction


SENSOR_SETS = [(), ("laser",), ("sonar",), ("laser", "sonar")]


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 10_000), drop=st.sampled_from([0.0, 0.1, 0.25, 0.4]), dup=st.sampled_from([0.0, 0.1]))
@example(seed=416, drop=0.4, dup=0.0)          # a holder released three times for lost reports
def test_under_loss_every_task_ends_served_or_unservable_and_resources_stay_within_capacity(seed, drop, dup):
    rnd = random.Random(seed)
    n = rnd.randint(2, 4)
    sensors = {r: rnd.choice(SENSOR_SETS) for r in range(1, n + 1)}
    poses = {r: (rnd.uniform(-5, 5), rnd.uniform(-5, 5), rnd.uniform(-3, 3)) for r in sensors}
    opts = ComutarOptions(processor=rnd.choice([0.3, 0.8]), link_capacity=rnd.choice([0.04, 1.0]))
    agents, bus = fleet(sensors, poses, opts, drop=drop, duplicate=dup, jitter=0.005, seed=seed)
    tasks = [Task(tid(rnd.randint(1, n), 1), "surveillance", Surveillance(0, 0, 4, 4, 2))]
    for r in sensors:
        tasks.append(Task(tid(rnd.randint(1, n), 10 + r), "avoid_obstacles", AvoidObstacles(r)))
    tasks.append(Task(tid(1, 99), "avoid_obstacles", AvoidObstacles(77)))      # no robot 77: unservable
    hand_in(agents, tasks)

    def settled():
        _invariants(agents, bus.now, opts)
        return False

    bus.run(150.0, stop=settled)
    # under loss a holder whose reports are lost member_timeout long is released and its task announced again
    # (silence and loss look alike), so a snapshot may catch a task between two awards: the losses end, and
    # every task must then settle
    bus.drop = bus.duplicate = 0.0
    bus.run(bus.now + 40.0, stop=settled)
    failed = {e.task: e for a in agents.values() for e in a.events if e.what == FAILED}
    assert tid(1, 99) in failed and failed[tid(1, 99)].detail.startswith("unservable")
    for t in tasks:
        job = agents[t.id >> 16].auction.jobs.get(t.id)
        if t.id in failed:
            assert job is None
            continue
        assert job is not None and job.state == SERVED, (t, job and job.state)
        held = holders(agents, t.id)
        assert set(held) == job.robots
        assert all(h.auction == job.auction for h in held.values())
    # nothing stays pre-allocated once the auctions are over
    bus.run(bus.now + opts.auction_timeout + opts.award_grace + 0.2, stop=settled)
    for a in agents.values():
        busy = any(j.state != SERVED for j in a.auction.jobs.values())
        assert busy or not a.ledger.preallocated()


SETTLING = (M.CmAward, M.CmAck, M.CmCancel, M.CmDone, M.CmResign)


def _lossy_run(seed: int, lose: float):
    """Robot 1 (no sensor), 2 (laser) and 3 (sonar): an avoidance task for robot 1 and a surveillance task,
    each copy of a settling message lost with probability ``lose``; run until it must have settled.  Checks
    the invariants throughout, and returns the agents, the bus and the tasks."""
    rnd = random.Random(seed)
    agents, bus = fleet({1: (), 2: ("laser",), 3: ("sonar",)},
                        {r: (rnd.uniform(-3, 3), rnd.uniform(-3, 3), rnd.uniform(-3, 3)) for r in (1, 2, 3)},
                        jitter=0.005, seed=seed)
    send = bus.send

    def lossy(msgs, now):
        send([m for m in msgs if not (isinstance(m, SETTLING) and rnd.random() < lose)], now)

    bus.send = lossy
    opts = ComutarOptions()
    tasks = [Task(tid(rnd.randint(1, 3), 1), "avoid_obstacles", AvoidObstacles(1)),
             Task(tid(rnd.randint(1, 3), 2), "surveillance", Surveillance(0, 0, 4, 4, 2))]
    hand_in(agents, tasks)
    # at 85 % a two-robot award is acknowledged in fewer than half of its rounds, and rounds back off: give it
    # twice as long (1000 seeds: 2 were still between awards at 120 s)
    bus.run(120.0 if lose < 0.8 else 240.0, stop=lambda: _invariants(agents, bus.now, opts) or False)
    for t in tasks:
        job = agents[t.id >> 16].auction.jobs.get(t.id)
        assert job is not None and job.state == SERVED, (t.kind, job and job.state)
        assert set(holders(agents, t.id)) == job.robots and job.robots
        assert 1 in job.robots if t.kind == "avoid_obstacles" else True
    bus.send = send                                         # the losses end: every stray pre-allocation lapses
    bus.run(bus.now + opts.auction_timeout + opts.award_grace + 0.2)
    assert all(not a.ledger.preallocated() for a in agents.values())
    return agents, bus, tasks


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 10_000), lose=st.sampled_from([0.3, 0.6, 0.85]))
@example(seed=9403, lose=0.85)                 # issue 17: reported unservable after 6 announcements
def test_when_awards_and_acks_are_lost_the_task_is_still_served_by_those_who_hold_it(seed, lose):
    """Digest §7: a lost award must not leave a task unserved (TCP hid it; UDP will not).  Only the messages
    that settle an auction are lost here, each copy with probability ``lose``."""
    _lossy_run(seed, lose)


def test_at_85_percent_loss_seed_9403_the_avoidance_task_is_still_served():
    """Issue 17: its awards went unacknowledged round after round (and a holder whose cancel was lost answered
    the next announcement with a report, not a bid); "unservable" must mean that no robot can do it."""
    agents, bus, (avoid, survey) = _lossy_run(9403, 0.85)
    events = [e for a in agents.values() for e in a.events if e.task == avoid.id]
    assert not [e for e in events if e.what == FAILED]
    assert [e for e in events if e.what == "released" and "did not acknowledge" in e.detail]


def test_a_holder_whose_cancel_was_lost_bids_when_its_auctioneer_announces_the_task_anew():
    """Robot 1's acknowledgements, reports and cancels are lost until 3.5 s: its award (auction 2.1) is
    cancelled at 3 s without its knowing, and the task announced again.  It still holds 2.1, but the
    auctioneer of 2.1 announcing the task anew tells it that award is over: it bids at once."""
    agents, bus = fleet({1: ("sonar",), 2: ()}, {1: (0, 0, 0), 2: (2, 0, 0)})
    send = bus.send

    def deaf(msgs, now):
        send([m for m in msgs if not (now < 3.5 and isinstance(m, (M.CmAck, M.CmHold, M.CmCancel)))], now)

    bus.send = deaf
    task = Task(tid(2, 1), "avoid_obstacles", AvoidObstacles(1))
    hand_in(agents, [task])
    bus.run(8.0)
    job = agents[2].auction.jobs[task.id]
    assert [e.what for e in agents[2].events] == ["released", AWARDED]
    assert job.state == SERVED and job.auction == 2 << 16 | 2 and agents[2].auction.stats.announced == 2
    assert agents[1].bidder.holdings[task.id].auction == job.auction


def test_a_round_that_only_a_holder_of_an_older_award_answers_does_not_count_towards_unservable():
    """max_announces 1: one round without a bid would make the task unservable, but robot 1 reports holding
    it under an older auction (of an auctioneer since lost, say): it can serve it once cancelled."""
    agents, bus = fleet({1: (), 2: ("laser",)}, {1: (0, 0, 0), 2: (2, 0, 0)}, ComutarOptions(max_announces=1))
    send = bus.send
    bus.send = lambda msgs, now: send([m for m in msgs if not (now < 1.05 and isinstance(m, M.CmBid))], now)
    task = Task(tid(2, 1), "avoid_obstacles", AvoidObstacles(1))
    hand_in(agents, [task])
    bus.run(0.5)
    bus.send(agents[2].on_message(M.CmHold(1, 2, 3 << 16 | 7, task.id, (1 << 16 | 40,)), bus.now), bus.now)
    bus.run(10.0)
    assert FAILED not in {e.what for e in agents[2].events}
    assert agents[2].auction.jobs[task.id].state == SERVED and set(holders(agents, task.id)) == {1, 2}


def _deaf_robot_2(max_backoff: float, until: float = 60.0):
    """Every award of robot 1's avoidance task (which needs robot 2's laser) is lost until ``until``; robot 1
    also has robot 2's avoidance task to auction.  Returns the agents, the bus, the two tasks and how often
    the first was announced while its awards were lost."""
    opts = ComutarOptions(max_backoff=max_backoff)
    agents, bus = fleet({1: (), 2: ("laser",)}, {1: (0, 0, 0), 2: (2, 0, 0)}, opts)
    mine, other = Task(tid(1, 1), "avoid_obstacles", AvoidObstacles(1)), Task(tid(1, 2), "avoid_obstacles",
                                                                             AvoidObstacles(2))
    announced = []
    send = bus.send

    def deaf(msgs, now):
        announced.extend(m for m in msgs if isinstance(m, M.CmAnnounce) and m.task == mine.id)
        send([m for m in msgs if not (now < until and isinstance(m, M.CmAward) and m.task == mine.id)], now)

    bus.send = deaf
    hand_in(agents, [mine, other])
    bus.run(until, stop=lambda: _invariants(agents, bus.now, opts) or False)
    return agents, bus, (mine, other), len(announced)


def test_awards_lost_for_a_minute_back_off_never_make_the_task_unservable_nor_starve_another():
    agents, bus, (mine, other), n = _deaf_robot_2(ComutarOptions().max_backoff)
    _, _, _, n_flat = _deaf_robot_2(0.0)                   # no back-off: announced again as soon as cancelled
    job = agents[1].auction.jobs[mine.id]
    assert job.state != SERVED and job.unacked >= ComutarOptions().max_announces        # 6 lost in a row (6 of 60 s)
    assert FAILED not in {e.what for a in agents.values() for e in a.events}
    assert agents[1].auction.jobs[other.id].state == SERVED                              # not starved
    assert n_flat >= 15 and n <= n_flat / 2, (n, n_flat)
    bus.run(bus.now + 2 * 2 * ComutarOptions().max_backoff + 10.0)                      # the losses end
    assert agents[1].auction.jobs[mine.id].state == SERVED and set(holders(agents, mine.id)) == {1, 2}


def test_a_lost_award_is_re_sent_until_acknowledged():
    agents, bus = fleet({1: (), 2: ("laser",)}, {1: (0, 0, 0), 2: (2, 0, 0)})
    lost = []
    send = bus.send

    def drop_first_awards(msgs, now):
        keep = []
        for m in msgs:
            if isinstance(m, M.CmAward) and len(lost) < 3:
                lost.append(m)
                continue
            keep.append(m)
        send(keep, now)

    bus.send = drop_first_awards
    hand_in(agents, [Task(tid(1, 1), "avoid_obstacles", AvoidObstacles(1))])
    bus.run(6.0)
    assert lost and agents[1].auction.stats.resent >= 1
    assert set(holders(agents, tid(1, 1))) == {1, 2}


def test_a_robot_that_never_acknowledges_loses_its_award_and_the_task_is_announced_again():
    agents, bus = fleet({1: (), 2: ("laser",)}, {1: (0, 0, 0), 2: (2, 0, 0)})
    send = bus.send
    deaf_until = 4.0                                   # every award to robot 2 is lost for longer than ack_timeout

    def deaf(msgs, now):
        send([m for m in msgs if not (isinstance(m, M.CmAward) and now < deaf_until)], now)

    bus.send = deaf
    task = Task(tid(1, 1), "avoid_obstacles", AvoidObstacles(1))
    hand_in(agents, [task])
    bus.run(deaf_until)
    released = [e for e in agents[1].events if e.what == "released"]
    assert released and "did not acknowledge" in released[0].detail
    assert not agents[2].bidder.holdings and not agents[1].bidder.holdings
    bus.run(15.0)
    assert agents[1].auction.jobs[task.id].state == SERVED and set(holders(agents, task.id)) == {1, 2}
    assert agents[1].auction.stats.announced >= 2


def test_a_lost_provider_sends_the_task_back_to_auction_and_another_provider_takes_it():
    agents, bus = fleet({1: (), 2: ("laser",), 3: ("sonar",)}, {1: (0, 0, 0), 2: (1, 0, 0), 3: (4, 0, 0)})
    task = Task(tid(1, 1), "avoid_obstacles", AvoidObstacles(1))
    hand_in(agents, [task])
    bus.run(5.0)
    first = set(holders(agents, task.id))
    provider = (first - {1}).pop()
    bus.down.add(provider)
    for r, a in agents.items():
        if r != provider:
            bus.send(a.on_peer_lost(provider, bus.now), bus.now)
    bus.run(bus.now + 10.0)
    now_held = set(holders(agents, task.id)) - {provider}
    assert 1 in now_held and now_held - {1} and provider not in now_held
    assert any(e.what == "released" for e in agents[1].events)


def test_the_lowest_live_robot_adopts_the_tasks_of_a_lost_auctioneer_without_reannouncing_held_ones():
    agents, bus = fleet({1: ("sonar",), 2: ("sonar",), 3: ("sonar",)}, {1: (0, 0, 0), 2: (2, 0, 0), 3: (4, 0, 0)})
    held = Task(tid(3, 1), "avoid_obstacles", AvoidObstacles(2))
    hand_in(agents, [held])
    bus.run(4.0)
    assert set(holders(agents, held.id)) == {2}
    fresh = Task(tid(3, 2), "avoid_obstacles", AvoidObstacles(1))
    bus.down.add(3)
    for r in (1, 2):
        agents[r].add_tasks([fresh], bus.now)
        bus.send(agents[r].on_peer_lost(3, bus.now), bus.now)
    bus.run(bus.now + 10.0)
    job = agents[1].auction.jobs[held.id]
    assert job.state == SERVED and job.robots == {2}
    assert agents[2].bidder.holdings[held.id].auction >> 16 == 3            # still the lost auctioneer's award
    assert set(holders(agents, fresh.id)) == {1}


def test_a_disarmed_robot_resigns_and_its_task_is_served_again():
    agents, bus = fleet({1: ("sonar",), 2: ("sonar",)}, {1: (0, 0, 0), 2: (2, 0, 0)})
    task = Task(tid(1, 1), "surveillance", Surveillance(0, 0, 2, 2, 2, robots=1))
    hand_in(agents, [task])
    bus.run(4.0)
    (who,) = holders(agents, task.id)
    bus.send(agents[who].set_available(False, bus.now), bus.now)
    bus.run(bus.now + 8.0)
    assert set(holders(agents, task.id)) == {3 - who}
    assert not agents[who].ledger.holds


def test_the_method_entry_describes_the_agent_for_phase_2():
    assert COMUTAR.name == "comutar" and set(COMUTAR.task_kinds) == {"surveillance", "avoid_obstacles"}
    agent = COMUTAR.make(AgentContext(3, (1, 2), Est(), ComutarOptions(), sensors=("laser",)))
    assert "laser_reader" in agent.catalogue.names
    assert agent.converged and agent.commitments == ()


# ---------------------------------------------------------------------- nonsense input

ids = st.integers(-3, 300)
num = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10, 10**10), st.none(), st.text(max_size=3))
arr = st.one_of(st.tuples(), st.lists(st.integers(-5, 2**33), max_size=60).map(tuple), st.lists(num, max_size=3))
MESSAGES = st.one_of(*[st.builds(cls, *([ids, ids] + [st.one_of(num, arr)] * (len(cls.__dataclass_fields__) - 2)))
                       for cls in M.WIRE_MESSAGES])


@settings(max_examples=300, deadline=None)
@given(st.lists(MESSAGES, min_size=1, max_size=20))
def test_random_and_invalid_messages_never_raise_and_are_counted(msgs):
    agents, bus = fleet({1: (), 2: ("laser",)}, {1: (0, 0, 0), 2: (1, 0, 0)})
    hand_in(agents, [Task(tid(1, 1), "avoid_obstacles", AvoidObstacles(1))])
    a = agents[1]
    now = 0.0
    for m in msgs:
        now += 0.05
        a.on_message(m, now)
        a.on_tick(now)
    taken = sum(1 for m in msgs if why_invalid(m) is None and m.sender == 2 and m.dest in (0, 1))
    assert sum(a.dropped.values()) >= len(msgs) - taken


def test_valid_but_unexpected_messages_are_ignored_and_counted():
    agents, bus = fleet({1: (), 2: ("laser",)}, {1: (0, 0, 0), 2: (1, 0, 0)})
    a = agents[1]
    a.on_message(M.CmAward(2, 1, 2 << 16 | 9, 1 << 16 | 1, (2 << 16 | 1,)), 0.0)      # an award for a task I never saw
    a.on_message(M.CmBid(2, 1, 1 << 16 | 5, 1 << 16 | 1, 1.0, (2 << 16 | 1,)), 0.0)   # a bid for no auction of mine
    a.on_message(M.CmCost(2, 1, 1 << 16 | 5, 1 << 16 | 7, 1.0, 0.0, (2 << 16 | 1,)), 0.0)
    a.on_message(M.CmAnnounce(3, 0, 3 << 16 | 1, 1 << 16 | 1, 1.0, 1), 0.0)          # robot 3 is not a peer
    assert a.auction.stats.late == 1 and a.bidder.stats.ignored == 1 and a.dropped["not a robot of the fleet"] == 1
    assert not a.ledger.holds and not a.commitments


def test_a_stream_carries_a_lasers_discs_nearest_the_consumer_and_a_sonars_nearest_the_provider():
    from runtime.allocation.comutar.messages import MAX_DISCS
    from runtime.allocation.comutar.protocol import stream_order

    ring = np.array([[math.cos(a), math.sin(a), 0.1] for a in np.linspace(0, 2 * math.pi, 16, endpoint=False)])
    ring[:, 0] += np.arange(16) * 0.01               # distinct distances from the provider at (0, 0)
    order = stream_order(ring, (0.0, 0.0), (5.0, 0.0))
    assert list(order) == list(np.argsort(np.hypot(ring[:, 0], ring[:, 1])))      # a sonar's: all go, as before
    scan = np.array([[3 * math.cos(a), 3 * math.sin(a), 0.05] for a in np.radians(np.arange(360))])
    first = stream_order(scan, (0.0, 0.0), (3.0, 0.0))[:MAX_DISCS]
    assert len(scan) > MAX_DISCS and set(first) == set(range(16)) | set(range(344, 360))   # within 16 deg of it
