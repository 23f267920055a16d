"""Occupancy grid: frames, rasterising worlds (yawed boxes, walls, inflation), random fields, sampling."""
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from runtime.config import Box, WorldConfig
from runtime.errors import InputError
from runtime.planning.grid import OccupancyGrid, random_obstacle_field, random_obstacle_world


def test_world_cell_round_trip_and_centres():
    g = OccupancyGrid(np.zeros((4, 6), bool), 0.5, (-1.5, -1.0))
    assert g.world_to_cell(-1.5, -1.0) == (0, 0)
    assert g.world_to_cell(-1.01, -0.51) == (0, 0)
    assert g.world_to_cell(-1.0, -0.5) == (1, 1)
    assert g.cell_to_world(0, 0) == (-1.25, -0.75)
    assert g.cell_to_world(5, 3) == (1.25, 0.75)
    assert g.size_m == (3.0, 2.0)
    assert not g.is_free(1.6, 0.0)          # outside the grid


@given(x=st.floats(-50, 50), y=st.floats(-50, 50), res=st.sampled_from([0.05, 0.1, 0.25, 1.0]))
def test_cell_contains_its_point(x, y, res):
    g = OccupancyGrid(np.zeros((2, 2), bool), res, (-3.0, 2.0))
    ix, iy = g.world_to_cell(x, y)
    cx, cy = g.cell_to_world(ix, iy)
    assert abs(cx - x) <= res / 2 + 1e-9 and abs(cy - y) <= res / 2 + 1e-9


def test_from_world_box_inflated_by_robot_radius():
    world = WorldConfig(size=(4.0, 4.0), obstacles=(Box(center=(0.0, 0.0), size=(1.0, 0.4)),), walls=False,
                        resolution=0.02)
    bare = OccupancyGrid.from_world(world, inflate=0.0)
    grown = OccupancyGrid.from_world(world, inflate=0.17)
    assert not bare.is_free(0.49, 0.19) and bare.is_free(0.52, 0.0) and bare.is_free(0.0, 0.22)
    # Inflated: blocked within 0.17 m of the box edge, free beyond 0.17 m + a cell.
    assert not grown.is_free(0.5 + 0.16, 0.0) and not grown.is_free(0.0, 0.2 + 0.16)
    assert grown.is_free(0.5 + 0.2, 0.0) and grown.is_free(0.0, 0.2 + 0.2)
    # Corners are rounded: diagonal distance counts.
    assert grown.is_free(0.5 + 0.14, 0.2 + 0.14)          # 0.198 m from the corner
    assert not grown.is_free(0.5 + 0.1, 0.2 + 0.1)         # 0.141 m from the corner
    assert bare.occupied_fraction == pytest.approx(0.4 / 16, rel=0.1)


def test_yawed_box_is_rotated():
    box = Box(center=(1.0, 0.0), size=(2.0, 0.2), yaw=math.pi / 2)     # now 0.2 wide in x, 2 long in y
    g = OccupancyGrid.from_world(WorldConfig(size=(6.0, 6.0), obstacles=(box,), walls=False, resolution=0.05), 0.0)
    assert not g.is_free(1.0, 0.9) and not g.is_free(1.0, -0.9)
    assert g.is_free(1.6, 0.0) and g.is_free(0.4, 0.0)
    diag = Box(center=(0.0, 0.0), size=(2.0, 0.1), yaw=math.pi / 4)
    g2 = OccupancyGrid.from_world(WorldConfig(size=(6.0, 6.0), obstacles=(diag,), walls=False, resolution=0.05), 0.0)
    assert not g2.is_free(0.5, 0.5) and g2.is_free(0.5, -0.5) and g2.is_free(0.9, 0.0)


def test_tiny_box_marks_its_cell_and_boxes_outside_are_clipped():
    world = WorldConfig(size=(2.0, 2.0), walls=False, resolution=0.1,
                        obstacles=(Box(center=(0.33, 0.33), size=(0.02, 0.02)), Box(center=(5.0, 5.0), size=(1, 1)),
                                   Box(center=(1.0, 0.0), size=(0.6, 0.6))))
    g = OccupancyGrid.from_world(world, 0.0)
    assert not g.is_free(0.33, 0.33) and g.is_free(0.5, 0.33)
    assert not g.is_free(0.95, 0.0) and g.is_free(0.65, 0.0)
    assert int(g.occ.sum()) == 1 + 3 * 6


def test_walls_block_the_border_by_the_inflation_radius():
    world = WorldConfig(size=(3.0, 2.0), walls=True, resolution=0.05)
    g = OccupancyGrid.from_world(world, inflate=0.17)
    assert g.shape == (40, 60)
    assert not g.is_free(-1.5 + 0.1, 0.0) and not g.is_free(0.0, 1.0 - 0.15)
    assert g.is_free(-1.5 + 0.23, 0.0) and g.is_free(0.0, 0.0)
    open_world = OccupancyGrid.from_world(WorldConfig(size=(3.0, 2.0), walls=False, resolution=0.05), 0.17)
    assert not open_world.occ.any()


@pytest.mark.parametrize("fraction", [0.05, 0.20, 0.40])
def test_random_field_hits_the_fraction(fraction):
    g = random_obstacle_field(75.0, 0.5, fraction, seed=3)
    assert g.shape == (150, 150)
    assert fraction <= g.occupied_fraction <= fraction + 0.01
    again = random_obstacle_field(75.0, 0.5, fraction, seed=3)
    other = random_obstacle_field(75.0, 0.5, fraction, seed=4)
    assert np.array_equal(g.occ, again.occ) and not np.array_equal(g.occ, other.occ)


def test_random_world_rasterises_to_the_same_field():
    world = random_obstacle_world(20.0, 0.25, 0.2, seed=1, walls=False)
    g = random_obstacle_field(20.0, 0.25, 0.2, seed=1)
    assert np.array_equal(OccupancyGrid.from_world(world, 0.0).occ, g.occ)


def test_free_cells_are_distinct_free_and_mutually_connected():
    from scipy import ndimage
    g = random_obstacle_field(30.0, 0.25, 0.4, seed=2)
    pts = g.free_cells(50, seed=1)
    assert pts.shape == (50, 2)
    assert len({tuple(p) for p in pts}) == 50
    assert all(g.is_free(x, y) for x, y in pts)
    labels, _ = ndimage.label(~g.occ)
    ix, iy = g.world_to_cell(pts[:, 0], pts[:, 1])
    assert len(set(labels[iy, ix])) == 1
    assert np.array_equal(pts, g.free_cells(50, seed=1))
    with pytest.raises(InputError, match="free cells"):
        OccupancyGrid(np.ones((3, 3), bool), 1.0).free_cells(1)


def test_segment_cannot_slip_between_diagonal_corners():
    occ = np.zeros((4, 4), bool)
    occ[1, 2] = occ[2, 1] = True                      # two cells touching at the vertex (2, 2)
    g = OccupancyGrid(occ, 1.0)
    assert not g.segment_free((1.5, 1.5), (2.5, 2.5))  # through the shared corner
    assert g.segment_free((0.5, 0.5), (3.5, 0.5))
    assert not g.segment_free((0.5, 0.5), (3.5, 3.5))
    assert not g.segment_free((0.5, 0.5), (4.5, 0.5))  # leaves the grid
    assert g.segments_free([(0.5, 0.5), (1.5, 1.5)], [(0.5, 3.5), (2.5, 2.5)]).tolist() == [True, False]


@settings(max_examples=150, deadline=None)
@given(seed=st.integers(0, 10_000), p=st.tuples(st.floats(0, 8, exclude_max=True), st.floats(0, 8, exclude_max=True)),
       q=st.tuples(st.floats(0, 8, exclude_max=True), st.floats(0, 8, exclude_max=True)))
def test_segment_free_agrees_with_dense_sampling(seed, p, q):
    occ = np.random.default_rng(seed).random((8, 8)) < 0.15
    g = OccupancyGrid(occ, 1.0)
    t = np.linspace(0, 1, 2001)
    x = np.clip(p[0] + t * (q[0] - p[0]), min(p[0], q[0]), max(p[0], q[0]))
    y = np.clip(p[1] + t * (q[1] - p[1]), min(p[1], q[1]), max(p[1], q[1]))
    sampled_free = not occ[np.floor(y).astype(int), np.floor(x).astype(int)].any()
    if g.segment_free(p, q):
        assert sampled_free            # exact test never misses a cell dense sampling finds
    cx, cy = g.segment_cells(p, q)
    hit = set(zip(cx.tolist(), cy.tolist()))
    assert {(int(a), int(b)) for a, b in zip(np.floor(x), np.floor(y))} <= hit


def test_bad_grids_raise_one_line_errors():
    for bad in (lambda: OccupancyGrid(np.zeros(3, bool), 1.0), lambda: OccupancyGrid(np.zeros((2, 2)), 0.0),
                lambda: OccupancyGrid(np.zeros((2, 2)), 1.0, (math.nan, 0)),
                lambda: random_obstacle_field(10, 0.1, 1.5), lambda: OccupancyGrid.empty(-1, 0.1),
                lambda: OccupancyGrid.empty(10, 0.0), lambda: OccupancyGrid(np.zeros((2, 2)), 1.0).inflate(-1)):
        with pytest.raises(InputError) as exc:
            bad()
        assert "\n" not in str(exc.value)


@settings(max_examples=300, deadline=None)
@given(seed=st.integers(0, 50), on_lines=st.booleans(),
       p=st.tuples(st.floats(-4, 12), st.floats(-4, 12)), q=st.tuples(st.floats(-4, 12), st.floats(-4, 12)))
def test_scalar_and_vectorised_segment_checks_agree(seed, on_lines, p, q):
    g = OccupancyGrid(np.random.default_rng(seed).random((16, 16)) < 0.2, 0.5, (-2.0, -2.0))
    if on_lines:                                   # end points on grid lines and vertices
        p = tuple(round(v * 2) / 2 for v in p)
        q = tuple(round(v * 2) / 2 for v in q)
    assert g.segment_free(p, q) == bool(g.segments_free([p], [q])[0])
