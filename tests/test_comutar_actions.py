"""Paper 003 Def. 1: actions and a robot's catalogue from its sensors; the surveillance and avoidance task specs
(mission items, waypoints) and the shared waypoint board (first claim wins)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from runtime.allocation.comutar import actions as A
from runtime.tasks import avoid_obstacles as avoidance, surveillance
from runtime.allocation.comutar.options import ComutarOptions
from runtime.tasks.surveillance import Board, Surveillance
from runtime.config.build import ConfigError, from_dict
from runtime.drivers.arcos import ArcosConfig
from runtime.drivers.create_oi import CreateOIConfig
from runtime.drivers.rplidar import RplidarConfig
from runtime.tasks import Profile


def test_which_actions_a_robot_has_follows_from_its_sensors():
    create = A.catalogue(A.sensors_of(CreateOIConfig()))
    assert create.names == ("survey", "obstacle_avoider", "obstacle_detector")
    assert not create.producing(A.RANGE_DATA)                        # it must borrow range data
    pioneer = A.catalogue(A.sensors_of(ArcosConfig()))
    assert [a.name for a in pioneer.producing(A.RANGE_DATA)] == ["sonar_reader"]
    quiet = A.catalogue(A.sensors_of(ArcosConfig(sonar=False)))
    assert not quiet.producing(A.RANGE_DATA)
    laser = A.catalogue(A.sensors_of(CreateOIConfig(), [RplidarConfig()]))     # a sensors: entry of an rplidar
    assert [a.name for a in laser.producing(A.RANGE_DATA)] == ["laser_reader"]
    assert [a.name for a in laser.accomplishing("avoid_obstacles")] == ["obstacle_avoider"]
    assert A.catalogue(["radar"]).sensors == ()


def test_the_chain_types_connect_reader_to_detector_to_avoider():
    assert A.LASER.outputs == A.DETECTOR.inputs == (A.RANGE_DATA,)
    assert A.DETECTOR.outputs == A.AVOIDER.inputs == (A.OBSTACLE_LIST,)
    assert A.LASER.rate(A.RANGE_DATA) == pytest.approx(0.02896)      # 181 ranges x 2 bytes x 10 Hz
    assert {a.code for a in A.ALL} == set(A.BY_CODE) and len(A.BY_CODE) == len(A.ALL)


def test_the_options_are_a_config_section_with_one_line_errors():
    opts = from_dict(ComutarOptions, {"method": "comutar", "link_capacity": 0.5})
    assert opts.link_capacity == 0.5
    with pytest.raises(ConfigError, match="sensors: expected no such key"):      # a laser is a sensors: entry
        from_dict(ComutarOptions, {"sensors": ["laser"]})
    with pytest.raises(ConfigError, match="auction_timeout"):
        from_dict(ComutarOptions, {"auction_timeout": -1})


def test_the_default_surveillance_region_is_the_digests_9_by_9_grid():
    pts = Surveillance(0, 0).waypoints()
    assert pts.shape == (81, 2)
    assert pts.min() == -8 and pts.max() == 8
    assert sorted(set(np.round(np.diff(np.unique(pts[:, 0])), 9))) == [2.0]
    assert surveillance.count(Surveillance(0, 0)) == 81


def test_a_surveillance_mission_item_round_trips_and_bad_params_say_why():
    spec = Surveillance(1.0, -2.0, 10.0, 6.0, 2.0, 3)
    cmd, params = surveillance.to_item(spec)
    assert cmd in surveillance.COMMANDS and surveillance.from_item(cmd, params, 1.0, -2.0) == spec
    with pytest.raises(ValueError, match="param3"):
        surveillance.from_item(cmd, (10.0, 10.0, 0.0, 0.0), 0, 0)
    with pytest.raises(ValueError, match="at most 200"):
        surveillance.from_item(cmd, (100.0, 100.0, 1.0, 0.0), 0, 0)
    with pytest.raises(ValueError, match="param4"):
        surveillance.from_item(cmd, (10.0, 10.0, 2.0, 1.5), 0, 0)
    est = surveillance.estimate(spec, Profile(0.25, 0.25), lambda x, y: math.hypot(x - 1.0, y + 2.0))
    assert est.cost == pytest.approx(math.sqrt(2)) and est.duration == pytest.approx(math.sqrt(2) / 0.25)   # 6 x 4 grid: none at the centre


def test_an_avoidance_mission_item_round_trips():
    spec = avoidance.AvoidObstacles(robot=3, duration=60.0)
    cmd, params = avoidance.to_item(spec)
    assert avoidance.from_item(cmd, params, 0.0, 0.0) == spec
    with pytest.raises(ValueError, match="param1"):
        avoidance.from_item(cmd, (0.0, 0.0, 0.0, 0.0), 0, 0)


def test_the_first_claim_wins_and_the_later_claimant_moves_on():
    pts = Surveillance(0, 0, 2, 0, 1).waypoints()          # (-1, 0), (0, 0), (1, 0)
    a, b = Board(pts, 1), Board(pts, 2)
    assert a.choose((0.1, 0), now=1.0) and a.target == 1
    assert b.choose((0.2, 0), now=2.0) and b.target == 1      # b has not heard of a's claim yet
    assert b.merge(1, [], a.target, a.claimed_at)             # a claimed first: b gives way
    assert b.target is None and b.choose((0.2, 0), now=2.1) and b.target == 2
    assert not a.merge(2, [], b.target, b.claimed_at) and a.target == 1
    a.visit(1)
    assert a.target is None and b.merge(1, sorted(a.visited), None, 0.0) is False and 1 in b.visited
    assert a.choose((0.0, 0), now=3.0) and a.target == 0      # the last free one
    c = Board(pts, 3)
    c.merge(1, [1], 0, 3.0)
    c.merge(2, [], 2, 2.1)
    assert not c.choose((0, 0), now=4.0) and c.target is None  # everything open is claimed: wait
    c.forget(2)                                                # robot 2 lost: its claim goes
    assert c.choose((0, 0), now=5.0) and c.target == 2


def test_a_claim_moves_only_to_a_waypoint_nearer_by_the_switch_margin():
    pts = np.array([[0.0, 0.0], [3.0, 0.0]])
    b = Board(pts, 1)
    b.choose((2.0, 0.0), 0.0)
    assert b.target == 1
    b.claims[2] = (1, -1.0)                                    # someone claimed waypoint 1 before me
    assert b.merge(2, [], 1, -1.0) and b.target is None
    b.claims.pop(2)
    b.target, b.claimed_at = 0, 1.0
    assert not b.choose((1.6, 0.0), 2.0, switch=0.5)           # 1.6 vs 1.4: not by 0.5
    assert b.choose((2.0, 0.0), 2.0, switch=0.5) and b.target == 1
