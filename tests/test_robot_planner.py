"""A robot's planner: what it drives when the configured planner finds none, how it prices tasks, and which
operator tasks it refuses."""
import logging
import math
from pathlib import Path

from runtime import config as C
from runtime import tasks as T
from runtime.planning.costs import grid_for
from runtime.planning.robot_planner import RobotPlanner, TravelEstimator

BOXES = Path(__file__).resolve().parents[1] / "configs/worlds/boxes_10m.yaml"
START = (-2.0, 0.0, 0.0)
TASKS = [T.Task(1, "goto", T.kind("goto").Goto(2.0, 0.0)), T.Task(2, "goto", T.kind("goto").Goto(-2.0, 3.5))]


def _planner(planner: str, rrt_iterations: int = 20000) -> RobotPlanner:
    cfg = C.from_dict(C.RobotConfig, {"robot": {"id": 3}, "gps": {"enabled": False},
                                      "planning": {"map": str(BOXES), "planner": planner,
                                                   "rrt_iterations": rrt_iterations}})
    return RobotPlanner.from_config(cfg, radius=0.17)


def _estimator(planner: str, rrt_iterations: int = 20000) -> TravelEstimator:
    return TravelEstimator(_planner(planner, rrt_iterations), T.Profile(speed=0.25, radius=0.17), lambda: START)


def test_rrt_miss_drives_the_astar_path_not_a_straight_line_into_the_box(caplog):
    p = _planner("rrt", rrt_iterations=3)      # trees of a few 0.25 m steps cannot reach 4 m away
    goal = (2.0, 0.0)                           # the 1 m box at the origin is in between
    grid = grid_for(p.world, p.inflate)
    assert not grid.segment_free(START[:2], goal)
    with caplog.at_level(logging.WARNING):
        route = p.route(START, goal)
    assert route[0] == START[:2] and route[-1] == goal and len(route) > 2
    assert all(grid.segment_free(a, b) for a, b in zip(route, route[1:]))
    assert (p.stats.plan_fallbacks, p.stats.plan_failures) == (1, 0)
    assert any("rrt found no path to (2.00, 0.00)" in r.getMessage() and "A*" not in r.getMessage()
               and "astar path" in r.getMessage() for r in caplog.records)


def test_no_path_at_all_heads_straight_and_is_counted():
    p = _planner("astar")
    route = p.route(START, (0.0, 0.0))            # the goal is inside the box
    assert route == [(-2.0, 0.0), (0.0, 0.0)]
    assert (p.stats.plan_fallbacks, p.stats.plan_failures) == (0, 1)


def test_a_found_path_is_the_configured_planners():
    p = _planner("rrt")
    p.route(START, (2.0, 0.0))
    assert (p.stats.plan_fallbacks, p.stats.plan_failures) == (0, 0)


def test_rrt_misses_in_bids_are_priced_not_bid_as_cannot():
    """A robot bidding inf for a task it can reach leaves BS and RTMA without a buyer when they resell it
    (found driving 6 robots among 40 % obstacles: one task unallocated, one robot idle)."""
    rrt = _estimator("rrt", rrt_iterations=3)
    astar = _estimator("astar")
    got, want = rrt.estimates(TASKS), astar.estimates(TASKS)
    assert [e.cost for e in got] == [e.cost for e in want]                    # the A* lengths
    assert all(math.isfinite(e.cost) for e in got)
    assert rrt.planner.stats.bid_fallbacks == 2
    fine = _estimator("rrt")
    assert 4.0 < fine.estimates(TASKS)[0].cost < 6.0 and fine.planner.stats.bid_fallbacks == 0


def test_estimates_are_one_search_reused_until_the_robot_moves():
    pose = {"p": START}
    est = TravelEstimator(_planner("astar"), T.Profile(speed=0.5, radius=0.17), lambda: pose["p"])
    calls = []
    real = est.planner.costs
    est.planner.costs = lambda start, points: calls.append(points) or real(start, points)
    first = est.estimates(TASKS)
    assert est.estimates(TASKS) == first and len(calls) == 1
    assert first[0].duration == first[0].cost / 0.5                           # goto: travel at cruise speed
    pose["p"] = (-1.9, 0.0, 0.0)                                              # 0.1 m: still the same row
    est.estimates(TASKS)
    assert len(calls) == 1
    pose["p"] = (-1.5, 0.0, 0.0)                                              # 0.5 m: priced again
    est.estimates(TASKS)
    assert len(calls) == 2
    pose["p"] = None
    assert all(math.isinf(e.cost) for e in est.estimates(TASKS))


def test_operator_tasks_off_the_map_in_a_box_or_out_of_reach_are_refused_naming_why():
    p = _planner("astar")
    assert p.refuse(START, 2.0, 0.0) is None
    assert "off the map" in p.refuse(START, 40.0, 0.0)
    assert "inside an obstacle" in p.refuse(START, 0.0, 0.0)
    assert "not a finite number" in p.refuse(START, math.nan, 0.0)


def _clear_of(route, points, clearance, step=0.02):
    """Every point along the route at least ``clearance`` from every obstacle point (less a cell's rounding)."""
    import numpy as np
    for (ax, ay), (bx, by) in zip(route, route[1:]):
        n = max(2, int(math.hypot(bx - ax, by - ay) / step))
        for t in np.linspace(0, 1, n):
            x, y = ax + t * (bx - ax), ay + t * (by - ay)
            if min(math.hypot(x - ox, y - oy) for ox, oy in points) < clearance - 0.08:
                return False
    return True


def test_a_detour_goes_around_sensed_obstacles_without_a_map():
    p = RobotPlanner(None, "euclid", 0.25, 100, 0)
    blocker = [(-1.0, 0.0), (-1.0, 0.15), (-1.0, -0.15)]          # a robot's front seen by sonar, in the way
    route = p.detour((-2.0, 0.0, 0.0), (1.0, 0.0), blocker, clearance=0.5)
    assert route[0] == (-2.0, 0.0) and route[-1] == (1.0, 0.0) and len(route) > 2
    assert _clear_of(route[1:], blocker, 0.5)
    assert p.stats.detours == 1


def test_a_detour_keeps_to_the_map_and_says_none_when_boxed_in():
    world = C.WorldConfig(size=(6.0, 6.0), walls=True, resolution=0.1, obstacles=())
    p = RobotPlanner(world, "astar", 0.25, 100, 0)
    wall = [(0.0, y / 10) for y in range(-30, 31)]                # sensed points right across the arena
    assert p.detour((-2.0, 0.0, 0.0), (2.0, 0.0), wall, clearance=0.3) is None
    gap = [pt for pt in wall if abs(pt[1]) > 0.8]                 # a gap of 1.6 m in the middle
    route = p.detour((-2.0, 0.0, 0.0), (2.0, 0.0), gap, clearance=0.3)
    assert route is not None and _clear_of(route, gap, 0.3)
    assert all(abs(x) < 3.0 - 0.25 and abs(y) < 3.0 - 0.25 for x, y in route)
