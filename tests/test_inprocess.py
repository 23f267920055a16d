"""The in-process host (runtime/inprocess.py): robot cores on the in-memory bus, moved by a motion, one clock."""
from __future__ import annotations

import math

import pytest

from runtime.inprocess import Discs, FixedAgent, Fleet, Kinematic, Liveness, fixed_method, kinematic, robot_config
from runtime.robot.core import RobotCore
from runtime.robot.ports import BaseFacts
from runtime.tasks import Commitment, Task
from runtime.tasks.goto import Goto

STARTS = {1: (0.0, 0.0, 0.0), 2: (2.0, 0.0, math.pi), 3: (0.0, 2.0, 0.0)}


def test_liveness_loses_a_silent_peer_once_and_a_heard_one_never():
    live = Liveness([2, 3], timeout=3.0)
    live.hear(2, 0.0)
    live.hear(3, 0.0)
    live.hear(9, 0.0)                                    # not a peer: not tracked
    assert live.due(2.9) == [] and 9 not in live.heard
    live.hear(3, 2.9)
    assert live.due(3.5) == [2] and live.due(4.0) == []  # once per silence
    live.hear(2, 4.0)                                    # back: live again, and lost again after a new silence
    assert live.due(6.0) == [3] and live.due(7.5) == [2]


def test_kinematic_motion_drives_exact_arcs_and_clips_speed():
    m = Kinematic({1: (0.0, 0.0, 0.0), 2: (0.0, 0.0, 0.0)}, max_speed=0.5)
    m.command(1, 0.25, 0.0)
    m.command(2, 2.0, math.pi / 2)                       # clipped to 0.5 m/s
    m.advance(1.0)
    (p1, _), (p2, _) = m.sense([1])[1], m.sense([2])[2]
    assert p1 == pytest.approx((0.25, 0.0, 0.0))
    r = 0.5 / (math.pi / 2)                              # a quarter circle of radius v / w
    assert p2 == pytest.approx((r, r, math.pi / 2))
    assert m.driven[2] == pytest.approx(0.5)


def test_discs_never_overlap_when_driven_into_each_other():
    d = Discs({1: (0.0, 0.0, 0.0), 2: (0.6, 0.0, math.pi)}, radius=0.25)
    for _ in range(20):
        d.command(1, 0.5, 0.0)
        d.command(2, 0.5, 0.0)
        d.advance(0.1)
        gap = math.dist(d.poses[0, :2], d.poses[1, :2])
        assert gap >= 0.5 - 1e-9
    assert d.contacts > 0


def test_a_kinematic_fleet_does_its_goto_tasks_with_the_real_executors():
    f = kinematic(STARTS, "auction")
    f.run(0.5)
    ids = f.hand_in(1, [Goto(1.0, 1.0, hold=1.0), Goto(-1.0, 0.5, hold=1.0), Goto(0.5, 2.5, hold=1.0)])
    f.run(120.0, stop=lambda fl: set(fl.done()) == set(ids))
    assert set(f.done()) == set(ids)
    for tid in ids:                                      # each done by the robot that drove there
        (rid,) = f.done()[tid]
        assert math.dist(f.motion.poses[rid][:2], f.task(tid).position) < 0.2
    assert all(h.core.executive.arrived is not None for h in f.robots.values())


def test_a_killed_robot_stops_and_its_peers_lose_it():
    f = kinematic(STARTS, "auction")
    f.run(2.0)
    f.kill(3)
    where = f.motion.poses[3]
    f.run(10.0)
    assert f.live() == [1, 2] and f.motion.poses[3] == where
    assert all(3 in f.robots[r].liveness.lost for r in (1, 2))
    assert all(3 in f.robots[r].core.stats.peers_lost for r in (1, 2))


def test_messages_due_by_the_end_of_a_run_are_delivered():
    f = kinematic(STARTS, "auction", delay=0.01)
    f.run(0.5)
    ids = f.hand_in(1, [Goto(1.0, 1.0)])
    f.run(f.now + 0.1)                                   # one step: the task records arrive within it
    assert all(ids[0] in h.node.table.entries for h in f.robots.values())


def test_the_same_seed_gives_the_same_fleet_and_loss_changes_it():
    def poses(drop):
        f = kinematic(STARTS, "auction", drop=drop, jitter=0.005, seed=3)
        f.run(0.5)
        f.hand_in(1, [Goto(1.0, 1.0), Goto(-1.0, 0.5), Goto(0.5, 2.5)])
        f.run(30.0)
        return {r: tuple(p) for r, p in f.motion.poses.items()}, f.bus.stats.sent
    assert poses(0.2) == poses(0.2)
    assert poses(0.2) != poses(0.0)


def test_fixed_commitments_are_driven_without_talking():
    ids = (1, 2)
    task = Task((1 << 16) | 1, "goto", Goto(1.0, 0.0, hold=None))
    cores = {r: RobotCore(robot_config(r, ids, None), BaseFacts(radius=0.2), method=fixed_method(), base_config=None)
             for r in ids}
    f = Fleet(cores, Kinematic({1: (0.0, 0.0, 0.0), 2: (0.0, 1.0, 0.0)}), period=0.1, bus=False)
    assert isinstance(f.robots[1].agent, FixedAgent)
    f.robots[1].agent.commitments = (Commitment(task),)
    f.run(20.0)
    assert math.dist(f.motion.poses[1][:2], (1.0, 0.0)) < 0.15        # it drove to its given task
    assert f.motion.poses[2] == (0.0, 1.0, 0.0)                      # the other had none and stood
    assert f.bus.stats.sent == 0                                      # nothing was said
