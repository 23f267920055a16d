"""Bid-cost provider: cost matrices for the auctions and the paths robots drive."""
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from runtime.config import Box, WorldConfig
from runtime.errors import InputError
from runtime.planning.astar import cost_table
from runtime.planning.costs import bid_costs, cost_matrix, grid_for, path, plan_route
from runtime.planning.grid import OccupancyGrid, random_obstacle_field
from runtime.planning.smoothing import path_length

WALL = WorldConfig(size=(10.0, 10.0), walls=True, resolution=0.05,
                   obstacles=(Box(center=(0.0, -1.0), size=(0.4, 8.0)),))    # wall from y=-5 to 3


def test_euclid_is_the_straight_line():
    r = [(0, 0), (3, 4)]
    t = [(1, 1), (-2, 0), (3, 0)]
    c = cost_matrix(None, r, t, "euclid")
    assert c.shape == (2, 3)
    assert c == pytest.approx(np.array([[math.sqrt(2), 2, 3], [math.sqrt(13), math.sqrt(41), 4]]))


@settings(max_examples=40, deadline=None)
@given(pts=st.lists(st.tuples(st.floats(-4.5, 4.5), st.floats(-4.5, 4.5)), min_size=2, max_size=6))
def test_astar_on_open_world_equals_euclid_at_any_angle(pts):
    world = WorldConfig(size=(10.0, 10.0), walls=True, resolution=0.1)
    half = len(pts) // 2
    a = cost_matrix(world, pts[:half], pts[half:], "astar")
    assert a == pytest.approx(cost_matrix(world, pts[:half], pts[half:], "euclid"), abs=1e-9)


def test_obstacles_make_costs_at_least_euclid_and_longer_behind_a_wall():
    robots, tasks = [(-3.0, -2.0), (-3.0, 4.0)], [(3.0, -2.0), (-4.0, 0.0)]
    euclid = cost_matrix(WALL, robots, tasks, "euclid")
    a = cost_matrix(WALL, robots, tasks, "astar")
    assert np.all(a >= euclid - 1e-12)
    # Around the wall top (y = 3 + 0.2 + radius) and back down: about 2 * hypot(3, 5.4) = 12.4 m.
    assert a[0, 0] > 12.0 and a[0, 0] < 13.5
    assert a[1, 1] == pytest.approx(euclid[1, 1])               # same side, clear line
    rrt = cost_matrix(WALL, robots, tasks, "rrt", seed=1)
    assert np.all(np.isfinite(rrt)) and np.all(rrt >= euclid - 1e-12)
    assert rrt[0, 0] > 12.0


def test_astar_costs_equal_grid_shortest_paths_when_no_clear_line():
    grid = random_obstacle_field(20.0, 0.1, 0.3, seed=9)
    pts = grid.free_cells(12, seed=9)
    r, t = pts[:6], pts[6:]
    c = cost_matrix(grid, r, t, "astar")
    table = cost_table(grid, [grid.world_to_cell(*p) for p in r], [grid.world_to_cell(*p) for p in t])
    euclid = cost_matrix(grid, r, t, "euclid")
    clear = np.array([[grid.segment_free(tuple(a), tuple(b)) for b in t] for a in r])
    assert np.allclose(c[clear], euclid[clear])
    assert np.allclose(c[~clear], np.maximum(table, euclid)[~clear])
    assert np.all(c <= table + 1e-9)


def test_world_config_grid_is_cached_per_config():
    assert grid_for(WALL) is grid_for(WALL)
    assert grid_for(WALL) is not grid_for(WALL, 0.3)
    other = WorldConfig(size=(10.0, 10.0), walls=True, resolution=0.05)
    assert grid_for(other) is not grid_for(WALL)
    cost_matrix(WALL, [(-3, 0)], [(3, 0)])
    assert ("bits", 8) in grid_for(WALL)._cache                  # move masks are built once per world


def test_unreachable_tasks_cost_inf_and_have_no_path():
    boxed = WorldConfig(size=(10.0, 10.0), walls=True, resolution=0.05, obstacles=(
        Box(center=(3.0, 1.0), size=(3.0, 0.2)), Box(center=(3.0, -1.0), size=(3.0, 0.2)),
        Box(center=(1.6, 0.0), size=(0.2, 2.2)), Box(center=(4.4, 0.0), size=(0.2, 2.2))))
    c = cost_matrix(boxed, [(-3.0, 0.0)], [(3.0, 0.0), (-3.0, 3.0)], "astar")
    assert c[0, 0] == math.inf and c[0, 1] == pytest.approx(3.0)
    assert path(boxed, (-3.0, 0.0), (3.0, 0.0)) is None
    r = cost_matrix(boxed, [(-3.0, 0.0)], [(3.0, 0.0)], "rrt", rrt_iterations=300)
    assert r[0, 0] == math.inf
    outside = cost_matrix(boxed, [(-30.0, 0.0)], [(0.0, 0.0)], "astar")
    assert outside[0, 0] == math.inf


def test_robot_inside_inflated_zone_is_snapped_to_free_space():
    near_wall = (-4.9, 0.0)                    # 0.1 m from the west wall: inside the 0.17 m inflation
    assert not grid_for(WALL).is_free(*near_wall)
    c = cost_matrix(WALL, [near_wall], [(-3.0, 0.0)], "astar")
    assert c[0, 0] == pytest.approx(1.9, abs=0.15)
    p = path(WALL, near_wall, (-3.0, 0.0))
    assert p[0] == near_wall and p[-1] == (-3.0, 0.0)


@pytest.mark.parametrize("planner", ["astar", "rrt"])
def test_path_is_smoothed_collision_free_and_prices_like_the_matrix(planner):
    start, goal = (-3.0, -2.0), (3.0, -2.0)
    p = path(WALL, start, goal, planner, seed=3)
    grid = grid_for(WALL)
    assert p[0] == start and p[-1] == goal
    assert all(grid.segment_free(a, b) for a, b in zip(p, p[1:]))
    assert len(p) <= 6
    if planner == "astar":
        assert path_length(p) <= cost_matrix(WALL, [start], [goal])[0, 0] + 1e-9
        assert path_length(p) >= math.dist(start, goal)


def test_straight_path_when_clear():
    assert path(WALL, (-3.0, -2.0), (-1.0, 2.0)) == [(-3.0, -2.0), (-1.0, 2.0)]
    assert path(None, (0, 0), (1, 1), "euclid") == [(0.0, 0.0), (1.0, 1.0)]


def test_bad_inputs_raise_one_line_errors():
    for bad in (lambda: cost_matrix(WALL, [(0, 0)], [(1, 1)], "dijkstra"),
                lambda: cost_matrix(WALL, [(0, math.nan)], [(1, 1)]),
                lambda: cost_matrix(WALL, [0, 1, 2], [(1, 1)]),
                lambda: cost_matrix("world.yaml", [(0, 0)], [(1, 1)]),
                lambda: path(WALL, (0, 0), (1, 1), "bfs")):
        with pytest.raises(InputError) as exc:
            bad()
        assert "\n" not in str(exc.value)
    assert cost_matrix(WALL, [], [(1, 1)]).shape == (0, 1)
    assert isinstance(grid_for(WALL), OccupancyGrid)


def test_plan_route_takes_the_astar_path_when_rrt_misses():
    """RRT trees too small to get round the wall miss the goal; the robot gets the A* path, not a straight
    line into the wall."""
    start, goal = (-3.0, -2.0), (3.0, -2.0)
    grid = grid_for(WALL)
    route, used = plan_route(WALL, start, goal, planner="rrt", seed=1, rrt_iterations=3)
    assert used == "astar"
    assert route == path(WALL, start, goal, "astar")
    assert route[0] == start and route[-1] == goal and max(y for _, y in route) > 3.0     # round the wall's end
    assert all(grid.segment_free(a, b) for a, b in zip(route, route[1:]))
    route, used = plan_route(WALL, start, goal, planner="rrt", seed=1)
    assert used == "rrt" and route == path(WALL, start, goal, "rrt", seed=1)


def test_plan_route_without_any_path(monkeypatch):
    boxed = WorldConfig(size=(10.0, 10.0), walls=True, resolution=0.05, obstacles=(
        Box(center=(3.0, 1.0), size=(3.0, 0.2)), Box(center=(3.0, -1.0), size=(3.0, 0.2)),
        Box(center=(1.6, 0.0), size=(0.2, 2.2)), Box(center=(4.4, 0.0), size=(0.2, 2.2))))
    trees = _count_trees(monkeypatch)
    for planner in ("astar", "rrt"):
        assert plan_route(boxed, (-3.0, 0.0), (3.0, 0.0), planner=planner, rrt_iterations=50) == (None, "")
    assert len(trees) == 1                       # A* says walled off: no second, 4x bigger tree
    assert plan_route(None, (0, 0), (1, 1), planner="euclid") == ([(0.0, 0.0), (1.0, 1.0)], "euclid")


def test_bid_costs_price_rrt_misses_by_a_second_tree_then_astar(monkeypatch):
    start, tasks = (-3.0, -2.0), [(3.0, -2.0), (-3.0, 0.0)]
    row, missed = bid_costs(WALL, start, tasks, planner="rrt", seed=1, rrt_iterations=3)   # both trees too small
    assert missed == 2 and row == pytest.approx(cost_matrix(WALL, [start], tasks, "astar")[0])
    row, missed = bid_costs(WALL, start, tasks, planner="rrt", seed=1)
    assert missed == 0 and np.array_equal(row, cost_matrix(WALL, [start], tasks, "rrt", seed=1)[0])
    row, missed = bid_costs(WALL, start, tasks, planner="astar", rrt_iterations=3)
    assert missed == 0 and np.array_equal(row, cost_matrix(WALL, [start], tasks, "astar")[0])
    boxed = WorldConfig(size=(10.0, 10.0), walls=True, resolution=0.05, obstacles=(
        Box(center=(3.0, 1.0), size=(3.0, 0.2)), Box(center=(3.0, -1.0), size=(3.0, 0.2)),
        Box(center=(1.6, 0.0), size=(0.2, 2.2)), Box(center=(4.4, 0.0), size=(0.2, 2.2))))
    trees = _count_trees(monkeypatch)
    row, missed = bid_costs(boxed, (-3.0, 0.0), [(3.0, 0.0)], planner="rrt", rrt_iterations=50)
    assert missed == 1 and row[0] == math.inf                # unreachable stays "cannot"
    assert len(trees) == 1                                   # without growing a second tree for it


def _count_trees(monkeypatch) -> list:
    from runtime.planning import costs
    calls, real = [], costs.rrt_multi
    monkeypatch.setattr(costs, "rrt_multi", lambda *a, **k: calls.append(k.get("max_iter")) or real(*a, **k))
    return calls
