"""RRT (goal-biased, seeded) and shortcut smoothing."""
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from runtime.errors import InputError
from runtime.planning.astar import astar
from runtime.planning.costs import cost_matrix
from runtime.planning.grid import OccupancyGrid, random_obstacle_field
from runtime.planning.rrt import rrt, rrt_cost, rrt_multi, rrt_path
from runtime.planning.smoothing import densify, drop_collinear, path_length, shortcut, smooth

OCTILE_MAX = math.sqrt(4 - 2 * math.sqrt(2))      # worst octile / Euclid ratio, 1.0824 (at 22.5 degrees)


def assert_collision_free(grid, pts):
    for a, b in zip(pts, pts[1:]):
        assert grid.segment_free(a, b), (a, b)


def test_rrt_finds_path_on_open_grid_and_smoothed_length_is_at_least_astar():
    grid = OccupancyGrid.empty(10.0, 0.1)
    start, goal = (-4.0, -3.0), (3.5, 2.2)
    raw = rrt(grid, start, goal, seed=1)
    assert raw is not None and raw[0] == start and raw[-1] == goal
    assert_collision_free(grid, raw)
    sm = rrt_path(grid, start, goal, seed=1)
    assert_collision_free(grid, sm)
    astar_cost = cost_matrix(grid, [start], [goal], "astar")[0, 0]
    assert path_length(sm) >= astar_cost - 1e-9
    assert path_length(sm) == pytest.approx(math.dist(start, goal))        # open: smooths to the line
    assert path_length(raw) >= path_length(sm)


def test_rrt_around_obstacles_is_collision_free_and_no_shorter_than_astar_allows():
    grid = random_obstacle_field(20.0, 0.2, 0.2, seed=4)
    pts = grid.free_cells(8, seed=4)
    for k in range(4):
        s, g = tuple(pts[2 * k]), tuple(pts[2 * k + 1])
        sm = rrt_path(grid, s, g, seed=k)
        assert sm is not None and sm[0] == s and sm[-1] == g
        assert_collision_free(grid, sm)
        grid_len, _ = astar(grid, grid.world_to_cell(*s), grid.world_to_cell(*g))
        # An any-angle path can beat the 8-connected one by at most the octile factor.
        assert path_length(sm) >= grid_len / OCTILE_MAX - 1e-9
        assert path_length(sm) >= math.dist(s, g) - 1e-9


def test_rrt_is_reproducible_per_seed():
    grid = random_obstacle_field(10.0, 0.1, 0.2, seed=2)
    s, g = grid.free_cells(2, seed=3)
    a = rrt(grid, tuple(s), tuple(g), seed=np.random.default_rng(5))
    b = rrt(grid, tuple(s), tuple(g), seed=np.random.default_rng(5))
    c = rrt(grid, tuple(s), tuple(g), seed=6)
    assert a == b and a is not None and c is not None and a != c


def test_rrt_gives_none_when_walled_off_or_blocked():
    occ = np.zeros((30, 30), bool)
    occ[:, 15] = True
    grid = OccupancyGrid(occ, 0.1)
    assert rrt(grid, (0.5, 1.5), (2.5, 1.5), max_iter=500, seed=0) is None
    assert rrt_cost(grid, (0.5, 1.5), (2.5, 1.5), max_iter=500) == math.inf
    assert rrt(grid, (1.55, 1.5), (2.5, 1.5)) is None                   # start on the wall
    assert rrt_multi(grid, (0.5, 1.5), [(1.0, 1.0), (2.5, 1.5)], max_iter=300)[1] is None


def test_goal_bias_one_drives_straight_at_the_goal():
    grid = OccupancyGrid.empty(10.0, 0.1)
    raw = rrt(grid, (-4.0, 0.0), (4.0, 0.0), goal_bias=1.0, step=0.5, max_iter=20)
    assert raw is not None and len(raw) == 16 + 1
    assert all(y == pytest.approx(0.0) for _, y in raw)


def test_multi_goal_tree_reaches_every_goal():
    grid = random_obstacle_field(15.0, 0.15, 0.15, seed=8)
    pts = grid.free_cells(6, seed=8)
    paths = rrt_multi(grid, tuple(pts[0]), [tuple(p) for p in pts[1:]], seed=2)
    for goal, p in zip(pts[1:], paths):
        assert p is not None and p[0] == tuple(pts[0]) and p[-1] == tuple(goal)
        assert_collision_free(grid, p)


def test_bad_rrt_parameters():
    grid = OccupancyGrid.empty(2.0, 0.1)
    for kwargs in (dict(goal_bias=1.5), dict(step=0.0), dict(max_iter=-1)):
        with pytest.raises(InputError):
            rrt(grid, (0, 0), (0.5, 0.5), **kwargs)


# ---------------------------------------------------------------- smoothing
def test_drop_collinear_and_densify():
    assert drop_collinear([(0, 0), (1, 0), (2, 0), (2, 0), (2, 1)]) == [(0, 0), (2, 0), (2, 1)]
    assert drop_collinear([(0, 0), (1, 0), (0, 0)]) == [(0, 0), (1, 0), (0, 0)]     # a reversal stays
    d = densify([(0, 0), (1, 0)], 0.3)
    assert len(d) == 5 and d[-1] == (1.0, 0.0) and path_length(d) == pytest.approx(1.0)


def test_smoothing_astar_paths_is_shorter_collision_free_and_keeps_ends():
    grid = random_obstacle_field(20.0, 0.2, 0.25, seed=11)
    pts = grid.free_cells(10, seed=11)
    for k in range(5):
        s, g = grid.world_to_cell(*pts[2 * k]), grid.world_to_cell(*pts[2 * k + 1])
        length, cells = astar(grid, s, g)
        xy = [grid.cell_to_world(*c) for c in cells]
        sm = smooth(grid, xy)
        assert sm[0] == xy[0] and sm[-1] == xy[-1]
        assert_collision_free(grid, sm)
        assert path_length(sm) <= length + 1e-9
        assert len(sm) < len(xy) or len(xy) <= 2


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 1000), n=st.integers(2, 12))
def test_shortcut_never_lengthens_or_collides(seed, n):
    rng = np.random.default_rng(seed)
    occ = rng.random((12, 12)) < 0.2
    grid = OccupancyGrid(occ, 1.0)
    # A random walk over free cell centres, each step to an orthogonal free neighbour (collision-free input).
    free = np.argwhere(~occ)
    if len(free) == 0:
        return
    y, x = free[rng.integers(len(free))]
    walk = [(x + 0.5, y + 0.5)]
    for _ in range(n):
        nbrs = [(x + dx, y + dy) for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1))
                if 0 <= x + dx < 12 and 0 <= y + dy < 12 and not occ[y + dy, x + dx]]
        if not nbrs:
            break
        x, y = nbrs[rng.integers(len(nbrs))]
        walk.append((x + 0.5, y + 0.5))
    out = shortcut(grid, walk)
    assert out[0] == walk[0] and out[-1] == walk[-1]
    assert path_length(out) <= path_length(walk) + 1e-9
    assert_collision_free(grid, out)
