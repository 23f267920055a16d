"""Peers as range readings (runtime/execution/peer_readings.py) and an idle robot without range sensors making
way for a peer by the peers' reports."""
from __future__ import annotations

import logging
import math

import pytest
from hypothesis import given, settings, strategies as st

from runtime.drivers.base import BaseSensors
from runtime.execution.executive import ExecContext, Executive, Tunables
from runtime.execution.peer_readings import readings
from runtime.messages import RobotState
from runtime.fleet.node import FleetNode
from runtime.planning.robot_planner import RobotPlanner


def test_a_peer_ahead_is_three_points_on_its_near_side():
    out = readings((0.0, 0.0, 0.0), {2: (1.0, 0.0, 5.0)}, 5.5, radius=0.2)
    assert len(out) == 3
    bearing, dist = out[0]
    assert bearing == pytest.approx(0.0) and dist == pytest.approx(0.8)           # the point facing us
    for b, d in out[1:]:
        assert 0.8 < d < 1.0 and abs(b) < 0.25                                     # both flanks, nearer than its centre


def test_bearings_are_in_the_robot_frame():
    (b, d), *_ = readings((1.0, 1.0, math.pi / 2), {2: (1.0, 2.0, 0.0)}, 0.0, radius=0.2)   # ahead of a robot facing north
    assert b == pytest.approx(0.0, abs=1e-12) and d == pytest.approx(0.8)
    (b, _), *_ = readings((0.0, 0.0, 0.0), {2: (0.0, -1.0, 0.0)}, 0.0, radius=0.2)
    assert b == pytest.approx(-math.pi / 2)                                        # on the right


def test_old_far_and_broken_reports_are_left_out():
    peers = {2: (1.0, 0.0, 0.0), 3: (9.0, 0.0, 10.0), 4: (math.nan, 0.0, 10.0), 5: (0.5, 0.5, 10.0),
             6: (0.0, 0.0, 10.0)}                                                   # 6: on top of us
    out = readings((0.0, 0.0, 0.0), peers, 10.0, radius=0.2)
    assert len(out) == 3 and all(d < 0.7 for _, d in out)                          # only robot 5
    assert readings((0.0, 0.0, 0.0), {2: (1.0, 0.0, 11.0)}, 10.0, radius=0.2) == ()   # a report from the future


@settings(max_examples=200, deadline=None)
@given(st.tuples(st.floats(-50, 50), st.floats(-50, 50), st.floats(-10, 10)),
       st.dictionaries(st.integers(1, 250), st.tuples(st.floats(allow_nan=True, allow_infinity=True),
                                                      st.floats(allow_nan=True, allow_infinity=True),
                                                      st.floats(-100, 100)), max_size=8))
def test_any_reports_give_finite_readings_in_range(pose, peers):
    for b, d in readings(pose, peers, 0.0, radius=0.2):
        assert -math.pi <= b <= math.pi and 0.0 <= d <= 2.0 + 0.2 + 1e-9


def test_the_fleet_node_keeps_where_each_peer_said_it_was_until_it_is_lost():
    class Agent:
        commitments = ()

        def on_message(self, msg, now):
            return []

        def on_peer_lost(self, rid, now):
            return []

    node = FleetNode(1, Agent(), peers=[1, 2])
    node.on_message(RobotState(2, 0, 0, (), 1.5, -2.0, 0, node.table.digest), 3.0)
    assert node.positions == {2: (1.5, -2.0, 3.0)}
    node.on_peer_lost(2, 9.0)
    assert node.positions == {}


def test_an_idle_robot_without_ranges_makes_way_for_a_peer_by_its_report():
    ctx = ExecContext(RobotPlanner(None, "euclid", 0.25, 0, 1), Tunables(0.25, 0.3, 2.0, 0.12),
                      logging.getLogger("test"), 0.17)
    ex = Executive(ctx)
    ex.make_way = True
    none = BaseSensors()
    assert ex.step((0.0, 0.0, 0.0), none, 0.0)[0] == (0.0, 0.0)                   # nobody near: stays
    ex.peers = readings((0.0, 0.0, 0.0), {2: (0.45, 0.0, 0.0)}, 0.1, radius=0.17)  # a peer 0.11 m off its front
    v, w = ex.step((0.0, 0.0, 0.0), none, 0.1)[0]
    assert v < 0 and w == 0.0 and ex.made_way == 1
    ex.peers = readings((0.0, 0.0, 0.0), {2: (1.5, 0.0, 0.0)}, 0.2, radius=0.17)
    assert ex.step((0.0, 0.0, 0.0), none, 0.2)[0] == (0.0, 0.0)                   # far enough: stays
