"""A* and the Dijkstra cost table against scipy.sparse.csgraph on an independently built grid graph."""
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.sparse import lil_matrix
from scipy.sparse.csgraph import shortest_path

from runtime.errors import InputError
from runtime.planning.astar import astar, cost_table, path_length, wavefront
from runtime.planning.grid import OccupancyGrid, random_obstacle_field


def reference_distances(occ: np.ndarray, res: float, connectivity: int = 8) -> np.ndarray:
    """All-pairs shortest paths over cells (flat iy * nx + ix), graph built cell by cell in plain Python."""
    ny, nx = occ.shape
    g = lil_matrix((nx * ny, nx * ny))
    moves = [(1, 0), (-1, 0), (0, 1), (0, -1)]
    if connectivity == 8:
        moves += [(1, 1), (1, -1), (-1, 1), (-1, -1)]
    for y in range(ny):
        for x in range(nx):
            if occ[y, x]:
                continue
            for dx, dy in moves:
                u, v = x + dx, y + dy
                if not (0 <= u < nx and 0 <= v < ny) or occ[v, u]:
                    continue
                if dx and dy and (occ[y, u] or occ[v, x]):
                    continue                        # would cut a corner
                g[y * nx + x, v * nx + u] = res * math.hypot(dx, dy)
    return shortest_path(g.tocsr(), method="D", directed=True)


def check_path(grid: OccupancyGrid, cells, start, goal):
    occ = grid.occ
    assert cells[0] == start and cells[-1] == goal
    for (x0, y0), (x1, y1) in zip(cells, cells[1:]):
        assert not occ[y0, x0] and not occ[y1, x1]
        assert max(abs(x1 - x0), abs(y1 - y0)) == 1
        if x1 != x0 and y1 != y0:
            assert not occ[y0, x1] and not occ[y1, x0], "corner cut"


def test_astar_equals_csgraph_on_seeded_random_grids():
    rng = np.random.default_rng(7)
    for trial in range(25):
        ny, nx = rng.integers(5, 16, size=2)
        occ = rng.random((ny, nx)) < rng.uniform(0.0, 0.45)
        res = float(rng.choice([0.05, 0.1, 1.0]))
        grid = OccupancyGrid(occ, res)
        ref = reference_distances(occ, res)
        for _ in range(8):
            s = (int(rng.integers(nx)), int(rng.integers(ny)))
            g = (int(rng.integers(nx)), int(rng.integers(ny)))
            length, cells = astar(grid, s, g)
            expected = ref[s[1] * nx + s[0], g[1] * nx + g[0]]
            if occ[s[1], s[0]] or occ[g[1], g[0]]:
                expected = math.inf
            if math.isinf(expected):
                assert length == math.inf and cells is None
            else:
                assert length == pytest.approx(expected, abs=1e-9)
                check_path(grid, cells, s, g)
                assert path_length(grid, cells) == pytest.approx(length, abs=1e-9)


@settings(max_examples=60, deadline=None)
@given(data=st.data(), ny=st.integers(1, 9), nx=st.integers(1, 9), connectivity=st.sampled_from([4, 8]))
def test_cost_table_and_astar_equal_csgraph(data, ny, nx, connectivity):
    occ = np.array(data.draw(st.lists(st.lists(st.booleans(), min_size=nx, max_size=nx), min_size=ny, max_size=ny)))
    grid = OccupancyGrid(occ, 0.5)
    ref = reference_distances(occ, 0.5, connectivity)
    cell = st.tuples(st.integers(0, nx - 1), st.integers(0, ny - 1))
    sources = data.draw(st.lists(cell, min_size=1, max_size=4))
    targets = data.draw(st.lists(cell, min_size=1, max_size=5))
    table = cost_table(grid, sources, targets, connectivity=connectivity)
    for i, s in enumerate(sources):
        for j, t in enumerate(targets):
            expected = ref[s[1] * nx + s[0], t[1] * nx + t[0]]
            if occ[s[1], s[0]] or occ[t[1], t[0]]:
                expected = math.inf
            assert table[i, j] == pytest.approx(expected, abs=1e-9) if math.isfinite(expected) else \
                table[i, j] == math.inf
            length, cells = astar(grid, s, t, connectivity=connectivity)
            assert (length == table[i, j]) if math.isinf(expected) else length == pytest.approx(expected, abs=1e-9)
            if cells is not None:
                check_path(grid, cells, s, t)
                if connectivity == 4:
                    assert all(a[0] == b[0] or a[1] == b[1] for a, b in zip(cells, cells[1:]))


def test_open_grid_lengths_are_octile():
    grid = OccupancyGrid(np.zeros((20, 30), bool), 0.1)
    length, _ = astar(grid, (0, 0), (29, 10))
    assert length == pytest.approx(0.1 * (19 + 10 * math.sqrt(2)))
    assert cost_table(grid, [(0, 0)], [(29, 10), (0, 19)])[0].tolist() == pytest.approx(
        [0.1 * (19 + 10 * math.sqrt(2)), 1.9])


def test_wall_forces_detour_and_sealed_goal_is_unreachable():
    occ = np.zeros((10, 10), bool)
    occ[:9, 5] = True                                  # wall with a gap at the top row
    grid = OccupancyGrid(occ, 1.0)
    length, cells = astar(grid, (2, 0), (8, 0))
    assert length > 6 + 8                              # must climb to row 9 and back
    assert any(y == 9 for _, y in cells)
    occ[9, 5] = True
    sealed = OccupancyGrid(occ, 1.0)
    assert astar(sealed, (2, 0), (8, 0)) == (math.inf, None)
    assert cost_table(sealed, [(2, 0), (7, 7)], [(8, 0)]).tolist() == [[math.inf], [pytest.approx(6 + math.sqrt(2))]]


def test_cost_table_on_benchmark_sized_field_matches_astar_and_scipy():
    grid = random_obstacle_field(30.0, 0.1, 0.25, seed=5)
    pts = grid.free_cells(12, seed=5)
    cells = [grid.world_to_cell(x, y) for x, y in pts]
    table = cost_table(grid, cells[:5], cells[5:])
    assert table.shape == (5, 7)
    assert np.allclose(table, cost_table(grid, cells[:5], cells[5:], method="scipy"), rtol=0, atol=1e-9)
    assert np.allclose(table.T, cost_table(grid, cells[5:], cells[:5]), rtol=0, atol=1e-9)    # flipped side
    for i in range(3):
        assert astar(grid, cells[i], cells[5 + i])[0] == pytest.approx(table[i, i], abs=1e-9)


def test_wavefront_chunks_give_the_same_lengths():
    grid = random_obstacle_field(6.0, 0.1, 0.3, seed=2)
    free = np.flatnonzero(~grid.occ.ravel())
    src, dst = free[::97][:9], free[::13]
    whole = wavefront(grid, src, dst)
    assert np.array_equal(whole, wavefront(grid, src, dst, max_elements=1))       # one source at a time
    assert whole.shape == (9, len(dst)) and np.isfinite(whole).any()


def test_bad_cells_and_connectivity_raise_input_error():
    grid = OccupancyGrid(np.zeros((3, 3), bool), 1.0)
    with pytest.raises(InputError, match="start cell"):
        astar(grid, (3, 0), (0, 0))
    with pytest.raises(InputError, match="connectivity"):
        cost_table(grid, [(0, 0)], [(1, 1)], connectivity=6)
    assert astar(grid, (1, 1), (1, 1)) == (0.0, [(1, 1)])


def test_benchmark_script_runs_and_reports_agreement(capsys):
    import importlib.util
    import pathlib
    path = pathlib.Path(__file__).resolve().parent.parent / "benchmarks" / "astar_costs.py"
    spec = importlib.util.spec_from_file_location("astar_costs_bench", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    bench.main(["--cells", "40", "--robots", "3", "--tasks", "4", "--repeat", "1", "--check-astar", "3"])
    out = capsys.readouterr().out
    assert "ratio ours/pyastar2d" in out
    assert "lengths agree on all 12 pairs: True" in out
    assert "our A* == our Dijkstra table on 3 sampled pairs: True" in out
