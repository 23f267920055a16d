"""Robots joining a fleet at run time (issue 34, point 3), on the in-process host (runtime/inprocess.py: robot cores
with kinematic motion on the in-memory bus, whose broadcasts reach every robot as a Zenoh router's do).

A fleet of three runs; a fourth robot, whose config names no peers, starts mid-run (``Fleet.join``).  With cores
that take joins (``RobotCore(joins=True)``; by default a core takes them when its transport lets robots join: Zenoh,
not UDP) every robot takes it into its roster at its first message, it takes them into its own, and it bids and does
work in every family: the formation methods, the coalition auction, DR and CoMutaR.  Without joins nothing changes:
the roster is the config's and the joiner's messages are dropped.  Loss of a joiner is the configured peers' rule.
The same over a real Zenoh router: tests/test_transport_zenoh.py."""
from __future__ import annotations

import dataclasses
import math

import pytest

from runtime.allocation import registry
from runtime.allocation.dr.options import DrOptions
from runtime.inprocess import Fleet, kinematic, kinematic_core, robot_config
from runtime.messages import IDLE, RobotState
from runtime.robot.core import Inbox, RobotCore, Sensed
from runtime.robot.ports import BaseFacts
from runtime.tasks.goto import Goto
from runtime.tasks.rendezvous import Rendezvous
from runtime.tasks.surveillance import Surveillance
from tests.dr_util import Watch as DrWatch, delivered, put

THREE = {1: (0.0, 0.0, 0.0), 2: (2.0, 0.0, 0.0), 3: (0.0, 2.0, 0.0)}
JOINER = 4


def join(f: Fleet, method: str, pose, options=None) -> RobotCore:
    """Robot 4 starts now at ``pose``: its config names no peers, its core takes joins."""
    core = kinematic_core(JOINER, (JOINER,), method, options, period=f.period, joins=True)
    f.join(core, pose)
    return core


def seen_by_all(f: Fleet) -> bool:
    """Every robot has the joiner in its roster, and the joiner has every other robot in its own."""
    others = [r for r in f.live() if r != JOINER]
    return all(JOINER in f.robots[r].core.roster for r in others) and f.robots[JOINER].core.roster == set(others)


def settled_twice(f: Fleet) -> list:
    """(time, task, holders) for each task two robots hold that both settled: a formation robot's commitment follows
    its solver's current assignment, so mid-auction a task is held by whoever bids for it last, by design."""
    return [(f.now, t, h) for t, h in f.holders().items() if sum(not f.robots[r].agent.allocating for r in h) > 1]


def run_until_seen(f: Fleet) -> float:
    """Run until :func:`seen_by_all` (at most 5 s); the sim time it took."""
    t0 = f.now
    f.run(f.now + 5.0, stop=seen_by_all)
    assert seen_by_all(f)
    return f.now - t0


@pytest.mark.parametrize("method", ["auction", "bs", "rtma"])
def test_a_robot_that_joins_mid_run_is_seen_bids_and_does_the_task_nearest_it(method):
    f = kinematic(THREE, method, joins=True)
    f.run(2.0)
    join(f, method, (4.0, 4.0, 0.0))
    took = run_until_seen(f)
    assert took <= 3 * f.period + 0.05              # its first state out, delivered, taken at the next cycle
    assert all(f.robots[r].core.stats.peers_joined == [JOINER] for r in THREE)
    assert f.robots[JOINER].core.stats.peers_joined == [1, 2, 3]
    ids = f.hand_in(1, [Goto(4.3, 4.2), Goto(0.2, 0.3)])     # the first nearest the joiner, the second robot 1
    twice = []

    def watch(fl):
        twice.extend(settled_twice(fl))
    f.run(f.now + 40.0, stop=lambda fl: set(fl.done()) == set(ids), observe=watch)
    assert f.done() == {ids[0]: (JOINER,), ids[1]: (1,)}
    assert not twice, twice[:3]
    assert all(f.robots[r].node.dropped["not a robot of the fleet"] == 0 for r in f.live())
    # a joiner that stops is lost by the configured peers' rule: messages and heartbeats silent for the timeout
    f.kill(JOINER)
    t0, timeout = f.now, f.robots[1].core.cfg.comms.heartbeat_timeout
    f.run(f.now + 2 * timeout, stop=lambda fl: all(JOINER in fl.robots[r].core.stats.peers_lost for r in THREE))
    assert all(f.robots[r].core.stats.peers_lost == [JOINER] for r in THREE)
    assert f.now - t0 <= timeout + 2 * f.period


def test_a_lowest_id_robot_joining_mid_round_waits_for_the_round_instead_of_splitting_it():
    """Robot 1 joins while robots 2-4 auction three tasks: it is the lowest id and free, but it never heard that round
    start; it holds off while they say they are allocating, so it starts no round of its own for the tasks they
    trade (it did, before: the two rounds gave one task to robots 1 and 3 at once until the lower id kept it)."""
    f = kinematic({2: (0.0, 0.0, 0.0), 3: (2.0, 0.0, 0.0), 4: (0.0, 2.0, 0.0)}, "auction", joins=True)
    f.run(1.0)
    ids = f.hand_in(2, [Goto(4.3, 4.2), Goto(0.2, 0.3), Goto(2.2, 0.1)])
    f.run(f.now + 0.3)                                    # their round is under way
    core = kinematic_core(1, (1,), "auction", period=f.period, joins=True)
    f.join(core, (4.0, 4.0, 0.0))
    split, twice = [], []

    def watch(fl):
        if any(fl.robots[r].agent.allocating for r in (2, 3, 4)):
            split.extend(rid for rid in core.agent.rounds if rid >> 16 == 1)
        twice.extend(settled_twice(fl))
    f.run(f.now + 60.0, stop=lambda fl: set(fl.done()) == set(ids), observe=watch)
    assert set(f.done()) == set(ids) and all(len(v) == 1 for v in f.done().values())
    assert not split and not twice, (split[:3], twice[:3])
    assert all(1 in f.robots[r].core.roster for r in (2, 3, 4))


def test_without_joins_the_roster_is_the_configs_and_a_newcomer_is_not_taken():
    """Over UDP (the default) a core takes no joins: the newcomer's messages are dropped, it never bids, and the
    task nearest it is done by a robot of the roster."""
    f = kinematic(THREE, "auction")
    f.run(1.0)
    core = kinematic_core(JOINER, (JOINER,), "auction", period=f.period)
    assert not core.joins
    f.join(core, (4.0, 4.0, 0.0))
    ids = f.hand_in(1, [Goto(4.3, 4.2)])
    f.run(f.now + 40.0, stop=lambda fl: set(fl.done()) == set(ids))
    assert set(f.done()) == set(ids) and JOINER not in f.done()[ids[0]]
    assert all(f.robots[r].core.roster == set(THREE) - {r} for r in THREE)
    assert all(f.robots[r].node.dropped["not a robot of the fleet"] > 0 for r in THREE)


def test_a_core_takes_joins_when_its_transport_lets_robots_join():
    m = registry.method("auction")
    cfg = robot_config(1, (1, 2), m.options())
    for transport, joins in (("udp", False), ("zenoh", True)):
        c = dataclasses.replace(cfg, comms=dataclasses.replace(cfg.comms, transport=transport))
        assert RobotCore(c, BaseFacts(radius=0.17), method=m, base_config=None).joins is joins


def test_a_daemons_core_takes_a_join_from_its_inbox_and_sends_the_joiner_its_state():
    """The daemon's path (messages in the cycle's ``Inbox``, not one by one): the joiner is in the roster, its
    heartbeat silence is tracked, its state was taken (not dropped), and it is sent this robot's state at once."""
    core = kinematic_core(1, (1, 2), "auction", joins=True)
    still = Sensed(pose=(0.0, 0.0, 0.0))
    core.step(0.0, still, Inbox(alive=[2]))
    out = core.step(0.1, still, Inbox(peers=[RobotState(JOINER, 0, IDLE, (), 3.0, 4.0, 0, 0)], alive=[2, JOINER]))
    assert core.roster == {2, JOINER} and core.stats.peers_joined == [JOINER]
    assert core.node.positions[JOINER][:2] == (3.0, 4.0) and not core.node.dropped
    assert any(isinstance(m, RobotState) and m.dest == JOINER for m in out.peer_messages())
    assert core.liveness.due(5.0, beats_lost=[JOINER]) == [JOINER]      # lost by the configured peers' rule
    stranger = kinematic_core(1, (1, 2), "auction")                       # UDP's: no joins
    stranger.step(0.0, still, Inbox(peers=[RobotState(JOINER, 0, IDLE, (), 3.0, 4.0, 0, 0)]))
    assert stranger.roster == {2} and stranger.node.dropped["not a robot of the fleet"] == 1


def test_a_task_for_four_robots_is_done_once_a_fourth_joins_a_coalition_fleet():
    """Three configured robots cannot do a rendezvous for four; the joiner is invited from the next call for bids."""
    f = kinematic({1: (-3.0, -2.0), 2: (-3.0, 0.0), 3: (-3.0, 2.0)}, "coalition", joins=True)
    f.run(1.0)
    join(f, "coalition", (3.0, 0.0))
    ids = f.hand_in(1, [Rendezvous(0.0, 0.0, 4, 200.0)])
    clashes = []

    def disjoint(fl):
        for r in fl.live():
            robots = [x for c in fl.robots[r].agent.auction.coalitions.values() for x in c.robots]
            if len(robots) != len(set(robots)):
                clashes.append((fl.now, r))
    f.run(f.now + 120.0, stop=lambda fl: set(fl.done()) == set(ids), observe=disjoint)
    assert set(f.done()[ids[0]]) == {1, 2, 3, JOINER} and not clashes
    assert any(JOINER in rec.robots for rec in f.robots[1].agent.rounds)     # invited to a call for bids


def test_a_dr_joiner_carries_part_of_an_object_and_no_weight_is_lost_or_doubled():
    o = DrOptions(strategy="NM_NI")
    f = kinematic({1: (-2.0, -1.0), 2: (-2.0, 0.0), 3: (-2.0, 1.0)}, "dr", options=o, period=0.1, joins=True)
    f.run(0.5)
    join(f, "dr", (2.0, 0.0), o)
    f.run(1.0)
    ids = put(f, 1, [(2.0, 0.5, 20, 60, 100)])
    watch = DrWatch(o)
    f.run(f.now + 200.0, stop=lambda fl: set(ids) <= set(fl.done()), observe=watch)
    assert not watch.violations, watch.violations[:5]
    assert delivered(f) == {ids[0]: pytest.approx(20.0)}
    assert JOINER in f.done()[ids[0]] and f.robots[JOINER].agent.accounts[ids[0]].delivered > 0


def test_a_comutar_joiner_takes_a_share_of_a_surveillance():
    f = kinematic({1: (-3.0, -3.0, 0.0), 2: (3.0, 3.0, math.pi), 3: (3.0, -3.0, math.pi / 2)}, "comutar", joins=True)
    f.run(0.5)
    join(f, "comutar", (-3.0, 3.0, 0.0))
    f.run(1.0)
    ids = f.hand_in(1, [Surveillance(0.0, 0.0, 4.0, 4.0, 2.0)])
    f.run(f.now + 60.0, stop=lambda fl: set(fl.done()) == set(ids))
    assert set(f.done()[ids[0]]) == {1, 2, 3, JOINER}
